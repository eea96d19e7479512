//! Per-axis rings of step segments and their playback by one timer compare channel per axis, so
//! pulse edges fall at their computed instants whatever the controller loop is doing
//! (`docs/firmware.md`, "The step channels").
//!
//! Each channel's compare interrupt alternates two events: the *rise* (STEP high, compare again
//! [`PULSE_TICKS`] later) and the *fall* (STEP low, schedule the next step: two additions, and
//! the next segment from the ring when the current one is played out). The board runs
//! [`StepQueue::on_compare`] from its interrupt; simulations call [`StepQueue::service`], which runs
//! the same code for every channel that is due.

use crate::capacity::SEGMENT_RING;
use crate::segment::{Playback, Segment};
use gonio_shared::instrument::AXIS_COUNT;
pub use gonio_shared::instrument::MAX_AXIS_STEP_RATE;
use gonio_shared::Axis;
use heapless::Deque;

/// STEP high time, ticks (3 us at 1 MHz: DRV8825 needs 1.9 us, A4988 1 us, TMC22xx 0.1 us). The
/// low time before the axis's next step is its interval minus this: at the 50 kHz cap, 17 us.
pub const PULSE_TICKS: u32 = 3;

/// Instructions the step path may spend per step (the gate of `.ci/step-cost`).
pub const STEP_COST_BUDGET: u64 = 120;
/// Instructions per second of the board (96 MHz, about one instruction a cycle).
pub const CPU_INSTRUCTIONS_PER_S: u64 = 96_000_000;
// Every axis at the cap at once must leave three quarters of the CPU to the loop and the link.
const _: () = assert!(
    AXIS_COUNT as u64 * MAX_AXIS_STEP_RATE as u64 * STEP_COST_BUDGET <= CPU_INSTRUCTIONS_PER_S / 4,
    "the step rate cap exceeds the step path's capacity"
);

/// `t` has come (wrap-safe: `t` at most 2^31 ticks in the past).
pub fn reached(t: u32, now: u32) -> bool {
    now.wrapping_sub(t) < 1 << 31
}

/// Pin changes for the board to apply, one bit per axis (`1 << Axis::index`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pins {
    pub step_high: u8,
    pub step_low: u8,
    pub dir_increasing: u8,
    pub dir_decreasing: u8,
}

impl Pins {
    pub fn is_empty(&self) -> bool {
        (self.step_high | self.step_low | self.dir_increasing | self.dir_decreasing) == 0
    }

    fn dir(bit: u8, increasing: bool) -> Self {
        if increasing {
            Self {
                dir_increasing: bit,
                ..Self::default()
            }
        } else {
            Self {
                dir_decreasing: bit,
                ..Self::default()
            }
        }
    }
}

/// What one compare event did to its channel's STEP pin, and the channel's next compare tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Edge {
    /// STEP rose; the fall is due at the tick.
    Rise(u32),
    /// STEP fell; the next step rises at the tick.
    Fall(u32),
    /// STEP fell and the next segment turned the axis round: set its DIR pin from
    /// [`StepQueue::dir_levels`] now (the next rise is an interval away).
    FallDir(u32),
    /// STEP fell and the channel has nothing left: disarm it.
    Ended,
}

/// No room for a segment: the producer checks [`StepQueue::room`] first, so this is a bug; counted
/// in [`QueueStats::overruns`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Full;

/// Counters, for the log and the tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueueStats {
    /// Rising STEP edges emitted.
    pub steps: u32,
    /// Steps dropped by a trip or a stop (queued, never played).
    pub flushed: u32,
    /// Pushes refused because a ring was full (must stay 0).
    pub overruns: u32,
    /// Rising edges later than their tick (a compare scheduled after its tick had passed).
    pub late: u32,
}

/// The rings and the channels' playback state. Owned by a critical-section mutex on the board (the
/// timer and EXTI interrupts and the controller loop share it), by a `RefCell` in tests.
#[derive(Debug)]
pub struct StepQueue {
    rings: [Deque<Segment, SEGMENT_RING>; AXIS_COUNT],
    play: [Playback; AXIS_COUNT],
    /// Each channel's armed compare tick (valid while its `running` bit is set).
    compare: [u32; AXIS_COUNT],
    /// Channels with a compare armed; STEP pins high now.
    running: u8,
    high: u8,
    /// Channels a trip stopped with a step scheduled and not yet risen (playback resumes there).
    pending: u8,
    /// Channels stopped by the loop since the board last disarmed their compares.
    disarmed: u8,
    /// DIR levels (bit set = increasing).
    dir: u8,
    /// Channels started since the board last armed their compares (bit per axis).
    kicked: u8,
    /// STEP pins a stop left high, for the board to lower (bit per axis).
    lowered: u8,
    /// Switches whose closing stops every channel (bit per axis).
    armed: u8,
    /// Armed switches that closed since the controller last looked; nothing plays while non-zero.
    tripped: u8,
    /// Steps loaded into the channels from the rings (for `QueueStats::steps`).
    loaded: u32,
    stats: QueueStats,
}

impl Default for StepQueue {
    fn default() -> Self {
        Self::new()
    }
}

impl StepQueue {
    pub const fn new() -> Self {
        Self {
            rings: [Deque::new(), Deque::new(), Deque::new(), Deque::new()],
            play: [Playback::new(); AXIS_COUNT],
            compare: [0; AXIS_COUNT],
            running: 0,
            high: 0,
            pending: 0,
            disarmed: 0,
            dir: 0,
            kicked: 0,
            lowered: 0,
            armed: 0,
            tripped: 0,
            loaded: 0,
            stats: QueueStats {
                steps: 0,
                flushed: 0,
                overruns: 0,
                late: 0,
            },
        }
    }

    /// Free segment slots of `axis`'s ring.
    pub fn room(&self, axis: Axis) -> usize {
        self.rings
            .get(axis.index())
            .map_or(0, |r| SEGMENT_RING.saturating_sub(r.len()))
    }

    /// Free segment slots of every ring, in axis order.
    pub fn rooms(&self) -> [usize; AXIS_COUNT] {
        self.rings.each_ref().map(|r| SEGMENT_RING.saturating_sub(r.len()))
    }

    /// The counters; `steps` is worked out here rather than counted in the interrupt: the steps
    /// loaded into the channels minus those not made yet.
    pub fn stats(&self) -> QueueStats {
        let unmade: u32 = (0..AXIS_COUNT).map(|i| self.unmade(i)).sum();
        QueueStats {
            steps: self.loaded.wrapping_sub(unmade),
            ..self.stats
        }
    }

    /// Steps channel `i` has loaded and not made: those left in its segment, and one scheduled
    /// and not risen yet.
    fn unmade(&self, i: usize) -> u32 {
        let scheduled = (self.pending | (self.running & !self.high)) & (1 << i) != 0;
        self.play.get(i).map_or(0, Playback::left) + u32::from(scheduled)
    }

    /// Is anything queued or playing?
    pub fn is_idle(&self) -> bool {
        (self.running | self.pending) == 0 && self.rings.iter().all(Deque::is_empty)
    }

    /// Is playback stopped by a trip the controller has not taken yet?
    pub fn tripped(&self) -> u8 {
        self.tripped
    }

    /// Which switches stop playback when they close (bit per axis).
    pub fn set_armed(&mut self, mask: u8) {
        self.armed = mask;
    }

    pub fn armed(&self) -> u8 {
        self.armed
    }

    /// DIR levels, bit per axis (set = increasing).
    pub fn dir_levels(&self) -> u8 {
        self.dir
    }

    /// Queue `seg` on `axis`; an idle channel starts on it at once (unless a trip holds playback).
    pub fn push(&mut self, axis: Axis, seg: Segment) -> Result<(), Full> {
        let Some(ring) = self.rings.get_mut(axis.index()) else {
            return Err(Full);
        };
        if ring.push_back(seg).is_err() {
            self.stats.overruns = self.stats.overruns.saturating_add(1);
            return Err(Full);
        }
        if self.tripped == 0 {
            self.start(axis.index());
        }
        Ok(())
    }

    /// Start channel `i` if it is idle and has a step to make: the board arms its compare at
    /// [`StepQueue::compare_tick`] and sets its DIR pin from [`StepQueue::dir_levels`].
    fn start(&mut self, i: usize) {
        let b = 1u8 << i;
        if self.running & b != 0 {
            return;
        }
        if self.pending & b == 0 {
            let (Some(ring), Some(play)) = (self.rings.get_mut(i), self.play.get_mut(i)) else {
                return;
            };
            let Some(seg) = ring.pop_front() else { return };
            play.load(&seg);
            self.loaded = self.loaded.wrapping_add(seg.count);
            self.dir = if seg.increasing { self.dir | b } else { self.dir & !b };
        }
        self.pending &= !b;
        if let (Some(c), Some(p)) = (self.compare.get_mut(i), self.play.get(i)) {
            *c = p.tick();
        }
        self.running |= b;
        self.kicked |= b;
        self.disarmed &= !b;
    }

    /// Channels started since the last call (bit per axis): the board arms their compares.
    pub fn take_kicked(&mut self) -> u8 {
        core::mem::take(&mut self.kicked)
    }

    /// STEP pins a stop left high since the last call: the board lowers them.
    pub fn take_lowered(&mut self) -> u8 {
        core::mem::take(&mut self.lowered)
    }

    /// STEP pins high now (bit per axis).
    pub fn high(&self) -> u8 {
        self.high
    }

    /// Channels with a compare armed (bit per axis).
    pub fn running(&self) -> u8 {
        self.running
    }

    /// Channels the loop stopped since the last call (bit per axis): the board disarms them.
    pub fn take_disarmed(&mut self) -> u8 {
        core::mem::take(&mut self.disarmed)
    }

    /// Channel `i`'s armed compare tick: its fall while its STEP pin is high, its next rise otherwise.
    pub fn compare_tick(&self, i: usize) -> u32 {
        let t = self.compare.get(i).copied().unwrap_or(0);
        if self.high & (1 << i) != 0 {
            t.wrapping_add(PULSE_TICKS)
        } else {
            t
        }
    }

    /// Channel `i`'s compare event: a rise or a fall of its STEP pin, and its next compare tick.
    #[inline(always)]
    pub fn on_compare(&mut self, i: usize) -> Edge {
        let b = 1u8 << i;
        let (Some(play), Some(compare)) = (self.play.get_mut(i), self.compare.get_mut(i)) else {
            return Edge::Ended;
        };
        if self.high & b == 0 {
            self.high |= b;
            return Edge::Rise(compare.wrapping_add(PULSE_TICKS));
        }
        self.high &= !b;
        if !play.schedule() {
            return self.next_segment(i);
        }
        *compare = play.tick();
        Edge::Fall(*compare)
    }

    /// A fall that ended channel `i`'s segment: play the next one, or stop the channel.
    #[inline(never)]
    fn next_segment(&mut self, i: usize) -> Edge {
        let b = 1u8 << i;
        let (Some(ring), Some(play), Some(compare)) =
            (self.rings.get_mut(i), self.play.get_mut(i), self.compare.get_mut(i))
        else {
            return Edge::Ended;
        };
        let Some(seg) = ring.pop_front() else {
            self.running &= !b;
            return Edge::Ended;
        };
        play.load(&seg);
        self.loaded = self.loaded.wrapping_add(seg.count);
        *compare = play.tick();
        if (self.dir & b != 0) != seg.increasing {
            self.dir ^= b;
            return Edge::FallDir(*compare);
        }
        Edge::Fall(*compare)
    }

    /// The board forced a compare whose tick had already passed (counted as a late step).
    pub fn note_late(&mut self) {
        self.stats.late = self.stats.late.wrapping_add(1);
    }

    /// The earliest compare among the running channels (`now` orders instants across a wrap).
    pub fn next_wake(&self, now: u32) -> Option<u32> {
        (0..AXIS_COUNT)
            .filter(|i| self.running & (1 << i) != 0)
            .map(|i| self.compare_tick(i))
            .min_by_key(|t| t.wrapping_sub(now).wrapping_add(1 << 31))
    }

    /// Every compare event due at `now`, as the interrupt would run them (simulations). The DIR
    /// levels of channels started since the last call come first, as the board sets them when it
    /// arms their compares.
    pub fn service(&mut self, now: u32) -> (Pins, Option<u32>) {
        let kicked = self.take_kicked();
        let mut pins = Pins {
            dir_increasing: kicked & self.dir,
            dir_decreasing: kicked & !self.dir,
            ..Pins::default()
        };
        for i in 0..AXIS_COUNT {
            let b = 1u8 << i;
            // A fall may schedule a step already due (a late one): play it too, bounded.
            for _ in 0..4 {
                let due = self.compare_tick(i);
                if self.running & b == 0 || !reached(due, now) {
                    break;
                }
                let edge = self.on_compare(i);
                if let Edge::Rise(_) = edge {
                    pins.step_high |= b;
                    if due != now {
                        self.note_late();
                    }
                } else {
                    pins.step_low |= b;
                }
                if let Edge::FallDir(_) = edge {
                    let d = Pins::dir(b, self.dir & b != 0);
                    pins.dir_increasing = (pins.dir_increasing & !b) | d.dir_increasing;
                    pins.dir_decreasing = (pins.dir_decreasing & !b) | d.dir_decreasing;
                }
            }
        }
        (pins, self.next_wake(now))
    }

    /// A switch's EXTI interrupt (`closed`: bit per axis). An armed one stops every channel at
    /// once: returns the STEP pins to force low (the board also disarms every compare). Unarmed
    /// switches are ignored (the azimuth's index sensor passes once a turn).
    pub fn trip(&mut self, closed: u8) -> Pins {
        let hit = closed & self.armed;
        if hit == 0 {
            return Pins::default();
        }
        self.tripped |= hit;
        self.pending |= self.running & !self.high;
        // A channel stopped while high has made its step: schedule the next, as its fall would.
        for (i, p) in self.play.iter_mut().enumerate() {
            if self.high & self.running & (1 << i) != 0 && p.schedule() {
                self.pending |= 1 << i;
            }
        }
        // The board's loop-side sync disarms and lowers them too, for a trip found by polling.
        self.disarmed |= self.running;
        self.running = 0;
        self.kicked = 0;
        let high = core::mem::take(&mut self.high);
        self.lowered |= high;
        Pins {
            step_low: high,
            ..Pins::default()
        }
    }

    /// The controller loop takes the latched trip (bit per axis) and resumes playback of what is
    /// still queued (the loop first drops it if the trip halted the move it belongs to).
    pub fn take_trip(&mut self) -> u8 {
        let t = core::mem::take(&mut self.tripped);
        for i in 0..AXIS_COUNT {
            self.start(i);
        }
        t
    }

    /// Stop every channel and drop everything queued; returns the steps per axis that were
    /// queued and never made (a rise already made counts as made).
    pub fn drop_all(&mut self) -> [u32; AXIS_COUNT] {
        let mut left = [0u32; AXIS_COUNT];
        for (i, l) in left.iter_mut().enumerate() {
            let unmade = self.unmade(i);
            self.loaded = self.loaded.wrapping_sub(unmade);
            let (Some(ring), Some(play)) = (self.rings.get_mut(i), self.play.get_mut(i)) else {
                continue;
            };
            let queued: u32 = ring.iter().map(|s| s.count).sum();
            *l = queued + unmade;
            ring.clear();
            *play = Playback::new();
        }
        self.stats.flushed = self.stats.flushed.wrapping_add(left.iter().sum::<u32>());
        self.disarmed |= self.running;
        self.running = 0;
        self.pending = 0;
        self.kicked = 0;
        self.lowered |= core::mem::take(&mut self.high);
        left
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(t0: u32, count: u32, increasing: bool) -> Segment {
        Segment {
            t0: u64::from(t0) << 32,
            interval: 10 << 32,
            add: 0,
            count,
            increasing,
        }
    }

    /// Service every compare until `until`; returns the rise ticks of `axis`.
    fn play(q: &mut StepQueue, mut now: u32, until: u32, axis: usize) -> Vec<u32, 64> {
        let mut rises = Vec::new();
        while let Some(w) = q.next_wake(now) {
            if w > until {
                break;
            }
            now = w.max(now);
            let (pins, _) = q.service(now);
            if pins.step_high & (1 << axis) != 0 {
                rises.push(now).unwrap();
            }
        }
        rises
    }

    use heapless::Vec;

    #[test]
    fn segments_play_back_to_back_with_pulses_and_dir() {
        let mut q = StepQueue::new();
        q.push(Axis::Tilt, seg(100, 3, true)).unwrap();
        q.push(Axis::Tilt, seg(130, 2, false)).unwrap();
        assert_eq!(q.dir_levels(), 1 << Axis::Tilt.index());
        let rises = play(&mut q, 0, 1_000, Axis::Tilt.index());
        assert_eq!(&rises[..], &[110, 120, 130, 140, 150]);
        assert_eq!(q.dir_levels(), 0, "the second segment turned the axis round");
        assert_eq!(q.stats().steps, 5);
        assert!(q.is_idle());
    }

    #[test]
    fn a_trip_stops_at_once_and_every_queued_step_is_made_or_counted_dropped() {
        let mut q = StepQueue::new();
        q.set_armed(1 << Axis::Light.index());
        q.push(Axis::Light, seg(0, 10, true)).unwrap();
        q.push(Axis::Light, seg(100, 5, true)).unwrap();
        let rises = play(&mut q, 0, 41, Axis::Light.index());
        assert_eq!(rises.len(), 4);
        // Mid-pulse of the 4th step: STEP forced low, nothing more plays.
        let pins = q.trip(1 << Axis::Light.index());
        assert_eq!(pins.step_low, 1 << Axis::Light.index());
        assert_eq!(q.next_wake(42), None);
        let left = q.drop_all();
        assert_eq!(left[Axis::Light.index()], 11);
        assert_eq!(q.stats().steps, 4);
        assert_eq!(q.stats().flushed, 11);
        assert_eq!(q.take_trip(), 1 << Axis::Light.index());
        assert!(q.is_idle());
    }
}
