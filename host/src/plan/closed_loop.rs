//! The closed loop (docs/scan.md, "Closed loop"): measure a plan one level at a time, reconstruct
//! from every direction measured so far, estimate the reconstruction's error without ground truth,
//! and stop on the user's rule.
//!
//! The error estimate needs no truth. After level L it renders the reconstructions of levels L-1
//! and L in the capture scene and takes their FLIP ("the change"); the error of level L is the
//! change times a ratio, with a 90% interval from the ratio's 5% and 95% quantiles. The ratios
//! were measured on the lab's training materials (`gonio-lab closed-loop --preset training`,
//! docs/tradeoff/closed-loop/) and are confirmed there on held-out and real materials. Level 1
//! has no previous level: its change is between the reconstructions from each half of its
//! measurements and from all of them, with its own (cautious) ratio.
//!
//! The per-direction predictive interval comes from held-out residuals: level L's new directions
//! were not seen by level L-1's reconstruction, so their residuals against it (in the
//! reconstruction's log space) say how far level L-1 is off; level L's half-width is that 90%
//! quantile times `INTERVAL_SHRINK` (its ratio measured on the training materials).

use super::predict::{score, Scorer};
use super::{LevelSummary, Plan, PlanError};
use crate::brdf::fit::fit_directions;
use crate::brdf::Material;
use crate::reconstruct::{reconstruct, LevelNodes, Levels, ReconstructError, Reconstruction, SingleLevel, RATIO_FLOOR};
use crate::render::Image;
use glam::DVec3;

/// Render side of the closed loop's change and truth renders (capture scene).
pub const ESTIMATE_SIZE: usize = 64;
/// True point FLIP over the change FLIP between consecutive levels on the 14 training materials
/// (42 levels): median, 5% and 95% quantiles (`gonio-lab closed-loop --preset training`,
/// docs/tradeoff/closed-loop/training/closed-loop.md; re-derived when the product's reconstruction changes).
pub const FLIP_RATIO: f64 = 0.691;
pub const FLIP_RATIO_LO: f64 = 0.447;
pub const FLIP_RATIO_HI: f64 = 1.094;
/// Level 1 has no previous level; its change is the mean FLIP between the reconstructions from
/// each half of its measurements (every other one, in measurement order) and from all of them.
/// True point FLIP over that change on the 14 training materials (the same report, its level-1
/// rows): the estimate takes the 90% quantile, not the median, since this ratio spreads wider than
/// the levels' (the smallest quantile that loses no training scan's stop: docs/tradeoff/README.md,
/// "A level-1 estimate from its two halves"); the interval, the 5% and 95% quantiles.
pub const FIRST_FLIP_RATIO: f64 = 1.587;
pub const FIRST_FLIP_RATIO_LO: f64 = 0.379;
pub const FIRST_FLIP_RATIO_HI: f64 = 2.801;
/// True point-render RMSE over the change RMSE between consecutive levels on the 14 training
/// materials (42 levels), median (the same report).
pub const RMSE_RATIO: f64 = 0.748;
/// Level 1's: true RMSE over the split change's RMSE (each half's squared error averaged), the 90%
/// quantile over the training level-1 rows, as `FIRST_FLIP_RATIO` (the same report).
pub const FIRST_RMSE_RATIO: f64 = 1.736;
/// Level L's 90% log-space half-width over level L-1's held-out residual quantile: with 0.6 the
/// training materials' per-direction intervals hold 92.0% of true values (levels 2-4, the same report).
pub const INTERVAL_SHRINK: f64 = 0.6;
/// The documented default target when the user gives no rule: estimated point FLIP <= 0.01.
pub const DEFAULT_TARGET_FLIP: f64 = 0.01;

/// Estimated point FLIP with its 90% interval from a change FLIP (`split`: level 1's split change).
pub fn estimated_flip(split: bool, change_flip: f64) -> (f64, f64, f64) {
    let (m, lo, hi) = if split {
        (FIRST_FLIP_RATIO, FIRST_FLIP_RATIO_LO, FIRST_FLIP_RATIO_HI)
    } else {
        (FLIP_RATIO, FLIP_RATIO_LO, FLIP_RATIO_HI)
    };
    (change_flip * m, change_flip * lo, change_flip * hi)
}

/// Estimated point PSNR (dB) from a change PSNR (`split`: level 1's split change): a true RMSE
/// the ratio times the change's.
pub fn estimated_psnr(split: bool, change_psnr: f64) -> f64 {
    let ratio = if split { FIRST_RMSE_RATIO } else { RMSE_RATIO };
    change_psnr - 20.0 * ratio.log10()
}

/// When the loop stops (the deepest level of the plan always stops it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StopRule {
    /// Every level of the plan (`--grid N` alone).
    Depth,
    /// The first level whose estimated point FLIP is at most this.
    TargetFlip(f64),
    /// The first level whose estimated point PSNR (dB) is at least this.
    TargetPsnr(f64),
    /// The deepest level whose cumulative instrument time fits this many seconds.
    TimeBudget(f64),
}

impl StopRule {
    /// The form `scan.toml` stores (`parse` reads it back).
    pub fn to_record(&self) -> String {
        match self {
            StopRule::Depth => "depth".into(),
            StopRule::TargetFlip(f) => format!("flip<={f:?}"),
            StopRule::TargetPsnr(db) => format!("psnr>={db:?}"),
            StopRule::TimeBudget(s) => format!("time<={s:?}"),
        }
    }

    pub fn parse(s: &str) -> Option<StopRule> {
        let num = |p: &str| s.strip_prefix(p)?.parse::<f64>().ok().filter(|v| v.is_finite());
        match s {
            "depth" => Some(StopRule::Depth),
            _ => num("flip<=")
                .map(StopRule::TargetFlip)
                .or_else(|| num("psnr>=").map(StopRule::TargetPsnr))
                .or_else(|| num("time<=").map(StopRule::TimeBudget)),
        }
    }

    /// In words, for the console and the report.
    pub fn describe(&self) -> String {
        match self {
            StopRule::Depth => "every level".into(),
            StopRule::TargetFlip(f) => format!("estimated point FLIP <= {f}"),
            StopRule::TargetPsnr(db) => format!("estimated point PSNR >= {db} dB"),
            StopRule::TimeBudget(s) => format!("time budget {:.1} min", s / 60.0),
        }
    }

    /// The deepest level `plan` may measure under this rule; an error if even level 1 is over budget.
    pub fn last_level(&self, plan: &Plan) -> Result<usize, PlanError> {
        let deepest = plan.levels.len();
        match *self {
            StopRule::TimeBudget(s) => plan.level_within_budget(s).ok_or_else(|| {
                PlanError::Invalid(format!(
                    "--time-budget {s:.0} s: even the first level needs {:.0} s",
                    plan.levels.first().map_or(0.0, |l| l.cumulative_seconds)
                ))
            }),
            _ => Ok(deepest),
        }
    }
}

/// What the loop knows after one level.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LevelAssessment {
    pub level: usize,
    pub n: usize,
    pub directions: usize,
    pub cumulative_seconds: f64,
    /// FLIP / PSNR between this level's and the previous level's capture renders; at level 1 its
    /// split change (`FIRST_FLIP_RATIO`, `FIRST_RMSE_RATIO`).
    pub change_flip: Option<f64>,
    pub change_psnr: Option<f64>,
    /// Estimated point FLIP with its 90% interval, and estimated point PSNR.
    pub est_flip: Option<(f64, f64, f64)>,
    pub est_psnr: Option<f64>,
    /// 90% half-width of the per-direction predictive interval, in ln(f + RATIO_FLOOR) (None at level 1).
    pub half_width: Option<f64>,
    /// In simulation: the true point FLIP and PSNR at `ESTIMATE_SIZE`, and the share of the
    /// truth's values (fit directions x channels) inside the predictive interval.
    pub true_flip: Option<f64>,
    pub true_psnr: Option<f64>,
    pub coverage: Option<f64>,
    /// The model the level's reconstruction interpolates on (`FittedPrior::kind`: two-lobes or pca).
    pub prior: &'static str,
}

/// The loop's result.
pub struct ClosedLoop {
    pub levels: Vec<LevelAssessment>,
    /// The level the loop stopped at, and its reconstruction.
    pub stop_level: usize,
    pub reconstruction: Reconstruction,
    /// One line: why it stopped.
    pub stop_reason: String,
}

/// The log space the reconstruction interpolates in.
fn log_space(v: DVec3) -> DVec3 {
    v.max(DVec3::ZERO).map(|x| (x + RATIO_FLOOR).ln())
}

/// 90% quantile of `v` (0 for none); NaNs sort last and are never chosen before finite values.
fn quantile90(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let i = ((v.len() as f64 * 0.9).ceil() as usize).clamp(1, v.len()) - 1;
    v[i]
}

/// Assesses levels one after another (keeps the previous level's render and reconstruction).
pub struct Assessor {
    scorer: Scorer,
    truth: Option<(Box<dyn Material>, Image)>,
    previous: Option<(Reconstruction, Image, f64)>,
    pairs: Vec<(DVec3, DVec3)>,
}

impl Assessor {
    /// `truth`: the ground truth's material spec, in simulation.
    pub fn new(truth: Option<&str>) -> Result<Self, PlanError> {
        let mut scorer = Scorer::new(ESTIMATE_SIZE)?;
        let truth = match truth {
            Some(spec) => {
                let image = scorer.render(crate::brdf::parse_material(spec)?);
                Some((crate::brdf::parse_material(spec)?, image))
            }
            None => None,
        };
        Ok(Self {
            scorer,
            truth,
            previous: None,
            pairs: fit_directions(),
        })
    }

    /// Reconstruct `level` from `values` (indexed like the measurements of `levels`: a plan, or
    /// the lab's levels planned from measurements) and assess it.
    pub fn assess(
        &mut self,
        levels: &dyn Levels,
        level: &LevelSummary,
        values: &[DVec3],
    ) -> Result<(LevelAssessment, Reconstruction), ReconstructError> {
        let rec = reconstruct(levels, level.level, values)?;
        let nodes = levels
            .level_nodes(level.level)
            .ok_or(ReconstructError::NoLevel(level.level))?;
        let image = self.scorer.render(Box::new(rec.clone()));
        let mut a = LevelAssessment {
            level: level.level,
            n: level.n,
            directions: level.cumulative_directions,
            cumulative_seconds: level.cumulative_seconds,
            change_flip: None,
            change_psnr: None,
            est_flip: None,
            est_psnr: None,
            half_width: None,
            true_flip: None,
            true_psnr: None,
            coverage: None,
            prior: rec.prior().map_or("none", |p| p.kind()),
        };
        let mut half_width = None;
        if let Some((prev, prev_image, _)) = &self.previous {
            // Held-out residuals: level L's new directions against level L-1's reconstruction.
            let new = nodes.measured.iter().enumerate().skip(level.first).take(level.count);
            let residuals = new
                .flat_map(|(d, &(_, wi, wo))| {
                    let r = log_space(values[d]) - log_space(prev.eval(wi, wo));
                    [r.x.abs(), r.y.abs(), r.z.abs()]
                })
                .filter(|r| r.is_finite())
                .collect();
            let h = quantile90(residuals) * INTERVAL_SHRINK;
            half_width = Some(h);
            if let Ok(c) = score(prev_image, &image) {
                let d = if c.flip.is_finite() { c.flip } else { 1.0 };
                a.change_flip = Some(d);
                a.change_psnr = Some(c.psnr);
                a.est_flip = Some(estimated_flip(false, d));
                a.est_psnr = Some(estimated_psnr(false, c.psnr));
            }
        }
        a.half_width = half_width;
        if let Some((truth, truth_image)) = &self.truth {
            if let Ok(c) = score(truth_image, &image) {
                a.true_flip = Some(c.flip);
                a.true_psnr = Some(c.psnr);
            }
            a.coverage = half_width.map(|h| {
                let mut inside = 0usize;
                for &(wi, wo) in &self.pairs {
                    let e = log_space(truth.eval(wi, wo)) - log_space(rec.eval(wi, wo));
                    inside += [e.x, e.y, e.z].iter().filter(|e| e.abs() <= h).count();
                }
                inside as f64 / (3 * self.pairs.len()).max(1) as f64
            });
        }
        if self.previous.is_none() {
            if let Some((d, psnr)) = self.split_change(&nodes, level.level, values, &image) {
                a.change_flip = Some(d);
                a.est_flip = Some(estimated_flip(true, d));
                a.change_psnr = Some(psnr);
                a.est_psnr = Some(estimated_psnr(true, psnr));
            }
        }
        self.previous = Some((rec.clone(), image, half_width.unwrap_or(f64::NAN)));
        Ok((a, rec))
    }

    /// The first level's change: the mean FLIP between the renders of the reconstructions from
    /// each half of its measurements and `image` (all of them), and the PSNR of their mean squared
    /// error; None if a half fails.
    fn split_change(
        &mut self,
        nodes: &LevelNodes<'_>,
        level: usize,
        values: &[DVec3],
        image: &Image,
    ) -> Option<(f64, f64)> {
        let (mut flip, mut sq) = (0.0, 0.0);
        for parity in 0..2 {
            let (half, half_values) = nodes.subset(values, |d| d % 2 == parity);
            let rec = reconstruct(&SingleLevel { level, nodes: half }, level, &half_values).ok()?;
            let c = score(image, &self.scorer.render(Box::new(rec))).ok()?;
            // Guard: a non-finite FLIP or RMSE (a black render) counts as the largest change.
            flip += if c.flip.is_finite() { c.flip } else { 1.0 };
            sq += if c.rmse.is_finite() { c.rmse * c.rmse } else { 1.0 };
        }
        Some((flip / 2.0, crate::render::metrics::psnr((sq / 2.0).sqrt())))
    }
}

/// Whether `rule` stops the loop after `a`, and why (one line); `last` is the deepest level allowed.
pub fn decide(rule: &StopRule, a: &LevelAssessment, last: usize) -> Option<String> {
    let met = match *rule {
        StopRule::TargetFlip(f) => a.est_flip.is_some_and(|(e, _, _)| e <= f),
        StopRule::TargetPsnr(db) => a.est_psnr.is_some_and(|e| e >= db),
        StopRule::Depth | StopRule::TimeBudget(_) => false,
    };
    if met {
        return Some(format!("stopped at level {}: {} met", a.level, rule.describe()));
    }
    if a.level < last {
        return None;
    }
    Some(match *rule {
        StopRule::Depth => format!("stopped at level {}: the deepest level asked for", a.level),
        StopRule::TimeBudget(_) => format!(
            "stopped at level {}: the deepest level within the {} ({:.1} min)",
            a.level,
            rule.describe(),
            a.cumulative_seconds / 60.0
        ),
        _ => format!(
            "target not met: {} not reached by the deepest level {} ({}x{}), stopped there",
            rule.describe(),
            a.level,
            a.n,
            a.n
        ),
    })
}

/// Run the loop over `plan`: `measure(level)` brings the values of every direction up to and
/// including that level (indexed like the plan); `on_level` sees each assessment as it comes.
pub fn run<E>(
    plan: &Plan,
    rule: &StopRule,
    truth: Option<&str>,
    measure: &mut dyn FnMut(&LevelSummary) -> Result<Vec<DVec3>, E>,
    on_level: &mut dyn FnMut(&LevelAssessment),
) -> Result<ClosedLoop, E>
where
    E: From<PlanError> + From<ReconstructError>,
{
    let last = rule.last_level(plan)?;
    let mut assessor = Assessor::new(truth)?;
    let mut levels = Vec::new();
    for summary in plan.levels.iter().take(last) {
        let values = measure(summary)?;
        let (a, rec) = assessor.assess(plan, summary, &values)?;
        on_level(&a);
        let stop = decide(rule, &a, last);
        levels.push(a);
        if let Some(stop_reason) = stop {
            return Ok(ClosedLoop {
                stop_level: summary.level,
                levels,
                reconstruction: rec,
                stop_reason,
            });
        }
    }
    Err(PlanError::Invalid("the plan has no level".into()).into())
}

/// One console line per level: level, directions, cumulative instrument minutes, estimated error
/// with its interval, and in simulation the true error.
pub fn level_line(a: &LevelAssessment) -> String {
    let est = match a.est_flip {
        Some((e, lo, hi)) => format!("estimated FLIP {e:.4} [{lo:.4}, {hi:.4}]"),
        None => "estimated FLIP -".into(),
    };
    let truth = a.true_flip.map_or(String::new(), |t| format!(", true FLIP {t:.4}"));
    format!(
        "level {} ({}x{}): {} directions, {:.1} min, prior {}, {est}{truth}",
        a.level,
        a.n,
        a.n,
        a.directions,
        a.cumulative_seconds / 60.0,
        a.prior
    )
}

#[cfg(test)]
mod tests;
