//! The test bench: a mock HAL that records every step (axis, direction, timestamp) and detector
//! trigger, with a controllable clock and switch model, and a host side that frames messages,
//! decodes the device's replies and drives the clock from `Device::next_deadline_us`.
#![allow(dead_code)]

pub mod board;

use gonio_firmware::{Clock, Detector, Device, Readout, Steppers, Switches};
use gonio_shared::frame::{encode, Frame, FrameDecoder, MAX_WIRE_FRAME};
use gonio_shared::instrument::{AxisConfig, HomeSide, InstrumentConfig, AXES};
use gonio_shared::kinematics::Kinematics;
use gonio_shared::msg::{ControllerState, DeviceMsg, Direction, Hello, HostMsg, PlanChunk, Status};
use gonio_shared::Axis;

/// A coarse instrument for fast simulation: the reference geometry, ~100x fewer steps per radian.
/// Arms: 800 steps/rev (127 steps/rad), 100 steps/s, 200 steps/s^2.
pub fn coarse_config() -> InstrumentConfig<f32> {
    let mut c = InstrumentConfig::<f32>::reference();
    for (axis, gear) in [
        (Axis::Light, 4.0),
        (Axis::Detector, 4.0),
        (Axis::Tilt, 3.0),
        (Axis::Azimuth, 2.0),
    ] {
        let a: &mut AxisConfig<f32> = &mut c.axes[axis.index()];
        a.microsteps = 1;
        a.gear_ratio = gear;
    }
    c.settle_ms = 5;
    c.exposure_us = 1_000;
    c
}

pub fn kin(cfg: &InstrumentConfig<f32>) -> Kinematics<f32> {
    Kinematics::new(*cfg).unwrap()
}

/// Steps per axis revolution (integer for the test configs).
pub fn steps_per_rev(cfg: &InstrumentConfig<f32>, axis: Axis) -> i64 {
    let a = cfg.axis(axis);
    (a.steps_per_rev as f32 * a.microsteps as f32 * a.gear_ratio).round() as i64
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepEvent {
    pub axis: Axis,
    pub increasing: bool,
    pub t_us: u64,
    /// True positions of all axes right after this step.
    pub after: [i64; 4],
}

#[derive(Clone, Copy, Debug)]
pub enum SwitchModel {
    /// Home on the max side: closed at or above this step position.
    AtOrAbove(i64),
    AtOrBelow(i64),
    /// Index sensor of a continuous axis: closed at 0 mod rev and in the `window` steps below it.
    Index {
        rev: i64,
        window: i64,
    },
}

impl SwitchModel {
    pub fn closed(&self, pos: i64) -> bool {
        match *self {
            SwitchModel::AtOrAbove(p) => pos >= p,
            SwitchModel::AtOrBelow(p) => pos <= p,
            SwitchModel::Index { rev, window } => {
                let r = pos.rem_euclid(rev);
                r == 0 || r > rev - window
            }
        }
    }
}

pub struct MockHal {
    pub now: u64,
    /// True axis positions (what the motors did).
    pub pos: [i64; 4],
    pub dir: [bool; 4],
    pub steps: Vec<StepEvent>,
    pub record_steps: bool,
    pub step_count: u64,
    pub switches: [SwitchModel; 4],
    /// Switch forced closed from this instant on (a fault injection).
    pub forced_closed: [Option<u64>; 4],
    /// Force a switch closed after this many steps in total (checked at each step).
    pub close_after_steps: Option<(Axis, u64)>,
    pub exposures: Vec<(u64, u32)>,
    pub exposure_done_us: Option<u64>,
    pub detector_dead: bool,
}

impl MockHal {
    /// A HAL whose switches sit where `cfg` says the home positions are.
    pub fn new(cfg: &InstrumentConfig<f32>) -> Self {
        let switches = AXES.map(|axis| {
            let c = cfg.axis(axis);
            if c.continuous {
                SwitchModel::Index {
                    rev: steps_per_rev(cfg, axis),
                    window: (steps_per_rev(cfg, axis) / 90).max(2),
                }
            } else {
                let home = gonio_firmware::homing::home_position(cfg, axis) as i64;
                match c.home {
                    HomeSide::Max => SwitchModel::AtOrAbove(home),
                    HomeSide::Min => SwitchModel::AtOrBelow(home),
                }
            }
        });
        Self {
            now: 0,
            pos: [0; 4],
            dir: [true; 4],
            steps: Vec::new(),
            record_steps: true,
            step_count: 0,
            switches,
            forced_closed: [None; 4],
            close_after_steps: None,
            exposures: Vec::new(),
            exposure_done_us: None,
            detector_dead: false,
        }
    }

    pub fn exposure_count(&self) -> usize {
        self.exposures.len()
    }
}

impl Clock for MockHal {
    fn now_us(&self) -> u64 {
        self.now
    }
}

impl Steppers for MockHal {
    fn set_direction(&mut self, axis: Axis, increasing: bool) {
        self.dir[axis.index()] = increasing;
    }
    fn step(&mut self, axis: Axis) {
        let i = axis.index();
        self.pos[i] += if self.dir[i] { 1 } else { -1 };
        self.step_count += 1;
        if self.record_steps {
            self.steps.push(StepEvent {
                axis,
                increasing: self.dir[i],
                t_us: self.now,
                after: self.pos,
            });
        }
        if let Some((a, n)) = self.close_after_steps {
            if self.step_count >= n && self.forced_closed[a.index()].is_none() {
                self.forced_closed[a.index()] = Some(self.now);
            }
        }
    }
}

impl Switches for MockHal {
    fn limit_closed(&self, axis: Axis) -> bool {
        let i = axis.index();
        self.forced_closed[i].is_some_and(|t| self.now >= t) || self.switches[i].closed(self.pos[i])
    }
}

impl Detector for MockHal {
    fn start_exposure(&mut self, exposure_us: u32) {
        self.exposures.push((self.now, exposure_us));
        self.exposure_done_us = Some(self.now + exposure_us as u64);
    }
    fn poll_readout(&mut self) -> Option<Readout> {
        if self.detector_dead {
            return None;
        }
        let done = self.exposure_done_us?;
        if self.now < done {
            return None;
        }
        self.exposure_done_us = None;
        let mut r = Readout::new();
        r.push(self.exposures.len() as u32).unwrap();
        r.push(7).unwrap();
        Some(r)
    }
}

pub fn frame(seq: u16, msg: &HostMsg) -> Vec<u8> {
    let mut out = [0u8; MAX_WIRE_FRAME];
    let n = encode(seq, msg, &mut out).unwrap();
    out[..n].to_vec()
}

/// Device + mock HAL + host side.
pub struct Bench {
    pub dev: Box<Device>,
    pub hal: MockHal,
    pub cfg: InstrumentConfig<f32>,
    host_dec: FrameDecoder,
    pub host_seq: u16,
    /// Every device message received, in order.
    pub log: Vec<DeviceMsg>,
    /// Device frame sequence numbers seen (to check the device numbers its frames).
    pub device_seqs: Vec<u16>,
    /// Every frame `send` sent, with its sequence number (to replay them).
    pub sent: Vec<(u16, Vec<u8>)>,
}

impl Bench {
    pub fn new(cfg: InstrumentConfig<f32>) -> Self {
        Self {
            dev: Box::new(Device::new()),
            hal: MockHal::new(&cfg),
            cfg,
            host_dec: FrameDecoder::new(),
            host_seq: 0,
            log: Vec::new(),
            device_seqs: Vec::new(),
            sent: Vec::new(),
        }
    }

    /// Feed raw bytes, draining the outbox whenever the device throttles; returns the messages
    /// that came back.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Vec<DeviceMsg> {
        let start = self.log.len();
        let mut rest = bytes;
        let mut stalls = 0;
        while !rest.is_empty() {
            let n = self.dev.receive(&mut self.hal, rest);
            rest = &rest[n..];
            if n == 0 {
                stalls += 1;
                assert!(stalls < 1000, "device stopped consuming input");
            }
            self.collect();
        }
        self.dev.poll(&mut self.hal);
        self.collect();
        self.log[start..].to_vec()
    }

    /// Send a message with the next sequence number.
    pub fn send(&mut self, msg: HostMsg) -> Vec<DeviceMsg> {
        let seq = self.host_seq;
        self.host_seq = self.host_seq.wrapping_add(1);
        let f = frame(seq, &msg);
        self.sent.push((seq, f.clone()));
        self.send_raw(&f)
    }

    /// Drain the outbox and decode what the device sent.
    pub fn collect(&mut self) {
        for Frame { seq, msg } in drain_device(&mut self.dev, &mut self.host_dec) {
            self.device_seqs.push(seq);
            self.log.push(msg);
        }
    }

    pub fn handshake_and_configure(&mut self) {
        let r = self.send(HostMsg::Hello(Hello::OURS));
        assert!(r.contains(&DeviceMsg::Hello(Hello::OURS)), "{r:?}");
        let r = self.send(HostMsg::Configure(self.cfg));
        assert!(r.iter().any(|m| matches!(m, DeviceMsg::Credit { .. })), "{r:?}");
    }

    /// `status` with the GetStatus at sequence number `seq` (after a new session).
    pub fn status_at(&mut self, seq: u16) -> Status {
        self.host_seq = seq;
        self.status()
    }

    pub fn status(&mut self) -> Status {
        let r = self.send(HostMsg::GetStatus);
        r.into_iter()
            .find_map(|m| match m {
                DeviceMsg::Status(s) => Some(s),
                _ => None,
            })
            .expect("a status reply")
    }

    /// Advance the clock to the device's next deadline and poll; `false` if it has none.
    pub fn tick(&mut self) -> bool {
        let Some(t) = self.dev.next_deadline_us() else {
            return false;
        };
        self.hal.now = self.hal.now.max(t);
        self.dev.poll(&mut self.hal);
        self.collect();
        true
    }

    /// Tick until the device has nothing to do on its own or `max_us` of simulated time passed.
    pub fn run_idle(&mut self, max_us: u64) {
        let end = self.hal.now + max_us;
        while self.hal.now < end && self.tick() {}
    }

    pub fn home(&mut self) {
        let r = self.send(HostMsg::Home);
        assert!(!r.iter().any(|m| matches!(m, DeviceMsg::Refused { .. })), "{r:?}");
        self.run_idle(600_000_000);
        assert_eq!(
            self.dev.controller().state(),
            ControllerState::Ready,
            "{:?}",
            self.log.last()
        );
    }

    /// Send `dirs` as plan chunks from `first`, as far as one credit allows; returns how many went.
    pub fn send_plan(&mut self, first: u32, dirs: &[Direction]) -> Vec<DeviceMsg> {
        let mut out = Vec::new();
        for (k, chunk) in dirs.chunks(gonio_shared::msg::caps::CHUNK_DIRECTIONS).enumerate() {
            let mut directions = heapless::Vec::new();
            for d in chunk {
                directions.push(*d).unwrap();
            }
            let first_index = first + (k * gonio_shared::msg::caps::CHUNK_DIRECTIONS) as u32;
            out.extend(self.send(HostMsg::Plan(PlanChunk {
                first_index,
                directions,
            })));
        }
        out
    }

    pub fn refusals(&self) -> Vec<&DeviceMsg> {
        self.log
            .iter()
            .filter(|m| matches!(m, DeviceMsg::Refused { .. }))
            .collect()
    }
}

/// A direction pair from degrees.
pub fn dir_deg(ti: f32, pi: f32, to: f32, po: f32) -> Direction {
    Direction {
        theta_i: ti.to_radians(),
        phi_i: pi.to_radians(),
        theta_o: to.to_radians(),
        phi_o: po.to_radians(),
    }
}

/// The arms' separation invariant on true step positions.
pub fn separation_ok(cfg: &InstrumentConfig<f32>, pos: &[i64; 4]) -> bool {
    let k = kin(cfg);
    let sep = pos[0] as f64 / k.steps_per_radian(Axis::Light) as f64
        - pos[1] as f64 / k.steps_per_radian(Axis::Detector) as f64;
    let b = cfg.blocking_angle as f64;
    sep >= b - 1e-6 && sep <= std::f64::consts::TAU - b + 1e-6
}

/// A proptest configuration with a fixed seed (reproducible in CI) and no regression files.
pub fn fixed_seed_config(cases: u32, seed: u64) -> proptest::test_runner::Config {
    proptest::test_runner::Config {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        failure_persistence: None,
        ..proptest::test_runner::Config::default()
    }
}

/// Everything in the device's outbox, decoded by the host's `dec` (a frame that does not decode
/// fails the test).
pub fn drain_device(dev: &mut Device, dec: &mut FrameDecoder) -> Vec<Frame<DeviceMsg>> {
    let mut frames = Vec::new();
    let mut buf = [0u8; 256];
    loop {
        let n = dev.drain_outbox(&mut buf);
        if n == 0 {
            return frames;
        }
        for &b in &buf[..n] {
            match dec.push::<DeviceMsg>(b) {
                None => {}
                Some(Ok(f)) => frames.push(f),
                Some(Err(e)) => panic!("the device sent a frame that does not decode: {e:?}"),
            }
        }
    }
}
