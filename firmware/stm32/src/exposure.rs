//! The detector's exposure timing, the same in the board and the QEMU build: an exposure started
//! at some instant is read out once its time has passed (the readout itself is the build's).

/// At most one exposure in flight.
#[derive(Clone, Copy)]
pub struct ExposureTimer {
    pending: Option<Pending>,
}

#[derive(Clone, Copy)]
struct Pending {
    done_us: u64,
    exposure_us: u32,
}

impl ExposureTimer {
    pub const fn new() -> Self {
        Self { pending: None }
    }

    /// Starts an exposure of `exposure_us` at `now_us` (a new start replaces one in flight).
    pub fn start(&mut self, now_us: u64, exposure_us: u32) {
        self.pending = Some(Pending {
            done_us: now_us.saturating_add(u64::from(exposure_us)),
            exposure_us,
        });
    }

    /// `None` until the exposure has run its time; then its length, once.
    pub fn take_done(&mut self, now_us: u64) -> Option<u32> {
        let pending = self.pending?;
        if now_us < pending.done_us {
            return None;
        }
        self.pending = None;
        Some(pending.exposure_us)
    }
}
