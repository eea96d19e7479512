//! Step times as Klipper-style `(interval, count, add)` segments, generated straight from the
//! analytic trapezoid, and the fixed-point arithmetic that plays them back (`docs/firmware.md`,
//! "Segments").
//!
//! Times are 32.32 fixed-point timer ticks (1 tick = 1 us): the high word is the tick, the low word
//! the fraction, and every sum wraps with the 32-bit timer. A segment's `count` steps fall at
//! `t0 + interval`, `t0 + 2 interval + add`, ... (the interval grows by `add` after each step),
//! so playing one costs two additions per step. The generator fits each segment to the ideal step
//! times of one axis: the fixed-point times stay within [`FIT_TOLERANCE`] of the ideal, a step's
//! tick (the rounded time) within half a tick more.

use gonio_shared::motion::Trapezoid;
use gonio_shared::Real;

/// One tick in 32.32 fixed point.
pub const ONE_TICK: u64 = 1 << 32;
/// Largest distance of a segment's step times from the ideal ones, ticks, checked at a quarter
/// and three quarters of each fitted segment, where a cubic residual peaks.
pub const FIT_TOLERANCE: f32 = 0.3;
/// Most steps in a fitted (ramp) segment.
const MAX_FIT: u32 = 1 << 16;
/// Ticks per second.
const TICKS_PER_S: f32 = 1.0e6;

/// Steps of one axis at times following a second-order recurrence.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Segment {
    /// The instant of the step before the first one of this segment (or of the move's start),
    /// 32.32 ticks; the playback resumes from here, so segments never drift apart.
    pub t0: u64,
    /// First interval, 32.32 ticks.
    pub interval: u64,
    /// Added to the interval after every step, 32.32 ticks (negative while accelerating).
    pub add: i64,
    /// Steps in the segment, at least 1.
    pub count: u32,
    /// Direction of every step of the segment.
    pub increasing: bool,
}

impl Segment {
    /// The instant of the segment's last step, exactly as playback computes it.
    pub fn end(&self) -> u64 {
        let c = u64::from(self.count);
        let tri = (c * c.saturating_sub(1) / 2) as i64;
        self.t0
            .wrapping_add(self.interval.wrapping_mul(c))
            .wrapping_add(self.add.wrapping_mul(tri) as u64)
    }
}

/// Playback of segments: where the next step falls. The step interrupt runs this (one channel per
/// axis), and so do the per-step path and every simulation, so all of them make the same steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Playback {
    /// The next step's instant plus half a tick, so its high word is the rounded tick.
    next: u64,
    interval: u64,
    add: i64,
    /// Steps of the current segment not yet scheduled.
    left: u32,
}

impl Playback {
    pub const fn new() -> Self {
        Self {
            next: 0,
            interval: 0,
            add: 0,
            left: 0,
        }
    }

    /// Start playing `seg` (the previous one is finished) and schedule its first step.
    pub fn load(&mut self, seg: &Segment) {
        self.next = seg.t0.wrapping_add(ONE_TICK / 2);
        self.interval = seg.interval;
        self.add = seg.add;
        self.left = seg.count;
        self.schedule();
    }

    /// Schedule the step after the one just made; `false` when the segment has none left (load
    /// the next one).
    #[inline(always)]
    pub fn schedule(&mut self) -> bool {
        if self.left == 0 {
            return false;
        }
        self.left -= 1;
        self.next = self.next.wrapping_add(self.interval);
        self.interval = self.interval.wrapping_add(self.add as u64);
        true
    }

    /// The tick of the scheduled step.
    #[inline(always)]
    pub fn tick(&self) -> u32 {
        (self.next >> 32) as u32
    }

    /// Steps of the current segment after the scheduled one.
    pub fn left(&self) -> u32 {
        self.left
    }
}

/// The ideal step times of one axis in a synchronised move, 32.32 ticks after the move's start.
/// Step `k` (1-based) of `n` falls where the unit trapezoid reaches `k / n`: `c sqrt(k)` on the
/// acceleration ramp, linear in `k` at cruise, mirrored on the deceleration ramp.
#[derive(Clone, Copy, Debug, Default)]
pub struct AxisProfile {
    pub total: u32,
    pub increasing: bool,
    /// Ticks per sqrt(step) on the ramps: 1e6 sqrt(2 / accel).
    c: f32,
    /// Steps covered by each ramp, and its whole part: the last ramp step.
    ramp: f32,
    /// `sqrt(ramp)`, once: every deceleration step time needs it.
    sqrt_ramp: f32,
    last_ramp: u32,
    /// The first step of the deceleration ramp.
    first_decel: u32,
    /// The cruise interval, and the end of the acceleration ramp (the instant of step `ramp`).
    cruise: u64,
    t_ramp: u64,
    /// `(ramp - last_ramp)` cruise intervals.
    frac: u64,
    /// The instant the deceleration ramp starts.
    t_decel: u64,
}

/// Microseconds to timer ticks: the timer counts the same microseconds, modulo 2^32.
pub fn tick(us: u64) -> u32 {
    us as u32
}

/// Fixed point to f32 ticks without a 64-bit conversion routine (whole and fraction apart).
fn to_ticks(x: i64) -> f32 {
    let whole = (x >> 32) as i32 as f32;
    whole + (x as u32) as f32 * (1.0 / ONE_TICK as f32)
}

fn fixed(ticks: f32) -> u64 {
    // Negative and NaN saturate to 0.
    (ticks * ONE_TICK as f32) as u64
}

/// `(num << shift) / den` by shift-and-subtract (no 128-bit division in flash); saturates.
fn shifted_ratio(num: u64, den: u64, shift: u32) -> u64 {
    if den == 0 {
        return u64::MAX;
    }
    let (mut q, mut r) = (num / den, num % den);
    for _ in 0..shift {
        if q >> 63 != 0 {
            return u64::MAX;
        }
        q <<= 1;
        r <<= 1;
        if r >= den {
            r -= den;
            q |= 1;
        }
    }
    q
}

/// Ticks per step at `speed` = `unit_speed * n` steps/s, 32.32, exact to the last bit of the f32
/// speed (a cruise of a million steps stays within a microsecond).
fn cruise_interval(unit_speed: f32, n: u32) -> u64 {
    let bits = unit_speed.to_bits();
    let mantissa = u64::from((bits & 0x7f_ffff) | 0x80_0000);
    // unit_speed = mantissa * 2^exp with exp = biased - 150.
    let exp = ((bits >> 23) & 0xff) as i32 - 150;
    let den = mantissa * u64::from(n);
    let shift = 32 - exp;
    if shift < 0 {
        return 0;
    }
    shifted_ratio(1_000_000, den, shift as u32)
}

impl AxisProfile {
    /// Axis with `total` steps along the unit trapezoid `unit` (a finite, positive profile).
    pub fn new(unit: &Trapezoid<f32>, total: u32, increasing: bool) -> Self {
        let n = total as f32;
        let accel = unit.accel * n;
        let speed = unit.peak_speed * n;
        let c = TICKS_PER_S * Real::sqrt(2.0 / accel);
        let ramp = Real::min(speed * speed / (2.0 * accel), 0.5 * n);
        let last_ramp = Real::floor(ramp) as u32;
        let first_decel = (-Real::floor(ramp - n)) as u32;
        let first_decel = first_decel.max(last_ramp + 1);
        let cruise = cruise_interval(unit.peak_speed, total);
        let sqrt_ramp = Real::sqrt(ramp);
        let t_ramp = fixed(c * sqrt_ramp);
        let frac = fixed((ramp - last_ramp as f32) * to_ticks(cruise as i64));
        let cruise_span = cruise.wrapping_mul(u64::from(total.saturating_sub(2 * last_ramp)));
        let t_decel = t_ramp.wrapping_add(cruise_span).saturating_sub(2 * frac);
        Self {
            total,
            increasing,
            c,
            ramp,
            sqrt_ramp,
            last_ramp,
            first_decel,
            cruise,
            t_ramp,
            frac,
            t_decel,
        }
    }

    /// The ideal instant of step `k` (1..=total), 32.32 ticks after the move's start.
    pub fn ideal(&self, k: u32) -> u64 {
        if k <= self.last_ramp {
            fixed(self.c * Real::sqrt(k as f32))
        } else if k < self.first_decel {
            let steps = u64::from(k - self.last_ramp);
            self.t_ramp.wrapping_add(self.cruise * steps).saturating_sub(self.frac)
        } else {
            // c (sqrt(ramp) - sqrt(left)), written so the difference does not cancel.
            let left = self.total.saturating_sub(k) as f32;
            let span = self.c * (self.ramp - left) / (self.sqrt_ramp + Real::sqrt(left));
            self.t_decel.wrapping_add(fixed(span))
        }
    }

    /// The last step's ideal instant: the move's duration.
    pub fn duration(&self) -> u64 {
        self.ideal(self.total)
    }
}

/// The segments of one axis's move, one after the other.
#[derive(Clone, Copy, Debug, Default)]
pub struct SegmentGen {
    pub profile: AxisProfile,
    /// Absolute instant of the move's start, 32.32 ticks.
    start: u64,
    /// Steps covered by the segments made so far, and the last one's end (relative to `start`).
    done: u32,
    end: u64,
    /// The last fitted segment's count: the next ramp segment starts from it.
    last_count: u32,
}

impl SegmentGen {
    pub fn new(profile: AxisProfile, start: u64) -> Self {
        Self {
            profile,
            start,
            ..Self::default()
        }
    }

    /// Steps covered by the segments made so far.
    pub fn generated(&self) -> u32 {
        self.done
    }

    pub fn is_done(&self) -> bool {
        self.done >= self.profile.total
    }

    /// The absolute instant of the last generated step (the move's start before any).
    pub fn generated_until(&self) -> u64 {
        self.start.wrapping_add(self.end)
    }

    /// The next segment, `None` once every step is covered.
    pub fn next_segment(&mut self) -> Option<Segment> {
        let p = &self.profile;
        let k0 = self.done;
        if k0 >= p.total {
            return None;
        }
        let (interval, add, count) = if k0 > p.last_ramp && k0 + 1 < p.first_decel {
            // Cruise: one exact linear segment (after the fractional first interval below).
            (p.cruise, 0, p.first_decel - 1 - k0)
        } else {
            let room = if k0 < p.last_ramp {
                p.last_ramp - k0
            } else if k0 == p.last_ramp && p.last_ramp + 1 < p.first_decel {
                1
            } else {
                p.total - k0
            };
            let grow = if k0 < p.last_ramp {
                self.last_count + self.last_count / 4 + 1
            } else {
                self.last_count.max(1)
            };
            self.fit(k0, grow.min(room))
        };
        self.last_count = count;
        let seg = Segment {
            t0: self.start.wrapping_add(self.end),
            interval,
            add,
            count,
            increasing: p.increasing,
        };
        self.done = k0 + count;
        self.end = seg.end().wrapping_sub(self.start);
        Some(seg)
    }

    /// The largest segment from step `k0` of at most `max` steps whose times stay within
    /// [`FIT_TOLERANCE`]: the quadratic through the last end, the ideal middle and the ideal end.
    fn fit(&self, k0: u32, max: u32) -> (u64, i64, u32) {
        let mut m = max.clamp(1, MAX_FIT);
        loop {
            if let Some((interval, add)) = self.quadratic(k0, m) {
                return (interval, add, m);
            }
            m = (m * 3 / 4).max(1);
        }
    }

    /// Interval and add of a segment of `m` steps from `k0`, if it fits. In f32 ticks relative to
    /// the segment's start (a segment spans well under 2^20 ticks, so they resolve ~0.06 tick
    /// or better), converted to fixed point once; the segment's exact end is kept by the caller.
    fn quadratic(&self, k0: u32, m: u32) -> Option<(u64, i64)> {
        let p = &self.profile;
        let e = |j: u32| to_ticks(p.ideal(k0 + j).wrapping_sub(self.end) as i64);
        let (em, mf) = (e(m), m as f32);
        let (interval, add) = if m <= 2 {
            // Through every step exactly.
            let e1 = e(1);
            if m == 1 {
                (em, 0.0)
            } else {
                (e1, em - 2.0 * e1)
            }
        } else {
            // t_j = j I + j (j - 1) / 2 A through (h, e(h)) and (m, e(m)).
            let h = (m / 2) as f32;
            let add = 2.0 * (h * em - mf * e(m / 2)) / (h * mf * (mf - h));
            (em / mf - 0.5 * (mf - 1.0) * add, add)
        };
        let at = |j: u32| {
            let j = j as f32;
            j * interval + 0.5 * j * (j - 1.0) * add
        };
        let ok = |j: u32| Real::abs(at(j) - e(j)) <= FIT_TOLERANCE;
        (m <= 2 || ok(m / 4) && ok(3 * m / 4)).then_some((fixed(interval), (add * ONE_TICK as f32) as i64))
    }
}
