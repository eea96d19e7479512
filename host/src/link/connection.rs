//! The body that `gonio measure` and `gonio scan` share: open the port (optionally through the
//! fault injector), handshake before anything is written, then open or resume the journal in the
//! output folder and run the plan with reconnects, reporting through a [`Progress`].
//!
//! The split into [`Connection::open`] and [`Connection::measure`] lets a caller write its own
//! files between the two (a scan stores its inputs once a gonio has answered, so a port that is
//! not a gonio leaves nothing behind).

use super::{
    run_plan_below, FaultConfig, FaultCounts, FaultyTransport, Link, LinkError, Progress, Reconnect, ReopenFaulty,
    ReopenPath, RunError, RunOptions, RunSummary, SerialTransport, SharedFaultCounts, Transport,
};
use crate::journal::{Journal, JournalError};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::msg::Direction;
use std::path::Path;
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum MeasureError {
    #[error("cannot open port {port}: {error}")]
    Open { port: String, error: std::io::Error },
    #[error("{port}: {error}")]
    Handshake { port: String, error: LinkError },
    #[error("--resume: {0} has no journal to continue")]
    NoJournal(String),
    #[error("{0} already holds a scan journal; continue it with --resume or choose another -o")]
    JournalExists(String),
    #[error("cannot create {path}: {error}")]
    CreateDir { path: String, error: std::io::Error },
    #[error(transparent)]
    Journal(#[from] JournalError),
    #[error(transparent)]
    Plan(#[from] crate::plan::file::PlanFileError),
    #[error("{port}: {error} ({done} of {total} directions are in the journal)")]
    Run {
        port: String,
        error: RunError,
        done: usize,
        total: u32,
    },
}

/// Refuse a fresh scan into a folder that already has a journal, and a resume of one that has none,
/// before anything else happens.
pub fn check_journal_state(out: &Path, resume: bool) -> Result<(), MeasureError> {
    let exists = Journal::path_in(out).exists();
    if resume && !exists {
        return Err(MeasureError::NoJournal(out.display().to_string()));
    }
    if !resume && exists {
        return Err(MeasureError::JournalExists(out.display().to_string()));
    }
    Ok(())
}

/// A port with a gonio that has answered the handshake.
pub struct Connection {
    port: String,
    transport: Box<dyn Transport>,
    faults: Option<FaultConfig>,
    fault_counts: SharedFaultCounts,
}

/// What [`Connection::measure`] did.
pub struct Measured {
    pub journal: Journal,
    pub summary: RunSummary,
    /// Directions that were already in the journal when this run started.
    pub resumed: usize,
    pub wall_s: f64,
    /// Injected faults (host->device, device->host), when faults were injected.
    pub injected: Option<(FaultCounts, FaultCounts)>,
}

impl Connection {
    /// Open `port` (through the seeded fault injector when `faults` is given) and handshake: a
    /// silent port or a firmware of another protocol is refused here, with nothing written.
    pub fn open(port: &str, faults: Option<FaultConfig>, opts: &RunOptions) -> Result<Self, MeasureError> {
        let serial = SerialTransport::open(port).map_err(|error| MeasureError::Open {
            port: port.to_string(),
            error,
        })?;
        let fault_counts = SharedFaultCounts::default();
        let transport: Box<dyn Transport> = match faults {
            Some(f) => Box::new(FaultyTransport::new(serial, f).with_shared_counts(fault_counts.clone())),
            None => Box::new(serial),
        };
        let transport = Link::connect(transport, opts.timing)
            .map_err(|error| MeasureError::Handshake {
                port: port.to_string(),
                error,
            })?
            .into_inner();
        Ok(Self {
            port: port.to_string(),
            transport,
            faults,
            fault_counts,
        })
    }

    pub fn port(&self) -> &str {
        &self.port
    }

    /// Create (or, with `resume`, continue) the journal in `out` and measure every plan direction
    /// it lacks. On failure everything measured so far stays in the journal.
    pub fn measure(
        self,
        cfg: &InstrumentConfig<f64>,
        plan: &[Direction],
        out: &Path,
        resume: bool,
        opts: &RunOptions,
        progress: &mut dyn Progress,
    ) -> Result<Measured, MeasureError> {
        self.measure_below(cfg, plan, plan.len(), out, resume, opts, progress)
    }

    /// `measure` of the plan's first `limit` directions (a progressive scan's level); the journal
    /// is the whole plan's.
    #[allow(clippy::too_many_arguments)]
    pub fn measure_below(
        self,
        cfg: &InstrumentConfig<f64>,
        plan: &[Direction],
        limit: usize,
        out: &Path,
        resume: bool,
        opts: &RunOptions,
        progress: &mut dyn Progress,
    ) -> Result<Measured, MeasureError> {
        let total = u32::try_from(plan.len()).unwrap_or(u32::MAX);
        let hash = super::plan_hash(plan)?;
        std::fs::create_dir_all(out).map_err(|error| MeasureError::CreateDir {
            path: out.display().to_string(),
            error,
        })?;
        let mut journal = if resume {
            Journal::resume(out, hash, total)?
        } else {
            Journal::create(out, hash, total)?
        };
        let resumed = journal.records().len();
        progress.update(resumed as u32, total, 0.0);
        let wall = Instant::now();
        let mut reopen_plain = ReopenPath(self.port.clone());
        let mut reopen_faulty = self.faults.map(|faults| ReopenFaulty {
            path: self.port.clone(),
            faults,
            counts: self.fault_counts.clone(),
        });
        let reopen: &mut dyn Reconnect = match &mut reopen_faulty {
            Some(r) => r,
            None => &mut reopen_plain,
        };
        let result = run_plan_below(self.transport, reopen, cfg, plan, limit, &mut journal, progress, opts);
        let summary = result.map_err(|error| MeasureError::Run {
            port: self.port.clone(),
            error,
            done: journal.records().len(),
            total,
        })?;
        let injected = match self.faults {
            Some(_) => self.fault_counts.lock().ok().map(|c| (c.0, c.1)),
            None => None,
        };
        Ok(Measured {
            journal,
            summary,
            resumed,
            wall_s: wall.elapsed().as_secs_f64(),
            injected,
        })
    }
}

/// Link options from the user's timeouts (seconds), clamped to sane ranges.
pub fn run_options(hello_timeout: f64, reconnect_wait: f64) -> RunOptions {
    let mut opts = RunOptions::default();
    opts.timing.hello_timeout = Duration::from_secs_f64(hello_timeout.clamp(0.1, 600.0));
    opts.reconnect_wait = Duration::from_secs_f64(reconnect_wait.clamp(0.0, 86_400.0));
    opts
}
