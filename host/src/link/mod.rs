//! The serial link to a gonio and the scan runner on top of it.
//!
//! - [`transport`]: the byte pipe (a serial port; a seeded fault injector around any pipe);
//! - [`session`]: frames, ACK/NAK, retransmission, handshake, configure/home/stream/collect;
//! - this module: [`run_plan`], the one call a scan makes: it streams the directions the journal
//!   does not have yet, journals each measurement as it arrives, and when the device goes away
//!   (killed, unplugged) waits for it to come back and continues; and [`write_csv`].

pub mod runner;
pub mod session;
pub mod transport;

use crate::journal::{Journal, JournalError};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::kinematics::Kinematics;
use gonio_shared::msg::{Direction, Measurement};
pub use runner::{check_journal_state, run_options, Connection, MeasureError, Measured};
pub use session::{Link, LinkError, LinkStats, LinkTiming, MeasurementSink};
use std::path::Path;
use std::time::{Duration, Instant};
pub use transport::{FaultConfig, FaultCounts, FaultyTransport, SerialTransport, SharedFaultCounts, Transport};

/// Opens the port again after the device went away.
pub trait Reconnect {
    fn open(&mut self) -> std::io::Result<Box<dyn Transport>>;
}

/// Reopen a serial port path (for a board, the same /dev path comes back on replug; for the
/// virtual gonio, its published link).
pub struct ReopenPath(pub String);

impl Reconnect for ReopenPath {
    fn open(&mut self) -> std::io::Result<Box<dyn Transport>> {
        Ok(Box::new(SerialTransport::open(&self.0)?))
    }
}

/// Reopen a port path through a fault injector (each connection with the next seed).
pub struct ReopenFaulty {
    pub path: String,
    pub faults: FaultConfig,
    pub counts: SharedFaultCounts,
}

impl Reconnect for ReopenFaulty {
    fn open(&mut self) -> std::io::Result<Box<dyn Transport>> {
        self.faults.seed = self.faults.seed.wrapping_add(1);
        let t = FaultyTransport::new(SerialTransport::open(&self.path)?, self.faults)
            .with_shared_counts(self.counts.clone());
        Ok(Box::new(t))
    }
}

/// Progress of a scan, for a progress bar or a log.
pub trait Progress {
    /// `done` of `total` directions are in the journal; `instrument_s` is the device's clock at the
    /// last reading.
    fn update(&mut self, done: u32, total: u32, instrument_s: f64);
    /// Something the user should know (device lost, back, ...), one line.
    fn note(&mut self, line: &str);
}

/// A progress sink that says nothing.
pub struct Quiet;
impl Progress for Quiet {
    fn update(&mut self, _: u32, _: u32, _: f64) {}
    fn note(&mut self, _: &str) {}
}

#[derive(Clone, Copy, Debug)]
pub struct RunOptions {
    pub timing: LinkTiming,
    /// How long to wait for a lost device to come back before giving up.
    pub reconnect_wait: Duration,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            timing: LinkTiming::default(),
            reconnect_wait: Duration::from_secs(30),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error(transparent)]
    Journal(#[from] JournalError),
    #[error("lost the device and it did not come back within {0:.0} s ({1})")]
    Gone(f64, String),
}

/// What a finished scan did.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    pub measured_now: u32,
    pub sessions: u32,
    pub reconnects: u32,
    pub stats: LinkStats,
    /// Instrument time spent by this run (sum over sessions of last - first timestamp, plus one
    /// exposure per session).
    pub instrument_s: f64,
}

fn add_stats(a: &mut LinkStats, b: &LinkStats) {
    a.frames_sent += b.frames_sent;
    a.retransmits += b.retransmits;
    a.naks += b.naks;
    a.timeouts += b.timeouts;
    a.bad_frames_in += b.bad_frames_in;
    a.duplicate_measurements += b.duplicate_measurements;
    a.resend_requests += b.resend_requests;
    a.status_requests += b.status_requests;
}

struct JournalSink<'a> {
    journal: &'a mut Journal,
    map: &'a [u32],
    progress: &'a mut dyn Progress,
    measured: u32,
    first_us: Option<u64>,
    last_us: u64,
    base_s: f64,
}

impl MeasurementSink for JournalSink<'_> {
    fn record(&mut self, m: &Measurement) -> Result<(), String> {
        let index = *self.map.get(m.index as usize).ok_or_else(|| {
            format!(
                "device measured direction {} of a {}-direction stream",
                m.index,
                self.map.len()
            )
        })?;
        self.journal.append(index, m).map_err(|e| e.to_string())?;
        self.measured += 1;
        self.first_us
            .get_or_insert(m.timestamp_us.saturating_sub(u64::from(m.exposure_us)));
        self.last_us = m.timestamp_us;
        let session_s = (self.last_us - self.first_us.unwrap_or(self.last_us)) as f64 * 1e-6;
        let done = self.journal.records().len() as u32;
        self.progress
            .update(done, self.journal.total(), self.base_s + session_s);
        Ok(())
    }
    fn sync(&mut self) -> Result<(), String> {
        self.journal.sync().map_err(|e| e.to_string())
    }
}

/// Measure every plan direction the journal lacks, over `first` (an open transport) and, after a
/// connection loss, whatever `reconnect` opens. Every measurement lands in the journal exactly
/// once; the device is told it may forget readings only after they are synced.
pub fn run_plan(
    first: Box<dyn Transport>,
    reconnect: &mut dyn Reconnect,
    cfg: &InstrumentConfig<f64>,
    plan: &[Direction],
    journal: &mut Journal,
    progress: &mut dyn Progress,
    opts: &RunOptions,
) -> Result<RunSummary, RunError> {
    let cfg32 = cfg.cast::<f32>();
    let mut summary = RunSummary::default();
    let mut transport = Some(first);
    loop {
        let remaining = journal.remaining();
        if remaining.is_empty() {
            return Ok(summary);
        }
        let t = match transport.take() {
            Some(t) => t,
            None => wait_for_device(reconnect, opts, progress)?,
        };
        let sub: Vec<Direction> = remaining
            .iter()
            .filter_map(|&i| plan.get(i as usize).copied())
            .collect();
        summary.sessions += 1;
        let result = (|| -> Result<(u32, f64, LinkStats), (LinkError, LinkStats)> {
            let mut link = Link::connect(t, opts.timing).map_err(|e| (e, LinkStats::default()))?;
            if let Err(e) = link.prepare(&cfg32) {
                return Err((e, link.stats));
            }
            let mut sink = JournalSink {
                journal,
                map: &remaining,
                progress,
                measured: 0,
                first_us: None,
                last_us: 0,
                base_s: summary.instrument_s,
            };
            let r = link.scan(&sub, &mut sink);
            let span = sink.first_us.map_or(0.0, |f| (sink.last_us - f) as f64 * 1e-6);
            let measured = sink.measured;
            match r {
                Ok(()) => Ok((measured, span, link.stats)),
                Err(e) => {
                    let _ = sink.sync();
                    Err((e, link.stats))
                }
            }
        })();
        journal.session += 1;
        match result {
            Ok((n, span, stats)) => {
                summary.measured_now += n;
                summary.instrument_s += span;
                add_stats(&mut summary.stats, &stats);
            }
            Err((e, stats)) => {
                add_stats(&mut summary.stats, &stats);
                if !e.is_connection_loss() {
                    return Err(to_plan_indices(e, &remaining).into());
                }
                progress.note(&format!(
                    "{e}; {} of {} directions are in the journal; waiting up to {:.0} s for the device",
                    journal.records().len(),
                    journal.total(),
                    opts.reconnect_wait.as_secs_f64()
                ));
                summary.reconnects += 1;
            }
        }
    }
}

/// The device numbers the directions of this session's stream from 0; the user knows them by
/// their plan-file index.
fn to_plan_indices(e: LinkError, remaining: &[u32]) -> LinkError {
    use gonio_shared::msg::Fault;
    match e {
        LinkError::Fault {
            fault: Fault::Unreachable { index, reason },
            pose,
            steps,
        } => LinkError::Fault {
            fault: Fault::Unreachable {
                index: remaining.get(index as usize).copied().unwrap_or(index),
                reason,
            },
            pose,
            steps,
        },
        other => other,
    }
}

fn wait_for_device(
    reconnect: &mut dyn Reconnect,
    opts: &RunOptions,
    progress: &mut dyn Progress,
) -> Result<Box<dyn Transport>, RunError> {
    let start = Instant::now();
    let mut last = String::from("not tried");
    // A moment for the old port to disappear, so we do not reopen the dying one.
    std::thread::sleep(Duration::from_millis(200));
    while start.elapsed() < opts.reconnect_wait {
        match reconnect.open() {
            Ok(t) => {
                progress.note("device is back; resuming");
                return Ok(t);
            }
            Err(e) => last = e.to_string(),
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    Err(RunError::Gone(opts.reconnect_wait.as_secs_f64(), last))
}

/// The journal's key for a plan: FNV-1a 64 of its canonical plan-file encoding, so `gonio measure`
/// (from a file) and a scan (from directions in memory) journal the same plan the same way.
pub fn plan_hash(directions: &[Direction]) -> Result<u64, crate::plan::file::PlanFileError> {
    Ok(crate::journal::fnv64(&crate::plan::file::encode_plan(directions)?))
}

/// The direction pair a reading was really taken at: forward kinematics of its step positions,
/// `(theta_i, phi_i, theta_o, phi_o)` in radians. On an isotropic instrument the azimuth stage
/// stays put, so both phis may differ from the requested ones by a common rotation; their
/// difference is what was measured.
pub fn reached(kin: &Kinematics<f64>, steps: &[i32; 4]) -> [f64; 4] {
    let (wi, wo) = kin.forward(&kin.from_steps(steps));
    let (ti, pi) = angles(wi);
    let (to, po) = angles(wo);
    [ti, pi, to, po]
}

/// (theta, phi) in radians of a local direction.
fn angles(v: gonio_shared::vec3::Vec3<f64>) -> (f64, f64) {
    (v.z.clamp(-1.0, 1.0).acos(), v.y.atan2(v.x))
}

/// `measurements.csv`, written atomically: one row per plan direction measured, by index.
///
/// Columns: `index`, the requested `theta_i,phi_i,theta_o,phi_o` (degrees), the pose reached (the
/// same four, from forward kinematics of the reported step positions, see [`reached`]), the four step
/// positions, `exposure_us`, `timestamp_us` (device clock of that session), `session`, and one
/// `count_K` column per detector channel.
pub fn write_csv(
    path: &Path,
    cfg: &InstrumentConfig<f64>,
    plan: &[Direction],
    journal: &Journal,
) -> std::io::Result<()> {
    use std::fmt::Write as _;
    let kin = Kinematics::new(*cfg).map_err(|e| std::io::Error::other(e.to_string()))?;
    let channels = journal.records().values().map(|r| r.counts.len()).max().unwrap_or(0);
    let mut s = String::from(
        "index,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,reached_theta_i_deg,reached_phi_i_deg,reached_theta_o_deg,reached_phi_o_deg,steps_light,steps_detector,steps_tilt,steps_azimuth,exposure_us,timestamp_us,session",
    );
    for k in 0..channels {
        let _ = write!(s, ",count_{k}");
    }
    s.push('\n');
    for (index, r) in journal.records() {
        let Some(d) = plan.get(*index as usize) else { continue };
        let [ti, pi, to, po] = reached(&kin, &r.steps).map(f64::to_degrees);
        let _ = write!(
            s,
            "{index},{:.6},{:.6},{:.6},{:.6},{ti:.6},{pi:.6},{to:.6},{po:.6},{},{},{},{},{},{},{}",
            f64::from(d.theta_i).to_degrees(),
            f64::from(d.phi_i).to_degrees(),
            f64::from(d.theta_o).to_degrees(),
            f64::from(d.phi_o).to_degrees(),
            r.steps[0],
            r.steps[1],
            r.steps[2],
            r.steps[3],
            r.exposure_us,
            r.timestamp_us,
            r.session
        );
        for k in 0..channels {
            let _ = write!(s, ",{}", r.counts.get(k).map_or(String::new(), u32::to_string));
        }
        s.push('\n');
    }
    crate::fsio::write_bytes_atomically(path, s.as_bytes())
}
