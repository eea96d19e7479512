//! What the controller tells the host: its status, plan credit, and the faults, state changes and
//! measurements not yet reported.

use super::Controller;
use crate::outbox::Outbox;
use gonio_shared::msg::caps::CHUNK_DIRECTIONS;
use gonio_shared::msg::{DeviceMsg, Status};

impl Controller {
    pub fn status(&self, bad_frames: u32) -> Status {
        Status {
            state: self.state,
            homed: self.homed,
            plan_next: self.plan.next_index(),
            plan_done: self.plan_done,
            plan_free: if self.streaming() { self.plan.free() } else { 0 },
            unacked: self.measurements.unacked(),
            bad_frames,
            steps: self.stepper.position(),
            last_fault: self.last_fault(),
        }
    }

    pub(super) fn grant_credit(&mut self, out: &mut Outbox) {
        let free = self.plan.free();
        out.reply(&DeviceMsg::Credit {
            next_index: self.plan.next_index(),
            free,
        });
        self.credit_reported = Some(free);
    }

    /// Send what the host has not been told yet, in order of urgency, as far as the outbox allows.
    pub(super) fn report(&mut self, out: &mut Outbox, bad_frames: u32) {
        while let Some(&f) = self.faults_unreported.front() {
            if !out.notify(&DeviceMsg::Fault(f)) {
                return;
            }
            self.faults_unreported.pop_front();
        }
        if self.status_unreported {
            if !out.notify(&DeviceMsg::Status(self.status(bad_frames))) {
                return;
            }
            self.status_unreported = false;
        }
        if self.streaming() {
            let free = self.plan.free();
            // Grant again once a chunk's worth of room opened up (or when forced).
            let due = self
                .credit_reported
                .is_none_or(|c| usize::from(free) >= usize::from(c) + CHUNK_DIRECTIONS);
            if due {
                let credit = DeviceMsg::Credit {
                    next_index: self.plan.next_index(),
                    free,
                };
                if !out.notify(&credit) {
                    return;
                }
                self.credit_reported = Some(free);
            }
        }
        while let Some(m) = self.measurements.to_send() {
            if !out.notify(&DeviceMsg::Measurement(m.clone())) {
                return;
            }
            self.measurements.mark_sent();
        }
    }
}
