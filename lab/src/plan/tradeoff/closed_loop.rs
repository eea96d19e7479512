//! The closed loop in the lab (`gonio-lab closed-loop`): the product's loop
//! (`gonio::plan::closed_loop`) run in simulation on each material, seeded by the encoder's
//! estimate on a capture photo (as `adaptive`), beside the uniform grid at the same levels.
//! Every level is measured (the report needs the oracle); the stop rules are then replayed on the
//! recorded estimates. It reports what the estimator's constants are chosen from (true FLIP over
//! the change between levels, held-out residual over the true error quantile), the predictive
//! interval's calibration, the stop rules' hit rate and instrument time against the oracle, and
//! the equal-directions ratio closed loop / uniform per level.

use super::{capture_photo, photo_estimate, HELDOUT_MATERIALS, TRAINING_MATERIALS};
use crate::plan::report::{csv, write};
use gonio::brdf::parse_material;
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::plan::closed_loop::{self, LevelAssessment, StopRule};
use gonio::plan::{square_grids, PlanConfig, PlanError, Planner, Strategy};
use gonio_shared::instrument::InstrumentConfig;
use std::fmt::Write as _;
use std::path::Path;

/// The three real pgII measurements beside the repo (`../shared/data/rgl`).
pub const REAL_MATERIALS: [&str; 3] = [
    "rgl:../shared/data/rgl/satin_rosaline_rgb.bsdf",
    "rgl:../shared/data/rgl/cc_iris_purple_gem_rgb.bsdf",
    "rgl:../shared/data/rgl/paper_white_rgb.bsdf",
];

/// Material sets of the closed-loop report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LoopPreset {
    /// Where the estimator's constants are chosen.
    Training,
    /// The encoder's held-out MERL materials.
    Heldout,
    /// The three real measurements.
    Real,
}

impl LoopPreset {
    pub fn materials(self) -> Vec<String> {
        let list: &[&str] = match self {
            LoopPreset::Training => &TRAINING_MATERIALS,
            LoopPreset::Heldout => &HELDOUT_MATERIALS,
            LoopPreset::Real => &REAL_MATERIALS,
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
}

fn rows_of(material: &str, strategy: &str, levels: &[LevelAssessment], uniform: &[usize]) -> Vec<LoopRow> {
    levels
        .iter()
        .map(|a| LoopRow {
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
        })
        .collect()
}

/// Run the loop (every level, `StopRule::Depth`) on each material for `adaptive` and `uniform`.
pub fn run_rows(
    materials: &[String],
    instrument: &InstrumentConfig<f64>,
    max_level: usize,
    progress: &dyn Fn(&str),
) -> Result<Vec<LoopRow>, PlanError> {
    let encoder = Encoder::shipped(ModelKind::Ggx).map_err(|e| PlanError::Invalid(e.to_string()))?;
    let mut rows = Vec::new();
    for spec in materials {
        let truth = parse_material(spec)?;
        let (_, photo) = capture_photo(spec)?;
        let (estimate, _) = photo_estimate(&photo, &encoder)?;
        let mut per = Vec::new();
        for strategy in [Strategy::Auto, Strategy::Uniform] {
            let config = PlanConfig {
                strategy,
                grids: square_grids(max_level),
                ..PlanConfig::default()
            };
            let plan = Planner::new(*instrument, estimate.clone())?.plan(&config)?;
            let values = plan.measure(truth.as_ref());
            let closed = closed_loop::run::<PlanError>(
                &plan,
                &StopRule::Depth,
                Some(spec),
                &mut |l| Ok(values[..l.cumulative_directions].to_vec()),
                &mut |_| {},
            )?;
            per.push(closed.levels);
        }
        let uniform: Vec<usize> = per[1].iter().map(|a| a.directions).collect();
        rows.extend(rows_of(spec, "adaptive", &per[0], &uniform));
        rows.extend(rows_of(spec, "uniform", &per[1], &uniform));
        progress(&format!(
            "{spec}: adaptive true FLIP {:?}, estimated {:?}",
            per[0]
                .iter()
                .map(|a| a.true_flip.unwrap_or(f64::NAN))
                .collect::<Vec<_>>(),
            per[0]
                .iter()
                .map(|a| a.est_flip.map_or(f64::NAN, |e| e.0))
                .collect::<Vec<_>>()
        ));
    }
    Ok(rows)
}

/// The `q` quantile (0..1) of `v` (nearest rank); NaN for none.
pub fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let i = ((v.len() as f64 * q).ceil() as usize).clamp(1, v.len()) - 1;
    v[i]
}

fn geomean(v: &[f64]) -> f64 {
    let v: Vec<f64> = v.iter().copied().filter(|x| x.is_finite() && *x > 0.0).collect();
    (v.iter().map(|x| x.ln()).sum::<f64>() / v.len().max(1) as f64).exp()
}

/// Replay a target on one material's adaptive levels: (stop level's true FLIP, its minutes, the
/// oracle's minutes: the first level whose true FLIP meets the target, if any).
pub fn replay(levels: &[&LoopRow], target: f64) -> Option<(f64, f64, Option<f64>)> {
    let last = levels.last()?;
    let stop = levels
        .iter()
        .find(|r| r.est_flip.is_some_and(|e| e <= target))
        .unwrap_or(last);
    let oracle = levels.iter().find(|r| r.true_flip.is_some_and(|t| t <= target));
    Some((stop.true_flip?, stop.minutes, oracle.map(|r| r.minutes)))
}

/// Rows with their estimates re-derived from the recorded change FLIP with the product's current
/// constants (so a csv made before a constant changed is summarised as the product now estimates).
pub fn with_current_constants(mut rows: Vec<LoopRow>) -> Vec<LoopRow> {
    for r in &mut rows {
        if let Some(d) = r.change_flip {
            r.est_flip = Some(d * closed_loop::FLIP_RATIO);
            r.est_lo = Some(d * closed_loop::FLIP_RATIO_LO);
            r.est_hi = Some(d * closed_loop::FLIP_RATIO_HI);
        }
    }
    rows
}

/// Read the rows of a `closed-loop.csv`.
pub fn read_rows(path: &Path) -> Result<Vec<LoopRow>, PlanError> {
    let err = |e: &dyn std::fmt::Display| PlanError::Invalid(format!("{}: {e}", path.display()));
    let mut reader = ::csv::Reader::from_path(path).map_err(|e| err(&e))?;
    reader.deserialize().map(|r| r.map_err(|e| err(&e))).collect()
}

/// The report's markdown from its rows.
pub fn summary(rows: &[LoopRow], title: &str, regenerate: &str) -> String {
    let rows = &with_current_constants(rows.to_vec());
    let mut md = String::new();
    let _ = writeln!(md, "# Closed loop: {title}\n\nRegenerate: `{regenerate}`\n");
    let adaptive: Vec<&LoopRow> = rows.iter().filter(|r| r.strategy == "adaptive").collect();
    let ratio: Vec<f64> = adaptive
        .iter()
        .filter_map(|r| Some(r.true_flip? / r.change_flip?.max(1e-9)))
        .collect();
    let _ = writeln!(
        md,
        "## Estimator\n\ntrue point FLIP / change FLIP over {} levels: median {:.3}, 5% {:.3}, 95% {:.3} \
         (product constants: {} [{}, {}]).\n",
        ratio.len(),
        quantile(ratio.clone(), 0.5),
        quantile(ratio.clone(), 0.05),
        quantile(ratio, 0.95),
        closed_loop::FLIP_RATIO,
        closed_loop::FLIP_RATIO_LO,
        closed_loop::FLIP_RATIO_HI
    );
    let inside = adaptive
        .iter()
        .filter_map(|r| Some(r.true_flip? >= r.est_lo? && r.true_flip? <= r.est_hi?))
        .collect::<Vec<_>>();
    let coverage: Vec<f64> = adaptive.iter().filter_map(|r| r.coverage).collect();
    let _ = writeln!(
        md,
        "Calibration: true FLIP inside the estimated 90% FLIP interval at {} of {} levels ({:.0}%); \
         per-direction 90% predictive interval (fit directions x RGB) holds {:.1}% of true values on average \
         (levels 2+, min {:.1}%, max {:.1}%).\n",
        inside.iter().filter(|b| **b).count(),
        inside.len(),
        100.0 * inside.iter().filter(|b| **b).count() as f64 / inside.len().max(1) as f64,
        100.0 * coverage.iter().sum::<f64>() / coverage.len().max(1) as f64,
        100.0 * quantile(coverage.clone(), 0.0),
        100.0 * quantile(coverage, 1.0)
    );
    let mut materials: Vec<&str> = rows.iter().map(|r| r.material.as_str()).collect();
    materials.dedup();
    let _ = writeln!(md, "## Stop rules (replayed on the recorded estimates)\n");
    let _ = writeln!(md, "| target FLIP | scans meeting it at the stop level | time / oracle (geomean, max) | scans whose target no level met |\n|---|---|---|---|");
    for target in [0.02, 0.01] {
        let (mut hit, mut n, mut ratios, mut unmet) = (0, 0, Vec::new(), 0);
        for m in &materials {
            let levels: Vec<&LoopRow> = adaptive.iter().copied().filter(|r| r.material == *m).collect();
            if let Some((t, minutes, oracle)) = replay(&levels, target) {
                n += 1;
                hit += usize::from(t <= target);
                match oracle {
                    Some(o) => ratios.push(minutes / o),
                    None => unmet += 1,
                }
            }
        }
        let _ = writeln!(
            md,
            "| {target} | {hit} of {n} | {:.2}, {:.2} | {unmet} |",
            geomean(&ratios),
            quantile(ratios.clone(), 1.0)
        );
    }
    let _ = writeln!(
        md,
        "\n## Equal directions: closed loop / uniform (true point FLIP, geometric mean over materials)\n"
    );
    let _ = writeln!(
        md,
        "| level | ratio | worst material ratio | adaptive directions <= uniform |\n|---|---|---|---|"
    );
    let max_level = rows.iter().map(|r| r.level).max().unwrap_or(0);
    for level in 1..=max_level {
        let pairs: Vec<(f64, bool)> = materials
            .iter()
            .filter_map(|m| {
                let get = |s: &str| {
                    rows.iter()
                        .find(|r| r.material == *m && r.strategy == s && r.level == level)
                };
                let (a, u) = (get("adaptive")?, get("uniform")?);
                Some((
                    a.true_flip? / u.true_flip?.max(1e-9),
                    a.directions <= a.uniform_directions,
                ))
            })
            .collect();
        let ratios: Vec<f64> = pairs.iter().map(|p| p.0).collect();
        let _ = writeln!(
            md,
            "| {level} | {:.3} | {:.3} | {} |",
            geomean(&ratios),
            quantile(ratios.clone(), 1.0),
            pairs.iter().all(|p| p.1)
        );
    }
    let mut worst_step = (1.0f64, String::new());
    for m in &materials {
        let levels: Vec<&LoopRow> = adaptive.iter().copied().filter(|r| r.material == *m).collect();
        for w in levels.windows(2) {
            if let (Some(a), Some(b)) = (w[0].true_flip, w[1].true_flip) {
                if b / a > worst_step.0 {
                    worst_step = (b / a, format!("{m} level {}", w[1].level));
                }
            }
        }
    }
    let _ = writeln!(
        md,
        "\nMonotonicity (adaptive, true point FLIP): largest level-to-level ratio {:.3}{}.",
        worst_step.0,
        if worst_step.1.is_empty() {
            String::new()
        } else {
            format!(" ({})", worst_step.1)
        }
    );
    md
}

/// Run the report into `dir` (`closed-loop.csv`, `closed-loop.md`); returns the markdown.
pub fn run(
    preset: LoopPreset,
    materials: &[String],
    instrument: &InstrumentConfig<f64>,
    max_level: usize,
    from_csv: Option<&Path>,
    dir: &Path,
    progress: &dyn Fn(&str),
) -> Result<String, PlanError> {
    let rows = match from_csv {
        Some(path) => read_rows(path)?,
        None => run_rows(materials, instrument, max_level, progress)?,
    };
    std::fs::create_dir_all(dir).map_err(|e| PlanError::Invalid(format!("{}: {e}", dir.display())))?;
    write(dir, "closed-loop.csv", &csv(&rows)?)?;
    let name = format!("{preset:?}").to_lowercase();
    let md = summary(
        &rows,
        &name,
        &format!("gonio-lab closed-loop --preset {name} -o {}", dir.display()),
    );
    write(dir, "closed-loop.md", md.as_bytes())?;
    Ok(md)
}
