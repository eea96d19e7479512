//! Safety: homing from any start, a limit switch mid-move, commands in the wrong state, plan
//! directions the instrument cannot reach, a silent detector.

mod common;

use common::*;
use gonio_firmware::homing;
use gonio_shared::instrument::AXES;
use gonio_shared::kinematics::Unreachable;
use gonio_shared::msg::{
    Command, ControllerState, DeviceMsg, Fault, Hello, HostMsg, PlanChunk, RefuseReason, SCHEMA_HASH,
};
use gonio_shared::Axis;
use proptest::prelude::*;

fn fixed(cases: u32) -> proptest::test_runner::Config {
    common::fixed_seed_config(cases, 0x5AFE)
}

fn refused(msgs: &[DeviceMsg]) -> Option<(Command, RefuseReason)> {
    msgs.iter().find_map(|m| match m {
        DeviceMsg::Refused { command, reason, .. } => Some((*command, *reason)),
        _ => None,
    })
}

fn faults(msgs: &[DeviceMsg]) -> Vec<Fault> {
    msgs.iter()
        .filter_map(|m| match m {
            DeviceMsg::Fault(f) => Some(*f),
            _ => None,
        })
        .collect()
}

/// Homes from `start` and checks the firmware's idea of every position against the truth.
fn home_from(start: [i64; 4]) {
    let cfg = coarse_config();
    let k = kin(&cfg);
    let mut b = Bench::new(cfg);
    b.hal.pos = start;
    b.handshake_and_configure();
    b.home();
    let fw = b.dev.controller().position();
    assert!(b.dev.controller().homed());
    for axis in AXES {
        let i = axis.index();
        let rest = homing::rest_position(&k, axis) as i64;
        if cfg.axis(axis).continuous {
            let rev = steps_per_rev(&cfg, axis);
            assert_eq!(
                (b.hal.pos[i] - fw[i] as i64).rem_euclid(rev),
                0,
                "{axis:?} from {start:?}"
            );
            assert_eq!((b.hal.pos[i] - rest).rem_euclid(rev), 0, "{axis:?} from {start:?}");
        } else {
            assert_eq!(b.hal.pos[i], fw[i] as i64, "{axis:?} from {start:?}");
            assert_eq!(b.hal.pos[i], rest, "{axis:?} from {start:?}");
        }
    }
    // Every axis actually travelled to its switch: some step sat on its home position.
    for axis in [Axis::Light, Axis::Detector, Axis::Tilt] {
        let home = homing::home_position(&cfg, axis) as i64;
        let reached = b
            .hal
            .steps
            .iter()
            .any(|s| s.axis == axis && s.after[axis.index()] == home)
            || start[axis.index()] == home;
        assert!(reached, "{axis:?} never reached its switch from {start:?}");
    }
    let s = b.status();
    assert_eq!(s.state, ControllerState::Ready);
    assert!(s.homed);
}

#[test]
fn homing_from_the_ends_and_from_on_the_switches() {
    let cfg = coarse_config();
    let h = |a| homing::home_position(&cfg, a) as i64;
    let rev = steps_per_rev(&cfg, Axis::Azimuth);
    // On every switch (azimuth inside its index window), then at the far ends.
    home_from([h(Axis::Light), h(Axis::Detector), h(Axis::Tilt), rev - 1]);
    home_from([h(Axis::Light) + 3, h(Axis::Detector) - 3, h(Axis::Tilt) - 2, 0]);
    home_from([-h(Axis::Light), -h(Axis::Detector), -h(Axis::Tilt), rev / 2]);
    home_from([0, 0, 0, -7 * rev - 1]);
}

proptest! {
    #![proptest_config(fixed(24))]

    /// Starts anywhere in each axis's travel, up to 1 % past either end (an arm resting slightly
    /// beyond its switch), and azimuth anywhere over several turns.
    #[test]
    fn homing_finds_the_switches_from_any_start(
        light in -1.01f64..=1.01,
        detector in -1.01f64..=1.01,
        tilt in -1.01f64..=1.01,
        azimuth in -2000i64..2000,
    ) {
        let cfg = coarse_config();
        let at = |axis: Axis, f: f64| (f * homing::home_position(&cfg, axis).abs() as f64).round() as i64;
        home_from([at(Axis::Light, light), at(Axis::Detector, detector), at(Axis::Tilt, tilt), azimuth]);
    }
}

#[test]
fn a_switch_that_never_closes_is_a_homing_fault() {
    let cfg = coarse_config();
    let mut b = Bench::new(cfg);
    // The tilt switch is wired wrong: it would close far beyond the travel.
    b.hal.switches[Axis::Tilt.index()] = SwitchModel::AtOrBelow(-100_000);
    b.handshake_and_configure();
    b.send(HostMsg::Home);
    b.run_idle(600_000_000);
    assert_eq!(b.dev.controller().state(), ControllerState::Fault);
    assert_eq!(faults(&b.log), vec![Fault::HomeNotFound(Axis::Tilt)]);
    // The seek was bounded: about the tilt's travel plus margins, not more.
    let travel = homing::seek_steps(&cfg, Axis::Tilt) as usize;
    assert_eq!(b.hal.steps.len(), travel);
}

/// Ready bench with a plan of big moves loaded.
fn running_bench() -> Bench {
    let mut b = Bench::new(coarse_config());
    b.hal.pos = [0, 0, 0, 0];
    b.handshake_and_configure();
    b.home();
    b.hal.steps.clear();
    let plan = [dir_deg(60.0, 0.0, 20.0, 180.0), dir_deg(10.0, 0.0, 70.0, 180.0)];
    b.send_plan(0, &plan);
    b.send(HostMsg::PlanEnd { total: 2 });
    b
}

#[test]
fn a_limit_switch_mid_move_stops_every_axis_within_one_step_and_needs_rehoming() {
    let mut b = running_bench();
    let before = b.hal.step_count;
    // The light switch closes (a crash, a loose arm) 40 steps into the scan.
    b.hal.close_after_steps = Some((Axis::Light, before + 40));
    b.send(HostMsg::Start);
    b.run_idle(60_000_000);
    let closed_at = b.hal.forced_closed[Axis::Light.index()].expect("the switch was closed mid-move");
    for axis in AXES {
        let after = b
            .hal
            .steps
            .iter()
            .filter(|s| s.axis == axis && s.t_us > closed_at)
            .count();
        assert!(after <= 1, "{axis:?} made {after} steps after the switch closed");
    }
    assert!(
        b.hal.steps.iter().filter(|s| s.t_us > closed_at).count() == 0,
        "this design stops before the next step"
    );
    assert_eq!(faults(&b.log), vec![Fault::LimitSwitch(Axis::Light)]);
    assert!(!b.dev.controller().is_moving());
    assert_eq!(b.hal.exposure_count(), 0, "no measurement after a crash");
    let s = b.status();
    assert_eq!(s.state, ControllerState::Fault);
    assert!(!s.homed);
    assert_eq!(s.last_fault, Some(Fault::LimitSwitch(Axis::Light)));
    // Nothing but homing clears it.
    let fault = RefuseReason::WrongState(ControllerState::Fault);
    for (cmd, command, reason) in [
        (HostMsg::Start, Command::Start, RefuseReason::NotHomed),
        (HostMsg::Resume, Command::Resume, fault),
        (HostMsg::Abort, Command::Abort, fault),
    ] {
        let r = b.send(cmd);
        assert_eq!(refused(&r), Some((command, reason)));
    }
    b.hal.forced_closed = [None; 4];
    b.hal.close_after_steps = None;
    b.home();
    assert!(b.dev.controller().homed());
}

#[test]
fn commands_in_the_wrong_state_are_refused_with_a_reason() {
    use RefuseReason::*;
    let cfg = coarse_config();
    let mut b = Bench::new(cfg);
    // Before the handshake.
    assert_eq!(refused(&b.send(HostMsg::Home)), Some((Command::Home, NoHandshake)));
    // A host of another schema is answered (so it can report) but not served.
    let other = Hello {
        schema: SCHEMA_HASH ^ 1,
        ..Hello::OURS
    };
    assert!(b.send(HostMsg::Hello(other)).contains(&DeviceMsg::Hello(Hello::OURS)));
    assert_eq!(refused(&b.send(HostMsg::Start)), Some((Command::Start, NoHandshake)));
    b.send(HostMsg::Hello(Hello::OURS));
    // Not configured.
    assert_eq!(refused(&b.send(HostMsg::Home)), Some((Command::Home, NotConfigured)));
    assert_eq!(refused(&b.send(HostMsg::Start)), Some((Command::Start, NotConfigured)));
    // A bad configuration names its reason.
    let mut bad = cfg;
    bad.blocking_angle = -1.0;
    let r = b.send(HostMsg::Configure(bad));
    assert_eq!(
        refused(&r),
        Some((
            Command::Configure,
            BadConfig(gonio_shared::instrument::ConfigError::BlockingAngle)
        ))
    );
    b.send(HostMsg::Configure(cfg));
    // Idle (not homed): Start says why.
    assert_eq!(refused(&b.send(HostMsg::Start)), Some((Command::Start, NotHomed)));
    assert_eq!(
        refused(&b.send(HostMsg::Resume)),
        Some((Command::Resume, WrongState(ControllerState::Idle)))
    );
    assert_eq!(
        refused(&b.send(HostMsg::Pause)),
        Some((Command::Pause, WrongState(ControllerState::Idle)))
    );
    // Homing.
    b.send(HostMsg::Home);
    assert_eq!(refused(&b.send(HostMsg::Start)), Some((Command::Start, NotHomed)));
    assert_eq!(
        refused(&b.send(HostMsg::Home)),
        Some((Command::Home, WrongState(ControllerState::Homing)))
    );
    assert_eq!(
        refused(&b.send(HostMsg::Configure(cfg))),
        Some((Command::Configure, WrongState(ControllerState::Homing)))
    );
    b.run_idle(600_000_000);
    // Ready: plan checks.
    let chunk = |first_index, n: usize| {
        let mut directions = heapless::Vec::new();
        for k in 0..n {
            directions.push(dir_deg(20.0 + k as f32, 0.0, 40.0, 180.0)).unwrap();
        }
        HostMsg::Plan(PlanChunk {
            first_index,
            directions,
        })
    };
    assert_eq!(
        refused(&b.send(chunk(3, 1))),
        Some((Command::Plan, OutOfOrder { expected: 0 }))
    );
    assert_eq!(
        refused(&b.send(HostMsg::Resume)),
        Some((Command::Resume, WrongState(ControllerState::Ready)))
    );
    assert_eq!(
        refused(&b.send(HostMsg::AckMeasurements { through: 0 })),
        Some((Command::Ack, OutOfOrder { expected: 0 }))
    );
    assert!(refused(&b.send(chunk(0, 2))).is_none());
    assert_eq!(
        refused(&b.send(HostMsg::PlanEnd { total: 1 })),
        Some((Command::PlanEnd, OutOfOrder { expected: 2 }))
    );
    b.send(HostMsg::PlanEnd { total: 2 });
    assert_eq!(refused(&b.send(chunk(2, 1))), Some((Command::Plan, NoCredit)));
    // Running.
    b.send(HostMsg::Start);
    assert_eq!(b.dev.controller().state(), ControllerState::Running);
    assert_eq!(
        refused(&b.send(HostMsg::Start)),
        Some((Command::Start, WrongState(ControllerState::Running)))
    );
    assert_eq!(
        refused(&b.send(HostMsg::Home)),
        Some((Command::Home, WrongState(ControllerState::Running)))
    );
    assert_eq!(
        refused(&b.send(HostMsg::Configure(cfg))),
        Some((Command::Configure, WrongState(ControllerState::Running)))
    );
    // Paused and back.
    assert!(refused(&b.send(HostMsg::Pause)).is_none());
    assert_eq!(b.dev.controller().state(), ControllerState::Paused);
    assert_eq!(
        refused(&b.send(HostMsg::Start)),
        Some((Command::Start, WrongState(ControllerState::Paused)))
    );
    assert!(refused(&b.send(HostMsg::Resume)).is_none());
    b.run_idle(600_000_000);
    // Done.
    assert_eq!(b.dev.controller().state(), ControllerState::Done);
    assert_eq!(
        refused(&b.send(chunk(2, 1))),
        Some((Command::Plan, WrongState(ControllerState::Done)))
    );
    assert_eq!(
        refused(&b.send(HostMsg::Start)),
        Some((Command::Start, WrongState(ControllerState::Done)))
    );
    // Measurement bookkeeping.
    assert!(refused(&b.send(HostMsg::AckMeasurements { through: 0 })).is_none());
    assert_eq!(
        refused(&b.send(HostMsg::ResendMeasurements { from: 0 })),
        Some((Command::Resend, Forgotten { oldest_kept: 1 }))
    );
    // Abort: back to Ready with an empty plan.
    assert!(refused(&b.send(HostMsg::Abort)).is_none());
    assert_eq!(b.dev.controller().state(), ControllerState::Ready);
    assert_eq!(b.status().plan_next, 0);
    assert_eq!(b.dev.outbox().lost_replies(), 0);
}

#[test]
fn an_unreachable_direction_is_rejected_with_its_index_and_reason() {
    let mut b = Bench::new(coarse_config());
    b.handshake_and_configure();
    b.home();
    let plan = [
        dir_deg(20.0, 0.0, 40.0, 180.0),
        dir_deg(30.0, 0.0, 50.0, 180.0),
        dir_deg(30.0, 0.0, 31.0, 0.0), // 1 degree apart: inside the 5 degree blocking angle
        dir_deg(40.0, 0.0, 50.0, 180.0),
    ];
    let r = b.send_plan(0, &plan);
    assert_eq!(
        faults(&r),
        vec![Fault::Unreachable {
            index: 2,
            reason: Unreachable::Blocked
        }]
    );
    let s = b.status();
    assert_eq!(
        s.plan_next, 2,
        "the directions before the bad one were accepted, none after"
    );
    assert_eq!(s.state, ControllerState::Fault);
    // Below the horizon, after clearing with Abort.
    assert!(refused(&b.send(HostMsg::Abort)).is_none());
    let r = b.send_plan(0, &[dir_deg(95.0, 0.0, 30.0, 180.0)]);
    assert_eq!(
        faults(&r),
        vec![Fault::Unreachable {
            index: 0,
            reason: Unreachable::BelowHorizon { incoming: true }
        }]
    );
    assert_eq!(b.hal.exposure_count(), 0);
}

#[test]
fn a_silent_detector_is_a_fault_not_a_hang() {
    let mut b = running_bench();
    b.hal.detector_dead = true;
    b.send(HostMsg::Start);
    b.run_idle(60_000_000);
    assert_eq!(faults(&b.log), vec![Fault::DetectorTimeout]);
    assert_eq!(b.status().state, ControllerState::Fault);
    // Not a motion fault: Abort clears it and the position is still trusted.
    assert!(refused(&b.send(HostMsg::Abort)).is_none());
    assert_eq!(b.status().state, ControllerState::Ready);
    assert!(b.status().homed);
}

#[test]
fn pause_finishes_the_direction_in_flight_and_starts_no_other() {
    let mut b = running_bench();
    b.send(HostMsg::Start);
    // Run until the first move is under way, then pause.
    while b.hal.step_count == 0 {
        assert!(b.tick());
    }
    b.send(HostMsg::Pause);
    b.run_idle(600_000_000);
    assert_eq!(b.dev.controller().state(), ControllerState::Paused);
    assert_eq!(
        b.hal.exposure_count(),
        1,
        "the direction in flight is measured, the next not started"
    );
    let steps_when_paused = b.hal.step_count;
    b.run_idle(600_000_000);
    assert_eq!(b.hal.step_count, steps_when_paused);
    b.send(HostMsg::Resume);
    b.run_idle(600_000_000);
    assert_eq!(b.dev.controller().state(), ControllerState::Done);
    assert_eq!(b.hal.exposure_count(), 2);
}
