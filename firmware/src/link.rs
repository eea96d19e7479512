//! The link layer: bytes in, checked and sequence-filtered host commands out (acks and NAKs to the
//! outbox); the sequence and session rules are in `docs/firmware.md`.

use crate::outbox::Outbox;
use gonio_shared::frame::FrameDecoder;
use gonio_shared::msg::{DeviceMsg, Hello, HostMsg, NakReason};

/// How far behind the expected sequence number a frame counts as a duplicate (re-ACKed) rather
/// than a gap (NAKed). Larger than any sane number of frames in flight.
pub const DUPLICATE_WINDOW: u16 = 64;

/// Bad frames in a row (no good frame between them) after which the link is not trusted and the
/// controller raises `Fault::BadFrame`: the host cannot reach us, so the scan must not go on
/// unsupervised.
pub const BAD_FRAME_FAULT_RUN: u32 = 16;

/// What one received byte completed.
#[derive(Clone, Debug, PartialEq)]
pub enum Incoming {
    /// A new host command, already acknowledged: execute it.
    Command { seq: u16, msg: HostMsg },
    /// [`BAD_FRAME_FAULT_RUN`] bad frames in a row.
    Untrusted,
}

pub struct Link {
    decoder: FrameDecoder,
    /// Host sequence number expected next.
    expected: u16,
    /// Session id of the `Hello` that opened the current session; `None` before the first.
    session: Option<u32>,
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

    pub fn decoder_stats(&self) -> &gonio_shared::frame::DecoderStats {
        self.decoder.stats()
    }

    /// Frames the decoder dropped since start (for `Status`).
    pub fn bad_frames(&self) -> u32 {
        self.decoder.stats().bad()
    }

    /// Feed one received byte; acks and NAKs go to `out`. The caller keeps room for them
    /// ([`Outbox::can_take_input`]). Not inlined, like `Controller::handle` (`docs/firmware.md`).
    #[inline(never)]
    pub fn push(&mut self, byte: u8, out: &mut Outbox) -> Option<Incoming> {
        match self.decoder.push::<HostMsg>(byte)? {
            Err(e) => {
                self.nak(NakReason::from(e), out);
                self.bad_run = self.bad_run.saturating_add(1);
                (self.bad_run == BAD_FRAME_FAULT_RUN).then_some(Incoming::Untrusted)
            }
            Ok(frame) => {
                self.bad_run = 0;
                self.on_frame(frame.seq, frame.msg, out)
            }
        }
    }

    fn on_frame(&mut self, seq: u16, msg: HostMsg, out: &mut Outbox) -> Option<Incoming> {
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
            out.reply(&DeviceMsg::Ack { seq });
            return Some(Incoming::Command { seq, msg });
        }
        let behind = self.expected.wrapping_sub(seq);
        if behind <= DUPLICATE_WINDOW {
            // Already executed; the host missed our Ack.
            out.reply(&DeviceMsg::Ack { seq });
            if let Some(session) = hello_session {
                // A resent opening Hello: the host may have missed our answer too.
                out.reply(&DeviceMsg::Hello(Hello::ours(session)));
            }
        } else {
            self.nak(NakReason::Sequence, out);
        }
        None
    }

    fn nak(&self, reason: NakReason, out: &mut Outbox) {
        out.reply(&DeviceMsg::Nak {
            expected: self.expected,
            reason,
        });
    }
}
