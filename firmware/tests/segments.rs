//! Step segments against the analytic trapezoid, at timer-tick resolution: every step's tick within
//! 1 us of the ideal instant (computed here in f64 from the same f32 profile), the exact step count,
//! and four axes at 50 kHz at once played by their compare channels with no late step.

mod common;

use common::*;
use gonio_firmware::segment::{AxisProfile, Playback, Segment, SegmentGen};
use gonio_firmware::step_queue::{StepQueue, PULSE_TICKS};
use gonio_firmware::stepper::Stepper;
use gonio_firmware::timed::{tick, QueuedHal, SharedQueue, LOOKAHEAD_US};
use gonio_firmware::{Clock, Detector, Readout, Switches};
use gonio_shared::instrument::{InstrumentConfig, AXES};
use gonio_shared::motion::Trapezoid;
use gonio_shared::Axis;
use std::cell::RefCell;

/// The ideal instant of step `k` of `n`, microseconds after the move's start, in f64.
fn ideal_us(unit: &Trapezoid<f32>, n: u32, k: u32) -> f64 {
    let (n, k) = (n as f64, k as f64);
    let a = unit.accel as f64 * n;
    let v = unit.peak_speed as f64 * n;
    let ramp = (v * v / (2.0 * a)).min(n / 2.0);
    let t_ramp = (2.0 * ramp / a).sqrt();
    let t = if k <= ramp {
        (2.0 * k / a).sqrt()
    } else if k < n - ramp {
        t_ramp + (k - ramp) / v
    } else {
        t_ramp + (n - 2.0 * ramp) / v + t_ramp - (2.0 * (n - k) / a).sqrt()
    };
    t * 1e6
}

/// Every step tick of one axis's move, as the compare channel plays it, starting at `start_us`.
fn play_axis(unit: &Trapezoid<f32>, n: u32, start_us: u64) -> (Vec<u64>, usize) {
    let mut g = SegmentGen::new(AxisProfile::new(unit, n, true), u64::from(tick(start_us)) << 32);
    let mut ticks = Vec::with_capacity(n as usize);
    let mut segments = 0;
    let mut p = Playback::new();
    while let Some(seg) = g.next_segment() {
        segments += 1;
        assert!(seg.count >= 1);
        p.load(&seg);
        loop {
            ticks.push(start_us + u64::from(p.tick().wrapping_sub(tick(start_us))));
            if !p.schedule() {
                break;
            }
        }
    }
    (ticks, segments)
}

/// Worst |tick - ideal| over a move, in us; asserts the count.
fn worst_error(unit: &Trapezoid<f32>, n: u32, start_us: u64) -> (f64, usize) {
    let (ticks, segments) = play_axis(unit, n, start_us);
    assert_eq!(ticks.len(), n as usize, "step count");
    let mut worst = 0.0f64;
    for (k, &t) in ticks.iter().enumerate() {
        let ideal = start_us as f64 + ideal_us(unit, n, k as u32 + 1);
        let e = (t as f64 - ideal).abs();
        assert!(e <= 1.0, "step {} of {n}: tick {t} vs ideal {ideal:.3}", k + 1);
        worst = worst.max(e);
    }
    (worst, segments)
}

#[test]
fn every_step_is_within_a_microsecond_of_the_trapezoid() {
    let arm = InstrumentConfig::<f32>::reference().axes[0];
    let steps_per_rad = arm.steps_per_radian();
    let mut worst = 0.0f64;
    // Short triangles, trapezoids, and a 70 s cruise (1.26 million steps at 18 kHz); odd and
    // even counts; starts that wrap the 32-bit timer.
    for (n, start) in [
        (1u32, 0u64),
        (2, 17),
        (3, 1 << 20),
        (10, 5),
        (101, 99),
        (4_500, 3),
        (9_000, 0),
        (9_001, 0),
        (40_000, u64::from(u32::MAX) - 250_000),
        (1_260_000, 12_345),
    ] {
        let rad = n as f32 / steps_per_rad;
        let unit = Trapezoid::new(1.0f32, arm.max_speed / rad, arm.max_accel / rad).unwrap();
        let (w, segments) = worst_error(&unit, n, start);
        eprintln!(
            "{n} steps ({:.1} s): {segments} segments, worst {w:.3} us",
            unit.duration()
        );
        worst = worst.max(w);
    }
    eprintln!("worst step error: {worst:.3} us");
}

#[test]
fn slow_homing_ramps_and_coarse_axes_stay_within_a_microsecond() {
    let cfg = coarse_config();
    for axis in AXES {
        let a = cfg.axis(axis);
        for n in [1u32, 7, 60, 333, 2_000] {
            let rad = n as f32 / a.steps_per_radian();
            for scale in [1.0f32, 0.25] {
                let unit = Trapezoid::new(1.0f32, a.max_speed * scale / rad, a.max_accel / rad).unwrap();
                worst_error(&unit, n, 1_000);
            }
        }
    }
}

/// A segment's closed-form end is where playback ends.
#[test]
fn a_segment_ends_where_its_playback_ends() {
    let seg = Segment {
        t0: (u64::from(u32::MAX) - 3) << 32,
        interval: 50 << 32 | 0x8000_0000,
        add: -(1 << 28),
        count: 40,
        increasing: false,
    };
    let mut p = Playback::new();
    p.load(&seg);
    while p.schedule() {}
    assert_eq!(p.tick(), (seg.end().wrapping_add(1 << 31) >> 32) as u32);
}

struct Board {
    real: u64,
}

impl Clock for Board {
    fn now_us(&self) -> u64 {
        self.real
    }
}

impl Switches for Board {
    fn limit_closed(&self, _: Axis) -> bool {
        false
    }
}

impl Detector for Board {
    fn start_exposure(&mut self, _: u32) {}
    fn poll_readout(&mut self) -> Option<Readout> {
        None
    }
}

/// Four axes cruising at 50 kHz each at once (200 k steps/s) through the real stepper, rings and
/// compare channels, the loop refilling only at the stepper's own deadlines: every rise lands on
/// its tick (none late), every pulse is `PULSE_TICKS` high, and the counts and positions are exact.
#[test]
fn four_axes_at_50_khz_at_once_make_no_late_step() {
    let mut cfg = InstrumentConfig::<f32>::reference();
    for a in cfg.axes.iter_mut() {
        // 50 k steps/s, reached in 0.05 s.
        a.max_speed = 50_000.0 / a.steps_per_radian();
        a.max_accel = 1_000_000.0 / a.steps_per_radian();
    }
    let target = [100_000, -100_000, 100_000, -100_000];
    let mut hal = QueuedHal::new(Board { real: 7 }, RefCell::new(StepQueue::new()));
    let mut st = Stepper::new();
    st.start(&mut hal, 7, target, &cfg, 1.0, None).unwrap();
    let mut run_at = st.next_due_us().map(|t| t.saturating_sub(LOOKAHEAD_US));
    let mut rises: [Vec<u32>; 4] = Default::default();
    let mut high_at = [None::<u32>; 4];
    loop {
        let now = hal.board.real;
        let wake = hal
            .queue
            .with(|q| q.next_wake(tick(now)))
            .map(|w| now + u64::from(w.wrapping_sub(tick(now))));
        let Some(t) = [wake, run_at].into_iter().flatten().min() else {
            break;
        };
        hal.board.real = t;
        if wake == Some(t) {
            let (pins, _) = hal.queue.with(|q| q.service(tick(t)));
            for i in 0..4 {
                if pins.step_high & (1 << i) != 0 {
                    rises[i].push(tick(t));
                    high_at[i] = Some(tick(t));
                }
                if pins.step_low & (1 << i) != 0 {
                    assert_eq!(Some(tick(t).wrapping_sub(PULSE_TICKS)), high_at[i], "pulse width");
                }
            }
        }
        if run_at.is_some_and(|r| r <= t) {
            st.poll(&mut hal, t + LOOKAHEAD_US, None).unwrap();
            run_at = st.next_due_us().map(|d| d.saturating_sub(LOOKAHEAD_US).max(t + 1));
        }
    }
    let stats = hal.queue.with(|q| q.stats());
    assert_eq!((stats.late, stats.overruns), (0, 0), "{stats:?}");
    assert_eq!(st.position(), target);
    let fastest: Vec<u32> = rises
        .iter()
        .map(|r| r.windows(2).map(|w| w[1].wrapping_sub(w[0])).min().unwrap())
        .collect();
    for (i, r) in rises.iter().enumerate() {
        assert_eq!(r.len(), 100_000, "axis {i}");
    }
    assert!(
        fastest.iter().all(|&f| f == 20),
        "shortest interval per axis {fastest:?} ticks"
    );
}
