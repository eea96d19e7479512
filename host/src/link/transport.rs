//! Byte transports under the link: a serial port (a board, or the virtual gonio's pty) and a
//! seeded fault injector that wraps any transport.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;
use std::io;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A byte pipe with a read timeout. `read` returns `Ok(0)` when the timeout passed with nothing to
/// read; a port that went away is an error.
pub trait Transport: Send {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
}

impl<T: Transport + ?Sized> Transport for Box<T> {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        (**self).write_all(bytes)
    }
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        (**self).read(buf, timeout)
    }
}

/// A serial port through the `serialport` crate (USB CDC-ACM, a UART adapter, a pty).
pub struct SerialTransport {
    port: Box<dyn serialport::SerialPort>,
}

/// Baud rate asked of the port (meaningless for USB CDC and ptys; what a UART bridge would run).
pub const BAUD: u32 = 921_600;

impl SerialTransport {
    /// Open `path`, drop whatever it buffered from before us (a previous session's frames).
    pub fn open(path: &str) -> io::Result<Self> {
        let port = serialport::new(path, BAUD)
            .timeout(Duration::from_millis(10))
            .open()
            .map_err(io::Error::from)?;
        let _ = port.clear(serialport::ClearBuffer::All);
        Ok(Self { port })
    }
}

impl Transport for SerialTransport {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        io::Write::write_all(&mut self.port, bytes)?;
        io::Write::flush(&mut self.port)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.port
            .set_timeout(timeout.max(Duration::from_millis(1)))
            .map_err(io::Error::from)?;
        match io::Read::read(&mut self.port, buf) {
            // After poll() said readable, 0 bytes means the other end hung up.
            Ok(0) => Err(io::Error::new(io::ErrorKind::ConnectionAborted, "the port hung up")),
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted
                ) =>
            {
                Ok(0)
            }
            Err(e) => Err(e),
        }
    }
}

/// Probabilities (0..=1) of what happens to each frame, and in which directions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaultConfig {
    pub drop: f64,
    pub corrupt: f64,
    pub duplicate: f64,
    pub delay: f64,
    /// How long a delayed frame is held (it is overtaken by the frames after it).
    pub delay_by: Duration,
    pub host_to_device: bool,
    pub device_to_host: bool,
    pub seed: u64,
    /// Drop this many `Credit` frames to the host (not counting a configuration's first grant,
    /// `next_index` 0, so the host sees its `Configure` taken), before any other fault; counted as
    /// dropped. Needs `device_to_host`.
    pub drop_credits: u32,
}

impl FaultConfig {
    pub const NONE: FaultConfig = FaultConfig {
        drop: 0.0,
        corrupt: 0.0,
        duplicate: 0.0,
        delay: 0.0,
        delay_by: Duration::from_millis(20),
        host_to_device: true,
        device_to_host: true,
        seed: 1,
        drop_credits: 0,
    };
}

impl std::str::FromStr for FaultConfig {
    type Err = String;

    /// `drop=0.05,corrupt=0.05,duplicate=0.05,delay=0.05,delay_ms=20,seed=1,dir=both,drop_credits=0`
    /// (any subset; `dir` is `both`, `to-device` or `to-host`).
    fn from_str(spec: &str) -> Result<Self, String> {
        let mut c = FaultConfig::NONE;
        for item in spec.split(',').filter(|i| !i.is_empty()) {
            let (key, value) = item
                .split_once('=')
                .ok_or_else(|| format!("fault spec {item:?}: expected KEY=VALUE"))?;
            let p = |v: &str| -> Result<f64, String> {
                v.parse::<f64>()
                    .ok()
                    .filter(|x| (0.0..=1.0).contains(x))
                    .ok_or_else(|| format!("fault spec {key}: {v:?} is not a probability in [0, 1]"))
            };
            match key {
                "drop" => c.drop = p(value)?,
                "corrupt" => c.corrupt = p(value)?,
                "duplicate" => c.duplicate = p(value)?,
                "delay" => c.delay = p(value)?,
                "delay_ms" => {
                    let ms: u64 = value.parse().map_err(|_| format!("fault spec delay_ms: {value:?}"))?;
                    c.delay_by = Duration::from_millis(ms);
                }
                "seed" => c.seed = value.parse().map_err(|_| format!("fault spec seed: {value:?}"))?,
                "drop_credits" => {
                    c.drop_credits = value
                        .parse()
                        .map_err(|_| format!("fault spec drop_credits: {value:?}"))?
                }
                "dir" => {
                    (c.host_to_device, c.device_to_host) = match value {
                        "both" => (true, true),
                        "to-device" => (true, false),
                        "to-host" => (false, true),
                        _ => return Err(format!("fault spec dir: {value:?} is not both, to-device or to-host")),
                    }
                }
                _ => return Err(format!("fault spec: unknown key {key:?}")),
            }
        }
        if c.drop + c.corrupt + c.duplicate + c.delay > 1.0 {
            return Err("fault spec: the probabilities add up to more than 1".into());
        }
        Ok(c)
    }
}

/// (host -> device, device -> host) counts, shared between the injectors of one run's connections.
pub type SharedFaultCounts = Arc<Mutex<(FaultCounts, FaultCounts)>>;

/// What the injector did, per direction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultCounts {
    pub frames: u64,
    pub dropped: u64,
    pub corrupted: u64,
    pub duplicated: u64,
    pub delayed: u64,
}

/// One direction of the injector: cuts the byte stream into frames at the 0x00 delimiters and
/// decides each frame's fate.
struct FaultLane {
    enabled: bool,
    /// Each direction has its own stream, so a lane's n-th frame meets the same fate whatever
    /// the timing of the other direction (reproducible runs).
    rng: ChaCha8Rng,
    partial: Vec<u8>,
    held: VecDeque<(Instant, Vec<u8>)>,
    counts: FaultCounts,
    /// `Credit` frames still to drop (device -> host lane only).
    credits_to_drop: u32,
}

impl FaultLane {
    fn new(enabled: bool, seed: u64, credits_to_drop: u32) -> Self {
        Self {
            enabled,
            rng: ChaCha8Rng::seed_from_u64(seed),
            partial: Vec::new(),
            held: VecDeque::new(),
            counts: FaultCounts::default(),
            credits_to_drop,
        }
    }

    /// Bytes in; the bytes to pass on now out.
    fn process(&mut self, bytes: &[u8], cfg: &FaultConfig, out: &mut Vec<u8>) {
        let rng = &mut self.rng;
        if !self.enabled {
            out.extend_from_slice(bytes);
            return;
        }
        for &b in bytes {
            self.partial.push(b);
            if b != 0 {
                continue;
            }
            let mut frame = std::mem::take(&mut self.partial);
            let counts = &mut self.counts;
            counts.frames += 1;
            if self.credits_to_drop > 0 && is_streaming_credit(&frame) {
                self.credits_to_drop -= 1;
                counts.dropped += 1;
                continue;
            }
            let r: f64 = rng.random();
            let mut edge = cfg.drop;
            if r < edge {
                counts.dropped += 1;
                continue;
            }
            edge += cfg.corrupt;
            if r < edge {
                counts.corrupted += 1;
                if frame.len() > 1 {
                    let i = rng.random_range(0..frame.len() - 1);
                    let bit = rng.random_range(0..8u32);
                    if let Some(x) = frame.get_mut(i) {
                        *x ^= 1 << bit;
                    }
                }
                out.extend_from_slice(&frame);
                continue;
            }
            edge += cfg.duplicate;
            if r < edge {
                counts.duplicated += 1;
                out.extend_from_slice(&frame);
                out.extend_from_slice(&frame);
                continue;
            }
            edge += cfg.delay;
            if r < edge {
                counts.delayed += 1;
                self.held.push_back((Instant::now() + cfg.delay_by, frame));
                continue;
            }
            out.extend_from_slice(&frame);
        }
    }

    fn release_due(&mut self, out: &mut Vec<u8>) {
        let now = Instant::now();
        while self.held.front().is_some_and(|(t, _)| *t <= now) {
            if let Some((_, f)) = self.held.pop_front() {
                out.extend_from_slice(&f);
            }
        }
    }
}

/// A transport that drops, corrupts, duplicates and delays whole frames, seeded.
pub struct FaultyTransport<T> {
    inner: T,
    cfg: FaultConfig,
    tx: FaultLane,
    rx: FaultLane,
    ready: VecDeque<u8>,
    /// Totals over every injector given the same handle (reconnections).
    shared: SharedFaultCounts,
    reported: (FaultCounts, FaultCounts),
}

impl<T: Transport> FaultyTransport<T> {
    pub fn new(inner: T, cfg: FaultConfig) -> Self {
        Self {
            inner,
            tx: FaultLane::new(cfg.host_to_device, cfg.seed, 0),
            rx: FaultLane::new(cfg.device_to_host, cfg.seed ^ 0x9e37_79b9_7f4a_7c15, cfg.drop_credits),
            cfg,
            ready: VecDeque::new(),
            shared: SharedFaultCounts::default(),
            reported: Default::default(),
        }
    }

    /// Add this injector's counts into `shared` (which other injectors may also add to).
    pub fn with_shared_counts(mut self, shared: SharedFaultCounts) -> Self {
        self.shared = shared;
        self
    }

    fn publish(&mut self) {
        let now = (self.tx.counts, self.rx.counts);
        if now != self.reported {
            if let Ok(mut s) = self.shared.lock() {
                add_counts(&mut s.0, &now.0, &self.reported.0);
                add_counts(&mut s.1, &now.1, &self.reported.1);
            }
            self.reported = now;
        }
    }

    fn flush_tx(&mut self) -> io::Result<()> {
        let mut out = Vec::new();
        self.tx.release_due(&mut out);
        if out.is_empty() {
            Ok(())
        } else {
            self.inner.write_all(&out)
        }
    }
}

/// A device frame carrying a `Credit` other than a configuration's first (`next_index` 0).
fn is_streaming_credit(frame: &[u8]) -> bool {
    use gonio_shared::msg::DeviceMsg;
    let mut dec = gonio_shared::frame::FrameDecoder::new();
    frame.iter().any(|&b| {
        matches!(
            dec.push::<DeviceMsg>(b),
            Some(Ok(f)) if matches!(f.msg, DeviceMsg::Credit { next_index, .. } if next_index > 0)
        )
    })
}

fn add_counts(total: &mut FaultCounts, now: &FaultCounts, before: &FaultCounts) {
    total.frames += now.frames - before.frames;
    total.dropped += now.dropped - before.dropped;
    total.corrupted += now.corrupted - before.corrupted;
    total.duplicated += now.duplicated - before.duplicated;
    total.delayed += now.delayed - before.delayed;
}

impl<T: Transport> Transport for FaultyTransport<T> {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        let mut out = Vec::new();
        self.tx.process(bytes, &self.cfg, &mut out);
        self.tx.release_due(&mut out);
        self.publish();
        self.inner.write_all(&out)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.flush_tx()?;
        let deadline = Instant::now() + timeout;
        loop {
            let mut released = Vec::new();
            self.rx.release_due(&mut released);
            self.ready.extend(released);
            if !self.ready.is_empty() {
                let n = buf.len().min(self.ready.len());
                for (slot, b) in buf.iter_mut().zip(self.ready.drain(..n)) {
                    *slot = b;
                }
                return Ok(n);
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(0);
            }
            // Wake for a held frame's release even if the wire stays quiet.
            let mut wait = deadline - now;
            if let Some((t, _)) = self.rx.held.front() {
                wait = wait.min(t.saturating_duration_since(now).max(Duration::from_millis(1)));
            }
            let mut tmp = [0u8; 1024];
            let n = self.inner.read(&mut tmp, wait)?;
            let mut out = Vec::new();
            self.rx.process(tmp.get(..n).unwrap_or(&[]), &self.cfg, &mut out);
            self.publish();
            self.ready.extend(out);
            self.flush_tx()?;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fault_specs_parse_and_bad_ones_say_why() {
        let c: FaultConfig = "drop=0.05,corrupt=0.01,seed=9,dir=to-host".parse().unwrap();
        assert_eq!(
            (c.drop, c.corrupt, c.seed, c.host_to_device, c.device_to_host),
            (0.05, 0.01, 9, false, true)
        );
        for (spec, why) in [
            ("drop=2", "probability"),
            ("jitter=0.1", "unknown key"),
            ("drop", "KEY=VALUE"),
            ("drop=0.6,delay=0.6", "more than 1"),
        ] {
            let e = spec.parse::<FaultConfig>().unwrap_err();
            assert!(e.contains(why), "{spec}: {e}");
        }
    }

    /// A loopback transport: what is written comes back on read.
    struct Loop(VecDeque<u8>);
    impl Transport for Loop {
        fn write_all(&mut self, b: &[u8]) -> io::Result<()> {
            self.0.extend(b);
            Ok(())
        }
        fn read(&mut self, buf: &mut [u8], _: Duration) -> io::Result<usize> {
            let n = buf.len().min(self.0.len());
            for (s, b) in buf.iter_mut().zip(self.0.drain(..n)) {
                *s = b;
            }
            Ok(n)
        }
    }

    #[test]
    fn the_injector_acts_on_whole_frames_and_is_reproducible() {
        let frames: Vec<u8> = (1..=200u8).flat_map(|k| [k, k, 0]).collect();
        let run = |cfg: FaultConfig| {
            let counts = SharedFaultCounts::default();
            let mut t = FaultyTransport::new(Loop(VecDeque::new()), cfg).with_shared_counts(counts.clone());
            t.write_all(&frames).unwrap();
            let mut got = Vec::new();
            let mut buf = [0u8; 64];
            loop {
                let n = t.read(&mut buf, Duration::from_millis(1)).unwrap();
                if n == 0 {
                    break;
                }
                got.extend_from_slice(&buf[..n]);
            }
            let c = *counts.lock().unwrap();
            (got, c)
        };
        let cfg = FaultConfig {
            drop: 0.1,
            duplicate: 0.1,
            ..FaultConfig::NONE
        };
        let (a, counts) = run(cfg);
        assert_eq!(run(cfg).0, a, "same seed, same faults");
        assert!(counts.0.dropped > 0 && counts.0.duplicated > 0 && counts.1.dropped > 0);
        // Every frame that arrives is one that was sent, whole.
        for f in a.split(|&b| b == 0).filter(|f| !f.is_empty()) {
            assert!(f.len() == 2 && f[0] == f[1], "{f:?}");
        }
        assert_eq!(run(FaultConfig::NONE).0, frames);
    }

    /// `drop_credits` drops that many streaming `Credit`s to the host and nothing else.
    #[test]
    fn drop_credits_drops_only_streaming_credits_to_the_host() {
        use gonio_shared::frame::{encode, FrameDecoder, MAX_WIRE_FRAME};
        use gonio_shared::msg::DeviceMsg;
        let msgs = [
            DeviceMsg::Credit {
                next_index: 0,
                free: 512,
            },
            DeviceMsg::Ack { seq: 1 },
            DeviceMsg::Credit {
                next_index: 8,
                free: 504,
            },
            DeviceMsg::Credit {
                next_index: 16,
                free: 504,
            },
            DeviceMsg::Credit {
                next_index: 24,
                free: 504,
            },
        ];
        let mut loop_back = Loop(VecDeque::new());
        for (k, m) in msgs.iter().enumerate() {
            let mut f = [0u8; MAX_WIRE_FRAME];
            let n = encode(k as u16, m, &mut f).unwrap();
            loop_back.0.extend(&f[..n]);
        }
        let cfg: FaultConfig = "drop_credits=2".parse().unwrap();
        let counts = SharedFaultCounts::default();
        let mut t = FaultyTransport::new(loop_back, cfg).with_shared_counts(counts.clone());
        let mut got = Vec::new();
        let mut buf = [0u8; 64];
        let mut dec = FrameDecoder::new();
        loop {
            let n = t.read(&mut buf, Duration::from_millis(1)).unwrap();
            if n == 0 {
                break;
            }
            for &b in &buf[..n] {
                if let Some(Ok(f)) = dec.push::<DeviceMsg>(b) {
                    got.push(f.msg);
                }
            }
        }
        assert_eq!(got, vec![msgs[0].clone(), msgs[1].clone(), msgs[4].clone()]);
        assert_eq!(counts.lock().unwrap().1.dropped, 2);
    }
}
