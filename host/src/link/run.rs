//! [`run_plan`], the one call a scan makes: it streams the directions the journal does not have
//! yet, journals each measurement as it arrives, and when the device goes away (killed,
//! unplugged) waits for it to come back and continues.

use super::client::{Link, MeasurementSink};
use super::error::LinkError;
use super::reliable::{LinkStats, LinkTiming};
use super::transport::{FaultConfig, FaultyTransport, SerialTransport, SharedFaultCounts, Transport};
use crate::journal::{Journal, JournalError};
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::msg::{Direction, Measurement};
use std::time::{Duration, Instant};

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

/// Progress of a scan, for a progress bar or a log (the library prints nothing itself).
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

/// The journal as a measurement sink for one session: maps the session's stream indices to plan
/// indices and reports progress.
struct JournalSink<'a> {
    journal: &'a mut Journal,
    map: &'a [u32],
    progress: &'a mut dyn Progress,
    measured: u32,
    first_us: Option<u64>,
    last_us: u64,
    base_s: f64,
}

impl<'a> JournalSink<'a> {
    fn new(journal: &'a mut Journal, map: &'a [u32], progress: &'a mut dyn Progress, base_s: f64) -> Self {
        Self {
            journal,
            map,
            progress,
            measured: 0,
            first_us: None,
            last_us: 0,
            base_s,
        }
    }

    /// Instrument seconds from this session's first exposure to its last reading.
    fn span_s(&self) -> f64 {
        self.first_us.map_or(0.0, |f| (self.last_us - f) as f64 * 1e-6)
    }
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
        let done = self.journal.records().len() as u32;
        self.progress
            .update(done, self.journal.total(), self.base_s + self.span_s());
        Ok(())
    }
    fn sync(&mut self) -> Result<(), String> {
        self.journal.sync().map_err(|e| e.to_string())
    }
}

/// Readings of a session that ended in a connection loss which the device may still keep: the
/// session's stream-to-plan index map and how many readings it took in order.
struct Kept {
    map: Vec<u32>,
    from: u32,
}

/// How one session ended.
struct Session {
    stats: LinkStats,
    result: Result<(), LinkError>,
    /// The session's stream-to-plan index map.
    map: Vec<u32>,
    /// The device was configured for `map` (so it numbers its readings by it).
    streamed: bool,
    measured: u32,
    span_s: f64,
}

/// Handshake; take the readings the device kept from our previous session (`kept`, cleared once
/// taken); prepare and stream what the journal still lacks below `limit`.
#[allow(clippy::too_many_arguments)]
fn run_session(
    t: Box<dyn Transport>,
    cfg: &InstrumentConfig<f32>,
    plan: &[Direction],
    limit: u32,
    journal: &mut Journal,
    progress: &mut dyn Progress,
    kept: &mut Option<Kept>,
    base_s: f64,
    timing: LinkTiming,
) -> Session {
    let mut session = Session {
        stats: LinkStats::default(),
        result: Ok(()),
        map: Vec::new(),
        streamed: false,
        measured: 0,
        span_s: 0.0,
    };
    let mut link = match Link::connect(t, timing) {
        Ok(link) => link,
        Err(e) => {
            session.result = Err(e);
            return session;
        }
    };
    if let Some(k) = kept.as_mut() {
        let mut sink = JournalSink::new(journal, &k.map, progress, base_s);
        let collected = link.collect_kept(k.from, &mut sink);
        session.measured += sink.measured;
        session.span_s += sink.span_s();
        k.from += sink.measured;
        if let Err(e) = collected {
            session.stats = link.stats();
            session.result = Err(e);
            return session;
        }
        *kept = None;
    }
    session.map = journal.remaining_below(limit);
    if session.map.is_empty() {
        session.stats = link.stats();
        return session;
    }
    let sub: Vec<Direction> = session
        .map
        .iter()
        .filter_map(|&i| plan.get(i as usize).copied())
        .collect();
    let mut sink = JournalSink::new(journal, &session.map, progress, base_s + session.span_s);
    let result = link.prepare(cfg).and_then(|_| {
        session.streamed = true;
        link.scan(&sub, &mut sink)
    });
    if result.is_err() {
        let _ = sink.sync();
    }
    session.measured += sink.measured;
    session.span_s += sink.span_s();
    session.stats = link.stats();
    session.result = result;
    session
}

/// Measure every plan direction the journal lacks, over `first` (an open transport) and, after a
/// connection loss, whatever `reconnect` opens. Every measurement lands in the journal exactly
/// once; the device is told it may forget readings only after they are synced, and a device that
/// comes back still holding readings of the lost session hands them over before anything resets it.
pub fn run_plan(
    first: Box<dyn Transport>,
    reconnect: &mut dyn Reconnect,
    cfg: &InstrumentConfig<f64>,
    plan: &[Direction],
    journal: &mut Journal,
    progress: &mut dyn Progress,
    opts: &RunOptions,
) -> Result<RunSummary, RunError> {
    run_plan_below(first, reconnect, cfg, plan, plan.len(), journal, progress, opts)
}

/// `run_plan` of the plan's first `limit` directions only (one level of a progressive scan; the
/// journal keeps the whole plan's numbering).
#[allow(clippy::too_many_arguments)]
pub fn run_plan_below(
    first: Box<dyn Transport>,
    reconnect: &mut dyn Reconnect,
    cfg: &InstrumentConfig<f64>,
    plan: &[Direction],
    limit: usize,
    journal: &mut Journal,
    progress: &mut dyn Progress,
    opts: &RunOptions,
) -> Result<RunSummary, RunError> {
    let limit = u32::try_from(limit).unwrap_or(u32::MAX);
    let cfg32 = cfg.cast::<f32>();
    let mut summary = RunSummary::default();
    let mut transport = Some(first);
    let mut kept: Option<Kept> = None;
    loop {
        if kept.is_none() && journal.remaining_below(limit).is_empty() {
            return Ok(summary);
        }
        let t = match transport.take() {
            Some(t) => t,
            None => wait_for_device(reconnect, opts, progress)?,
        };
        summary.sessions += 1;
        let s = run_session(
            t,
            &cfg32,
            plan,
            limit,
            journal,
            progress,
            &mut kept,
            summary.instrument_s,
            opts.timing,
        );
        journal.session += 1;
        summary.stats.add(&s.stats);
        summary.measured_now += s.measured;
        summary.instrument_s += s.span_s;
        let Err(e) = s.result else {
            continue;
        };
        if !e.is_connection_loss() {
            return Err(to_plan_indices(e, &s.map).into());
        }
        if s.streamed {
            // What this session took in order; the device may keep the readings after those.
            let from = journal_count_in(journal, &s.map);
            kept = Some(Kept { map: s.map, from });
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

/// Readings of a session's stream in the journal: the stream is measured in order, so these are
/// its first ones.
fn journal_count_in(journal: &Journal, map: &[u32]) -> u32 {
    let n = map.iter().take_while(|i| journal.records().contains_key(i)).count();
    u32::try_from(n).unwrap_or(u32::MAX)
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
