//! Timed STEP/DIR events and the playback a timer interrupt runs, so pulse edges fall at their
//! computed instants whatever the controller loop is doing (`docs/firmware.md`).

use crate::capacity::STEP_QUEUE_EVENTS;
use gonio_shared::instrument::AXIS_COUNT;
use gonio_shared::Axis;
use heapless::Deque;

/// Minimum STEP high time, ticks (3 us at 1 MHz: DRV8825 needs 1.9 us, A4988 1 us, TMC22xx 0.1 us).
pub const PULSE_TICKS: u32 = 3;
/// Minimum STEP low time before the same axis steps again, ticks (DRV8825 1.9 us).
pub const LOW_TICKS: u32 = 3;
/// DIR setup before the next rising STEP edge, ticks: 2 so that the setup is a full tick (1 us)
/// even when the two edges land at opposite ends of their tick (DRV8825 650 ns, A4988 200 ns).
pub const DIR_SETUP_TICKS: u32 = 2;

/// A pulse may stay high up to this much longer than [`PULSE_TICKS`] when another axis's event
/// follows within it, so one interrupt ends the pulse and starts the next (STEP high time has no
/// maximum; the same axis's low time is still enforced). With 4 axes at 20 kHz events come every
/// ~12 us on average.
pub const MERGE_TICKS: u32 = 10;

/// `t` has come (wrap-safe: `t` at most 2^31 ticks in the past).
fn reached(t: u32, now: u32) -> bool {
    now.wrapping_sub(t) < 1 << 31
}

/// Of two instants in the near future, the earlier one (wrap-safe relative to `now`).
fn earlier(a: u32, b: u32, now: u32) -> u32 {
    if a.wrapping_sub(now) <= b.wrapping_sub(now) {
        a
    } else {
        b
    }
}

fn bit(axis: Axis) -> u8 {
    1 << axis.index()
}

/// What one event does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum What {
    Step,
    Dir(bool),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Event {
    due: u32,
    axis: Axis,
    what: What,
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
}

/// No room for an event: the producer checks [`StepQueue::free`] first, so this is a bug; counted
/// in [`QueueStats::overruns`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Full;

/// The event queue and the playback state. Owned by a critical-section mutex on the board (the
/// timer and EXTI interrupts and the controller loop share it), by a `RefCell` in tests.
#[derive(Debug)]
pub struct StepQueue {
    events: Deque<Event, STEP_QUEUE_EVENTS>,
    /// STEP pins high now, and when each rose / last fell.
    high: u8,
    rose: [u32; AXIS_COUNT],
    fell: [u32; AXIS_COUNT],
    dir_changed: [u32; AXIS_COUNT],
    /// Switches whose closing stops playback (bit per axis).
    armed: u8,
    /// Armed switches that closed since the controller last looked; playback stays stopped while
    /// non-zero.
    tripped: u8,
    stats: QueueStats,
}

/// Counters, for the log and the tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueueStats {
    /// Rising STEP edges emitted.
    pub steps: u32,
    /// Step events dropped by a trip (queued, never played).
    pub flushed: u32,
    /// Pushes refused because the queue was full (must stay 0).
    pub overruns: u32,
    /// STEP edges later than their due tick (the loop fell behind, or a stretch). A DIR change
    /// waiting for a pulse to end (a park move right after a home switch) is not counted.
    pub late: u32,
}

impl Default for StepQueue {
    fn default() -> Self {
        Self::new()
    }
}

impl StepQueue {
    pub const fn new() -> Self {
        Self {
            events: Deque::new(),
            high: 0,
            rose: [0; AXIS_COUNT],
            fell: [0; AXIS_COUNT],
            dir_changed: [0; AXIS_COUNT],
            armed: 0,
            tripped: 0,
            stats: QueueStats {
                steps: 0,
                flushed: 0,
                overruns: 0,
                late: 0,
            },
        }
    }

    pub fn free(&self) -> usize {
        STEP_QUEUE_EVENTS.saturating_sub(self.events.len())
    }

    pub fn len(&self) -> usize {
        self.events.len()
    }

    pub fn is_empty(&self) -> bool {
        self.events.is_empty()
    }

    pub fn stats(&self) -> QueueStats {
        self.stats
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

    /// Queue `e`. While a trip is latched, events are held (not played): the controller loop
    /// decides when it takes the trip whether they belong to the halted move ([`StepQueue::flush`]).
    fn push(&mut self, e: Event) -> Result<(), Full> {
        self.events.push_back(e).map_err(|_| {
            self.stats.overruns = self.stats.overruns.saturating_add(1);
            Full
        })
    }

    /// Drop every queued event (counted in [`QueueStats::flushed`]).
    pub fn flush(&mut self) {
        let steps = self.events.iter().filter(|e| e.what == What::Step).count();
        self.stats.flushed = self
            .stats
            .flushed
            .saturating_add(u32::try_from(steps).unwrap_or(u32::MAX));
        self.events.clear();
    }

    /// One STEP pulse of `axis` rising at `due`. Events must be pushed in time order.
    pub fn push_step(&mut self, axis: Axis, due: u32) -> Result<(), Full> {
        self.push(Event {
            due,
            axis,
            what: What::Step,
        })
    }

    /// Set the DIR pin of `axis` at `due`.
    pub fn push_dir(&mut self, axis: Axis, increasing: bool, due: u32) -> Result<(), Full> {
        self.push(Event {
            due,
            axis,
            what: What::Dir(increasing),
        })
    }

    /// When the timer must call [`StepQueue::service`] next (`now` orders instants across a wrap):
    /// the end of a pulse in progress or the next event, whichever is first; `None` when idle.
    pub fn next_wake(&self, now: u32) -> Option<u32> {
        // Held events (a trip not yet taken) wake nothing: the interrupt would only spin on them.
        let head = self.events.front().filter(|_| self.tripped == 0);
        let next = head.map(|e| (self.ready_at(e, now), bit(e.axis)));
        let mut end: Option<u32> = None;
        for (i, &rose) in self.rose.iter().enumerate() {
            if self.high & (1 << i) != 0 {
                let e = rose.wrapping_add(PULSE_TICKS);
                end = Some(end.map_or(e, |w| earlier(w, e, now)));
            }
        }
        match (next, end) {
            // The next event comes soon after the pulse end and is another axis's: end the pulse
            // in that wake-up instead of one of its own (half the interrupts with 4 axes busy).
            (Some((t, b)), Some(e)) if self.high & b == 0 && t.wrapping_sub(e) <= MERGE_TICKS && reached(e, t) => {
                Some(t)
            }
            (Some((t, _)), Some(e)) => Some(earlier(t, e, now)),
            (Some((t, _)), None) => Some(t),
            (None, e) => e,
        }
    }

    /// The earliest instant `e` may be applied without breaking the pulse shape: never `now` unless
    /// `service(now)` would apply it, so the timer never spins. Constraints are recognised only
    /// within their few ticks after `now`, so a timestamp that has aged past the counter's half
    /// range can never look like a future one.
    fn ready_at(&self, e: &Event, now: u32) -> u32 {
        if !reached(e.due, now) {
            return e.due;
        }
        let i = e.axis.index();
        if self.high & bit(e.axis) != 0 {
            // Its pulse ends first (a STEP or DIR change never cuts a pulse short).
            let end = self.rose.get(i).map_or(now, |&r| r.wrapping_add(PULSE_TICKS));
            if !reached(end, now) {
                return end;
            }
        }
        let mut t = now;
        if e.what == What::Step {
            let low = self.fell.get(i).map(|&f| (f.wrapping_add(LOW_TICKS), LOW_TICKS));
            let dir = self
                .dir_changed
                .get(i)
                .map(|&d| (d.wrapping_add(DIR_SETUP_TICKS), DIR_SETUP_TICKS));
            for (c, window) in [low, dir].into_iter().flatten() {
                let ahead = c.wrapping_sub(now);
                if ahead != 0 && ahead <= window && ahead > t.wrapping_sub(now) {
                    t = c;
                }
            }
        }
        t
    }

    /// The timer interrupt: at `now`, end pulses that have lasted [`PULSE_TICKS`], apply every due
    /// event the pulse shape allows, in order. Returns the pin changes and the next wake-up.
    pub fn service(&mut self, now: u32) -> (Pins, Option<u32>) {
        let mut pins = Pins {
            step_low: self.end_pulses(now),
            ..Pins::default()
        };
        if self.tripped == 0 {
            while let Some(&e) = self.events.front() {
                if !reached(e.due, now) {
                    break;
                }
                let b = bit(e.axis);
                let i = e.axis.index();
                if self.high & b != 0 || self.ready_at(&e, now) != now {
                    break;
                }
                if e.due != now && e.what == What::Step {
                    self.stats.late = self.stats.late.saturating_add(1);
                }
                match e.what {
                    What::Step => {
                        self.high |= b;
                        pins.step_high |= b;
                        if let Some(r) = self.rose.get_mut(i) {
                            *r = now;
                        }
                        self.stats.steps = self.stats.steps.wrapping_add(1);
                    }
                    What::Dir(increasing) => {
                        if increasing {
                            pins.dir_increasing |= b;
                            pins.dir_decreasing &= !b;
                        } else {
                            pins.dir_decreasing |= b;
                            pins.dir_increasing &= !b;
                        }
                        if let Some(d) = self.dir_changed.get_mut(i) {
                            *d = now;
                        }
                    }
                }
                self.events.pop_front();
            }
        }
        (pins, self.next_wake(now))
    }

    /// A switch's EXTI interrupt (`closed`: bit per axis). An armed one stops playback at once:
    /// queued events are dropped and every STEP pin goes low. Unarmed switches are ignored (the
    /// azimuth's index sensor passes once a turn). Returns the pin changes.
    pub fn trip(&mut self, closed: u8, now: u32) -> Pins {
        let hit = closed & self.armed;
        if hit == 0 {
            return Pins::default();
        }
        self.tripped |= hit;
        self.flush();
        // End the pulses that have met the driver's minimum; a shorter one may or may not count
        // as a step, so it completes and ends at the next service instead.
        Pins {
            step_low: self.end_pulses(now),
            ..Pins::default()
        }
    }

    /// Lower the STEP pins high for at least [`PULSE_TICKS`]; returns them (bit per axis).
    fn end_pulses(&mut self, now: u32) -> u8 {
        let mut ended = 0;
        for i in 0..AXIS_COUNT {
            let b = 1u8 << i;
            let done = self
                .rose
                .get(i)
                .is_some_and(|&r| reached(r.wrapping_add(PULSE_TICKS), now));
            if self.high & b != 0 && done {
                self.high &= !b;
                ended |= b;
                if let Some(f) = self.fell.get_mut(i) {
                    *f = now;
                }
            }
        }
        ended
    }

    /// The controller loop takes the latched trip (bit per axis) and resumes playback. Events
    /// queued since the trip are kept: the loop flushes them if the trip halted the move they
    /// belong to (see `timed::QueuedHal`).
    pub fn take_trip(&mut self) -> u8 {
        core::mem::take(&mut self.tripped)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Run the timer: service at every wake-up until idle; returns (tick, pins) of every change.
    fn play(q: &mut StepQueue, mut now: u32, until: u32) -> heapless::Vec<(u32, Pins), 256> {
        let mut log = heapless::Vec::new();
        loop {
            let (pins, wake) = q.service(now);
            if !pins.is_empty() {
                log.push((now, pins)).unwrap();
            }
            match wake {
                Some(w) if w.wrapping_sub(until) as i32 <= 0 => now = if reached(w, now) { now + 1 } else { w },
                _ => return log,
            }
        }
    }

    #[test]
    fn steps_rise_at_their_instants_and_fall_after_the_pulse() {
        let mut q = StepQueue::new();
        q.push_step(Axis::Light, 100).unwrap();
        q.push_step(Axis::Detector, 100).unwrap();
        q.push_step(Axis::Light, 150).unwrap();
        q.push_step(Axis::Tilt, 151).unwrap();
        let log = play(&mut q, 0, 1_000);
        let rises: heapless::Vec<(u32, u8), 8> = log
            .iter()
            .filter(|(_, p)| p.step_high != 0)
            .map(|&(t, p)| (t, p.step_high))
            .collect();
        assert_eq!(&rises[..], &[(100, 0b0011), (150, 0b0001), (151, 0b0100)]);
        let falls: heapless::Vec<(u32, u8), 8> = log
            .iter()
            .filter(|(_, p)| p.step_low != 0)
            .map(|&(t, p)| (t, p.step_low))
            .collect();
        assert_eq!(&falls[..], &[(103, 0b0011), (153, 0b0001), (154, 0b0100)]);
        assert_eq!(q.stats().steps, 4);
        assert!(q.is_empty());
        assert_eq!(q.next_wake(1_000), None);
    }

    #[test]
    fn a_pulse_ends_in_the_next_axis_wake_up_when_it_follows_closely() {
        let mut q = StepQueue::new();
        q.push_step(Axis::Light, 100).unwrap();
        q.push_step(Axis::Detector, 100 + PULSE_TICKS + 4).unwrap();
        q.push_step(Axis::Tilt, 200).unwrap();
        let log = play(&mut q, 0, 1_000);
        let wakes: heapless::Vec<(u32, Pins), 8> = log.iter().copied().collect();
        // Light rises at 100 and falls with the detector's rise at 107; the detector's pulse has
        // no close follower and ends on its own; the tilt alike.
        assert_eq!(wakes[0].0, 100);
        assert_eq!(
            (wakes[1].0, wakes[1].1.step_low, wakes[1].1.step_high),
            (107, 0b0001, 0b0010)
        );
        assert_eq!((wakes[2].0, wakes[2].1.step_low), (110, 0b0010));
        assert_eq!(wakes.len(), 5);
    }

    #[test]
    fn a_too_fast_schedule_is_stretched_never_shortened() {
        let mut q = StepQueue::new();
        // Same axis 2 ticks apart: below pulse + low time.
        q.push_step(Axis::Azimuth, 10).unwrap();
        q.push_step(Axis::Azimuth, 12).unwrap();
        let log = play(&mut q, 0, 100);
        let rises: heapless::Vec<u32, 4> = log.iter().filter(|(_, p)| p.step_high != 0).map(|&(t, _)| t).collect();
        assert_eq!(&rises[..], &[10, 10 + PULSE_TICKS + LOW_TICKS]);
        assert!(q.stats().late > 0);
    }

    #[test]
    fn dir_changes_between_pulses_with_setup_time() {
        let mut q = StepQueue::new();
        q.push_step(Axis::Light, 10).unwrap();
        // A direction change due while the pulse is high waits for it to end.
        q.push_dir(Axis::Light, false, 11).unwrap();
        q.push_step(Axis::Light, 12).unwrap();
        let log = play(&mut q, 0, 100);
        let dir_at = log.iter().find(|(_, p)| p.dir_decreasing != 0).unwrap().0;
        assert_eq!(dir_at, 10 + PULSE_TICKS);
        let second_rise = log.iter().filter(|(_, p)| p.step_high != 0).nth(1).unwrap().0;
        assert!(second_rise >= dir_at + DIR_SETUP_TICKS);
        assert!(second_rise >= 10 + PULSE_TICKS + LOW_TICKS);
    }

    #[test]
    fn an_armed_trip_flushes_stops_and_latches() {
        let mut q = StepQueue::new();
        q.set_armed(bit(Axis::Light) | bit(Axis::Tilt));
        for k in 0..10 {
            q.push_step(Axis::Detector, 100 + 20 * k).unwrap();
        }
        let (_, _) = q.service(100);
        // Unarmed switch: nothing happens.
        assert_eq!(q.trip(bit(Axis::Azimuth), 101), Pins::default());
        assert_eq!(q.len(), 9);
        // Armed, 1 tick into a pulse: the pulse completes at the next service, nothing else plays.
        let pins = q.trip(bit(Axis::Tilt), 101);
        assert_eq!(pins.step_low, 0);
        assert_eq!(q.tripped(), bit(Axis::Tilt));
        assert!(q.is_empty());
        assert_eq!(q.stats().flushed, 9);
        let (pins, wake) = q.service(103);
        assert_eq!(pins.step_low, bit(Axis::Detector));
        assert_eq!(wake, None);
        // Held, not played, until the controller takes the trip.
        q.push_step(Axis::Light, 150).unwrap();
        let (pins, _) = q.service(160);
        assert_eq!(pins.step_high, 0);
        assert_eq!(q.take_trip(), bit(Axis::Tilt));
        assert_eq!(q.tripped(), 0);
        assert_eq!(q.service(200).0.step_high, bit(Axis::Light));
        assert_eq!(q.stats().steps, 2);
    }

    /// Whenever `next_wake` says "now", `service(now)` changes a pin: the timer never spins.
    #[test]
    fn a_wake_up_always_makes_progress() {
        let mut q = StepQueue::new();
        q.set_armed(bit(Axis::Light));
        q.push_step(Axis::Light, 10).unwrap();
        q.push_dir(Axis::Light, false, 11).unwrap();
        q.push_step(Axis::Light, 11).unwrap();
        q.push_step(Axis::Tilt, 12).unwrap();
        let mut now = 10;
        for _ in 0..100 {
            let (pins, wake) = q.service(now);
            let Some(w) = wake else { break };
            if w == now {
                assert!(!pins.is_empty() || q.service(now).0 != Pins::default(), "spin at {now}");
            }
            now = if reached(w, now) { now + 1 } else { w };
        }
        assert!(q.is_empty());
        // Held events after a trip wake nothing.
        q.push_step(Axis::Light, now + 5).unwrap();
        q.trip(bit(Axis::Light), now);
        q.push_step(Axis::Light, now + 6).unwrap();
        assert_eq!(q.next_wake(now + 10), None);
    }

    #[test]
    fn overrun_is_refused_and_counted() {
        let mut q = StepQueue::new();
        for k in 0..STEP_QUEUE_EVENTS {
            q.push_step(Axis::Tilt, k as u32 * 10).unwrap();
        }
        assert_eq!(q.free(), 0);
        assert_eq!(q.push_step(Axis::Tilt, 1 << 20), Err(Full));
        assert_eq!(q.stats().overruns, 1);
    }

    #[test]
    fn playback_is_exact_across_the_counter_wrap() {
        let mut q = StepQueue::new();
        let start = u32::MAX - 25;
        for k in 0..5u32 {
            q.push_step(Axis::Detector, start.wrapping_add(k * 20)).unwrap();
        }
        let mut now = start.wrapping_sub(5);
        let mut rises = heapless::Vec::<u32, 8>::new();
        for _ in 0..200 {
            let (pins, wake) = q.service(now);
            if pins.step_high != 0 {
                rises.push(now).unwrap();
            }
            let Some(w) = wake else { break };
            now = if reached(w, now) { now.wrapping_add(1) } else { w };
        }
        let expect: heapless::Vec<u32, 8> = (0..5u32).map(|k| start.wrapping_add(k * 20)).collect();
        assert_eq!(rises, expect);
    }
}
