//! The scan's measuring phase, level by level: each level measures the plan's directions up to
//! its end (a prefix of the order) into the one journal of the whole plan, and returns the
//! calibrated values of everything measured so far; `plan::closed_loop` reconstructs, estimates
//! and decides between levels. A level already complete in the journal (a resume) is read, not
//! measured again; one cut short is continued, so a resume mid-level or between levels gives the
//! uninterrupted scan's values, decisions and outputs.

use super::calibration::Calibration;
use super::{calibrated_values, io_err, ScanError, ScanRecord, SCAN_FILE};
use crate::journal::Journal;
use crate::link::{self, Connection, Measured, Progress, RunOptions, RunSummary};
use crate::plan::closed_loop::LevelAssessment;
use crate::plan::LevelSummary;
use glam::DVec3;
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::msg::Direction;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// Measures a scan's levels over one port.
pub struct LevelMeasurer<'a> {
    pub out: &'a Path,
    pub port: String,
    pub instrument: &'a InstrumentConfig<f64>,
    pub calibration: &'a Calibration,
    pub wire: &'a [Direction],
    pub options: &'a RunOptions,
    pub faults: Option<link::FaultConfig>,
    pub record: ScanRecord,
    /// The connection opened before the scan's files were written (used for the first level measured).
    pub first: Option<Connection>,
    /// Whether the journal exists already.
    pub journal_exists: bool,
    /// Summed over the levels: link summary, wall seconds of measuring, readings found in the journal.
    pub summary: RunSummary,
    pub wall_s: f64,
    pub resumed: Option<usize>,
    pub injected: Option<(link::FaultCounts, link::FaultCounts)>,
    pub journal: Option<Journal>,
}

impl LevelMeasurer<'_> {
    /// Every value up to and including `level` (indexed like the plan), measuring what the journal lacks.
    pub fn measure(&mut self, level: &LevelSummary, progress: &mut dyn Progress) -> Result<Vec<DVec3>, ScanError> {
        let limit = level.cumulative_directions;
        let total = u32::try_from(self.wire.len()).unwrap_or(u32::MAX);
        // scan.toml says which level is being measured (a resume reads the journal to know where).
        self.record.level = level.level;
        let text = toml::to_string(&self.record).map_err(|e| ScanError::Input(format!("{SCAN_FILE}: {e}")))?;
        let path = self.out.join(SCAN_FILE);
        crate::fsio::write_bytes_atomically(&path, text.as_bytes()).map_err(io_err(&path))?;
        let complete = match self.journal_exists {
            true => {
                let journal =
                    Journal::resume(self.out, link::plan_hash(self.wire)?, total).map_err(link::MeasureError::from)?;
                self.resumed.get_or_insert(journal.records().len());
                let done = journal.remaining_below(limit as u32).is_empty();
                self.journal = Some(journal);
                done
            }
            false => false,
        };
        if !complete {
            let connection = match self.first.take() {
                Some(c) => c,
                None => Connection::open(&self.port, self.faults, self.options)?,
            };
            let t = Instant::now();
            let m: Measured = connection.measure_below(
                self.instrument,
                self.wire,
                limit,
                self.out,
                self.journal_exists,
                self.options,
                progress,
            )?;
            self.wall_s += t.elapsed().as_secs_f64();
            self.resumed.get_or_insert(m.resumed);
            self.summary.measured_now += m.summary.measured_now;
            self.summary.sessions += m.summary.sessions;
            self.summary.reconnects += m.summary.reconnects;
            self.summary.instrument_s += m.summary.instrument_s;
            self.summary.stats.add(&m.summary.stats);
            self.injected = m.injected.or(self.injected.take());
            self.journal = Some(m.journal);
            self.journal_exists = true;
        }
        let journal = self
            .journal
            .as_ref()
            .ok_or_else(|| ScanError::Input("no journal after measuring".into()))?;
        calibrated_values(journal, self.wire.len(), self.instrument, self.calibration)
    }

    /// What the levels measured, as one `Measured` (the journal of the last level).
    pub fn into_measured(self) -> Result<Measured, ScanError> {
        Ok(Measured {
            journal: self
                .journal
                .ok_or_else(|| ScanError::Input("no journal after measuring".into()))?,
            summary: self.summary,
            resumed: self.resumed.unwrap_or(0),
            wall_s: self.wall_s,
            injected: self.injected,
        })
    }
}

/// The report's per-level table (markdown) and the stop line.
pub fn levels_markdown(levels: &[LevelAssessment], stop_reason: &str, rule: &str) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "## Levels (closed loop)\n");
    let _ = writeln!(
        md,
        "Rule: {rule}. {stop_reason}. The estimate needs no ground truth: the FLIP between this level's and \
         the previous level's capture renders (at level 1: between the renders from each half of its \
         measurements and from all of them) times a ratio measured on training materials, with its 90% \
         interval (docs/scan.md, \"Closed loop\"); renders {} px. ![levels](levels.png)\n",
        crate::plan::closed_loop::ESTIMATE_SIZE
    );
    let _ = writeln!(
        md,
        "| level | N | directions | instrument min | prior | change FLIP | estimated FLIP [90%] | estimated PSNR | interval half-width (ln) | true FLIP | true PSNR | truth inside interval |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|---|---|---|");
    let f = |v: Option<f64>, p: usize| v.map_or("-".to_string(), |x| format!("{x:.p$}"));
    for a in levels {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.1} | {} | {} | {} | {} | {} | {} | {} | {} |",
            a.level,
            a.n,
            a.directions,
            a.cumulative_seconds / 60.0,
            a.prior,
            f(a.change_flip, 4),
            a.est_flip
                .map_or("-".into(), |(e, lo, hi)| format!("{e:.4} [{lo:.4}, {hi:.4}]")),
            f(a.est_psnr, 1),
            f(a.half_width, 3),
            f(a.true_flip, 4),
            f(a.true_psnr, 1),
            a.coverage.map_or("-".into(), |c| format!("{:.0}%", c * 100.0)),
        );
    }
    md
}
