//! The reliability layer (Klipper's serialqueue): frames with sequence numbers, a window of frames
//! in flight, acknowledged cumulatively, resent from the one the device expects on a NAK
//! (go-back-N) or when the oldest waited longer than the retransmit timeout; device frames decoded
//! and queued for the layer above, with a silent device reported as lost.

use super::error::LinkError;
use super::transport::Transport;
use gonio_shared::frame::{encode, FrameDecoder, MAX_WIRE_FRAME};
use gonio_shared::msg::{DeviceMsg, HostMsg};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Frames sent and not yet acknowledged, at most.
pub const WINDOW: usize = 16;

/// Timing of the link, wall time.
#[derive(Clone, Copy, Debug)]
pub struct LinkTiming {
    pub hello_timeout: Duration,
    /// Resend the oldest unacknowledged frame after this.
    pub rto: Duration,
    /// Ask for status after this long without any message from the device.
    pub idle: Duration,
    /// Give up (connection lost) after this long without any frame from the device.
    pub silence: Duration,
    /// Longest homing, wall time.
    pub homing: Duration,
}

impl Default for LinkTiming {
    fn default() -> Self {
        Self {
            hello_timeout: Duration::from_secs(2),
            rto: Duration::from_millis(150),
            idle: Duration::from_millis(400),
            silence: Duration::from_secs(5),
            homing: Duration::from_secs(600),
        }
    }
}

/// What the link did, for reports and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    pub frames_sent: u64,
    pub retransmits: u64,
    pub naks: u64,
    pub timeouts: u64,
    pub bad_frames_in: u64,
    pub duplicate_measurements: u64,
    pub resend_requests: u64,
    pub status_requests: u64,
}

impl LinkStats {
    /// Add another connection's counters to these.
    pub fn add(&mut self, b: &LinkStats) {
        self.frames_sent += b.frames_sent;
        self.retransmits += b.retransmits;
        self.naks += b.naks;
        self.timeouts += b.timeouts;
        self.bad_frames_in += b.bad_frames_in;
        self.duplicate_measurements += b.duplicate_measurements;
        self.resend_requests += b.resend_requests;
        self.status_requests += b.status_requests;
    }
}

/// One transport with sequence numbers, a send window and retransmission.
pub struct Reliable<T: Transport> {
    t: T,
    dec: FrameDecoder,
    tx_seq: u16,
    inflight: VecDeque<(u16, Vec<u8>)>,
    oldest_sent: Instant,
    last_nak: Option<(u16, Instant)>,
    rx: VecDeque<DeviceMsg>,
    last_rx: Instant,
    pub timing: LinkTiming,
    pub stats: LinkStats,
}

fn io(e: std::io::Error) -> LinkError {
    LinkError::Disconnected(e.to_string())
}

impl<T: Transport> Reliable<T> {
    pub fn new(t: T, timing: LinkTiming) -> Self {
        Self {
            t,
            dec: FrameDecoder::new(),
            tx_seq: 0,
            inflight: VecDeque::new(),
            oldest_sent: Instant::now(),
            last_nak: None,
            rx: VecDeque::new(),
            last_rx: Instant::now(),
            timing,
            stats: LinkStats::default(),
        }
    }

    pub fn into_inner(self) -> T {
        self.t
    }

    /// Forget every frame in flight and number the next one 0 (a Hello opens a new session).
    pub fn restart_numbering(&mut self) {
        self.inflight.clear();
        self.tx_seq = 0;
    }

    /// Forget every frame in flight without waiting for its Ack (the device showed it has them).
    pub fn forget_inflight(&mut self) {
        self.inflight.clear();
    }

    /// Drop every device message queued and not yet taken.
    pub fn clear_queued(&mut self) {
        self.rx.clear();
    }

    /// Queue `msg` with the next sequence number (waits while the window is full); returns the
    /// sequence number it went with (named by a `Refused` answering it).
    pub fn send(&mut self, msg: &HostMsg) -> Result<u16, LinkError> {
        while self.inflight.len() >= WINDOW {
            self.pump(Duration::from_millis(10))?;
        }
        let mut buf = [0u8; MAX_WIRE_FRAME];
        let n =
            encode(self.tx_seq, msg, &mut buf).map_err(|e| LinkError::Encode(format!("cannot encode {msg:?}: {e}")))?;
        let frame = buf.get(..n).unwrap_or(&[]).to_vec();
        self.t.write_all(&frame).map_err(io)?;
        self.stats.frames_sent += 1;
        if self.inflight.is_empty() {
            self.oldest_sent = Instant::now();
        }
        let seq = self.tx_seq;
        self.inflight.push_back((seq, frame));
        self.tx_seq = seq.wrapping_add(1);
        Ok(seq)
    }

    /// The sequence number the next frame will go with.
    pub fn next_seq(&self) -> u16 {
        self.tx_seq
    }

    /// Every frame sent has been acknowledged (the device has executed them all).
    pub fn all_acked(&self) -> bool {
        self.inflight.is_empty()
    }

    pub fn window_free(&self) -> bool {
        self.inflight.len() < WINDOW
    }

    fn resend_from(&mut self, from: Option<u16>) -> Result<(), LinkError> {
        let mut bytes = Vec::new();
        for (seq, f) in &self.inflight {
            // Frames before `from` were executed; only the rest go again.
            if from.is_none_or(|s| seq.wrapping_sub(s) < 0x8000) {
                bytes.extend_from_slice(f);
                self.stats.retransmits += 1;
            }
        }
        if !bytes.is_empty() {
            // A leading delimiter ends any partial frame the device holds.
            let mut out = vec![0u8];
            out.extend_from_slice(&bytes);
            self.t.write_all(&out).map_err(io)?;
        }
        self.oldest_sent = Instant::now();
        Ok(())
    }

    /// Read what arrived within `timeout`, handle Acks and NAKs, queue the rest; retransmit on
    /// timeout. Fails when the device has been silent for `timing.silence`.
    pub fn pump(&mut self, timeout: Duration) -> Result<(), LinkError> {
        let mut buf = [0u8; 1024];
        let n = self.t.read(&mut buf, timeout).map_err(io)?;
        for &b in buf.get(..n).unwrap_or(&[]) {
            match self.dec.push::<DeviceMsg>(b) {
                None => {}
                Some(Err(_)) => self.stats.bad_frames_in += 1,
                Some(Ok(frame)) => {
                    self.last_rx = Instant::now();
                    self.on_msg(frame.msg)?;
                }
            }
        }
        if !self.inflight.is_empty() && self.oldest_sent.elapsed() >= self.timing.rto {
            self.stats.timeouts += 1;
            self.resend_from(None)?;
        }
        if self.last_rx.elapsed() >= self.timing.silence {
            return Err(LinkError::Silent(format!(
                "nothing received for {:.1} s",
                self.timing.silence.as_secs_f64()
            )));
        }
        Ok(())
    }

    fn on_msg(&mut self, msg: DeviceMsg) -> Result<(), LinkError> {
        match msg {
            DeviceMsg::Ack { seq } => {
                let before = self.inflight.len();
                // The device executes in order: an Ack covers every frame up to it.
                while self
                    .inflight
                    .front()
                    .is_some_and(|(s, _)| seq.wrapping_sub(*s) < 0x8000)
                {
                    self.inflight.pop_front();
                }
                if self.inflight.len() != before {
                    self.oldest_sent = Instant::now();
                }
            }
            DeviceMsg::Nak { expected, .. } => {
                self.stats.naks += 1;
                // Every frame after a lost one is NAKed with the same `expected`: go back once
                // per retransmit timeout, not once per NAK.
                let recent = self
                    .last_nak
                    .is_some_and(|(e, t)| e == expected && t.elapsed() < self.timing.rto);
                if !recent {
                    self.last_nak = Some((expected, Instant::now()));
                    self.resend_from(Some(expected))?;
                }
            }
            other => self.rx.push_back(other),
        }
        Ok(())
    }

    /// The oldest queued device message, without reading.
    pub fn take_queued(&mut self) -> Option<DeviceMsg> {
        self.rx.pop_front()
    }

    /// The next queued device message, reading for up to `timeout`.
    pub fn next_msg(&mut self, timeout: Duration) -> Result<Option<DeviceMsg>, LinkError> {
        if let Some(m) = self.rx.pop_front() {
            return Ok(Some(m));
        }
        let deadline = Instant::now() + timeout;
        loop {
            self.pump(
                deadline
                    .saturating_duration_since(Instant::now())
                    .min(Duration::from_millis(20)),
            )?;
            if let Some(m) = self.rx.pop_front() {
                return Ok(Some(m));
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
        }
    }

    /// Wait until every frame sent has been acknowledged.
    pub fn flush(&mut self) -> Result<(), LinkError> {
        while !self.inflight.is_empty() {
            self.pump(Duration::from_millis(10))?;
        }
        Ok(())
    }
}
