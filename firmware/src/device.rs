//! The whole firmware behind one value: the link, the controller and the outbox, wired together.
//!
//! The binary (or a test, or the virtual gonio) owns a [`Device`] and a HAL and calls, in any order:
//! [`Device::receive`] with bytes from the host, [`Device::poll`] whenever
//! [`Device::next_deadline_us`] has passed or anything was received, and [`Device::drain_outbox`]
//! to get bytes for the host. Nothing here blocks, allocates or panics.

use crate::controller::Controller;
use crate::hal::Hal;
use crate::link::{Incoming, Link};
use crate::outbox::Outbox;

#[derive(Default)]
pub struct Device {
    link: Link,
    controller: Controller,
    outbox: Outbox,
}

impl Device {
    pub const fn new() -> Self {
        Self {
            link: Link::new(),
            controller: Controller::new(),
            outbox: Outbox::new(),
        }
    }

    /// Feed bytes from the host; returns how many were consumed (all of them unless the outbox
    /// is too full to answer: drain it and offer the rest again).
    pub fn receive<H: Hal>(&mut self, hal: &mut H, bytes: &[u8]) -> usize {
        for (consumed, &byte) in bytes.iter().enumerate() {
            if !self.outbox.can_take_input() {
                return consumed;
            }
            match self.link.push(byte, &mut self.outbox) {
                None => {}
                Some(Incoming::Command { seq, msg }) => {
                    let bad_frames = self.link.bad_frames();
                    self.controller.handle(seq, msg, hal, &mut self.outbox, bad_frames);
                }
                Some(Incoming::Untrusted) => self.controller.link_untrusted(hal),
            }
        }
        bytes.len()
    }

    /// Step, home, scan and report whatever is due now.
    pub fn poll<H: Hal>(&mut self, hal: &mut H) {
        let bad_frames = self.link.bad_frames();
        self.controller.poll(hal, &mut self.outbox, bad_frames);
    }

    /// Move outgoing bytes into `out`; returns how many.
    pub fn drain_outbox(&mut self, out: &mut [u8]) -> usize {
        self.outbox.drain(out)
    }

    /// Forget a partly received frame, e.g. when the USB host reconnects: its tail will never come,
    /// and the next session's first frame must not be glued to it.
    pub fn reset_link_decoder(&mut self) {
        self.link.reset_decoder();
    }

    /// When `poll` next has work; `None` when only the host can make progress.
    pub fn next_deadline_us(&self) -> Option<u64> {
        self.controller.next_deadline_us()
    }

    /// Switches whose closing must stop all motion at once (bit per `Axis::index`): what the
    /// controller itself stops on, for a board that stops its step timer in the switch interrupt.
    pub fn stop_mask(&self) -> u8 {
        self.controller.stop_mask()
    }

    /// Would a trip of these switches (from `stop_mask`) halt a move the controller has not
    /// stopped yet? Then steps queued since the trip belong to that move.
    pub fn halts_on(&self, closed: u8) -> bool {
        self.controller.halts_on(closed)
    }

    /// The board stopped every axis because these switches closed: react as to the switch found
    /// by polling (homing: that is the home position; otherwise `Fault::LimitSwitch`).
    pub fn limit_tripped<H: Hal>(&mut self, hal: &mut H, closed: u8) {
        self.controller.limit_tripped(hal, closed);
    }

    /// The board's loop runs at real time `real_us`: a move whose queued steps ran dry before it
    /// came back is a `Fault::StepsLate`.
    pub fn check_steps_on_time<H: Hal>(&mut self, hal: &mut H, real_us: u64) {
        self.controller.check_steps_on_time(hal, real_us);
    }

    /// See [`Controller::set_host_silent_us`].
    pub fn set_host_silent_us(&mut self, us: u64) {
        self.controller.set_host_silent_us(us);
    }

    pub fn controller(&self) -> &Controller {
        &self.controller
    }

    pub fn link(&self) -> &Link {
        &self.link
    }

    pub fn outbox(&self) -> &Outbox {
        &self.outbox
    }
}
