//! Plan streaming as a state machine without a transport: the driver (`Link::scan`) feeds it what
//! the device said (`on_credit`, `on_measurement`, `on_status`, `on_refused`) and the passing of
//! time, and sends what it asks for. It streams the plan in chunks under the device's credit,
//! ends and starts it, takes measurements in sequence order, acknowledges them, and asks for
//! resends on gaps and for status on silences and lost grants.

use super::error::LinkError;
use super::reliable::{LinkTiming, WINDOW};
use gonio_shared::msg::caps::CHUNK_DIRECTIONS;
use gonio_shared::msg::{
    Command, ControllerState, Direction, Fault, HostMsg, Measurement, PlanChunk, RefuseReason, Status,
};
use std::collections::VecDeque;
use std::time::Instant;

/// Status answers in a row showing a device out of plan that grants no credit, before the scan
/// gives up (about 10 s at the idle poll interval).
const STARVED_STATUS_LIMIT: u32 = 25;

/// Acknowledge measurements at least every this many. Each acknowledgement costs a journal sync
/// (fsync); 32 keeps the firmware's 128-slot buffer at most a quarter full in steady streaming.
const ACK_EVERY: u32 = 32;

/// What to do with a measurement that arrived.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reading {
    /// The next in sequence: hand it to the sink.
    Record,
    /// Already taken (a resent or duplicated copy).
    Duplicate,
    /// After a gap: ask the device to send again from `from`.
    Resend { from: u32 },
    /// After a gap already asked about: wait for the resend.
    Early,
}

/// Why a status ends the stream.
#[derive(Debug)]
pub enum Stop {
    /// The device is in its fault state (with the fault it names, if any).
    Fault(Option<Fault>),
    Error(LinkError),
}

/// The plan conversation of one connection.
pub struct PlanStream<'a> {
    plan: &'a [Direction],
    total: u32,
    timing: LinkTiming,
    /// The device takes plan indices below this.
    credit_limit: u32,
    /// The first plan index not yet sent.
    next_send: u32,
    end_sent: bool,
    started: bool,
    /// The sequence number of the next measurement expected (= measurements taken).
    next_reading: u32,
    /// Measurements acknowledged (count).
    acked: u32,
    /// The resend asked for last: from which measurement, and when.
    resend_at: Option<(u32, Instant)>,
    last_activity: Instant,
    /// A status asked for after a silence: only its answer can reveal lost measurements (an
    /// unsolicited status may overtake readings that are merely still on their way).
    probing: bool,
    /// Sequence numbers of our Start and of the plan chunks in flight (with their first index),
    /// to match a `Refused` to the frame it answers.
    start_seq: Option<u16>,
    chunk_seqs: VecDeque<(u16, u32)>,
    /// Refusals of frames sent before this sequence number are stale: the plan was rewound since.
    epoch: u16,
    /// When the plan credit last grew (or was last asked for).
    last_grant: Instant,
    starved_statuses: u32,
}

impl<'a> PlanStream<'a> {
    /// A stream of `plan` (indices 0..len on the wire) whose first frame goes with `first_seq`.
    pub fn new(plan: &'a [Direction], first_seq: u16, timing: LinkTiming, now: Instant) -> Result<Self, LinkError> {
        let total = u32::try_from(plan.len()).map_err(|_| LinkError::PlanTooLong(plan.len()))?;
        Ok(Self {
            plan,
            total,
            timing,
            credit_limit: 0,
            next_send: 0,
            end_sent: false,
            started: false,
            next_reading: 0,
            acked: 0,
            resend_at: None,
            last_activity: now,
            probing: false,
            start_seq: None,
            chunk_seqs: VecDeque::new(),
            epoch: first_seq,
            // The configuration's grant went to `prepare`: ask for the current one at once.
            last_grant: now.checked_sub(timing.idle).unwrap_or(now),
            starved_statuses: 0,
        })
    }

    /// Measurements taken in order so far.
    pub fn received(&self) -> u32 {
        self.next_reading
    }

    /// Every measurement of the plan taken.
    pub fn is_complete(&self) -> bool {
        self.next_reading == self.total
    }

    /// Length of the next chunk to send (0 when everything is sent).
    fn next_len(&self) -> u32 {
        (self.total - self.next_send).min(CHUNK_DIRECTIONS as u32)
    }

    /// The next chunk does not fit the credit.
    fn credit_starved(&self) -> bool {
        let len = self.next_len();
        len > 0 && self.next_send + len > self.credit_limit
    }

    /// The next plan frame due, if any: a chunk within the credit, then `PlanEnd`, then `Start`.
    /// Tell [`sent`](Self::sent) the sequence number it went with.
    pub fn next_frame(&mut self) -> Result<Option<HostMsg>, LinkError> {
        if self.next_send < self.total && !self.credit_starved() {
            let len = self.next_len();
            let lo = self.next_send as usize;
            let dirs = self.plan.get(lo..lo + len as usize).unwrap_or(&[]);
            let directions = heapless::Vec::from_slice(dirs)
                .map_err(|_| LinkError::Encode(format!("a plan chunk of {len} directions")))?;
            let chunk = PlanChunk {
                first_index: self.next_send,
                directions,
            };
            self.next_send += len;
            return Ok(Some(HostMsg::Plan(chunk)));
        }
        if self.next_send == self.total && !self.end_sent {
            self.end_sent = true;
            return Ok(Some(HostMsg::PlanEnd { total: self.total }));
        }
        if !self.started && self.next_send > 0 {
            self.started = true;
            return Ok(Some(HostMsg::Start));
        }
        Ok(None)
    }

    /// `msg` (from [`next_frame`](Self::next_frame)) went with sequence number `seq`.
    pub fn sent(&mut self, msg: &HostMsg, seq: u16) {
        match msg {
            HostMsg::Plan(chunk) => {
                if self.chunk_seqs.len() >= 2 * WINDOW {
                    self.chunk_seqs.pop_front();
                }
                self.chunk_seqs.push_back((seq, chunk.first_index));
            }
            HostMsg::Start => self.start_seq = Some(seq),
            _ => {}
        }
    }

    /// A plan grant: the device takes indices below `next_index + free`.
    pub fn on_credit(&mut self, next_index: u32, free: u16, now: Instant) {
        let limit = next_index.saturating_add(u32::from(free));
        if limit > self.credit_limit {
            self.credit_limit = limit;
            self.last_grant = now;
        }
    }

    /// May a resend be asked for now (none asked, or the last one long enough ago)?
    fn resend_allowed(&self, now: Instant) -> bool {
        self.resend_at
            .is_none_or(|(_, t)| now.saturating_duration_since(t) >= self.timing.rto * 2)
    }

    fn ask_resend(&mut self, now: Instant) -> u32 {
        self.resend_at = Some((self.next_reading, now));
        self.next_reading
    }

    /// A measurement arrived.
    pub fn on_measurement(&mut self, m: &Measurement, now: Instant) -> Result<Reading, LinkError> {
        if m.seq == self.next_reading {
            if m.index >= self.total {
                return Err(LinkError::OutOfPlan {
                    index: m.index,
                    total: self.total,
                });
            }
            self.next_reading += 1;
            if self.resend_at.is_some_and(|(from, _)| self.next_reading > from) {
                self.resend_at = None;
            }
            Ok(Reading::Record)
        } else if m.seq < self.next_reading {
            Ok(Reading::Duplicate)
        } else if self.resend_allowed(now) {
            // A gap: the device keeps everything unacknowledged; ask from the hole.
            Ok(Reading::Resend {
                from: self.ask_resend(now),
            })
        } else {
            Ok(Reading::Early)
        }
    }

    /// A status arrived; returns what to send in answer (a `Start` again, a resend request).
    pub fn on_status(&mut self, s: &Status, now: Instant) -> Result<Vec<HostMsg>, Stop> {
        // The same grant as a Credit: recovers from a lost one (see `DeviceMsg::Credit`).
        self.on_credit(s.plan_next, s.plan_free, now);
        // Deadlock watch: the device has run out of plan (everything it took is measured), we
        // have sent everything it granted, and its status grants nothing more. Never so with a
        // working device; a bounded number of such answers in a row is an error, not a hang.
        let starved = self.credit_starved()
            && s.plan_next == self.next_send
            && s.plan_done >= s.plan_next
            && matches!(s.state, ControllerState::Running | ControllerState::Ready);
        self.starved_statuses = if starved { self.starved_statuses + 1 } else { 0 };
        if self.starved_statuses > STARVED_STATUS_LIMIT {
            return Err(Stop::Error(LinkError::Stalled(format!(
                "the device ran out of plan at direction {} of {} and grants no credit",
                self.next_send, self.total
            ))));
        }
        if s.state == ControllerState::Fault {
            return Err(Stop::Fault(s.last_fault));
        }
        if s.state == ControllerState::Idle && !s.homed {
            return Err(Stop::Error(LinkError::Disconnected(
                "the device restarted mid-scan".into(),
            )));
        }
        let mut replies = Vec::new();
        if s.state == ControllerState::Ready && self.started && self.next_reading < self.total {
            // Our Start was refused or lost (e.g. sent before the plan reached it).
            replies.push(HostMsg::Start);
        }
        // We never pause a scan: a device paused with room for readings held because it heard
        // nothing from us for a while (`HOST_SILENT_US`); we are back, so it may go on. (A full
        // buffer resumes by itself once our acknowledgements free it.)
        let room = usize::from(s.unacked) < gonio_firmware::capacity::MEASUREMENT_CAPACITY;
        if s.state == ControllerState::Paused && room && self.started && self.next_reading < self.total {
            replies.push(HostMsg::Resume);
        }
        if std::mem::take(&mut self.probing) && s.plan_done > self.next_reading && self.resend_allowed(now) {
            replies.push(HostMsg::ResendMeasurements {
                from: self.ask_resend(now),
            });
        }
        Ok(replies)
    }

    /// A status read while every frame we sent is acknowledged (`next_seq`: our next frame's
    /// sequence number). A device that ran out of plan short of what we sent refused a chunk and
    /// the refusal was lost (a lossy link): go back to where it stands, as the refusal would have.
    /// Only a starved device counts: a status that overtook our last chunks' Acks shows an older
    /// `plan_next`, but then the device still has plan to measure.
    pub fn on_settled_status(&mut self, s: &Status, next_seq: u16) {
        let starved =
            s.plan_done >= s.plan_next && matches!(s.state, ControllerState::Running | ControllerState::Ready);
        if starved && s.plan_next < self.next_send {
            self.next_send = s.plan_next;
            self.epoch = next_seq;
        }
    }

    /// The device refused frame `seq`; `next_seq` is the sequence number our next frame goes
    /// with. Returns a status request to send if the window has room.
    pub fn on_refused(
        &mut self,
        seq: u16,
        command: Command,
        reason: RefuseReason,
        next_seq: u16,
    ) -> Result<Option<HostMsg>, LinkError> {
        if let RefuseReason::BadConfig(_) | RefuseReason::NotConfigured | RefuseReason::NoHandshake = reason {
            return Err(LinkError::Refused {
                what: "a scan command",
                reason,
            });
        }
        let since_epoch = seq.wrapping_sub(self.epoch) < 0x8000;
        let chunk_first = self.chunk_seqs.iter().find(|(s, _)| *s == seq).map(|&(_, first)| first);
        let ours_start = self.start_seq == Some(seq);
        match (command, reason, chunk_first) {
            // A chunk the device did not take: every later chunk in flight is refused too (out of
            // order). Go back to where the device stands, once.
            (Command::Plan, RefuseReason::OutOfOrder { expected }, Some(_))
                if since_epoch && expected < self.next_send =>
            {
                self.next_send = expected;
                self.epoch = next_seq;
            }
            (Command::Plan, RefuseReason::NoCredit, Some(first)) if since_epoch && first < self.next_send => {
                // Our idea of the credit was wrong: wait for a fresh grant.
                self.next_send = first;
                self.credit_limit = first;
                self.epoch = next_seq;
            }
            (Command::Start, RefuseReason::NotHomed, _) if ours_start => {
                return Err(LinkError::Refused {
                    what: "the scan's Start",
                    reason,
                });
            }
            // E.g. a move still winding down: the status answer says when Ready (and
            // `on_status` starts again).
            (Command::Start, _, _) if ours_start => return Ok(Some(HostMsg::GetStatus)),
            _ => {}
        }
        Ok(None)
    }

    /// A message arrived at `now`.
    pub fn on_activity(&mut self, now: Instant) {
        self.last_activity = now;
    }

    /// The acknowledgement due now, if any (`quiet`: the last wait brought no message): every
    /// [`ACK_EVERY`] measurements, on a quiet moment, and at the end. The caller syncs its sink
    /// before sending it.
    pub fn ack_due(&mut self, quiet: bool) -> Option<HostMsg> {
        let unacked = self.next_reading - self.acked;
        if unacked > 0 && (unacked >= ACK_EVERY || quiet || self.is_complete()) {
            self.acked = self.next_reading;
            return Some(HostMsg::AckMeasurements {
                through: self.next_reading - 1,
            });
        }
        None
    }

    /// A status request due now, if any: waiting for room while measurements still flow (so
    /// never quiet), a `Credit` may have been lost; when quiet, a Credit, Measurement or Status
    /// may have been. The answer carries the plan credit too (`Status::plan_free`).
    pub fn status_due(&mut self, now: Instant) -> Option<HostMsg> {
        if self.credit_starved() && now.saturating_duration_since(self.last_grant) >= self.timing.idle {
            self.last_grant = now;
            return Some(HostMsg::GetStatus);
        }
        None
    }

    /// A status request after a silence, if one is due: its answer may show lost measurements.
    pub fn probe_due(&mut self, now: Instant) -> Option<HostMsg> {
        if now.saturating_duration_since(self.last_activity) >= self.timing.idle {
            self.probing = true;
            self.last_activity = now;
            return Some(HostMsg::GetStatus);
        }
        None
    }
}

#[cfg(test)]
mod tests;
