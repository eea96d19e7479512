//! The closed loop in the lab (`gonio-lab closed-loop`): the product's loop
//! (`gonio::plan::closed_loop`) run in simulation on each material, seeded by the encoder's
//! estimate on a capture photo (as `adaptive`), beside the uniform grid at the same levels.
//! Every level is measured (the report needs the oracle); the stop rules are then replayed on the
//! recorded estimates. It reports what the estimator's constants are chosen from (true FLIP over
//! the change between levels, held-out residual over the true error quantile), the predictive
//! interval's calibration, the stop rules' hit rate and instrument time against the oracle, and
//! the equal-directions ratios closed loop / uniform per level on point FLIP, environment FLIP
//! (the noise-free quadrature render, `render::quadrature`) and `brdf_log_err`, and monotonicity.

use super::{
    capture_photo, choose, designed, photo_estimate, reseed, HELDOUT_MATERIALS, REAL_MATERIALS, TRAINING_MATERIALS,
    TRAINING_POOL_MATERIALS,
};
use crate::plan::report::{csv, write};
use gonio::brdf::parse_material;
use gonio::brdf::warp::MixtureWeights;
use gonio::brdf::Material;
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::closed_loop::{self, Assessor, LevelAssessment};
use gonio::plan::predict::{log_err_over, score, Scorer};
use gonio::plan::{square_grids, Estimate, LevelSummary, Plan, PlanConfig, PlanError, Planner, Strategy};
use gonio::reconstruct::Levels;
use gonio::render::Image;
use gonio::render::Scene;
use gonio_shared::instrument::InstrumentConfig;
use std::path::Path;

mod summary;
pub use summary::{quantile, replay, stop_replay, summary, with_current_constants};

/// Material sets of the closed-loop report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LoopPreset {
    /// Where the estimator's constants are chosen.
    Training,
    /// The encoder's held-out MERL materials.
    Heldout,
    /// The three real measurements.
    Real,
    /// 26 further MERL materials the encoder trained on, mostly sharp (`TRAINING_POOL_MATERIALS`): a
    /// second set to choose on, where one material moves a geometric mean less than among 14.
    TrainingPool,
}

impl LoopPreset {
    /// The preset called `name` (training, heldout, real or training-pool), for the lab's examples.
    pub fn named(name: &str) -> Result<Self, String> {
        <Self as clap::ValueEnum>::from_str(name, true)
            .map_err(|_| format!("unknown preset {name:?} (training, heldout, real or training-pool)"))
    }

    /// Its name on the command line.
    pub fn name(self) -> String {
        clap::ValueEnum::to_possible_value(&self).map_or_else(String::new, |v| v.get_name().to_string())
    }

    pub fn materials(self) -> Vec<String> {
        let list: &[&str] = match self {
            LoopPreset::Training => &TRAINING_MATERIALS,
            LoopPreset::Heldout => &HELDOUT_MATERIALS,
            LoopPreset::Real => &REAL_MATERIALS,
            LoopPreset::TrainingPool => &TRAINING_POOL_MATERIALS,
        };
        list.iter().map(|s| s.to_string()).collect()
    }
}

/// One level of one material and strategy.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct LoopRow {
    pub material: String,
    /// `adaptive` (the closed loop) or `uniform`.
    pub strategy: String,
    pub level: usize,
    pub directions: usize,
    /// The uniform grid's cumulative count at this level (equal-directions check).
    pub uniform_directions: usize,
    pub minutes: f64,
    pub change_flip: Option<f64>,
    pub est_flip: Option<f64>,
    pub est_lo: Option<f64>,
    pub est_hi: Option<f64>,
    pub true_flip: Option<f64>,
    pub true_psnr: Option<f64>,
    pub half_width: Option<f64>,
    pub coverage: Option<f64>,
    /// `brdf_log_err` over the fit's direction set (absent in csvs made before it was recorded).
    #[serde(default)]
    pub brdf_log_err: Option<f64>,
    /// Environment-light FLIP, noise-free quadrature render (`ENV_SIZE` px, `examples/sphere-sky.toml`).
    #[serde(default)]
    pub env_flip: Option<f64>,
    /// Trial `choose`: the schedule up to this level (K x N per level) and the sensitivities the
    /// choice after this level read (`choose::Sensitivity`).
    #[serde(default)]
    pub schedule: Option<String>,
    #[serde(default)]
    pub e_in: Option<f64>,
    #[serde(default)]
    pub e_out: Option<f64>,
    /// The prior the level's reconstruction chose (`FittedPrior::kind`; absent in older csvs).
    #[serde(default)]
    pub prior: Option<String>,
    /// PSNR (dB) between this level's and the previous level's capture renders, at level 1 its
    /// split change's (sets `RMSE_RATIO` and `FIRST_RMSE_RATIO`; absent in older csvs).
    #[serde(default)]
    pub change_psnr: Option<f64>,
    /// `liu_log_err` (`liu`: 25,000 random pairs at every elevation), beside `brdf_log_err`, whose
    /// fixed set stops at theta_i 80 deg and weighs the mirror pairs (absent in older csvs).
    #[serde(default)]
    pub liu_log_err: Option<f64>,
}

/// Side (px) of the environment render the report scores (the point render's `ESTIMATE_SIZE`).
pub const ENV_SIZE: usize = closed_loop::ESTIMATE_SIZE;

/// Instrument minutes the real-materials goal allows (issue 25).
pub const GOAL_MINUTES: f64 = 10.0;

/// A lab trial run beside the product's loop and the uniform grid.
#[derive(Clone, Debug, PartialEq)]
pub enum Trial {
    /// Levels 2.. planned from level 1's fit (`reseed`), rows `reseed`.
    Reseed,
    /// The photo's lobe-following plan kept only while level 1's fit confirms a sharp lobe; where
    /// the fit's stronger lobe is rough (`auto` on it plans the uniform grid), levels 2.. follow the
    /// uniform grid, its own level-1 nodes filled from their neighbours (`confirm`), rows `confirm`.
    Confirm,
    /// Per-level incoming elevations and outgoing N x N, [(K, N)] (`PlanConfig::incoming`), for
    /// the product's plan and the uniform grid: rows `adaptive K1xN1,...` and `uniform K1xN1,...`.
    Schedule(Vec<(usize, usize)>),
    /// Each level's elevations or outgoing grid chosen by the measurements (`choose`), one row
    /// set per constant c for the product's plan and the uniform grid: rows `adaptive choose c=C`.
    Choose(Vec<f64>),
    /// The product's plan with other mixture weights (w_s, w_u), one row set per pair: rows
    /// `adaptive mix s=S u=U` (materials the estimate plans on the uniform grid repeat `adaptive`).
    Mixture(Vec<MixtureWeights>),
    /// Level 1 the peer's condition-number design at the uniform grid's level-1 count, levels 2..
    /// the photo plan's (`designed`), rows `designed`.
    Designed,
    /// Other outgoing grids per level, N x M (8 elevations), for the product's plan and the
    /// uniform grid (`grids`): rows `adaptive grids` and `uniform grids`.
    Grids(Vec<(usize, usize)>),
}

impl Trial {
    /// `reseed` or `schedule:8x2,8x4,8x8,15x8` (K x N per level).
    pub fn parse(s: &str) -> Result<Trial, String> {
        if s == "reseed" {
            return Ok(Trial::Reseed);
        }
        if s == "designed" {
            return Ok(Trial::Designed);
        }
        if s == "confirm" {
            return Ok(Trial::Confirm);
        }
        if let Some(list) = s.strip_prefix("grids:") {
            let grids = pairs(list).ok_or_else(|| format!("trial {s:?}: a level is not NxM"))?;
            gonio::plan::check_levels(&grids, &[], PlanConfig::default().k).map_err(|e| e.to_string())?;
            return Ok(Trial::Grids(grids));
        }
        if let Some(list) = s.strip_prefix("mixture:") {
            let ws: Option<Vec<MixtureWeights>> = list
                .split(',')
                .map(|w| {
                    let (s, u) = w.split_once('/')?;
                    MixtureWeights::new(s.trim().parse().ok()?, u.trim().parse().ok()?)
                })
                .collect();
            return ws
                .map(Trial::Mixture)
                .ok_or_else(|| format!("trial {s:?}: expected mixture:S/U,S/U,... (weights in [0, 1], S + U <= 1)"));
        }
        if let Some(list) = s.strip_prefix("choose:") {
            let cs: Option<Vec<f64>> = list
                .split(',')
                .map(|c| c.trim().parse().ok().filter(|c: &f64| *c >= 0.0))
                .collect();
            return cs
                .map(Trial::Choose)
                .ok_or_else(|| format!("trial {s:?}: expected choose:C,C,... (C >= 0 or inf)"));
        }
        let list = s
            .strip_prefix("schedule:")
            .ok_or_else(|| format!("trial {s:?}: expected reseed or schedule:KxN,KxN,..."))?;
        let levels = pairs(list).ok_or_else(|| format!("trial {s:?}: a level is not KxN"))?;
        let config = choose::config(Strategy::Auto, &levels, UNPADDED);
        gonio::plan::check_levels(&config.grids, &config.incoming, config.k).map_err(|e| e.to_string())?;
        Ok(Trial::Schedule(levels))
    }

    /// The rows' strategy name of this trial for the product's plan (`auto`) or the uniform grid.
    fn label(&self, strategy: Strategy) -> String {
        match self {
            Trial::Reseed => "reseed".into(),
            Trial::Confirm => "confirm".into(),
            Trial::Choose(_) => choose_label(strategy, f64::INFINITY),
            Trial::Mixture(_) => "adaptive mix".into(),
            Trial::Designed => "designed".into(),
            Trial::Grids(_) => format!("{} grids", row_name(strategy)),
            Trial::Schedule(levels) => format!("{} {}", row_name(strategy), choose::label(levels)),
        }
    }
}

/// `AxB,AxB,...` as [(A, B)]; None if any item is not two integers joined by `x`.
fn pairs(list: &str) -> Option<Vec<(usize, usize)>> {
    list.split(',')
        .map(|l| {
            let (a, b) = l.split_once('x')?;
            Some((a.trim().parse().ok()?, b.trim().parse().ok()?))
        })
        .collect()
}

/// The rows' name of the product's plan (`auto`: `adaptive`) or the uniform grid.
fn row_name(strategy: Strategy) -> &'static str {
    if strategy == Strategy::Uniform {
        "uniform"
    } else {
        "adaptive"
    }
}

/// The rows' strategy name of trial `choose` with constant `c`.
fn choose_label(strategy: Strategy, c: f64) -> String {
    format!("{} choose c={c}", row_name(strategy))
}

/// The rows' strategy name of trial `mixture` with weights `w`.
fn mixture_label(w: MixtureWeights) -> String {
    format!("adaptive mix s={} u={}", w.specular, w.uniform)
}

/// The `schedule:` trial plans its schedule as given, without `choose`'s padding level (its
/// committed rows were made so; docs/tradeoff/README.md says what that changes).
const UNPADDED: usize = 0;

/// A level's assessment with the report's own scores of its reconstruction.
#[derive(Clone, Debug)]
struct Scored {
    assessment: LevelAssessment,
    brdf_log_err: f64,
    liu_log_err: f64,
    env_flip: f64,
}

/// A trial's rows of one material: label, levels, and the choice that made them (`choose`).
type Run = (String, Vec<Scored>, Option<choose::Choice>);

fn rows_of(material: &str, strategy: &str, levels: &[Scored], uniform: &[usize]) -> Vec<LoopRow> {
    levels
        .iter()
        .map(|s| {
            let a = &s.assessment;
            LoopRow {
                material: material.to_string(),
                strategy: strategy.to_string(),
                level: a.level,
                directions: a.directions,
                uniform_directions: uniform.get(a.level - 1).copied().unwrap_or(0),
                minutes: a.cumulative_seconds / 60.0,
                change_flip: a.change_flip,
                est_flip: a.est_flip.map(|e| e.0),
                est_lo: a.est_flip.map(|e| e.1),
                est_hi: a.est_flip.map(|e| e.2),
                true_flip: a.true_flip,
                true_psnr: a.true_psnr,
                half_width: a.half_width,
                coverage: a.coverage,
                brdf_log_err: Some(s.brdf_log_err),
                env_flip: Some(s.env_flip),
                schedule: None,
                e_in: None,
                e_out: None,
                prior: Some(a.prior.to_string()),
                change_psnr: a.change_psnr,
                liu_log_err: Some(s.liu_log_err),
            }
        })
        .collect()
}

/// The photo's estimate of `spec` and the product's plan from it (`max_level` square levels), as
/// `run_rows` plans its `adaptive` rows: the lab's examples read the same plan.
pub fn photo_plan(
    spec: &str,
    encoder: &Encoder,
    instrument: &InstrumentConfig<f64>,
    max_level: usize,
) -> Result<(Estimate, Plan), PlanError> {
    let (_, photo) = capture_photo(spec)?;
    let (estimate, _) = photo_estimate(&photo, encoder)?;
    let config = PlanConfig {
        strategy: Strategy::Auto,
        grids: square_grids(max_level),
        ..PlanConfig::default()
    };
    let plan = Planner::new(*instrument, estimate.clone())?.plan(&config)?;
    Ok((estimate, plan))
}

/// Run the loop's assessment at every level (as `closed_loop::run` with `StopRule::Depth`) on each
/// material for `adaptive` and `uniform`, scoring each level's reconstruction also by
/// `brdf_log_err` and by environment FLIP under `env_scene` (rendered at `ENV_SIZE`).
pub fn run_rows(
    materials: &[String],
    instrument: &InstrumentConfig<f64>,
    max_level: usize,
    mut env_scene: Scene,
    trials: &[Trial],
    progress: &dyn Fn(&str),
) -> Result<Vec<LoopRow>, PlanError> {
    let encoder = Encoder::shipped(ModelKind::Ggx).map_err(|e| PlanError::Invalid(e.to_string()))?;
    env_scene.camera.width = ENV_SIZE;
    env_scene.camera.height = ENV_SIZE;
    let mut scorer = Scorer::new(ENV_SIZE)?.with_env(env_scene);
    let no_env = || PlanError::Invalid("no environment scene".into());
    let mut rows = Vec::new();
    // The peer's design (trial `designed`), made on the first material that needs it.
    let mut design = None;
    for spec in materials {
        let truth = parse_material(spec)?;
        let truth_env = scorer.render_env(parse_material(spec)?, spec).ok_or_else(no_env)?;
        let (_, photo) = capture_photo(spec)?;
        let (estimate, _) = photo_estimate(&photo, &encoder)?;
        let mut per: Vec<Vec<Scored>> = Vec::new();
        let mut photo_plan = None;
        for strategy in [Strategy::Auto, Strategy::Uniform] {
            let config = PlanConfig {
                strategy,
                grids: square_grids(max_level),
                ..PlanConfig::default()
            };
            let plan = Planner::new(*instrument, estimate.clone())?.plan(&config)?;
            let values = plan.measure(truth.as_ref());
            per.push(assess_levels(
                &plan,
                &plan.levels,
                &values,
                spec,
                &mut scorer,
                &truth_env,
            )?);
            if strategy == Strategy::Auto {
                photo_plan = Some((plan, config));
            }
        }
        let uniform: Vec<usize> = per[1].iter().map(|s| s.assessment.directions).collect();
        rows.extend(rows_of(spec, "adaptive", &per[0], &uniform));
        rows.extend(rows_of(spec, "uniform", &per[1], &uniform));
        let line = |levels: &[Scored]| {
            levels
                .iter()
                .map(|s| format!("{:.4}/{:.4}", s.assessment.true_flip.unwrap_or(f64::NAN), s.env_flip))
                .collect::<Vec<_>>()
                .join(" ")
        };
        let mut lines = vec![format!("adaptive {}, uniform {}", line(&per[0]), line(&per[1]))];
        let photo_plan = photo_plan.ok_or_else(|| PlanError::Invalid("no photo plan".into()))?;
        for trial in trials {
            let mut ctx = MaterialRun {
                instrument,
                estimate: &estimate,
                truth: truth.as_ref(),
                spec,
                truth_env: &truth_env,
                photo_plan: (&photo_plan.0, &photo_plan.1),
                photo_levels: &per[0],
                uniform: &uniform,
                max_level,
                scorer: &mut scorer,
                design: &mut design,
            };
            let runs = trial_runs(trial, &mut ctx)?;
            for (label, levels, choice) in runs {
                lines.push(format!("{label} {}", line(&levels)));
                let mut new = rows_of(spec, &label, &levels, &uniform);
                if let Some(choice) = choice {
                    lines.push(format!("({})", choose::label(&choice.schedule)));
                    for (l, r) in new.iter_mut().enumerate() {
                        r.schedule = Some(choose::label(&choice.schedule[..=l]));
                        let s = choice.sensitivities.get(l).copied().flatten();
                        (r.e_in, r.e_out) = (s.map(|s| s.e_in), s.map(|s| s.e_out));
                    }
                }
                rows.extend(new);
            }
        }
        progress(&format!("{spec}: point/env FLIP {}", lines.join("; ")));
    }
    Ok(rows)
}

/// One material's run, as every trial reads it.
struct MaterialRun<'a> {
    instrument: &'a InstrumentConfig<f64>,
    estimate: &'a Estimate,
    truth: &'a dyn Material,
    spec: &'a str,
    truth_env: &'a Image,
    /// The product's plan (`auto`) and its config, and its assessed levels.
    photo_plan: (&'a Plan, &'a PlanConfig),
    photo_levels: &'a [Scored],
    /// The uniform grid's cumulative directions per level.
    uniform: &'a [usize],
    max_level: usize,
    scorer: &'a mut Scorer,
    /// The peer's designed level 1 and its instrument seconds, once made (trial `designed`).
    design: &'a mut Option<(Vec<(glam::DVec3, glam::DVec3)>, f64)>,
}

impl MaterialRun<'_> {
    /// The levels of `plan` measured on the truth and assessed.
    fn assess_plan(&mut self, plan: &Plan) -> Result<Vec<Scored>, PlanError> {
        let values = plan.measure(self.truth);
        assess_levels(plan, &plan.levels, &values, self.spec, self.scorer, self.truth_env)
    }

    /// The product's plan and the uniform grid, each planned with `config(strategy)`.
    fn both_strategies(
        &mut self,
        trial: &Trial,
        config: impl Fn(Strategy) -> PlanConfig,
    ) -> Result<Vec<Run>, PlanError> {
        let mut out = Vec::new();
        for strategy in [Strategy::Auto, Strategy::Uniform] {
            let plan = Planner::new(*self.instrument, self.estimate.clone())?.plan(&config(strategy))?;
            out.push((trial.label(strategy), self.assess_plan(&plan)?, None));
        }
        Ok(out)
    }
}

/// A trial's runs on one material.
fn trial_runs(trial: &Trial, m: &mut MaterialRun) -> Result<Vec<Run>, PlanError> {
    Ok(match trial {
        Trial::Reseed | Trial::Confirm => {
            let (first, config) = m.photo_plan;
            let level1 = gonio::reconstruct::reconstruct(first, 1, &first.measure(m.truth))?;
            let (next, skipped) = match trial {
                Trial::Reseed => (
                    reseed::replan(m.instrument, config, level1.prior())?,
                    reseed::SkippedNodes::NearestFirst,
                ),
                _ => (
                    reseed::unconfirmed(first, m.instrument, m.estimate, config, level1.prior())?,
                    reseed::SkippedNodes::SameOrUnmeasured,
                ),
            };
            let levels = match next {
                Some(next) => replanned_levels((first, &next, skipped), m.uniform, m.spec, m.scorer, m.truth_env)?,
                None => None,
            };
            vec![(
                trial.label(Strategy::Auto),
                levels.unwrap_or_else(|| m.photo_levels.to_vec()),
                None,
            )]
        }
        Trial::Schedule(schedule) => m.both_strategies(trial, |s| choose::config(s, schedule, UNPADDED))?,
        Trial::Grids(grids) => m.both_strategies(trial, |strategy| PlanConfig {
            strategy,
            grids: grids.clone(),
            ..PlanConfig::default()
        })?,
        Trial::Designed => {
            let (pairs, seconds) = match m.design.take() {
                Some(d) => d,
                None => super::peer::design(m.instrument, m.uniform.first().copied().unwrap_or(0))?,
            };
            let designed = designed::Designed::new(m.photo_plan.0, &pairs, seconds)
                .ok_or_else(|| PlanError::Invalid("a designed direction is below the horizon".into()))?;
            let values: Vec<_> = designed.pairs().iter().map(|&(wi, wo)| m.truth.eval(wi, wo)).collect();
            let summaries = designed.levels();
            let levels = assess_levels(&designed, &summaries, &values, m.spec, m.scorer, m.truth_env)?;
            *m.design = Some((pairs, seconds));
            vec![(trial.label(Strategy::Auto), levels, None)]
        }
        Trial::Mixture(weights) => {
            let mut out = Vec::new();
            for &w in weights {
                let plan = Planner::new(*m.instrument, m.estimate.clone())?
                    .with_mixture_weights(w)
                    .plan(m.photo_plan.1)?;
                // The weights change nothing where the estimate plans the uniform grid.
                let levels = if plan.warp == Strategy::Mixture {
                    m.assess_plan(&plan)?
                } else {
                    m.photo_levels.to_vec()
                };
                out.push((mixture_label(w), levels, None));
            }
            out
        }
        Trial::Choose(cs) => {
            let planner = Planner::new(*m.instrument, m.estimate.clone())?;
            let truth = (m.truth, m.spec, m.truth_env);
            choose_runs(&planner, truth, cs, m.max_level, m.uniform, m.scorer)?
        }
    })
}

/// Trial `choose`: per strategy and constant c, the chosen schedule's levels assessed (a schedule
/// chosen by several c is assessed once). `truth`: material, spec, environment render.
fn choose_runs(
    planner: &Planner,
    truth: (&dyn gonio::brdf::Material, &str, &gonio::render::Image),
    cs: &[f64],
    max_level: usize,
    uniform: &[usize],
    scorer: &mut Scorer,
) -> Result<Vec<Run>, PlanError> {
    let (material, spec, truth_env) = truth;
    let mut out = Vec::new();
    for strategy in [Strategy::Auto, Strategy::Uniform] {
        let mut explorer = choose::Explorer::new(planner, material, strategy, 1 << max_level)?;
        let mut done: Vec<(choose::Schedule, Vec<Scored>)> = Vec::new();
        for &c in cs {
            let choice = explorer.choose(c, max_level, uniform)?;
            if !done.iter().any(|d| d.0 == choice.schedule) {
                let (plan, values) = explorer.plan(&choice.schedule)?;
                let summaries = &plan.levels[..choice.schedule.len()];
                let levels = assess_levels(plan, summaries, values, spec, scorer, truth_env)?;
                done.push((choice.schedule.clone(), levels));
            }
            let levels = done.iter().find(|d| d.0 == choice.schedule).map(|d| d.1.clone());
            out.push((choose_label(strategy, c), levels.unwrap_or_default(), Some(choice)));
        }
    }
    Ok(out)
}

/// Level 1 of `first`, then levels 2.. of `next` (`reseed`, `confirm`): None (the photo's plan
/// goes on) unless every level's count is within the uniform grid's.
fn replanned_levels(
    (first, next, skipped): (&Plan, &Plan, reseed::SkippedNodes),
    uniform: &[usize],
    spec: &str,
    scorer: &mut Scorer,
    truth_env: &gonio::render::Image,
) -> Result<Option<Vec<Scored>>, PlanError> {
    let truth = parse_material(spec)?;
    let Some(r) = reseed::Reseeded::new(first, next, skipped) else {
        return Ok(None);
    };
    let within = r
        .levels()
        .iter()
        .zip(uniform)
        .all(|(l, u)| l.cumulative_directions <= *u);
    if !within {
        return Ok(None);
    }
    let values: Vec<_> = r.pairs().iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
    assess_levels(&r, &r.levels(), &values, spec, scorer, truth_env).map(Some)
}

/// Assess every level of `levels` (as `closed_loop::run` with `StopRule::Depth`), scoring each
/// reconstruction also by `brdf_log_err` and by environment FLIP against `truth_env`.
fn assess_levels(
    levels: &dyn Levels,
    summaries: &[LevelSummary],
    values: &[glam::DVec3],
    spec: &str,
    scorer: &mut Scorer,
    truth_env: &gonio::render::Image,
) -> Result<Vec<Scored>, PlanError> {
    let truth = parse_material(spec)?;
    let mut assessor = Assessor::new(Some(spec))?;
    let liu = super::liu::liu_pairs();
    let mut out = Vec::new();
    for summary in summaries {
        let (assessment, rec) = assessor.assess(levels, summary, &values[..summary.cumulative_directions])?;
        let brdf_log_err = scorer.log_err(truth.as_ref(), &rec);
        let liu_log_err = log_err_over(&liu, truth.as_ref(), &rec);
        let env = scorer
            .render_env(Box::new(rec), spec)
            .ok_or_else(|| PlanError::Invalid("no environment scene".into()))?;
        out.push(Scored {
            assessment,
            brdf_log_err,
            liu_log_err,
            env_flip: score(truth_env, &env)?.flip,
        });
    }
    Ok(out)
}

/// Read the rows of a `closed-loop.csv`.
pub fn read_rows(path: &Path) -> Result<Vec<LoopRow>, PlanError> {
    let err = |e: &dyn std::fmt::Display| PlanError::Invalid(format!("{}: {e}", path.display()));
    let mut reader = ::csv::Reader::from_path(path).map_err(|e| err(&e))?;
    reader.deserialize().map(|r| r.map_err(|e| err(&e))).collect()
}

/// Where the report's rows come from.
pub enum RowSource<'a> {
    /// Simulate every level (`run_rows`).
    Simulate {
        materials: &'a [String],
        instrument: &'a InstrumentConfig<f64>,
        max_level: usize,
        env_scene: Box<Scene>,
        trials: &'a [Trial],
    },
    /// An earlier run's `closed-loop.csv`.
    Csv(&'a Path),
}

/// Run the report into `dir` (`closed-loop.csv`, `closed-loop.md`); returns the markdown.
/// `options`: the command line's options that shape the rows, as given (the regenerate line repeats them).
pub fn run(
    preset: LoopPreset,
    source: RowSource<'_>,
    dir: &Path,
    options: &str,
    progress: &dyn Fn(&str),
) -> Result<String, PlanError> {
    let rows = match source {
        // An earlier run's rows, their estimates re-derived so the csv agrees with the summary.
        RowSource::Csv(path) => with_current_constants(read_rows(path)?),
        RowSource::Simulate {
            materials,
            instrument,
            max_level,
            env_scene,
            trials,
        } => run_rows(materials, instrument, max_level, *env_scene, trials, progress)?,
    };
    std::fs::create_dir_all(dir).map_err(|e| PlanError::Invalid(format!("{}: {e}", dir.display())))?;
    write(dir, "closed-loop.csv", &csv(&rows)?)?;
    let name = preset.name();
    let md = summary(
        &rows,
        &name,
        &format!("gonio-lab closed-loop --preset {name}{options} -o {}", dir.display()),
    );
    write(dir, "closed-loop.md", md.as_bytes())?;
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio::plan::closed_loop::StopRule;

    fn row(material: &str, strategy: &str, level: usize, error: f64) -> LoopRow {
        LoopRow {
            material: material.into(),
            strategy: strategy.into(),
            level,
            directions: 10 * level,
            uniform_directions: 10 * level,
            minutes: 6.0 * level as f64,
            change_flip: None,
            est_flip: None,
            est_lo: None,
            est_hi: None,
            true_flip: Some(error),
            true_psnr: None,
            half_width: None,
            coverage: None,
            brdf_log_err: Some(2.0 * error),
            env_flip: Some(4.0 * error),
            schedule: None,
            e_in: None,
            e_out: None,
            prior: Some(if level == 1 { "two-lobes" } else { "pca" }.into()),
            change_psnr: None,
            liu_log_err: Some(3.0 * error),
        }
    }

    /// The replay's ratio is the chosen quantile of the training rows' true / change FLIP, and a
    /// larger ratio stops later (here one level later: 1.5x the oracle's time at 0.02).
    #[test]
    fn stop_replay_chooses_its_ratio_on_training_and_replays_other_runs() {
        let rows: Vec<LoopRow> = [(0.03, None), (0.015, Some(0.03)), (0.008, Some(0.01))]
            .iter()
            .enumerate()
            .map(|(l, &(t, c))| LoopRow {
                change_flip: c,
                ..row("a", "adaptive", l + 1, t)
            })
            .collect();
        let runs = [("run".to_string(), rows.clone())];
        let median = stop_replay(&rows, "adaptive", (0.5, 0.9), &runs).unwrap();
        assert!(median.contains("ratio (0.5 quantile) 0.500"), "{median}");
        assert!(median.contains("| run | 0.02 | 1 of 1 | 1.00, 1.00 | 0 |"), "{median}");
        assert!(median.contains("| run | 0.01 | 1 of 1 | 1.00, 1.00 | 0 |"), "{median}");
        let cautious = stop_replay(&rows, "adaptive", (0.9, 0.9), &runs).unwrap();
        assert!(cautious.contains("ratio (0.9 quantile) 0.800"), "{cautious}");
        assert!(
            cautious.contains("| run | 0.02 | 1 of 1 | 1.50, 1.50 | 0 |"),
            "{cautious}"
        );
        assert!(stop_replay(&rows, "uniform", (0.5, 0.9), &runs).is_err());
        // Level 1 with a split change has its own ratio (the median of 0.75 and 0.9 by nearest
        // rank: 0.75): b stops at level 1 (estimate 0.015), its oracle, where without level 1's
        // estimate it would stop at level 2 (time / oracle 2); a goes on (estimate 0.03).
        let first = |m: &str, c: f64, t: f64| LoopRow {
            change_flip: Some(c),
            ..row(m, "adaptive", 1, t)
        };
        let mut two = rows.clone();
        two[0] = first("a", 0.04, 0.03);
        two.push(first("b", 0.02, 0.018));
        two.extend(rows[1..].iter().map(|r| LoopRow {
            material: "b".into(),
            ..r.clone()
        }));
        let runs = [("run".to_string(), two.clone())];
        let md = stop_replay(&two, "adaptive", (0.5, 0.5), &runs).unwrap();
        assert!(md.contains("ratio (0.5 quantile) 0.750"), "{md}");
        assert!(md.contains("| run | 0.02 | 2 of 2 | 1.00, 1.00 | 0 |"), "{md}");
    }

    /// The examples' preset names are the command line's; others are refused in one line.
    #[test]
    fn presets_are_named_as_on_the_command_line() {
        assert_eq!(LoopPreset::named("heldout"), Ok(LoopPreset::Heldout));
        assert_eq!(LoopPreset::named("real"), Ok(LoopPreset::Real));
        assert_eq!(LoopPreset::named("training-pool"), Ok(LoopPreset::TrainingPool));
        assert_eq!(LoopPreset::TrainingPool.name(), "training-pool");
        let err = LoopPreset::named("merl").unwrap_err();
        assert!(err.contains("\"merl\"") && !err.contains('\n'), "{err}");
    }

    /// A schedule trial parses K x N per level and is refused when its elevations do not nest.
    #[test]
    fn trials_parse_and_refuse_schedules_that_do_not_nest() {
        assert_eq!(Trial::parse("reseed"), Ok(Trial::Reseed));
        assert_eq!(Trial::parse("designed"), Ok(Trial::Designed));
        assert_eq!(Trial::parse("confirm"), Ok(Trial::Confirm));
        assert_eq!(Trial::Confirm.label(Strategy::Auto), "confirm");
        assert_eq!(
            Trial::parse("grids:2x2,4x2,4x4"),
            Ok(Trial::Grids(vec![(2, 2), (4, 2), (4, 4)]))
        );
        assert_eq!(Trial::Grids(vec![(2, 2)]).label(Strategy::Uniform), "uniform grids");
        assert_eq!(
            Trial::parse("schedule:8x2,8x4,15x4"),
            Ok(Trial::Schedule(vec![(8, 2), (8, 4), (15, 4)]))
        );
        assert_eq!(
            Trial::Schedule(vec![(8, 2), (15, 2)]).label(Strategy::Uniform),
            "uniform 8x2,15x2"
        );
        assert_eq!(
            Trial::parse("choose:0.5,1,inf"),
            Ok(Trial::Choose(vec![0.5, 1.0, f64::INFINITY]))
        );
        assert_eq!(choose_label(Strategy::Auto, 2.0), "adaptive choose c=2");
        let w = MixtureWeights::new(0.2, 0.7).unwrap();
        assert_eq!(Trial::parse("mixture:0.2/0.7"), Ok(Trial::Mixture(vec![w])));
        assert_eq!(mixture_label(w), "adaptive mix s=0.2 u=0.7");
        for bad in [
            "mixture:",
            "mixture:0.5",
            "grids:2x2,3x2",
            "grids:2x2,4x",
            "mixture:0.6/0.6",
            "mixture:-0.1/0.5",
            "choose:",
            "choose:-1",
            "schedule:8x2,16x4",
            "schedule:8x2,8x2",
            "schedule:8x",
            "grid:8x2",
            "schedule:",
        ] {
            assert!(Trial::parse(bad).is_err(), "{bad}");
        }
    }

    /// The estimators' ratios are split by level (level 1's split change apart), and the PSNR
    /// estimate's RMSE ratio is 10^((change - true PSNR) / 20) over the levels that have both.
    #[test]
    fn summary_reports_each_estimators_ratios() {
        let rows = vec![
            LoopRow {
                change_flip: Some(0.01),
                true_psnr: Some(30.0),
                change_psnr: Some(50.0),
                ..row("a", "adaptive", 1, 0.02)
            },
            LoopRow {
                change_flip: Some(0.04),
                true_psnr: Some(34.0),
                change_psnr: Some(40.0),
                ..row("a", "adaptive", 2, 0.01)
            },
        ];
        let md = summary(&rows, "test", "cmd");
        assert!(
            md.contains("over 1 levels 2..: median 0.250, 5% 0.250, 95% 0.250"),
            "{md}"
        );
        assert!(
            md.contains("true / split change over 1 levels: median 2.000, 5% 2.000, 95% 2.000"),
            "{md}"
        );
        assert!(md.contains("change RMSE over 1 levels 2..: median 1.995,"), "{md}");
        assert!(md.contains("split change RMSE over 1 levels: median 10.000,"), "{md}");
    }

    /// A PSNR target stops at the first level whose estimate (from the change PSNR) meets it and is
    /// judged on the true PSNR; a level without a change PSNR (level 1 of older csvs) never stops.
    #[test]
    fn a_psnr_target_is_replayed_on_the_change_psnr() {
        let psnr = |level, change: Option<f64>, truth| LoopRow {
            change_psnr: change,
            true_psnr: Some(truth),
            ..row("a", "adaptive", level, 0.01)
        };
        let rows = [
            psnr(1, None, 46.0),
            psnr(2, Some(80.0), 48.0),
            psnr(3, Some(90.0), 52.0),
        ];
        let refs: Vec<&LoopRow> = rows.iter().collect();
        // 45 dB: level 1 truly meets it but has no estimate; level 2's estimate stops there.
        assert_eq!(
            summary::replay(&refs, StopRule::TargetPsnr(45.0)),
            Some((true, 12.0, Some(6.0)))
        );
        // 50 dB: level 2's estimate meets it, its truth does not; the oracle is level 3.
        assert_eq!(
            summary::replay(&refs, StopRule::TargetPsnr(50.0)),
            Some((false, 12.0, Some(18.0)))
        );
        let md = summary(&rows, "test", "cmd");
        assert!(md.contains("| 45 | 1 of 1 | 2.00, 2.00 | 0 |"), "{md}");
        assert!(md.contains("| 50 | 0 of 1 | 0.67, 0.67 | 0 |"), "{md}");
    }

    /// A trial's rows get their own equal-directions table and monotonicity rows.
    #[test]
    fn trial_rows_are_summarised_beside_the_loop() {
        let mut rows = vec![
            row("a", "adaptive", 1, 0.02),
            row("a", "uniform", 1, 0.01),
            row("a", "adaptive 8x2", 1, 0.005),
        ];
        rows.push(row("a", "adaptive 8x2", 2, 0.01));
        let md = summary(&rows, "test", "cmd");
        assert!(md.contains("## Equal directions: adaptive 8x2 (lab trial"), "{md}");
        assert!(md.contains("| 1 | 0.500 | 0.500 |"), "{md}");
        assert!(
            md.contains("| adaptive 8x2 | point FLIP | 2.000 | a level 2 | 1 of 1 |"),
            "{md}"
        );
    }

    /// The equal-directions ratios are geometric means over materials with the worst beside them,
    /// on all three metrics; a level whose error grows is caught; the 10-minute table takes level 1.
    #[test]
    fn summary_reports_ratios_monotonicity_and_the_goal_minutes() {
        let rows = vec![
            row("a", "adaptive", 1, 0.02),
            row("a", "adaptive", 2, 0.03),
            row("a", "uniform", 1, 0.01),
            row("a", "uniform", 2, 0.01),
            row("b", "adaptive", 1, 0.01),
            row("b", "adaptive", 2, 0.005),
            row("b", "uniform", 1, 0.02),
            row("b", "uniform", 2, 0.01),
        ];
        let md = summary(&rows, "test", "cmd");
        // Level 1: ratios 2 and 0.5, geomean 1, worst 2 (the same on every metric).
        assert!(
            md.contains("| 1 | 1.000 | 2.000 | 1.000 | 2.000 | 1.000 | 2.000 | 1.000 | 2.000 | true |"),
            "{md}"
        );
        // The test rows pick the basis at level 2 only.
        assert!(
            md.contains("adaptive: pca at 2 of 4 levels (levels 1.. : 0 of 2, 2 of 2)"),
            "{md}"
        );
        // Absolute: adaptive level 1 errors 0.02 and 0.01 (geomean 0.01414), directions 10 each.
        assert!(
            md.contains("| adaptive | 1 | 10 | 0.01414 | 0.05657 | 0.02828 | 0.04243 |"),
            "{md}"
        );
        // Level 2: 3 and 0.5.
        assert!(
            md.contains("| 2 | 1.225 | 3.000 | 1.225 | 3.000 | 1.225 | 3.000 | 1.225 | 3.000 | true |"),
            "{md}"
        );
        assert!(
            md.contains("| adaptive | point FLIP | 1.500 | a level 2 | 1 of 2 |"),
            "{md}"
        );
        assert!(
            md.contains("| uniform | env FLIP | 1.000 | a level 2 | 0 of 2 |"),
            "{md}"
        );
        assert!(
            md.contains("| a | adaptive | 1 | 10 | 6.0 | 0.0200 | 0.0800 | 0.0400 |"),
            "{md}"
        );
        assert!(
            md.contains("| adaptive | liu_log_err | 1.500 | a level 2 | 1 of 2 |"),
            "{md}"
        );
    }

    /// Rows from a csv made before `liu_log_err` was recorded: its cells read `-` and it has no
    /// monotonicity row; the other metrics are as before.
    #[test]
    fn rows_without_liu_log_err_leave_its_cells_empty() {
        let rows: Vec<LoopRow> = [("adaptive", 0.02), ("uniform", 0.01)]
            .iter()
            .flat_map(|&(strategy, e)| {
                (1..=2).map(move |level| LoopRow {
                    liu_log_err: None,
                    ..row("a", strategy, level, e)
                })
            })
            .collect();
        let md = summary(&rows, "test", "cmd");
        assert!(
            md.contains("| 1 | 2.000 | 2.000 | 2.000 | 2.000 | 2.000 | 2.000 | - | - | true |"),
            "{md}"
        );
        assert!(
            md.contains("| adaptive | 1 | 10 | 0.02000 | 0.08000 | 0.04000 | - |"),
            "{md}"
        );
        assert!(!md.contains("| adaptive | liu_log_err |"), "{md}");
        // An older csv (no liu_log_err column) reads back with the field empty.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.csv");
        let header = "material,strategy,level,directions,uniform_directions,minutes,true_flip\n";
        std::fs::write(&path, format!("{header}a,adaptive,1,10,10,0.5,0.02\n")).unwrap();
        let read = read_rows(&path).unwrap();
        assert_eq!(read.len(), 1);
        assert_eq!(read[0].liu_log_err, None);
        assert_eq!(read[0].true_flip, Some(0.02));
    }
}
