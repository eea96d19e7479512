//! `gonio scan`: the whole chain in one command, photo -> estimate -> plan -> stream over serial ->
//! measure -> reconstruct -> outputs, against a board (`--port`) or the virtual gonio (`--sim`).
//!
//! Phases (each timed on the host clock and reported in `report.md`):
//! 1. **estimate**: `encoder::photo::estimate_from_photo` (encoder + diffuse/specular split);
//! 2. **plan**: `plan::Planner` with nested levels up to the cap (`--grid`, default 16); the encoded
//!    plan is re-simulated before it is sent (`Plan::check_encoded`);
//! 3. **calibrate**: with `--calibration CAL.toml` that file; against `--sim` without one, the scan
//!    calibrates itself first on the same simulated instrument (a light trap and the white standard
//!    in the sample holder, see [`calibration`]); against a port without one it refuses;
//! 4. **measure and reconstruct, level by level** (the closed loop, `plan::closed_loop`, driven by
//!    [`progressive`]): each level is measured through `link::Connection` (the code `gonio measure`
//!    runs) into the one journal in OUTDIR with a progress bar; counts -> BRDF with the calibration
//!    at the pose each reading was taken; the level is reconstructed from every direction so far,
//!    its error estimated without ground truth (one console line per level), and the stop rule
//!    (`--target-flip`, default 0.01; `--target-psnr`; `--time-budget`; `--grid` alone: every
//!    level) decides whether the next level is measured;
//! 6. **outputs** ([`outputs`]): `grid.json`, `measured.binary`, `measured.bsdf`, renders, and in
//!    simulation the scores against the ground truth; `report.md`.
//!
//! ## Resume
//! Once a gonio has answered the handshake, and before the first direction is sent, OUTDIR gets
//! everything a resume needs: `scan.toml` (the gonio version and reconstruction settings, and the
//! inputs: image, estimate to full precision, plan rule and level, instrument file text, the
//! source (port, or the simulated scene's path and text, seed and speedup), render settings),
//! `plan.bin` (the plan file `gonio measure` reads) and `calibration.toml`. `gonio scan --resume
//! OUTDIR` refuses a scan made by another build or with other reconstruction settings, re-reads
//! the rest, plans again from the stored estimate (the planner is deterministic) and refuses to go
//! on unless that plan encodes to the stored `plan.bin` byte for byte; then it runs the loop again:
//! levels complete in the journal are read, the level cut short is continued. The decisions and
//! outputs depend only on the journal's readings, the plan, the calibration and the
//! reconstruction, so they equal an uninterrupted scan's, whether it stopped mid-level or between
//! levels.

pub mod calibration;
pub mod outputs;
pub mod plot;
pub mod progressive;

use crate::encoder::ModelKind;
use crate::link::{self, Connection, FaultConfig, Progress, RunOptions};
use crate::plan::closed_loop::{self, StopRule};
use crate::plan::{Estimate, Plan, PlanConfig, Planner, Spacing, Strategy};
use crate::sim::{model::SimModel, SimHandle};
use calibration::Calibration;
use glam::DVec3;
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::msg::Direction;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

pub const SCAN_FILE: &str = "scan.toml";
pub const PLAN_FILE: &str = "plan.bin";
pub const CALIBRATION_FILE: &str = "calibration.toml";
/// Version of `scan.toml` (2: the gonio version and the reconstruction settings; 3: the closed
/// loop's stop rule, the level being measured and the journal).
pub const SCAN_FORMAT: u32 = 3;
/// The journal's file name in OUTDIR (one journal for every level).
pub const JOURNAL_FILE: &str = crate::journal::FILE_NAME;

#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    /// A bad input, said in one line.
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Photo(#[from] crate::encoder::photo::PhotoError),
    #[error(transparent)]
    Plan(#[from] crate::plan::PlanError),
    #[error(transparent)]
    Reconstruct(#[from] crate::reconstruct::ReconstructError),
    #[error(transparent)]
    PlanFile(#[from] crate::plan::file::PlanFileError),
    #[error(transparent)]
    Instrument(#[from] crate::instrument::InstrumentFileError),
    #[error(transparent)]
    Scene(#[from] crate::sim::model::SceneError),
    #[error(transparent)]
    Sim(#[from] crate::sim::SimError),
    #[error(transparent)]
    Calibration(#[from] calibration::CalibrationError),
    #[error(transparent)]
    Measure(#[from] link::MeasureError),
    #[error("{path}: {error}")]
    Io { path: String, error: std::io::Error },
    #[error(transparent)]
    Output(#[from] outputs::OutputError),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> ScanError + '_ {
    move |error| ScanError::Io {
        path: path.display().to_string(),
        error,
    }
}

/// Planner level of an N x N grid.
pub fn level_of(n: usize) -> Result<usize, ScanError> {
    if n < 2 || !n.is_power_of_two() || n.trailing_zeros() as usize > crate::plan::MAX_LEVEL {
        return Err(ScanError::Input(format!(
            "grid {n} must be a power of two from 2 to {}",
            1usize << crate::plan::MAX_LEVEL
        )));
    }
    Ok(n.trailing_zeros() as usize)
}

/// Where the readings come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceRecord {
    /// A serial port (a board, or a `gonio sim` started by hand).
    pub port: Option<String>,
    /// The virtual gonio's scan scene: its path (anchors relative paths and names it in messages)
    /// and its text as it was at the start (what a resume simulates).
    pub sim_scene: Option<String>,
    pub sim_scene_text: Option<String>,
    pub seed: u64,
    pub speedup: f64,
}

/// `OUTDIR/scan.toml`: the inputs of a scan, enough to resume it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanRecord {
    pub format: u32,
    /// The build that made the scan (`crate::VERSION`); a resume by another build is refused.
    #[serde(default)]
    pub gonio_version: String,
    /// The reconstruction the scan's outputs use (`reconstruct::settings`); a resume whose
    /// build reconstructs otherwise is refused.
    #[serde(default)]
    pub reconstruction: String,
    pub image: String,
    /// The encoder model and its raw outputs (`ModelKind::outputs` order).
    pub encoder: String,
    pub encoder_outputs: Vec<f64>,
    /// The estimate the plan was built from (a spec that parses back to the same f64 values).
    pub estimate: String,
    /// The stop rule, in words.
    pub rule: String,
    /// The stop rule (`StopRule::to_record`).
    pub stop_rule: String,
    pub strategy: String,
    pub spacing: String,
    pub incoming: usize,
    /// The plan's levels (the cap); `plan.bin` holds all of them.
    pub max_level: usize,
    /// The level being measured (a finished scan: the level it stopped at).
    pub level: usize,
    /// Directions of the whole plan (the journal's numbering).
    pub directions: usize,
    /// The journal's file name in OUTDIR.
    pub journal: String,
    /// FNV-1a 64 of `plan.bin`, hex.
    pub plan_hash: String,
    /// The instrument file's text (the shipped one when none was given).
    pub instrument_toml: String,
    pub render_size: usize,
    pub env_spp: u32,
    pub source: SourceRecord,
}

impl ScanRecord {
    pub fn read(dir: &Path) -> Result<Self, ScanError> {
        let path = dir.join(SCAN_FILE);
        let text = std::fs::read_to_string(&path).map_err(|e| {
            ScanError::Input(format!(
                "--resume: {} has no readable {SCAN_FILE} ({e}); was it made by gonio scan?",
                dir.display()
            ))
        })?;
        let record: ScanRecord = toml::from_str(&text).map_err(|e| {
            ScanError::Input(format!(
                "{}: {}",
                path.display(),
                e.message().lines().next().unwrap_or("invalid TOML")
            ))
        })?;
        if record.format != SCAN_FORMAT {
            return Err(ScanError::Input(format!(
                "{}: format {} is not {SCAN_FORMAT}",
                path.display(),
                record.format
            )));
        }
        Ok(record)
    }

    /// Refuse, in one line, a resume by a build that is not the one that made the scan or that
    /// reconstructs otherwise: its outputs would not be the original scan's.
    pub fn check_same_build(&self, dir: &Path) -> Result<(), ScanError> {
        let here = crate::reconstruct::settings();
        if self.gonio_version != crate::VERSION || self.reconstruction != here {
            return Err(ScanError::Input(format!(
                "--resume: {} was made by gonio {} (reconstruction {}), this is gonio {} (reconstruction {here}); resume it with the build that made it",
                dir.join(SCAN_FILE).display(),
                if self.gonio_version.is_empty() { "?" } else { &self.gonio_version },
                if self.reconstruction.is_empty() { "?" } else { &self.reconstruction },
                crate::VERSION,
            )));
        }
        Ok(())
    }

    pub fn instrument(&self, dir: &Path) -> Result<InstrumentConfig<f64>, ScanError> {
        Ok(crate::instrument::parse(&self.instrument_toml, &dir.join(SCAN_FILE))?)
    }

    pub fn plan_config(&self) -> Result<PlanConfig, ScanError> {
        let strategy: Strategy = self
            .strategy
            .parse()
            .map_err(|_| ScanError::Input(format!("{SCAN_FILE}: unknown strategy {:?}", self.strategy)))?;
        let spacing: Spacing = self
            .spacing
            .parse()
            .map_err(|_| ScanError::Input(format!("{SCAN_FILE}: unknown spacing {:?}", self.spacing)))?;
        Ok(PlanConfig {
            strategy,
            spacing,
            k: self.incoming,
            grids: crate::plan::square_grids(self.max_level),
            incoming: Vec::new(),
        })
    }

    pub fn stop_rule(&self) -> Result<StopRule, ScanError> {
        StopRule::parse(&self.stop_rule)
            .ok_or_else(|| ScanError::Input(format!("{SCAN_FILE}: unknown stop rule {:?}", self.stop_rule)))
    }

    pub fn estimate(&self) -> Result<Estimate, ScanError> {
        let model = crate::brdf::spec::parse_analytic(&self.estimate)
            .map_err(|e| ScanError::Input(format!("{SCAN_FILE}: estimate: {e}")))?;
        Ok(Estimate { model })
    }

    /// The simulated scene, if the source is the virtual gonio.
    pub fn sim_model(&self, instrument: InstrumentConfig<f64>) -> Result<Option<SimModel>, ScanError> {
        match (&self.source.sim_scene, &self.source.sim_scene_text) {
            (Some(path), Some(text)) => Ok(Some(SimModel::from_toml(
                text,
                Path::new(path),
                instrument,
                self.source.seed,
            )?)),
            _ => Ok(None),
        }
    }
}

/// Host wall time per phase, seconds.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct PhaseTimes {
    pub estimate: f64,
    pub plan: f64,
    pub calibrate: f64,
    pub measure: f64,
    pub reconstruct: f64,
    pub outputs: f64,
}

impl PhaseTimes {
    pub fn total(&self) -> f64 {
        self.estimate + self.plan + self.calibrate + self.measure + self.reconstruct + self.outputs
    }
}

/// A new scan's inputs.
#[derive(Clone, Debug)]
pub struct FreshScan {
    pub image: PathBuf,
    pub model: ModelKind,
    /// When the closed loop stops.
    pub rule: StopRule,
    /// The deepest grid (N x N) the loop may reach (a power of two).
    pub max_grid: usize,
    pub instrument: Option<PathBuf>,
    pub calibration: Option<PathBuf>,
    /// `Some(port)` or `None` with `sim`.
    pub port: Option<String>,
    pub sim: Option<PathBuf>,
    pub seed: u64,
    pub speedup: f64,
    pub render_size: usize,
    pub env_spp: u32,
}

#[derive(Clone, Debug)]
pub enum Start {
    Fresh(Box<FreshScan>),
    /// Continue the scan in OUTDIR; a board may come back under another port path, and a
    /// simulation may run at another speed.
    Resume {
        port: Option<String>,
        speedup: Option<f64>,
    },
}

#[derive(Clone, Debug)]
pub struct ScanRequest {
    pub out: PathBuf,
    pub start: Start,
    pub options: RunOptions,
    pub faults: Option<FaultConfig>,
}

/// What a finished scan did.
pub struct ScanOutcome {
    pub record: ScanRecord,
    /// The closed loop's levels and why it stopped.
    pub levels: Vec<closed_loop::LevelAssessment>,
    pub stop_reason: String,
    pub measured: link::Measured,
    pub report: outputs::Report,
    pub times: PhaseTimes,
}

/// A planned scan, ready to send.
struct Planned {
    plan: Plan,
    wire: Vec<Direction>,
    bytes: Vec<u8>,
}

fn encode_checked(plan: Plan, instrument: &InstrumentConfig<f64>) -> Result<Planned, ScanError> {
    let wire = plan.wire();
    let bytes = crate::plan::file::encode_plan(&wire)?;
    plan.check_encoded(instrument, &bytes)?;
    Ok(Planned { plan, wire, bytes })
}

/// Convert every journaled reading to a BRDF value, indexed like the plan's directions.
pub fn calibrated_values(
    journal: &crate::journal::Journal,
    plan_len: usize,
    instrument: &InstrumentConfig<f64>,
    cal: &Calibration,
) -> Result<Vec<DVec3>, ScanError> {
    let kin = gonio_shared::kinematics::Kinematics::new(*instrument)
        .map_err(|e| ScanError::Input(format!("instrument: {e}")))?;
    let mut values = vec![DVec3::ZERO; plan_len];
    for (index, r) in journal.records() {
        let cos_i = link::reached(&kin, &r.steps)[0].cos();
        let f = cal
            .brdf(&r.counts, cos_i, r.exposure_us)
            .map_err(|e| ScanError::Input(format!("direction {index}: {e}")))?;
        if let Some(v) = values.get_mut(*index as usize) {
            *v = f;
        }
    }
    Ok(values)
}

/// The self-calibration of a scan against the virtual gonio: the scene's instrument with a light
/// trap, then the white standard, in the sample holder.
pub fn calibrate_sim(
    scene_text: &str,
    scene_path: &Path,
    instrument: InstrumentConfig<f64>,
    seed: u64,
    speedup: f64,
    reference: &str,
    options: &RunOptions,
) -> Result<Calibration, ScanError> {
    calibration::reference_albedo(reference)?;
    let directions = calibration::directions();
    let mut sets = Vec::new();
    for material in [calibration::DARK_TRAP, reference] {
        let model = SimModel::from_toml_with_material(scene_text, scene_path, instrument, seed, material)?;
        let sim = SimHandle::spawn(Arc::new(model), speedup, None)?;
        let port = sim.path().display().to_string();
        let readings = calibration::measure_reference(&port, &instrument, &directions, options.timing);
        sim.stop();
        sets.push(readings?);
    }
    Ok(calibration::fit(
        &instrument,
        reference,
        &sets[0],
        &sets[1],
        &format!("sim:{}", scene_path.display()),
    )?)
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), ScanError> {
    crate::fsio::write_bytes_atomically(path, bytes).map_err(io_err(path))
}

/// Run a scan (fresh or resumed) to its outputs. Bad inputs are refused before OUTDIR is touched.
pub fn run(
    req: &ScanRequest,
    progress: &mut dyn Progress,
    note: &mut dyn FnMut(&str),
) -> Result<ScanOutcome, ScanError> {
    let mut times = PhaseTimes::default();
    let out = &req.out;
    let resume = matches!(req.start, Start::Resume { .. });
    link::check_journal_state(out, resume)?;
    let (record, planned, cal, sim_model) = match &req.start {
        Start::Fresh(f) => prepare_fresh(f, out, &req.options, &mut times, note)?,
        Start::Resume { .. } => prepare_resume(out, &mut times)?,
    };
    let instrument = record.instrument(out)?;
    // The device: a simulation started here, or a port.
    let speedup = match req.start {
        Start::Resume { speedup: Some(s), .. } => s,
        _ => record.source.speedup,
    };
    if !(speedup.is_finite() && speedup >= 1.0) {
        return Err(ScanError::Input("--speedup must be >= 1".into()));
    }
    let sim = match sim_model {
        Some(model) => Some(SimHandle::spawn(Arc::new(model), speedup, None)?),
        None => None,
    };
    let port = match (&sim, &req.start, &record.source.port) {
        (Some(s), _, _) => s.path().display().to_string(),
        (None, Start::Resume { port: Some(p), .. }, _) => p.clone(),
        (None, _, Some(p)) => p.clone(),
        (None, _, None) => return Err(ScanError::Input("give --port PATH or --sim SCENE".into())),
    };
    let t = Instant::now();
    let connection = Connection::open(&port, req.faults, &req.options)?;
    // A gonio answered: store what a resume needs, then measure.
    if !resume {
        std::fs::create_dir_all(out).map_err(io_err(out))?;
        write_file(&out.join(PLAN_FILE), &planned.bytes)?;
        write_file(&out.join(CALIBRATION_FILE), cal.to_toml().as_bytes())?;
    }
    times.measure = t.elapsed().as_secs_f64();
    note(&format!(
        "measuring level by level on {} (up to {} directions; stop rule: {})",
        if sim.is_some() {
            "the virtual gonio"
        } else {
            port.as_str()
        },
        planned.wire.len(),
        record.rule
    ));
    let rule = record.stop_rule()?;
    let truth = record.sim_model(instrument)?.map(|m| m.material_spec);
    let mut measurer = progressive::LevelMeasurer {
        out,
        port,
        instrument: &instrument,
        calibration: &cal,
        wire: &planned.wire,
        options: &req.options,
        faults: req.faults,
        record: record.clone(),
        first: Some(connection),
        journal_exists: resume,
        summary: Default::default(),
        wall_s: 0.0,
        resumed: None,
        injected: None,
        journal: None,
    };
    let mut values = Vec::new();
    let loop_start = Instant::now();
    let result = closed_loop::run::<ScanError>(
        &planned.plan,
        &rule,
        truth.as_deref(),
        &mut |level| {
            let v = measurer.measure(level, progress)?;
            values.clone_from(&v);
            Ok(v)
        },
        &mut |a| note(&closed_loop::level_line(a)),
    );
    let closed = result?;
    let loop_s = loop_start.elapsed().as_secs_f64();
    note(&closed.stop_reason);
    let mut record = measurer.record.clone();
    let measured = measurer.into_measured()?;
    times.measure += measured.wall_s;
    // Host time between levels: reconstructions, error estimates and decisions.
    times.reconstruct = (loop_s - measured.wall_s).max(0.0);
    if let Some(sim) = sim {
        sim.stop();
    }
    record.level = closed.stop_level;
    let plan = planned.plan.clone().truncate(closed.stop_level);
    let values = &values[..plan.directions.len().min(values.len())];
    let t = Instant::now();
    let report = outputs::write_all(&outputs::OutputInputs {
        out,
        record: &record,
        plan: &plan,
        values,
        journal: &measured.journal,
        instrument: &instrument,
        calibration: &cal,
        grid: &closed.reconstruction,
        truth: truth.as_deref(),
    })?;
    plot::write_levels(&out.join(LEVELS_PNG), &closed.levels).map_err(ScanError::Input)?;
    times.outputs = t.elapsed().as_secs_f64();
    let mut report = outputs::finish_report(
        out,
        report,
        &record,
        &plan,
        &measured,
        &times,
        &progressive::levels_markdown(&closed.levels, &closed.stop_reason, &record.rule),
    )?;
    report
        .files
        .insert(report.files.len().saturating_sub(1), LEVELS_PNG.to_string());
    Ok(ScanOutcome {
        record,
        levels: closed.levels,
        stop_reason: closed.stop_reason,
        measured,
        report,
        times,
    })
}

/// The per-level chart's file name in OUTDIR.
pub const LEVELS_PNG: &str = "levels.png";

type Prepared = (ScanRecord, Planned, Calibration, Option<SimModel>);

fn prepare_fresh(
    f: &FreshScan,
    out: &Path,
    options: &RunOptions,
    times: &mut PhaseTimes,
    note: &mut dyn FnMut(&str),
) -> Result<Prepared, ScanError> {
    if out.join(SCAN_FILE).exists() {
        return Err(ScanError::Input(format!(
            "{} already holds a scan; continue it with --resume or choose another -o",
            out.display()
        )));
    }
    if !(16..=2048).contains(&f.render_size) || !(1..=4096).contains(&f.env_spp) {
        return Err(ScanError::Input(
            "--render-size must be in 16..=2048 and --env-spp in 1..=4096".into(),
        ));
    }
    // Every input is read and checked before the (slow) estimate and plan.
    level_of(f.max_grid)?;
    let (instrument_toml, origin) = match &f.instrument {
        Some(p) => (std::fs::read_to_string(p).map_err(io_err(p))?, p.clone()),
        None => (
            crate::instrument::DEFAULT_INSTRUMENT_TOML.to_string(),
            PathBuf::from("examples/gonio.toml"),
        ),
    };
    let instrument = crate::instrument::parse(&instrument_toml, &origin)?;
    gonio_shared::kinematics::Kinematics::new(instrument)
        .map_err(|e| ScanError::Input(format!("{}: {e}", origin.display())))?;
    let (sim_model, scene_text, scene_path) = match &f.sim {
        Some(scene) => {
            let text = std::fs::read_to_string(scene).map_err(io_err(scene))?;
            let abs = std::path::absolute(scene).unwrap_or_else(|_| scene.clone());
            let model = SimModel::from_toml(&text, &abs, instrument, f.seed)?;
            (Some(model), Some(text), Some(abs))
        }
        None => (None, None, None),
    };
    if f.sim.is_none() && f.port.is_none() {
        return Err(ScanError::Input("give --port PATH or --sim SCENE".into()));
    }
    if !(f.speedup.is_finite() && f.speedup >= 1.0) {
        return Err(ScanError::Input("--speedup must be >= 1".into()));
    }
    let given_cal = match &f.calibration {
        Some(p) => Some(Calibration::read(p)?),
        None if f.sim.is_none() => return Err(ScanError::Input(
            "a scan on a port needs --calibration CAL.toml (make one with `gonio calibrate --port PORT -o CAL.toml`)"
                .into(),
        )),
        None => None,
    };
    let t = Instant::now();
    let photo = crate::encoder::photo::estimate_from_photo(&f.image, f.model)?;
    times.estimate = t.elapsed().as_secs_f64();
    note(&format!("estimate: {} ({:.2} s)", photo.spec(), times.estimate));
    let t = Instant::now();
    let max_level = level_of(f.max_grid)?;
    let config = PlanConfig {
        grids: crate::plan::square_grids(max_level),
        ..PlanConfig::default()
    };
    let plan = Planner::new(instrument, photo.estimate.clone())?.plan(&config)?;
    f.rule.last_level(&plan)?;
    let planned = encode_checked(plan, &instrument)?;
    times.plan = t.elapsed().as_secs_f64();
    note(&format!(
        "plan: up to {} directions in {max_level} levels (to {}x{} x {} incoming, {} strategy), {:.1} min instrument time if every level is measured ({:.2} s)",
        planned.wire.len(),
        1 << max_level,
        1 << max_level,
        planned.plan.thetas.len(),
        planned.plan.strategy_label(),
        planned.plan.total_seconds() / 60.0,
        times.plan
    ));
    let cal = match given_cal {
        Some(c) => c,
        None => {
            let t = Instant::now();
            let (text, path) = (
                scene_text.as_deref().unwrap_or(""),
                scene_path.as_deref().unwrap_or(Path::new("")),
            );
            let c = calibrate_sim(
                text,
                path,
                instrument,
                f.seed,
                f.speedup,
                calibration::DEFAULT_WHITE,
                options,
            )?;
            times.calibrate = t.elapsed().as_secs_f64();
            note(&format!(
                "calibrated on the virtual gonio ({}): dark {:?} counts, gain {:?} counts per 1/sr ({:.2} s)",
                c.reference,
                c.dark_counts.iter().map(|v| format!("{v:.1}")).collect::<Vec<_>>(),
                c.gain.iter().map(|v| format!("{v:.1}")).collect::<Vec<_>>(),
                times.calibrate
            ));
            c
        }
    };
    let record = ScanRecord {
        format: SCAN_FORMAT,
        gonio_version: crate::VERSION.to_string(),
        reconstruction: crate::reconstruct::settings(),
        image: f.image.display().to_string(),
        encoder: photo.kind.name().to_string(),
        encoder_outputs: photo.outputs.clone(),
        estimate: photo.spec(),
        rule: f.rule.describe(),
        stop_rule: f.rule.to_record(),
        strategy: config.strategy.to_string(),
        spacing: config.spacing.to_string(),
        incoming: config.k,
        max_level: config.grids.len(),
        level: 1,
        directions: planned.wire.len(),
        journal: JOURNAL_FILE.to_string(),
        plan_hash: format!("{:016x}", crate::journal::fnv64(&planned.bytes)),
        instrument_toml,
        render_size: f.render_size,
        env_spp: f.env_spp,
        source: SourceRecord {
            port: f.port.clone(),
            sim_scene: scene_path.map(|p| p.display().to_string()),
            sim_scene_text: scene_text,
            seed: f.seed,
            speedup: f.speedup,
        },
    };
    Ok((record, planned, cal, sim_model))
}

fn prepare_resume(out: &Path, times: &mut PhaseTimes) -> Result<Prepared, ScanError> {
    let record = ScanRecord::read(out)?;
    record.check_same_build(out)?;
    let instrument = record.instrument(out)?;
    let cal = Calibration::read(&out.join(CALIBRATION_FILE))?;
    let plan_path = out.join(PLAN_FILE);
    let stored = std::fs::read(&plan_path).map_err(io_err(&plan_path))?;
    crate::plan::file::decode_plan(&stored).map_err(|e| ScanError::Input(format!("{}: {e}", plan_path.display())))?;
    let t = Instant::now();
    let plan = Planner::new(instrument, record.estimate()?)?.plan(&record.plan_config()?)?;
    record.stop_rule()?;
    let planned = encode_checked(plan, &instrument)?;
    times.plan = t.elapsed().as_secs_f64();
    if planned.bytes != stored {
        return Err(ScanError::Input(format!(
            "{}: does not match the plan of {SCAN_FILE} (made by another gonio version, or edited); cannot resume",
            plan_path.display()
        )));
    }
    let sim_model = record.sim_model(instrument)?;
    Ok((record, planned, cal, sim_model))
}
