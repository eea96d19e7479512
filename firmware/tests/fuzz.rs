//! Seeded, bounded fuzzing in the normal test run (`docs/firmware.md`, "Fuzzing"): the frame
//! decoders under random bytes and under CRC-valid frames around random payloads, then a `Device`
//! behind `QueuedHal` + `StepQueue` (simulated compare interrupts, EXTI trips, switches, a detector
//! that sometimes never answers) driven by a hostile host: valid commands with random arguments,
//! impossible configurations, wrong sequence numbers, garbage and random CRC-valid payloads.
//!
//! Checks: no panic, no hang (bounded loop turns at one instant), no step queue overrun, no lost
//! reply (every frame with the expected sequence number is acknowledged, every `GetStatus`
//! answered), every device frame decodes. Each test prints its counts. Longer, unseeded runs of
//! the decoder: `cargo fuzz run frame_decoder` in `shared/fuzz`.

mod common;

use common::board::{isr, isr_at, sim_hal, SimHal};
use common::*;
use gonio_firmware::timed::SharedQueue;
use gonio_firmware::Device;
use gonio_shared::frame::{encode, Frame, FrameDecoder, MAX_PAYLOAD, MAX_WIRE_FRAME};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::msg::{DeviceMsg, Direction, Hello, HostMsg, PlanChunk, PROTOCOL_VERSION};

/// SplitMix64: small, seeded, good enough to pick fuzz inputs.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn chance(&mut self, p: f64) -> bool {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64 <= p
    }
    fn f32_in(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next() >> 40) as f32 / (1u64 << 24) as f32)
    }
    /// A float a hostile host might send: ordinary, tiny, huge, zero, negative, infinite or NaN.
    fn hostile_f32(&mut self, ordinary: f32) -> f32 {
        match self.below(10) {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => -ordinary,
            3 => 0.0,
            4 => f32::MAX,
            5 => 1e-30,
            6 => ordinary * 1e6,
            _ => ordinary * self.f32_in(0.5, 2.0),
        }
    }
}

/// Bytes of a frame with a valid CRC around `payload` (random bytes need not be a message).
fn crc_valid_frame(seq: u16, payload: &[u8]) -> Vec<u8> {
    // A tuple of byte arrays serialises as the bytes themselves (no length prefix).
    let mut out = [0u8; MAX_WIRE_FRAME];
    let mut padded = [0u8; MAX_PAYLOAD];
    padded[..payload.len()].copy_from_slice(payload);
    let a = |k: usize| <[u8; 32]>::try_from(&padded[32 * k..32 * k + 32]).unwrap();
    let n = match payload.len() {
        0..=8 => encode(seq, &<[u8; 8]>::try_from(&padded[..8]).unwrap(), &mut out),
        9..=32 => encode(seq, &a(0), &mut out),
        33..=64 => encode(seq, &(a(0), a(1)), &mut out),
        _ => encode(seq, &(a(0), a(1), a(2), a(3)), &mut out),
    }
    .unwrap();
    out[..n].to_vec()
}

#[test]
fn the_decoders_take_random_bytes_and_crc_valid_random_payloads() {
    let mut rng = Rng(0x26_f022);
    let mut host = FrameDecoder::new();
    let mut device = FrameDecoder::new();
    let (mut bytes, mut accepted) = (0u64, 0u64);
    let mut frame_start = Vec::new();
    // Random bytes, with a delimiter about every 64 so candidate frames keep coming.
    for _ in 0..4_000_000 {
        let b = if rng.chance(1.0 / 64.0) { 0 } else { rng.next() as u8 };
        bytes += 1;
        frame_start.push(b);
        for ok in [
            host.push::<HostMsg>(b).map(|r| r.map(|f| reencode_host(f.seq, &f.msg))),
            device
                .push::<DeviceMsg>(b)
                .map(|r| r.map(|f| reencode_device(f.seq, &f.msg))),
        ]
        .into_iter()
        .flatten()
        .flatten()
        {
            // Nothing is accepted that is not exactly the canonical frame it decodes to.
            assert_eq!(ok, frame_start, "an accepted frame is not canonical");
            accepted += 1;
        }
        if b == 0 {
            frame_start.clear();
        }
    }
    // Frames with a valid CRC around random payloads: only well-formed messages get through.
    let (mut crc_frames, mut messages, mut non_canonical) = (0u64, 0u64, 0u64);
    for i in 0..1_000_000u32 {
        let len = rng.below(MAX_PAYLOAD as u64 + 1) as usize;
        let len = len.min(128);
        let payload: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
        let f = crc_valid_frame(i as u16, &payload);
        crc_frames += 1;
        for &b in &f {
            if let Some(Ok(frame)) = host.push::<HostMsg>(b) {
                // postcard takes over-long varints: the message re-encodes shorter, to a frame
                // that decodes to itself.
                let canonical = reencode_host(frame.seq, &frame.msg);
                if canonical != f {
                    non_canonical += 1;
                }
                let mut again = FrameDecoder::new();
                let back = canonical
                    .iter()
                    .find_map(|&b| again.push::<HostMsg>(b))
                    .unwrap()
                    .unwrap();
                assert_eq!(reencode_host(back.seq, &back.msg), canonical);
                messages += 1;
            }
        }
    }
    eprintln!(
        "fuzz decoders: {bytes} random bytes ({accepted} accepted frames), {crc_frames} CRC-valid random frames ({messages} decoded to host messages, {non_canonical} of them not in canonical form)"
    );
    assert!(crc_frames >= 1_000_000);
}

fn reencode_host(seq: u16, msg: &HostMsg) -> Vec<u8> {
    let mut out = [0u8; MAX_WIRE_FRAME];
    let n = encode(seq, msg, &mut out).expect("an accepted frame re-encodes");
    out[..n].to_vec()
}

fn reencode_device(seq: u16, msg: &DeviceMsg) -> Vec<u8> {
    let mut out = [0u8; MAX_WIRE_FRAME];
    let n = encode(seq, msg, &mut out).expect("an accepted frame re-encodes");
    out[..n].to_vec()
}

#[derive(Default, Debug)]
struct Counts {
    frames: u64,
    good_frames: u64,
    garbage: u64,
    crc_random: u64,
    device_frames: u64,
    refusals: u64,
    faults: u64,
    measurements: u64,
    step_edges: u64,
    trips: u64,
    configures_refused: u64,
}

struct Fuzz {
    rng: Rng,
    dev: Box<Device>,
    hal: SimHal,
    run_at: Option<u64>,
    seq: u16,
    dec: FrameDecoder,
    got: Vec<DeviceMsg>,
    counts: Counts,
    last_measurement: u32,
    fault_kinds: std::collections::BTreeMap<String, u64>,
}

impl Fuzz {
    fn drain(&mut self) {
        for Frame { msg, .. } in drain_device(&mut self.dev, &mut self.dec) {
            self.counts.device_frames += 1;
            match &msg {
                DeviceMsg::Refused { .. } => self.counts.refusals += 1,
                DeviceMsg::Fault(f) => {
                    self.counts.faults += 1;
                    *self
                        .fault_kinds
                        .entry(format!("{f:?}").split([' ', '(']).next().unwrap_or("").to_string())
                        .or_default() += 1;
                }
                DeviceMsg::Measurement(m) => {
                    self.counts.measurements += 1;
                    self.last_measurement = self.last_measurement.max(m.seq);
                }
                _ => {}
            }
            self.got.push(msg);
        }
    }

    /// Offer `bytes`, draining the outbox whenever the device throttles.
    fn feed(&mut self, bytes: &[u8]) {
        let mut rest = bytes;
        let mut stalls = 0;
        while !rest.is_empty() {
            let n = self.dev.receive(&mut self.hal, rest);
            rest = &rest[n..];
            stalls = if n == 0 { stalls + 1 } else { 0 };
            assert!(stalls < 100, "the device stopped taking input");
            self.drain();
        }
        self.run_at = self.hal.run(&mut self.dev);
        self.drain();
    }

    fn random_direction(&mut self) -> Direction {
        let r = &mut self.rng;
        if r.chance(0.01) {
            return Direction {
                theta_i: r.hostile_f32(0.5),
                phi_i: r.hostile_f32(0.1),
                theta_o: r.hostile_f32(0.5),
                phi_o: r.hostile_f32(3.0),
            };
        }
        if r.chance(0.001) {
            // Anywhere, often below the horizon or into the arms' blocking angle.
            return dir_deg(r.f32_in(0.0, 95.0), 0.0, r.f32_in(0.0, 95.0), r.f32_in(-180.0, 180.0));
        }
        dir_deg(r.f32_in(10.0, 60.0), 0.0, r.f32_in(10.0, 70.0), r.f32_in(150.0, 210.0))
    }

    fn config(&mut self) -> InstrumentConfig<f32> {
        let r = &mut self.rng;
        let mut c = if r.chance(0.7) {
            coarse_config()
        } else {
            InstrumentConfig::reference()
        };
        let a = r.below(4) as usize;
        match r.below(10) {
            0 => c.axes[a].max_speed = r.hostile_f32(c.axes[a].max_speed),
            1 => c.axes[a].max_accel = r.hostile_f32(c.axes[a].max_accel),
            2 => c.axes[a].gear_ratio = r.hostile_f32(c.axes[a].gear_ratio),
            3 => c.axes[a].max = r.hostile_f32(c.axes[a].max),
            4 => c.blocking_angle = r.hostile_f32(c.blocking_angle),
            5 => c.settle_ms = r.next() as u32 >> r.below(32),
            6 => c.exposure_us = r.next() as u32 >> r.below(32),
            // As fast as the cap allows (and just beyond it).
            7 => c.axes[a].max_speed = 50_000.0 * r.f32_in(0.9, 1.1) / c.axes[a].steps_per_radian(),
            _ => {}
        }
        c
    }

    /// A command with random arguments. Mostly what a host running a scan sends, so scans do run
    /// (homing, moves, readings); now and then one that breaks it up.
    fn command(&mut self) -> HostMsg {
        use gonio_shared::msg::ControllerState::*;
        let st = self.dev.controller().status(0);
        let r = &mut self.rng;
        if matches!(st.state, Idle | Fault) && r.chance(0.3) {
            return HostMsg::Home;
        }
        if matches!(st.state, Ready) && r.chance(0.3) {
            return HostMsg::Start;
        }
        // Now and then (about once per homing) a command that breaks up what runs.
        match r.below(30_000) {
            0 => return HostMsg::Configure(self.config()),
            1 => return HostMsg::Home,
            2 => return HostMsg::Abort,
            _ => {}
        }
        match r.below(1000) {
            0..=299 => {
                let first_index = if r.chance(0.98) {
                    st.plan_next
                } else {
                    r.next() as u32 >> r.below(32)
                };
                let n = 1 + r.below(gonio_shared::msg::caps::CHUNK_DIRECTIONS as u64) as usize;
                let mut directions = heapless::Vec::new();
                for _ in 0..n {
                    let d = self.random_direction();
                    directions.push(d).unwrap();
                }
                HostMsg::Plan(PlanChunk {
                    first_index,
                    directions,
                })
            }
            300..=309 => HostMsg::PlanEnd {
                total: st.plan_next + r.below(40) as u32,
            },
            310..=399 => HostMsg::Start,
            400..=409 => HostMsg::Pause,
            410..=459 => HostMsg::Resume,
            460..=699 => HostMsg::GetStatus,
            700..=949 => HostMsg::AckMeasurements {
                through: self.last_measurement.saturating_sub(r.below(3) as u32),
            },
            _ => HostMsg::ResendMeasurements {
                from: self.last_measurement.saturating_sub(r.below(200) as u32),
            },
        }
    }

    /// One host frame (or garbage), and its answer checked.
    fn host_turn(&mut self) {
        self.counts.frames += 1;
        self.got.clear();
        match self.rng.below(100) {
            // A new session.
            0 => {
                let mut hello = Hello::ours(self.rng.next() as u32);
                if self.rng.chance(0.2) {
                    hello.protocol = PROTOCOL_VERSION.wrapping_add(1);
                }
                self.feed(&frame(0, &HostMsg::Hello(hello)));
                self.seq = 1;
                assert!(
                    self.got.contains(&DeviceMsg::Ack { seq: 0 })
                        && self.got.iter().any(|m| matches!(m, DeviceMsg::Hello(_))),
                    "Hello unanswered: {:?}",
                    self.got
                );
            }
            1..=3 => {
                self.counts.garbage += 1;
                let n = 1 + self.rng.below(80) as usize;
                let mut bytes: Vec<u8> = (0..n).map(|_| self.rng.next() as u8).collect();
                bytes.push(0);
                self.feed(&bytes);
            }
            4..=5 => {
                self.counts.crc_random += 1;
                let len = self.rng.below(128) as usize;
                let payload: Vec<u8> = (0..len).map(|_| self.rng.next() as u8).collect();
                let seq = self.seq;
                self.feed(&crc_valid_frame(seq, &payload));
                // Taken as a command (a random payload that is one), NAKed, or nothing else.
                if self.got.contains(&DeviceMsg::Ack { seq }) {
                    self.seq = self.seq.wrapping_add(1);
                }
            }
            6..=7 => {
                // A stale or a future sequence number: re-acknowledged or NAKed, never executed.
                let seq = self.seq.wrapping_add(self.rng.below(200) as u16).wrapping_sub(100);
                if seq != self.seq {
                    self.feed(&frame(seq, &HostMsg::GetStatus));
                    assert!(
                        self.got
                            .iter()
                            .any(|m| matches!(m, DeviceMsg::Ack { .. } | DeviceMsg::Nak { .. })),
                        "frame {seq} (expected {}) unanswered: {:?}",
                        self.seq,
                        self.got
                    );
                }
            }
            _ => {
                let msg = self.command();
                let seq = self.seq;
                self.seq = self.seq.wrapping_add(1);
                self.feed(&frame(seq, &msg));
                self.counts.good_frames += 1;
                assert!(
                    self.got.contains(&DeviceMsg::Ack { seq }),
                    "frame {seq} ({msg:?}) not acknowledged: {:?}",
                    self.got
                );
                if matches!(msg, HostMsg::GetStatus) {
                    assert!(
                        self.got.iter().any(|m| matches!(m, DeviceMsg::Status(_))),
                        "status lost"
                    );
                }
                if matches!(msg, HostMsg::Configure(_))
                    && self.got.iter().any(|m| matches!(m, DeviceMsg::Refused { .. }))
                {
                    self.counts.configures_refused += 1;
                }
            }
        }
    }

    /// The board for `us` of real time: compare interrupts, switches, the controller loop.
    fn advance(&mut self, us: u64) {
        let until = self.hal.board.real + us;
        let (mut last_t, mut same) = (u64::MAX, 0u32);
        loop {
            let isr = isr_at(&self.hal);
            let Some(t) = [isr, self.run_at].into_iter().flatten().min().filter(|&t| t <= until) else {
                break;
            };
            same = if t == last_t { same + 1 } else { 0 };
            last_t = t;
            assert!(same < 1_000, "stuck at t = {t} us");
            self.hal.board.real = self.hal.board.real.max(t);
            if isr.is_some_and(|w| w <= t) {
                self.isr();
            }
            if self.run_at.is_some_and(|r| r <= t) {
                self.run_at = self.hal.run(&mut self.dev);
                self.drain();
            }
        }
        self.hal.board.real = self.hal.board.real.max(until);
    }

    fn isr(&mut self) {
        let (rose, closed) = isr(&mut self.hal);
        self.counts.step_edges += u64::from(rose.count_ones());
        if closed != 0 {
            self.counts.trips += 1;
        }
    }
}

#[test]
fn a_device_on_the_step_queue_survives_a_million_hostile_host_frames() {
    let cfg = coarse_config();
    let mut f = Fuzz {
        rng: Rng(0x0026_5eed),
        dev: Box::new(Device::new()),
        hal: sim_hal(&cfg, [0; 4]),
        run_at: Some(0),
        seq: 0,
        dec: FrameDecoder::new(),
        got: Vec::new(),
        counts: Counts::default(),
        last_measurement: 0,
        fault_kinds: Default::default(),
    };
    f.feed(&frame(0, &HostMsg::Hello(Hello::ours(1))));
    f.seq = 1;
    while f.counts.frames < 1_000_000 {
        f.host_turn();
        // Real time between frames: mostly short, now and then long enough for moves to end.
        let us = if f.rng.chance(0.01) {
            f.rng.below(2_000_000)
        } else {
            f.rng.below(2_000)
        };
        f.advance(us);
        // A switch forced closed for a while (an EXTI trip), a detector that dies or recovers.
        if f.hal.board.forced != 0 && f.rng.chance(0.1) {
            f.hal.board.forced = 0;
        } else if f.rng.chance(0.0002) {
            let bit = 1u8 << f.rng.below(4);
            f.hal.board.forced |= bit;
            f.counts.trips += 1;
            f.hal.queue.with(|q| q.trip(bit));
        }
        if f.rng.chance(0.0005) {
            f.hal.board.detector_dead = !f.hal.board.detector_dead;
        }
        let overruns = f.hal.queue.with(|q| q.stats().overruns);
        assert_eq!(overruns, 0, "step queue overrun after {:?}", f.counts);
    }
    let st = f.hal.queue.with(|q| q.stats());
    eprintln!(
        "fuzz device: {:?}; faults {:?}; step queue {st:?}; {:.0} s of instrument time",
        f.counts,
        f.fault_kinds,
        f.hal.board.real as f64 * 1e-6
    );
    assert!(
        f.counts.measurements > 0 && f.counts.step_edges > 0 && f.counts.faults > 0,
        "the fuzz run never reached a scan: {:?}",
        f.counts
    );
}
