//! What the command line shows of a run on the link: a terminal progress bar behind the library's
//! [`Progress`] trait, and the run's summary lines. CLI only (the library prints nothing).

use crate::link::{Measured, Progress};
use std::time::Instant;

/// A terminal progress bar: directions done, instrument time at the last reading, and the ETA
/// from this run's wall rate (hidden when stderr is not a terminal).
pub struct TerminalProgress {
    bar: indicatif::ProgressBar,
    start: Instant,
    first_done: Option<u32>,
}

impl TerminalProgress {
    pub fn new(total: usize) -> Self {
        let bar = indicatif::ProgressBar::new(total as u64).with_style(
            indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} directions, {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        Self {
            bar,
            start: Instant::now(),
            first_done: None,
        }
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Progress for TerminalProgress {
    fn update(&mut self, done: u32, total: u32, instrument_s: f64) {
        self.bar.set_length(u64::from(total));
        self.bar.set_position(u64::from(done));
        // The rate counts only this run's readings: resumed ones took no time here.
        let first = *self.first_done.get_or_insert(done);
        let measured = done.saturating_sub(first);
        let eta = if measured > 0 {
            let per = self.start.elapsed().as_secs_f64() / f64::from(measured);
            format!("{:.0} s", per * f64::from(total.saturating_sub(done)))
        } else {
            "?".into()
        };
        self.bar
            .set_message(format!("instrument {instrument_s:.1} s, ETA {eta}"));
    }
    fn note(&mut self, line: &str) {
        self.bar.suspend(|| eprintln!("{line}"));
    }
}

/// The run's rates and link statistics, two or three lines.
pub fn print_run(m: &Measured) {
    let summary = &m.summary;
    let n = summary.measured_now;
    println!(
        "measured {n} directions ({} resumed from the journal) in {:.1} s instrument time, {:.2} s wall: {:.1} directions/s instrument, {:.1} directions/s wall",
        m.resumed,
        summary.instrument_s,
        m.wall_s,
        f64::from(n) / summary.instrument_s.max(1e-9),
        f64::from(n) / m.wall_s.max(1e-9)
    );
    let s = summary.stats;
    println!(
        "link: {} frames sent, {} retransmitted ({} timeouts, {} NAKs), {} bad frames in, {} duplicate measurements, {} resend requests, {} reconnects",
        s.frames_sent, s.retransmits, s.timeouts, s.naks, s.bad_frames_in, s.duplicate_measurements, s.resend_requests, summary.reconnects
    );
    if let Some((to_device, to_host)) = &m.injected {
        println!("injected faults: host->device {to_device:?}; device->host {to_host:?}");
    }
}
