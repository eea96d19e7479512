//! Encoded frames for the host, in a bounded byte queue the binary drains to USB/UART.
//!
//! Replies to a host frame always fit: the link consumes input only while [`REPLY_RESERVE`] bytes
//! are free, and the controller's own messages ([`Outbox::notify`]) never eat into that reserve. So
//! a host that does not read throttles the firmware instead of making it drop a reply.

use crate::capacity::OUTBOX_BYTES;
use gonio_shared::frame::{encode, MAX_WIRE_FRAME};
use gonio_shared::msg::DeviceMsg;
use heapless::Deque;

/// Frames one host frame can cause: `Ack` plus at most two answers (e.g. `Fault` + `Credit`).
const REPLIES_PER_FRAME: usize = 3;
/// Bytes kept free for the replies to one host frame.
pub const REPLY_RESERVE: usize = REPLIES_PER_FRAME * MAX_WIRE_FRAME;

pub struct Outbox {
    bytes: Deque<u8, OUTBOX_BYTES>,
    /// Sequence number of our next frame.
    tx_seq: u16,
    /// Replies that did not fit (a bug in the reserve arithmetic if ever non-zero).
    lost_replies: u32,
}

impl Default for Outbox {
    fn default() -> Self {
        Self::new()
    }
}

impl Outbox {
    pub const fn new() -> Self {
        Self {
            bytes: Deque::new(),
            tx_seq: 0,
            lost_replies: 0,
        }
    }

    /// Bytes waiting to be drained.
    pub fn pending_bytes(&self) -> usize {
        self.bytes.len()
    }

    pub fn lost_replies(&self) -> u32 {
        self.lost_replies
    }

    /// Room for the replies to one more host frame?
    pub fn can_take_input(&self) -> bool {
        self.free() >= REPLY_RESERVE
    }

    fn free(&self) -> usize {
        OUTBOX_BYTES.saturating_sub(self.bytes.len())
    }

    /// Move up to `out.len()` bytes into `out`; returns how many.
    pub fn drain(&mut self, out: &mut [u8]) -> usize {
        let mut n = 0;
        for slot in out.iter_mut() {
            let Some(b) = self.bytes.pop_front() else { break };
            *slot = b;
            n += 1;
        }
        n
    }

    /// Send an answer to the host frame being handled (room for it was reserved).
    pub fn reply(&mut self, msg: &DeviceMsg) {
        if !self.push_frame(msg, 0) {
            self.lost_replies = self.lost_replies.saturating_add(1);
        }
    }

    /// Send a message of the controller's own (measurement, fault, credit, status) if it fits
    /// without eating into the reply reserve; `false` means "not now, try again later".
    pub fn notify(&mut self, msg: &DeviceMsg) -> bool {
        self.push_frame(msg, REPLY_RESERVE)
    }

    /// Encode `msg` into the queue if it leaves `keep_free` bytes free.
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
            let _ = self.bytes.push_back(b);
        }
        self.tx_seq = self.tx_seq.wrapping_add(1);
        true
    }
}
