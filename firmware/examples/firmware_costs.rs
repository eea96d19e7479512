//! Host-side cost figures of the firmware logic (not a test; numbers vary with the machine):
//!
//! - the step generator's cost per step, bare (`Stepper::poll`) and through the whole device
//!   (`Device::poll`: switch checks, separation guard, scan sequence), measured in the same run;
//! - frames per second through the shared decoder alone, and through the whole link (decoder,
//!   sequence check, controller, encoded replies).
//!
//! Run: `cargo run --release -p gonio-firmware --example firmware_costs`

use gonio_firmware::stepper::Stepper;
use gonio_firmware::{Clock, Detector, Device, Readout, Steppers, Switches};
use gonio_shared::frame::{encode, FrameDecoder, MAX_WIRE_FRAME};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::msg::{Direction, Hello, HostMsg, PlanChunk};
use gonio_shared::Axis;
use std::hint::black_box;
use std::time::Instant;

/// A HAL that does nothing but keep time and count.
struct NullHal {
    now: u64,
    steps: u64,
}

impl Clock for NullHal {
    fn now_us(&self) -> u64 {
        self.now
    }
}

impl Steppers for NullHal {
    fn set_direction(&mut self, _: Axis, _: bool) {}
    fn step(&mut self, _: Axis) {
        self.steps += 1;
    }
}

impl Switches for NullHal {
    fn limit_closed(&self, _: Axis) -> bool {
        false
    }
}

impl Detector for NullHal {
    fn start_exposure(&mut self, _: u32) {}
    fn poll_readout(&mut self) -> Option<Readout> {
        Some(Readout::new())
    }
}

fn frame(seq: u16, msg: &HostMsg) -> Vec<u8> {
    let mut out = [0u8; MAX_WIRE_FRAME];
    let n = encode(seq, msg, &mut out).expect("frame fits");
    out[..n].to_vec()
}

fn main() {
    let cfg = InstrumentConfig::<f32>::reference();
    println!(
        "RAM of the whole firmware state (Device: link + controller + plan ring + measurement buffer): {} bytes",
        std::mem::size_of::<Device>()
    );
    let bare_ns = bare_generator(&cfg);
    let mut bench = Bench::homed(cfg);
    bench.scan(bare_ns);
    decoder_throughput();
    bench.link_throughput();
}

/// Bare step generator: one long 4-axis move on the full-resolution instrument, polled at every
/// step instant. Returns ns per step.
fn bare_generator(cfg: &InstrumentConfig<f32>) -> f64 {
    let target = [60_000, -45_000, 20_000, 15_000];
    let mut hal = NullHal { now: 0, steps: 0 };
    let mut st = Stepper::new();
    let t0 = Instant::now();
    let mut polls = 0u64;
    st.start(&mut hal, 0, target, cfg, 1.0, None).expect("valid move");
    while let Some(t) = st.next_due_us() {
        hal.now = t;
        st.poll(&mut hal, t, None).expect("no guard");
        polls += 1;
    }
    let bare = t0.elapsed().as_secs_f64();
    let bare_ns = bare * 1e9 / hal.steps as f64;
    println!(
        "step generator (Stepper::poll): {} steps in {} polls, {:.1} ms, {:.1} ns/step, {:.1} ns/poll",
        hal.steps,
        polls,
        bare * 1e3,
        bare_ns,
        bare * 1e9 / polls as f64
    );
    bare_ns
}

fn d(ti: f32, to: f32) -> Direction {
    Direction {
        theta_i: ti.to_radians(),
        phi_i: 0.0,
        theta_o: to.to_radians(),
        phi_o: std::f32::consts::PI,
    }
}

/// The whole device behind a HAL whose switches close at the home positions.
struct Bench {
    dev: Box<Device>,
    hal: SwitchHal,
    seq: u16,
}

impl Bench {
    /// Handshake, configure and home (untimed).
    fn homed(cfg: InstrumentConfig<f32>) -> Self {
        let mut b = Self {
            dev: Box::new(Device::new()),
            hal: SwitchHal {
                inner: NullHal { now: 0, steps: 0 },
                pos: [0; 4],
                dir: [true; 4],
                cfg,
            },
            seq: 0,
        };
        b.send(HostMsg::Hello(Hello::OURS));
        b.send(HostMsg::Configure(cfg));
        b.send(HostMsg::Home);
        b.run();
        assert_eq!(
            b.dev.controller().state(),
            gonio_shared::msg::ControllerState::Ready,
            "homing: {:?}",
            b.dev.controller().last_fault()
        );
        b
    }

    fn send(&mut self, msg: HostMsg) {
        let f = frame(self.seq, &msg);
        self.seq = self.seq.wrapping_add(1);
        self.dev.receive(&mut self.hal, &f);
        self.drain();
    }

    fn drain(&mut self) {
        let mut sink = [0u8; 4096];
        while self.dev.drain_outbox(&mut sink) > 0 {}
    }

    /// Poll every deadline until the device waits for the host; returns the polls.
    fn run(&mut self) -> u64 {
        let mut polls = 0u64;
        while let Some(t) = self.dev.next_deadline_us() {
            self.hal.inner.now = self.hal.inner.now.max(t);
            self.dev.poll(&mut self.hal);
            self.drain();
            polls += 1;
        }
        polls
    }

    /// The same kind of motion as the bare generator through the whole device: a timed scan of 8
    /// moves between two far poses, settle and exposure included.
    fn scan(&mut self, bare_ns: f64) {
        let mut directions = heapless::Vec::new();
        for k in 0..8 {
            let dir = if k % 2 == 0 { d(70.0, 10.0) } else { d(10.0, 70.0) };
            directions.push(dir).expect("chunk capacity");
        }
        self.send(HostMsg::Plan(PlanChunk {
            first_index: 0,
            directions,
        }));
        self.send(HostMsg::PlanEnd { total: 8 });
        self.send(HostMsg::Start);
        assert_eq!(
            self.dev.controller().state(),
            gonio_shared::msg::ControllerState::Running,
            "{:?}",
            self.dev.controller().last_fault()
        );
        let steps_before = self.hal.inner.steps;
        let t0 = Instant::now();
        let polls = self.run();
        let full = t0.elapsed().as_secs_f64();
        let steps = self.hal.inner.steps - steps_before;
        let full_ns = full * 1e9 / steps as f64;
        println!(
            "whole device (Device::poll, 8 plan moves): {steps} steps in {polls} polls, {:.1} ms, {:.1} ns/step ({:.2}x the bare generator)",
            full * 1e3,
            full_ns,
            full_ns / bare_ns
        );
    }

    /// Small frames (GetStatus): the decoder alone, then the whole link on the same bytes.
    fn link_throughput(&mut self) {
        let frames = 20_000u32;
        let mut wire = Vec::new();
        for k in 0..frames {
            wire.extend(frame(self.seq.wrapping_add(k as u16), &HostMsg::GetStatus));
        }
        let mut dec = FrameDecoder::new();
        let t0 = Instant::now();
        for &b in &wire {
            black_box(dec.push::<HostMsg>(b));
        }
        let decode_only = t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let mut rest = &wire[..];
        while !rest.is_empty() {
            let n = self.dev.receive(&mut self.hal, rest);
            rest = &rest[n..];
            self.drain();
        }
        let link = t0.elapsed().as_secs_f64();
        println!(
            "GetStatus frames: decoder alone {:.0} frames/s; whole link (decode, sequence check, controller, \
             encode Ack + Status) {:.0} frames/s ({:.2}x the decoder's time)",
            frames as f64 / decode_only,
            frames as f64 / link,
            link / decode_only
        );
    }
}

/// Decoder throughput: a mix of the largest frame (a full plan chunk) and the smallest.
fn decoder_throughput() {
    let mut directions = heapless::Vec::new();
    while directions.push(d(30.0, 40.0)).is_ok() {}
    let big = HostMsg::Plan(PlanChunk {
        first_index: 123_456,
        directions,
    });
    let mut wire = Vec::new();
    let frames = 20_000u32;
    for k in 0..frames {
        let msg = if k % 2 == 0 { big.clone() } else { HostMsg::GetStatus };
        wire.extend(frame(k as u16, &msg));
    }
    let mut dec = FrameDecoder::new();
    let t0 = Instant::now();
    let mut ok = 0u32;
    for &b in &wire {
        if let Some(Ok(f)) = dec.push::<HostMsg>(b) {
            black_box(&f);
            ok += 1;
        }
    }
    let t = t0.elapsed().as_secs_f64();
    assert_eq!(ok, frames);
    println!(
        "frame decoder: {frames} frames ({} bytes, half of them full plan chunks) in {:.1} ms: {:.0} frames/s, {:.1} MB/s",
        wire.len(),
        t * 1e3,
        frames as f64 / t,
        wire.len() as f64 / t / 1e6
    );
}

/// A HAL whose switches close exactly at the configured home positions, so homing completes.
struct SwitchHal {
    inner: NullHal,
    pos: [i64; 4],
    dir: [bool; 4],
    cfg: InstrumentConfig<f32>,
}

impl Clock for SwitchHal {
    fn now_us(&self) -> u64 {
        self.inner.now
    }
}

impl Steppers for SwitchHal {
    fn set_direction(&mut self, axis: Axis, increasing: bool) {
        self.dir[axis.index()] = increasing;
    }
    fn step(&mut self, axis: Axis) {
        let i = axis.index();
        self.pos[i] += if self.dir[i] { 1 } else { -1 };
        self.inner.step(axis);
    }
}

impl Switches for SwitchHal {
    fn limit_closed(&self, axis: Axis) -> bool {
        let i = axis.index();
        let home = gonio_firmware::homing::home_position(&self.cfg, axis) as i64;
        match (self.cfg.axis(axis).continuous, self.cfg.axis(axis).home) {
            (true, _) => self.pos[i] == 0,
            (false, gonio_shared::HomeSide::Max) => self.pos[i] >= home,
            (false, gonio_shared::HomeSide::Min) => self.pos[i] <= home,
        }
    }
}

impl Detector for SwitchHal {
    fn start_exposure(&mut self, e: u32) {
        self.inner.start_exposure(e);
    }
    fn poll_readout(&mut self) -> Option<Readout> {
        self.inner.poll_readout()
    }
}
