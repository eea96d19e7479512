//! Measurements kept until the host acknowledges them, sequence-numbered from 0 without gaps.
//!
//! Each measurement is sent once when it is made; the host acknowledges cumulatively and asks for
//! a resend from a sequence number when it missed one. Nothing is ever dropped: a full buffer makes
//! the controller pause before the next direction ([`MeasurementBuffer::is_full`]).

use crate::capacity::MEASUREMENT_CAPACITY;
use gonio_shared::msg::{Measurement, RefuseReason};
use heapless::Deque;

pub struct MeasurementBuffer {
    kept: Deque<Measurement, MEASUREMENT_CAPACITY>,
    /// Sequence number of the next measurement made.
    next_seq: u32,
    /// Sequence number of the next measurement to transmit (`next_seq` when all are sent).
    send_next: u32,
}

impl Default for MeasurementBuffer {
    fn default() -> Self {
        Self::new()
    }
}

impl MeasurementBuffer {
    pub const fn new() -> Self {
        Self {
            kept: Deque::new(),
            next_seq: 0,
            send_next: 0,
        }
    }

    /// Forget everything and restart at sequence number 0 (a new session: `Configure`).
    pub fn reset(&mut self) {
        self.kept.clear();
        self.next_seq = 0;
        self.send_next = 0;
    }

    pub fn is_full(&self) -> bool {
        self.kept.is_full()
    }

    pub fn unacked(&self) -> u16 {
        u16::try_from(self.kept.len()).unwrap_or(u16::MAX)
    }

    /// Sequence number the next measurement will get.
    pub fn next_seq(&self) -> u32 {
        self.next_seq
    }

    /// Oldest sequence number still kept (`next_seq` when none is).
    pub fn oldest_kept(&self) -> u32 {
        self.kept.front().map_or(self.next_seq, |m| m.seq)
    }

    /// Keep a new measurement; its `seq` is overwritten with the next sequence number. Gives the
    /// measurement back if the buffer is full (the controller checks before measuring, so this is
    /// a fault, never a silent drop). Not inlined: inlined into the scan sequence, the copy into
    /// the ring became a call to `memmove`, which alone is 1.5 KiB of flash.
    #[inline(never)]
    pub fn push(&mut self, mut m: Measurement) -> Result<u32, Measurement> {
        let seq = self.next_seq;
        m.seq = seq;
        self.kept.push_back(m)?;
        self.next_seq = seq.wrapping_add(1);
        Ok(seq)
    }

    /// The next measurement to transmit, if any.
    pub fn to_send(&self) -> Option<&Measurement> {
        let offset = self.send_next.wrapping_sub(self.oldest_kept());
        self.kept.iter().nth(usize::try_from(offset).ok()?)
    }

    /// The measurement returned by [`Self::to_send`] went out.
    pub fn mark_sent(&mut self) {
        if self.send_next != self.next_seq {
            self.send_next = self.send_next.wrapping_add(1);
        }
    }

    /// Forget every measurement with `seq <= through`. Acknowledging one not yet made is refused.
    pub fn ack(&mut self, through: u32) -> Result<(), RefuseReason> {
        if through >= self.next_seq {
            return Err(RefuseReason::OutOfOrder {
                expected: self.next_seq,
            });
        }
        while self.kept.front().is_some_and(|m| m.seq <= through) {
            self.kept.pop_front();
        }
        // Acknowledged means received: no need to send those again.
        if self.send_next < self.oldest_kept() {
            self.send_next = self.oldest_kept();
        }
        Ok(())
    }

    /// Send every kept measurement from `from` on again.
    pub fn resend(&mut self, from: u32) -> Result<(), RefuseReason> {
        let oldest_kept = self.oldest_kept();
        if from < oldest_kept {
            return Err(RefuseReason::Forgotten { oldest_kept });
        }
        if from > self.next_seq {
            return Err(RefuseReason::OutOfOrder {
                expected: self.next_seq,
            });
        }
        self.send_next = from;
        Ok(())
    }
}
