//! The board's step path, simulated: the controller runs ahead of real time through `QueuedHal`,
//! simulated compare channels play the `StepQueue`'s segments back at their compare ticks, and the motors' true
//! positions come only from the played STEP edges and DIR levels. Switches close on those true
//! positions and raise the EXTI trip as the board's interrupt does.
//!
//! Checks: the controller's positions equal the true ones after homing (found by EXTI trips) and at
//! every measurement; the queue never runs dry (no event played late) at full speed on the reference
//! instrument; a limit switch stops playback at the instant it closes and faults.

mod common;

use common::board::{isr, isr_at, sim_hal, SimHal};
use common::*;
use gonio_firmware::step_queue::QueueStats;
use gonio_firmware::timed::{tick, SharedQueue};
use gonio_firmware::Device;
use gonio_shared::frame::FrameDecoder;
use gonio_shared::instrument::{InstrumentConfig, AXES};
use gonio_shared::msg::{ControllerState, DeviceMsg, Direction, Fault, Hello, HostMsg, Measurement, PlanChunk};
use gonio_shared::Axis;

struct Sim {
    dev: Box<Device>,
    hal: SimHal,
    run_at: Option<u64>,
    host_seq: u16,
    dec: FrameDecoder,
    log: Vec<DeviceMsg>,
    /// (real time, axis) of every rising STEP edge.
    edges: Vec<(u64, Axis)>,
    /// True positions when each measurement's exposure started.
    at_exposure: Vec<[i64; 4]>,
}

impl Sim {
    fn new(cfg: InstrumentConfig<f32>, start: [i64; 4]) -> Self {
        let mut s = Self {
            dev: Box::new(Device::new()),
            hal: sim_hal(&cfg, start),
            run_at: Some(0),
            host_seq: 0,
            dec: FrameDecoder::new(),
            log: Vec::new(),
            edges: Vec::new(),
            at_exposure: Vec::new(),
        };
        s.send(HostMsg::Hello(Hello::OURS));
        s.send(HostMsg::Configure(cfg));
        s
    }

    fn collect(&mut self) {
        let frames = drain_device(&mut self.dev, &mut self.dec);
        self.log.extend(frames.into_iter().map(|f| f.msg));
    }

    fn send(&mut self, msg: HostMsg) {
        let f = frame(self.host_seq, &msg);
        self.host_seq = self.host_seq.wrapping_add(1);
        let mut rest = &f[..];
        while !rest.is_empty() {
            let n = self.dev.receive(&mut self.hal, rest);
            rest = &rest[n..];
            self.collect();
        }
        self.run_at = self.hal.run(&mut self.dev);
        self.collect();
    }

    fn stats(&self) -> QueueStats {
        self.hal.queue.with(|q| q.stats())
    }

    fn isr_at(&self) -> Option<u64> {
        isr_at(&self.hal)
    }

    /// The compare interrupt; every rising STEP edge is logged.
    fn isr(&mut self) {
        let now = self.hal.board.real;
        let (rose, _) = isr(&mut self.hal);
        self.edges.extend(
            AXES.into_iter()
                .filter(|a| rose & (1 << a.index()) != 0)
                .map(|a| (now, a)),
        );
    }

    /// Run until nothing is scheduled or `until` (real time); a switch forced closed at `force`.
    fn run_until(&mut self, until: u64, mut force: Option<(u64, Axis)>) {
        let (mut last_t, mut same) = (u64::MAX, 0u32);
        loop {
            let isr = self.isr_at();
            let next = [isr, self.run_at, force.map(|f| f.0)].into_iter().flatten().min();
            let Some(t) = next else { return };
            if t > until {
                return;
            }
            // Neither the timer nor the loop may spin at one instant.
            same = if t == last_t { same + 1 } else { 0 };
            last_t = t;
            assert!(same < 1_000, "stuck at t = {t} us: {:?}", self.stats());
            self.hal.board.real = self.hal.board.real.max(t);
            if let Some((at, axis)) = force.filter(|f| f.0 <= t) {
                force = None;
                let bit = 1u8 << axis.index();
                self.hal.board.forced |= bit;
                let _ = at;
                self.hal.queue.with(|q| q.trip(bit));
                continue;
            }
            if isr.is_some_and(|w| w <= t) {
                self.isr();
            }
            if self.run_at.is_some_and(|r| r <= t) {
                let exposures = self.hal.board.exposures;
                self.run_at = self.hal.run(&mut self.dev);
                if self.hal.board.exposures > exposures {
                    self.at_exposure.push(self.hal.board.pos);
                }
                self.collect();
            }
        }
    }

    /// The reference instrument homed and 300 ms into the first of two four-axis moves (its
    /// rings hold many steps).
    fn mid_move() -> (InstrumentConfig<f32>, Self) {
        let cfg = InstrumentConfig::<f32>::reference();
        let mut sim = Self::new(cfg, [0; 4]);
        sim.home();
        sim.plan(&[dir_deg(70.0, 0.0, 10.0, 90.0), dir_deg(10.0, 0.0, 70.0, -90.0)]);
        sim.send(HostMsg::Start);
        let t0 = sim.hal.board.real;
        sim.run_until(t0 + 300_000, None);
        assert!(sim.dev.controller().is_moving());
        (cfg, sim)
    }

    fn home(&mut self) {
        self.send(HostMsg::Home);
        self.run_until(u64::MAX, None);
        assert_eq!(
            self.dev.controller().state(),
            ControllerState::Ready,
            "{:?}",
            self.dev.controller().last_fault()
        );
    }

    fn plan(&mut self, dirs: &[Direction]) {
        let mut directions = heapless::Vec::new();
        for d in dirs {
            directions.push(*d).unwrap();
        }
        self.send(HostMsg::Plan(PlanChunk {
            first_index: 0,
            directions,
        }));
        self.send(HostMsg::PlanEnd {
            total: dirs.len() as u32,
        });
    }

    fn measurements(&self) -> Vec<Measurement> {
        self.log
            .iter()
            .filter_map(|m| match m {
                DeviceMsg::Measurement(m) => Some(m.clone()),
                _ => None,
            })
            .collect()
    }

    /// Controller positions equal the true ones (continuous axes modulo a turn).
    fn assert_positions_true(&self, cfg: &InstrumentConfig<f32>, fw: [i32; 4], truth: [i64; 4], what: &str) {
        for axis in AXES {
            let i = axis.index();
            if cfg.axis(axis).continuous {
                let rev = steps_per_rev(cfg, axis);
                assert_eq!((truth[i] - fw[i] as i64).rem_euclid(rev), 0, "{axis:?} {what}");
            } else {
                assert_eq!(truth[i], fw[i] as i64, "{axis:?} {what}");
            }
        }
    }
}

#[test]
fn homing_by_exti_trips_and_a_scan_keep_true_positions() {
    let cfg = coarse_config();
    for start in [[0, 0, 0, 0], [-60, 150, 40, 333], [250, -250, -60, -50]] {
        let mut sim = Sim::new(cfg, start);
        sim.home();
        let what = format!("after homing from {start:?}");
        sim.assert_positions_true(&cfg, sim.dev.controller().position(), sim.hal.board.pos, &what);
        assert!(sim.stats().flushed > 0 || sim.stats().steps > 0);
        let dirs = [
            dir_deg(60.0, 0.0, 20.0, 180.0),
            dir_deg(10.0, 0.0, 70.0, 180.0),
            dir_deg(45.0, 0.0, 30.0, 90.0),
            dir_deg(20.0, 0.0, 50.0, -120.0),
        ];
        sim.plan(&dirs);
        sim.send(HostMsg::Start);
        sim.run_until(u64::MAX, None);
        assert_eq!(sim.dev.controller().state(), ControllerState::Done);
        let ms = sim.measurements();
        assert_eq!(ms.len(), dirs.len());
        assert_eq!(sim.at_exposure.len(), dirs.len());
        for (m, truth) in ms.iter().zip(&sim.at_exposure) {
            sim.assert_positions_true(&cfg, m.steps, *truth, &format!("at measurement {}", m.index));
        }
        let st = sim.stats();
        assert_eq!((st.overruns, st.late), (0, 0), "{st:?}");
    }
}

#[test]
fn the_queue_keeps_ahead_at_full_speed_on_the_reference_instrument() {
    let cfg = InstrumentConfig::<f32>::reference();
    let mut sim = Sim::new(cfg, [0; 4]);
    sim.home();
    let homing_edges = sim.edges.len();
    // A long move of all four axes at once.
    sim.plan(&[dir_deg(70.0, 0.0, 10.0, 90.0), dir_deg(10.0, 0.0, 70.0, -90.0)]);
    sim.send(HostMsg::Start);
    sim.run_until(u64::MAX, None);
    assert_eq!(sim.dev.controller().state(), ControllerState::Done);
    let st = sim.stats();
    assert_eq!((st.overruns, st.late), (0, 0), "{st:?}");
    let scan_edges = &sim.edges[homing_edges..];
    // The fastest arm interval seen: the reference arms run at full speed (tens of kHz).
    let light: Vec<u64> = scan_edges.iter().filter(|e| e.1 == Axis::Light).map(|e| e.0).collect();
    let min_dt = light.windows(2).map(|w| w[1] - w[0]).min().unwrap();
    assert!(min_dt <= 100, "light arm never faster than {min_dt} us per step");
    for (m, truth) in sim.measurements().iter().zip(&sim.at_exposure) {
        sim.assert_positions_true(&cfg, m.steps, *truth, "reference scan");
    }
}

#[test]
fn a_limit_switch_stops_playback_at_the_instant_it_closes_and_faults() {
    // The reference instrument, so that the queue holds many steps when the switch closes.
    let (_, mut sim) = Sim::mid_move();
    let queued = sim
        .hal
        .queue
        .with(|q| (0..4).map(|i| 16 - q.room(AXES[i])).sum::<usize>());
    assert!(queued > 4, "only {queued} segments queued");
    let moving_edges = sim.edges.len();
    assert!(moving_edges > 0 && sim.dev.controller().is_moving());
    let t_close = sim.hal.board.real + 1;
    sim.run_until(t_close, Some((t_close, Axis::Tilt)));
    assert_eq!(sim.hal.queue.with(|q| q.tripped()), 1 << Axis::Tilt.index());
    // On the board the switch interrupt can fire in the middle of a poll: what that poll queues
    // after the trip belongs to the halted move and must never play.
    for axis in [Axis::Light, Axis::Detector] {
        let seg = gonio_firmware::segment::Segment {
            t0: u64::from(tick(t_close)) << 32,
            interval: 100 << 32,
            add: 0,
            count: 5,
            increasing: true,
        };
        gonio_firmware::Steppers::queue_segment(&mut sim.hal, axis, seg);
    }
    sim.run_until(u64::MAX, None);
    assert!(
        sim.edges.iter().all(|&(t, _)| t <= t_close),
        "a step after the switch closed"
    );
    assert!(sim.stats().flushed > 0, "queued steps were dropped: {:?}", sim.stats());
    assert!(
        sim.log.contains(&DeviceMsg::Fault(Fault::LimitSwitch(Axis::Tilt))),
        "{:?}",
        sim.log
    );
    assert_eq!(sim.dev.controller().state(), ControllerState::Fault);
    assert!(!sim.dev.controller().homed());
    assert!(sim.measurements().is_empty());
}

/// A switch whose interrupt never fires (an edge the EXTI missed, a contact already closed) is
/// seen by the loop's switch poll: playback stops within `SWITCH_POLL_US` and the queued steps are
/// dropped, not played out.
#[test]
fn a_switch_seen_only_by_polling_stops_playback_and_drops_the_queued_steps() {
    use gonio_firmware::timed::SWITCH_POLL_US;
    let (_, mut sim) = Sim::mid_move();
    // The tilt switch closes with no interrupt: only its level changes.
    let t_close = sim.hal.board.real + 1;
    sim.hal.board.forced |= 1 << Axis::Tilt.index();
    sim.run_until(u64::MAX, None);
    let last = sim.edges.last().map_or(0, |e| e.0);
    assert!(
        last <= t_close + SWITCH_POLL_US,
        "steps {} us after the switch closed",
        last - t_close
    );
    assert!(
        sim.stats().flushed > 0,
        "queued steps were played out: {:?}",
        sim.stats()
    );
    assert!(sim.hal.queue.with(|q| q.is_idle()));
    assert_eq!(faults_in(&sim.log), vec![Fault::LimitSwitch(Axis::Tilt)]);
    assert_eq!(sim.dev.controller().position(), sim.hal.board.pos.map(|p| p as i32));
}

#[test]
fn a_fault_during_homing_drops_the_queued_segments() {
    // The reference instrument: a tilt seek at a quarter speed queues many steps ahead.
    let cfg = InstrumentConfig::<f32>::reference();
    let mut sim = Sim::new(cfg, [0; 4]);
    sim.send(HostMsg::Home);
    // Homing starts with the tilt axis's seek; let it make 100 steps.
    while sim.edges.iter().filter(|e| e.1 == Axis::Tilt).count() < 100 {
        let t = sim.hal.board.real + 1_000;
        sim.run_until(t, None);
        sim.hal.board.real = sim.hal.board.real.max(t);
    }
    assert_eq!(sim.dev.controller().state(), ControllerState::Homing);
    assert!(sim.hal.queue.with(|q| !q.is_idle()), "nothing queued ahead");
    // A plan chunk with a direction below the horizon: rejected with a fault mid-seek.
    sim.plan(&[dir_deg(30.0, 0.0, 100.0, 180.0)]);
    let edges = sim.edges.len();
    let t_fault = sim.hal.board.real;
    sim.run_until(u64::MAX, None);
    let faults: Vec<Fault> = sim
        .log
        .iter()
        .filter_map(|m| match m {
            DeviceMsg::Fault(f) => Some(*f),
            _ => None,
        })
        .collect();
    assert!(
        matches!(faults[..], [Fault::Unreachable { index: 0, .. }]),
        "{faults:?}"
    );
    assert!(!sim.dev.controller().is_moving());
    assert!(sim.hal.queue.with(|q| q.is_idle()));
    assert!(sim.stats().flushed > 0, "{:?}", sim.stats());
    // No step after the fault: the seek did not run on into its switch.
    assert_eq!(sim.edges.len(), edges, "steps after the fault at {t_fault} us");
    assert_eq!(sim.dev.controller().position(), sim.hal.board.pos.map(|p| p as i32));
}

fn faults_in(log: &[DeviceMsg]) -> Vec<Fault> {
    log.iter()
        .filter_map(|m| match m {
            DeviceMsg::Fault(f) => Some(*f),
            _ => None,
        })
        .collect()
}

#[test]
fn a_loop_that_falls_behind_the_step_generator_is_a_steps_late_fault() {
    let (cfg, mut sim) = Sim::mid_move();
    // The loop stalls for 200 ms (far past what the rings hold) while the channels play on.
    let stalled_until = sim.hal.board.real + 200_000;
    sim.run_at = Some(stalled_until);
    sim.run_until(u64::MAX, None);
    assert_eq!(faults_in(&sim.log), vec![Fault::StepsLate]);
    assert_eq!(sim.dev.controller().state(), ControllerState::Fault);
    assert!(!sim.dev.controller().is_moving());
    assert!(sim.hal.queue.with(|q| q.is_idle()));
    // Positions stay counted: what the controller believes is what the motors made.
    sim.assert_positions_true(
        &cfg,
        sim.dev.controller().position(),
        sim.hal.board.pos,
        "after the fault",
    );
    assert!(sim.edges.iter().all(|&(t, _)| t <= stalled_until));
}

#[test]
fn host_frames_during_a_move_are_not_late_steps() {
    let cfg = InstrumentConfig::<f32>::reference();
    let mut sim = Sim::new(cfg, [0; 4]);
    sim.home();
    sim.plan(&[dir_deg(70.0, 0.0, 10.0, 90.0), dir_deg(10.0, 0.0, 70.0, -90.0)]);
    sim.send(HostMsg::Start);
    // A status request every 3 ms for the whole scan.
    let mut frames = 0;
    while sim.dev.controller().state() == ControllerState::Running {
        let t = sim.hal.board.real + 3_000;
        sim.run_until(t, None);
        sim.hal.board.real = sim.hal.board.real.max(t);
        sim.send(HostMsg::GetStatus);
        frames += 1;
    }
    assert!(frames > 100, "{frames} frames");
    sim.run_until(u64::MAX, None);
    assert_eq!(
        sim.dev.controller().state(),
        ControllerState::Done,
        "{:?}",
        faults_in(&sim.log)
    );
    assert_eq!(faults_in(&sim.log), vec![]);
    let st = sim.stats();
    assert_eq!((st.overruns, st.late), (0, 0), "{st:?}");
}
