//! The link layer: bytes in, checked host frames to the controller, encoded device frames out.
//!
//! - Every byte goes through the shared [`FrameDecoder`]; a bad frame is answered with a `Nak`
//!   carrying the sequence number the link expects next, so the host resends from there.
//! - Host sequence numbers: the expected one is executed and acknowledged; a recent one (a resend
//!   whose `Ack` was lost) is acknowledged again but not executed; anything else is a gap and is
//!   NAKed. `Hello` with sequence number 0 and a session id other than the current session's opens
//!   a new session (the count restarts at 1); every other `Hello` obeys the rules above like any
//!   frame, and a duplicate of the opening one is answered again (see `msg::Hello`). So a late,
//!   duplicated or reordered `Hello` never restarts the count mid-session, and a resent frame is
//!   never executed twice.
//! - Output frames go into a bounded byte outbox that the binary drains to USB/UART. Input is only
//!   consumed while the outbox has room for the worst-case replies to one frame, so a host that
//!   does not read cannot make the firmware drop a reply: it is throttled instead.

use crate::capacity::OUTBOX_BYTES;
use crate::controller::Controller;
use crate::hal::Hal;
use gonio_shared::frame::{encode, FrameDecoder, MAX_WIRE_FRAME};
use gonio_shared::msg::{DeviceMsg, Hello, HostMsg, NakReason};
use heapless::Deque;

/// How far behind the expected sequence number a frame counts as a duplicate (re-ACKed) rather
/// than a gap (NAKed). Larger than any sane number of frames in flight.
pub const DUPLICATE_WINDOW: u16 = 64;

/// Bad frames in a row (no good frame between them) after which the link is not trusted and the
/// controller raises `Fault::BadFrame`. A burst of line noise or a cable unplugged mid-frame costs a
/// few; 16 in a row means the host cannot reach us, so the scan must not go on unsupervised.
pub const BAD_FRAME_FAULT_RUN: u32 = 16;

/// Frames one host frame can cause: `Ack` plus at most two answers (e.g. `Fault` + `Credit`).
const REPLIES_PER_FRAME: usize = 3;
const REPLY_RESERVE: usize = REPLIES_PER_FRAME * MAX_WIRE_FRAME;

/// Where the controller's messages go.
pub trait Outbox {
    /// Send an answer to the host frame being handled (the link reserved room for it).
    fn reply(&mut self, msg: &DeviceMsg);
    /// Send a message of the controller's own (measurement, fault, credit, status) if it fits
    /// without eating into the reply reserve; `false` means "not now, try again later".
    fn notify(&mut self, msg: &DeviceMsg) -> bool;
    /// Frames the decoder dropped since start (for `Status`).
    fn bad_frames(&self) -> u32;
}

pub struct Link {
    decoder: FrameDecoder,
    /// Host sequence number expected next.
    expected: u16,
    /// Session id of the `Hello` that opened the current session; `None` before the first.
    session: Option<u32>,
    /// Sequence number of our next frame.
    tx_seq: u16,
    outbox: Deque<u8, OUTBOX_BYTES>,
    /// Replies that did not fit (a bug in the reserve arithmetic if ever non-zero).
    lost_replies: u32,
    /// Bad frames since the last good one.
    bad_run: u32,
}

impl Default for Link {
    fn default() -> Self {
        Self::new()
    }
}

impl Link {
    pub const fn new() -> Self {
        Self {
            decoder: FrameDecoder::new(),
            expected: 0,
            session: None,
            tx_seq: 0,
            outbox: Deque::new(),
            lost_replies: 0,
            bad_run: 0,
        }
    }

    /// Forget a partial frame (the host reconnected).
    pub fn reset_decoder(&mut self) {
        self.decoder.reset();
    }

    pub fn expected_seq(&self) -> u16 {
        self.expected
    }

    pub fn lost_replies(&self) -> u32 {
        self.lost_replies
    }

    pub fn decoder_stats(&self) -> &gonio_shared::frame::DecoderStats {
        self.decoder.stats()
    }

    /// Bytes waiting in the outbox.
    pub fn pending_bytes(&self) -> usize {
        self.outbox.len()
    }

    fn free(&self) -> usize {
        OUTBOX_BYTES.saturating_sub(self.outbox.len())
    }

    /// Move up to `out.len()` outbox bytes into `out`; returns how many.
    pub fn drain(&mut self, out: &mut [u8]) -> usize {
        let mut n = 0;
        for slot in out.iter_mut() {
            let Some(b) = self.outbox.pop_front() else { break };
            *slot = b;
            n += 1;
        }
        n
    }

    /// Feed received bytes. Returns how many were consumed: fewer than `bytes.len()` when the
    /// outbox is too full to answer; the caller drains it and offers the rest again.
    pub fn receive<H: Hal>(&mut self, bytes: &[u8], controller: &mut Controller, hal: &mut H) -> usize {
        for (consumed, &byte) in bytes.iter().enumerate() {
            if self.free() < REPLY_RESERVE {
                return consumed;
            }
            match self.decoder.push::<HostMsg>(byte) {
                None => {}
                Some(Err(e)) => {
                    self.nak(e.nak_reason());
                    self.bad_run = self.bad_run.saturating_add(1);
                    if self.bad_run == BAD_FRAME_FAULT_RUN {
                        controller.link_untrusted();
                    }
                }
                Some(Ok(frame)) => {
                    self.bad_run = 0;
                    self.on_frame(frame.seq, frame.msg, controller, hal);
                }
            }
        }
        bytes.len()
    }

    fn on_frame<H: Hal>(&mut self, seq: u16, msg: HostMsg, controller: &mut Controller, hal: &mut H) {
        let hello_session = match &msg {
            HostMsg::Hello(h) if seq == 0 => Some(h.session),
            _ => None,
        };
        let new_session = hello_session.is_some_and(|s| self.session != Some(s));
        if new_session {
            self.session = hello_session;
        }
        if new_session || seq == self.expected {
            self.expected = seq.wrapping_add(1);
            self.reply(&DeviceMsg::Ack { seq });
            controller.handle(seq, msg, hal, self);
            return;
        }
        let behind = self.expected.wrapping_sub(seq);
        if behind <= DUPLICATE_WINDOW {
            // Already executed; the host missed our Ack.
            self.reply(&DeviceMsg::Ack { seq });
            if let Some(session) = hello_session {
                // A resent opening Hello: the host may have missed our answer too.
                self.reply(&DeviceMsg::Hello(Hello::ours(session)));
            }
        } else {
            self.nak(NakReason::Sequence);
        }
    }

    fn nak(&mut self, reason: NakReason) {
        let expected = self.expected;
        self.reply(&DeviceMsg::Nak { expected, reason });
    }

    /// Encode `msg` into the outbox if it leaves `keep_free` bytes free.
    fn push_frame(&mut self, msg: &DeviceMsg, keep_free: usize) -> bool {
        let mut frame = [0u8; MAX_WIRE_FRAME];
        let Ok(n) = encode(self.tx_seq, msg, &mut frame) else {
            return false;
        };
        if self.free() < n.saturating_add(keep_free) {
            return false;
        }
        for &b in frame.get(..n).unwrap_or(&[]) {
            // Cannot fail: room was checked above.
            let _ = self.outbox.push_back(b);
        }
        self.tx_seq = self.tx_seq.wrapping_add(1);
        true
    }
}

impl Outbox for Link {
    fn reply(&mut self, msg: &DeviceMsg) {
        if !self.push_frame(msg, 0) {
            self.lost_replies = self.lost_replies.saturating_add(1);
        }
    }

    fn notify(&mut self, msg: &DeviceMsg) -> bool {
        self.push_frame(msg, REPLY_RESERVE)
    }

    fn bad_frames(&self) -> u32 {
        self.decoder.stats().bad()
    }
}
