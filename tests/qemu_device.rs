//! The QEMU build of the firmware (firmware/stm32, `--features qemu`) over its serial port: run by
//! `.ci/qemu-scan`, which boots the image and passes the port in `GONIO_QEMU_PORT`. The tests are
//! ignored in the normal test run (they need the emulator) and fail without their environment.
//!
//! - `qemu_boot`: the image answers a `Hello` (sent until it does); prints the boot time from
//!   `GONIO_QEMU_T0` (Unix seconds at QEMU's launch).
//! - `qemu_journal`: after `gonio measure` ran the plan `GONIO_QEMU_PLAN`
//!   into `GONIO_QEMU_SCAN`, every direction is journaled exactly once and the device agrees
//!   (Done, all measured, nothing unacknowledged).
//! - `qemu_refusals`: hostile input gets the expected answer each: garbage bytes a NAK, a Configure
//!   with impossible speeds `Refused(BadConfig(TooFast))`, a plan with a pose below the horizon
//!   `Fault(Unreachable)`, a `Hello` of another protocol version our own `Hello` and then
//!   `Refused(NoHandshake)`. First 200 `GetStatus` written at once (every one answered, no byte
//!   lost: the device holds the host back, never drops or stalls), then 200 `GetStatus` (4 in
//!   flight) for the link's frame rate.

use gonio::link::{SerialTransport, Transport};
use gonio_shared::frame::FrameDecoder;
use gonio_shared::instrument::{ConfigError, InstrumentConfig};
use gonio_shared::kinematics::Unreachable;
use gonio_shared::msg::{
    Command, ControllerState, DeviceMsg, Direction, Fault, Hello, HostMsg, NakReason, PlanChunk, RefuseReason,
    PROTOCOL_VERSION,
};
use gonio_shared::Axis;
use gonio_tests::frame_bytes;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// How long one expected answer may take (the emulated device is slower than a board).
const ANSWER_WAIT: Duration = Duration::from_secs(10);
/// How long the image may take to answer its first `Hello`.
const BOOT_WAIT: Duration = Duration::from_secs(60);
/// `GetStatus` requests for the frame rate, and how many may be unanswered at once.
const BURST: u16 = 200;
const WINDOW: u16 = 4;

fn env(name: &str) -> String {
    std::env::var(name).unwrap_or_else(|_| panic!("{name} is not set: run .ci/qemu-scan"))
}

/// The device's side of one session: frames decoded from the port.
struct Device {
    port: SerialTransport,
    decoder: FrameDecoder,
    frames: std::collections::VecDeque<DeviceMsg>,
    next_seq: u16,
    received: u64,
}

impl Device {
    /// An open port whose device answered our Hello with our protocol.
    fn greeted() -> Self {
        let mut dev = Device::open();
        let session = session_id();
        assert_eq!(
            dev.hello(Hello::ours(session)),
            Hello::ours(session),
            "the image speaks another protocol"
        );
        dev
    }

    fn open() -> Self {
        let path = env("GONIO_QEMU_PORT");
        let port = SerialTransport::open(&path).unwrap_or_else(|e| panic!("cannot open {path}: {e}"));
        Self {
            port,
            decoder: FrameDecoder::new(),
            frames: Default::default(),
            next_seq: 0,
            received: 0,
        }
    }

    fn send(&mut self, msg: &HostMsg) -> u16 {
        let seq = self.next_seq;
        self.port.write_all(&frame_bytes(seq, msg)).expect("write to the port");
        self.next_seq = seq.wrapping_add(1);
        seq
    }

    fn raw(&mut self, bytes: &[u8]) {
        self.port.write_all(bytes).expect("write to the port");
    }

    /// The next device frame within `wait`, or `None`.
    fn next(&mut self, wait: Duration) -> Option<DeviceMsg> {
        let end = Instant::now() + wait;
        let mut buf = [0u8; 256];
        loop {
            if let Some(m) = self.frames.pop_front() {
                return Some(m);
            }
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            let n = self
                .port
                .read(&mut buf, left.min(Duration::from_millis(50)))
                .expect("read the port");
            for &b in &buf[..n] {
                match self.decoder.push::<DeviceMsg>(b) {
                    Some(Ok(f)) => {
                        self.received += 1;
                        self.frames.push_back(f.msg);
                    }
                    Some(Err(e)) => panic!("the device sent a bad frame: {e:?}"),
                    None => {}
                }
            }
        }
    }

    /// Read until `want` matches a frame; frames that `ignore` accepts are skipped, anything else
    /// fails the test.
    fn expect(
        &mut self,
        what: &str,
        want: impl Fn(&DeviceMsg) -> bool,
        ignore: impl Fn(&DeviceMsg) -> bool,
    ) -> DeviceMsg {
        loop {
            match self.next(ANSWER_WAIT) {
                Some(m) if want(&m) => return m,
                Some(m) if ignore(&m) => continue,
                Some(m) => panic!("{what}: unexpected answer {m:?}"),
                None => panic!("{what}: no answer within {ANSWER_WAIT:?}"),
            }
        }
    }

    /// Read the answer to the command sent as `seq`: until `want` matches, skipping that
    /// command's `Ack` and harmless frames.
    fn answer_to(&mut self, what: &str, seq: u16, want: impl Fn(&DeviceMsg) -> bool) -> DeviceMsg {
        self.expect(what, want, |m| {
            harmless(m) || matches!(m, DeviceMsg::Ack { seq: s } if *s == seq)
        })
    }

    /// The device's `Status`.
    fn status(&mut self) -> gonio_shared::msg::Status {
        let seq = self.send(&HostMsg::GetStatus);
        match self.answer_to("status", seq, |m| matches!(m, DeviceMsg::Status(_))) {
            DeviceMsg::Status(s) => s,
            _ => unreachable!(),
        }
    }

    /// Open a session with `hello` (sequence 0) and return the device's `Hello`.
    fn hello(&mut self, hello: Hello) -> Hello {
        self.next_seq = 0;
        self.send(&HostMsg::Hello(hello));
        let ack0 = |m: &DeviceMsg| matches!(m, DeviceMsg::Ack { seq: 0 });
        match self.expect(
            "hello",
            |m| matches!(m, DeviceMsg::Hello(h) if h.session == hello.session),
            |m| ack0(m) || harmless(m),
        ) {
            DeviceMsg::Hello(h) => h,
            _ => unreachable!(),
        }
    }
}

/// Frames a device may send at any time that say nothing about the question asked.
fn harmless(m: &DeviceMsg) -> bool {
    matches!(m, DeviceMsg::Credit { .. } | DeviceMsg::Status(_))
}

fn session_id() -> u32 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(1, |d| d.subsec_nanos() | 1)
}

#[test]
#[ignore = "needs the QEMU image: .ci/qemu-scan runs it"]
fn qemu_boot() {
    let t0: f64 = env("GONIO_QEMU_T0").parse().expect("GONIO_QEMU_T0: Unix seconds");
    let mut dev = Device::open();
    let session = session_id();
    let start = Instant::now();
    // Until the image runs, a Hello goes nowhere (QEMU connects the pty within a second): resend.
    let answer = loop {
        assert!(start.elapsed() < BOOT_WAIT, "no Hello answer within {BOOT_WAIT:?}");
        dev.next_seq = 0;
        dev.send(&HostMsg::Hello(Hello::ours(session)));
        if let Some(DeviceMsg::Hello(h)) = std::iter::from_fn(|| dev.next(Duration::from_millis(300)))
            .find(|m| matches!(m, DeviceMsg::Hello(h) if h.session == session))
        {
            break h;
        }
    };
    assert_eq!(answer, Hello::ours(session), "the image speaks another protocol");
    let now = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .expect("clock")
        .as_secs_f64();
    println!("qemu boot: {:.2} s to the first Hello answer", now - t0);
}

/// Every `m <index> ...` record of a scan journal, counted per index; and the header's size.
fn journal_counts(dir: &Path) -> (u32, BTreeMap<u32, u32>) {
    let path = gonio::journal::Journal::path_in(dir);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header = lines.next().expect("journal header");
    let total = header
        .split(' ')
        .find_map(|f| f.strip_prefix("directions="))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("journal header without directions=: {header}"));
    let mut counts = BTreeMap::new();
    for line in lines {
        let mut fields = line.split(' ');
        assert_eq!(fields.next(), Some("m"), "journal line is not a reading: {line}");
        let index: u32 = fields.next().and_then(|i| i.parse().ok()).expect("journal index");
        *counts.entry(index).or_insert(0) += 1;
    }
    (total, counts)
}

#[test]
#[ignore = "needs the QEMU image and a scan: .ci/qemu-scan runs it"]
fn qemu_journal() {
    let plan_path = PathBuf::from(env("GONIO_QEMU_PLAN"));
    let scan = PathBuf::from(env("GONIO_QEMU_SCAN"));
    let plan = gonio::plan::file::decode_plan(&std::fs::read(&plan_path).expect("plan file")).expect("plan");
    let n = u32::try_from(plan.len()).expect("plan size");

    let mut dev = Device::greeted();
    let status = dev.status();

    // Every direction journaled exactly once.
    let (total, counts) = journal_counts(&scan);
    assert_eq!(total, n, "journal is of a {total}-direction plan, the plan has {n}");
    let missing: Vec<u32> = (0..n).filter(|i| !counts.contains_key(i)).collect();
    let twice: Vec<(&u32, &u32)> = counts.iter().filter(|(_, c)| **c != 1).collect();
    assert!(missing.is_empty(), "directions never journaled: {missing:?}");
    assert!(
        twice.is_empty(),
        "directions journaled more than once (index, times): {twice:?}"
    );
    assert!(counts.keys().all(|i| *i < n), "journal has directions outside the plan");
    // The device agrees: the scan is done, all measured, nothing left unacknowledged.
    assert_eq!(
        (status.state, status.plan_done, status.unacked, status.last_fault),
        (ControllerState::Done, n, 0, None),
        "device status after the scan: {status:?}"
    );
    println!("qemu journal: {n} directions, {} journaled exactly once", counts.len());
}

/// `BURST` `GetStatus` in one write, far more than the device's receive buffer holds: every one is
/// answered, and none was damaged on the way (no NAK, the device's bad-frame count unchanged), so
/// the device held the host back rather than dropping bytes, and never went silent.
fn burst(dev: &mut Device) {
    let before = dev.status().bad_frames;
    let mut bytes = Vec::new();
    for _ in 0..BURST {
        bytes.extend(frame_bytes(dev.next_seq, &HostMsg::GetStatus));
        dev.next_seq = dev.next_seq.wrapping_add(1);
    }
    dev.raw(&bytes);
    let start = Instant::now();
    let mut statuses = 0;
    while statuses < BURST {
        match dev.next(ANSWER_WAIT) {
            Some(DeviceMsg::Status(_)) => statuses += 1,
            Some(DeviceMsg::Ack { .. } | DeviceMsg::Credit { .. }) => {}
            Some(other) => panic!("burst: {other:?} after {statuses} of {BURST} answers"),
            None => panic!("burst: no answer within {ANSWER_WAIT:?} after {statuses} of {BURST} answers"),
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    let after = dev.status().bad_frames;
    assert_eq!(
        after, before,
        "burst: the device's bad-frame count went from {before} to {after}"
    );
    println!(
        "qemu burst: {BURST} GetStatus in one write ({} bytes), {statuses} answered, no bad frame, {elapsed:.2} s",
        bytes.len()
    );
}

#[test]
#[ignore = "needs the QEMU image: .ci/qemu-scan runs it"]
fn qemu_refusals() {
    let instrument = PathBuf::from(env("GONIO_QEMU_INSTRUMENT"));
    let mut dev = Device::greeted();
    let status = dev.status();
    assert_eq!(status.last_fault, None, "device status before the checks: {status:?}");

    burst(&mut dev);
    // Frame rate: GetStatus with WINDOW requests in flight, every Ack and Status counted.
    let start = Instant::now();
    let before = dev.received;
    let (mut sent, mut statuses) = (0, 0);
    while statuses < BURST {
        while sent < BURST && sent - statuses < WINDOW {
            dev.send(&HostMsg::GetStatus);
            sent += 1;
        }
        match dev.next(ANSWER_WAIT) {
            Some(DeviceMsg::Status(_)) => statuses += 1,
            Some(DeviceMsg::Ack { .. } | DeviceMsg::Credit { .. }) => {}
            other => panic!("status requests: unexpected answer {other:?}"),
        }
    }
    let frames_per_s = (dev.received - before) as f64 / start.elapsed().as_secs_f64();

    let mut refusals = 0;
    // 1. Garbage bytes (a broken COBS frame): NAKed, the sequence number expected next named.
    dev.raw(&[0x13, 0x37, 0xde, 0xad, 0xbe, 0xef, 0x00]);
    let expected = dev.next_seq;
    let nak = dev.expect("garbage", |m| matches!(m, DeviceMsg::Nak { .. }), harmless);
    assert!(
        matches!(nak, DeviceMsg::Nak { expected: e, reason: NakReason::Cobs | NakReason::Crc } if e == expected),
        "garbage: {nak:?}"
    );
    refusals += 1;

    // 2. A Configure with impossible speeds: refused before anything moves.
    let good: InstrumentConfig<f32> = gonio::instrument::load(&instrument)
        .expect("instrument file")
        .cast::<f32>();
    let mut fast = good;
    fast.axes[Axis::Light.index()].max_speed = 1.0e3; // rad/s: ~318 k steps/s at 2000 steps per turn
    let seq = dev.send(&HostMsg::Configure(fast));
    let refused = dev.answer_to("impossible speeds", seq, |m| matches!(m, DeviceMsg::Refused { .. }));
    assert_eq!(
        refused,
        DeviceMsg::Refused {
            seq,
            command: Command::Configure,
            reason: RefuseReason::BadConfig(ConfigError::TooFast(Axis::Light)),
        }
    );
    refusals += 1;

    // 3. A plan with an unreachable pose (outgoing direction below the horizon), after the valid
    // instrument (the same one again keeps a finished scan's homing): the plan faults at that index.
    let seq = dev.send(&HostMsg::Configure(good));
    dev.expect(
        "configure",
        |m| matches!(m, DeviceMsg::Ack { seq: s } if *s == seq),
        harmless,
    );
    let below = Direction {
        theta_i: 30f32.to_radians(),
        phi_i: 0.0,
        theta_o: 100f32.to_radians(),
        phi_o: 0.0,
    };
    let seq = dev.send(&HostMsg::Plan(PlanChunk {
        first_index: 0,
        directions: [below].into_iter().collect(),
    }));
    let fault = dev.answer_to("unreachable pose", seq, |m| matches!(m, DeviceMsg::Fault(_)));
    assert_eq!(
        fault,
        DeviceMsg::Fault(Fault::Unreachable {
            index: 0,
            reason: Unreachable::BelowHorizon { incoming: false },
        })
    );
    refusals += 1;

    // 4. A Hello of another protocol version: the device answers with its own (the host sees the
    // mismatch) and then refuses commands.
    let other = Hello {
        protocol: PROTOCOL_VERSION.wrapping_add(1),
        ..Hello::ours(session_id().wrapping_add(2))
    };
    let theirs = dev.hello(other);
    assert_eq!(
        theirs,
        Hello::ours(other.session),
        "the device's answer to another version"
    );
    let seq = dev.send(&HostMsg::Home);
    let refused = dev.answer_to("command after a mismatched Hello", seq, |m| {
        matches!(m, DeviceMsg::Refused { .. })
    });
    assert_eq!(
        refused,
        DeviceMsg::Refused {
            seq,
            command: Command::Home,
            reason: RefuseReason::NoHandshake,
        }
    );
    refusals += 1;

    println!("qemu refusals: {refusals} refusals as expected, {frames_per_s:.0} frames/s");
}
