//! When the controller loop feeds the board's independent watchdog (IWDG): at most every
//! [`FEED_US`], and only while the step path is [`healthy`]; once it is not, never again, so the
//! IWDG resets the board within [`TIMEOUT_US`] of the last feed (as it does a hung loop).

use crate::step_queue::QueueStats;

/// The IWDG's timeout, as the board sets it.
pub const TIMEOUT_US: u32 = 500_000;
/// The loop feeds it at most this often.
pub const FEED_US: u64 = 100_000;
// A feed that is due may wait for one slow turn of the loop without the watchdog biting.
const _: () = assert!(FEED_US * 2 <= TIMEOUT_US as u64);

/// The step queue never overran: the loop keeps room for what it queues, so an overrun is a bug,
/// and the steps it refused leave the axis positions wrong.
pub fn healthy(stats: &QueueStats) -> bool {
    stats.overruns == 0
}

/// The feeding rule's state.
#[derive(Clone, Copy, Debug)]
pub struct Feed {
    fed_us: u64,
    /// Unhealthy once: no more feeds.
    stopped: bool,
}

impl Feed {
    /// The watchdog started (or was fed) at `now_us`.
    pub const fn new(now_us: u64) -> Self {
        Self {
            fed_us: now_us,
            stopped: false,
        }
    }

    /// Whether to feed the watchdog at `now_us`: [`FEED_US`] after the last feed, if `healthy`
    /// (asked only then). Also the instant to be asked again; `None` once it stopped feeding
    /// (the loop need not wake for a reset).
    pub fn poll(&mut self, now_us: u64, healthy: impl FnOnce() -> bool) -> (bool, Option<u64>) {
        let due = self.fed_us.saturating_add(FEED_US);
        let feed = !self.stopped && now_us >= due && {
            self.stopped = !healthy();
            !self.stopped
        };
        if feed {
            self.fed_us = now_us;
        }
        let next = (!self.stopped).then(|| self.fed_us.saturating_add(FEED_US));
        (feed, next)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segment::Segment;
    use crate::step_queue::StepQueue;
    use gonio_shared::Axis;
    extern crate std;
    use std::vec::Vec;

    /// A loop that polls at every wake `poll` asks for, and also at `extra_us` intervals (other
    /// work), against a model IWDG; `health(t)` is the step path's health at `t`. Returns the
    /// feed instants and the instant the IWDG bit (if it did before `end_us`).
    fn run(extra_us: u64, end_us: u64, health: impl Fn(u64) -> bool) -> (Vec<u64>, Option<u64>) {
        let mut feed = Feed::new(0);
        let (mut fed, mut bit) = (Vec::new(), None);
        let (mut last_feed, mut t) = (0u64, 0u64);
        while t <= end_us {
            if t > last_feed + u64::from(TIMEOUT_US) {
                bit = Some(last_feed + u64::from(TIMEOUT_US));
                break;
            }
            let (pet, next) = feed.poll(t, || health(t));
            if pet {
                fed.push(t);
                last_feed = t;
            }
            let other = t + extra_us;
            t = next.map_or(other, |w| w.min(other)).max(t + 1);
        }
        (fed, bit)
    }

    #[test]
    fn fed_every_period_while_healthy_and_never_bites() {
        for extra in [7_919, 33_333, 250_000] {
            let (fed, bit) = run(extra, 10_000_000, |_| true);
            assert_eq!(bit, None, "bit with polls every {extra} us");
            assert!(fed.len() >= 99, "{} feeds in 10 s", fed.len());
            for w in fed.windows(2) {
                assert!(w[1] - w[0] >= FEED_US, "fed twice within {FEED_US} us: {w:?}");
                assert!(w[1] - w[0] <= FEED_US + 1, "feed late: {w:?}");
            }
        }
    }

    #[test]
    fn unhealthy_stops_feeding_for_good_and_the_watchdog_bites() {
        let sick_at = 3_000_000;
        // Health comes back later: the feeding stays stopped all the same.
        let (fed, bit) = run(10_000, 10_000_000, |t| !(sick_at..sick_at + 50_000).contains(&t));
        let last = *fed.last().expect("fed before");
        assert!(last < sick_at + FEED_US, "fed at {last} us, unhealthy from {sick_at}");
        assert_eq!(bit, Some(last + u64::from(TIMEOUT_US)));
        // No wake is asked for once stopped.
        let mut feed = Feed::new(0);
        assert_eq!(feed.poll(FEED_US, || false), (false, None));
        assert_eq!(feed.poll(2 * FEED_US, || true), (false, None));
    }

    #[test]
    fn health_is_lost_on_a_step_queue_overrun() {
        let mut q = StepQueue::new();
        assert!(healthy(&q.stats()));
        let seg = Segment {
            t0: 0,
            interval: 100 << 32,
            add: 0,
            count: 1,
            increasing: true,
        };
        while q.push(Axis::Tilt, seg).is_ok() {
            assert!(healthy(&q.stats()));
        }
        assert!(!healthy(&q.stats()), "{:?}", q.stats());
    }
}
