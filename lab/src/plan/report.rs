//! The accuracy-vs-time report (`gonio-lab plan-report`): for each material, plan with each strategy,
//! measure the ground truth at the planned directions (the virtual scan without effects),
//! reconstruct every level and score it; compare the stopping rules with the oracle and the
//! orders' motion times.
//!
//! Scoring: the capture scene (`examples/sphere-point.toml`: a sphere under a point light, rendered
//! at `size` pixels) of the reconstruction against that of the ground truth, with `render::metrics`
//! (RMSE and PSNR of the 8-bit sRGB images as the paper computed them, mean LDR FLIP); and `brdf_log_err`, the mean over the fit's
//! documented direction set (`fit::fit_directions`) of |log(1 + f cos) - log(1 + f_rec cos)| over
//! RGB (Liu et al. 2023), which no single highlight pixel dominates.
//! Cost: planning is O(n^2) in the n directions of a level (neighbour lists, spanning tree);
//! each score is one render (size^2 reconstruction lookups) plus the fixed direction set.

use super::predict::{score, Scorer};
use super::{estimate_for, Estimate, Plan, PlanConfig, PlanError, Planner, Spacing, Strategy};
use crate::plot::{Chart, Mark, Series};
use gonio::brdf::{parse_material, Material};
use gonio::reconstruct::{reconstruct, reconstruct_with, NoPrior};
use gonio::render::Image;
use gonio_shared::instrument::InstrumentConfig;
use std::fmt::Write;
use std::path::Path;
use std::time::Instant;

/// Default materials: four MERL neural fits (the paper's Table 1 set) and two analytic lobes (a
/// sharp peak on a diffuse base; a rough lobe).
pub const DEFAULT_MATERIALS: [&str; 6] = [
    "nbrdf:pink-fabric",
    "nbrdf:green-metallic-paint",
    "nbrdf:white-diffuse-bball",
    "nbrdf:gold-metallic-paint",
    "ggx:alpha=0.03,diffuse=0.3,specular=1",
    "ggx:alpha=0.5,diffuse=0.05,specular=1",
];

#[derive(Clone, Debug)]
pub struct ReportConfig {
    pub materials: Vec<String>,
    pub max_level: usize,
    pub k: usize,
    pub size: usize,
    /// FLIP targets for the stopping rules.
    pub flip_targets: Vec<f64>,
    /// Incoming spacing of the strategy comparison.
    pub spacing: Spacing,
}

impl Default for ReportConfig {
    fn default() -> Self {
        Self {
            materials: DEFAULT_MATERIALS.iter().map(|s| s.to_string()).collect(),
            max_level: 4,
            k: 8,
            size: 128,
            flip_targets: vec![0.1, 0.05],
            spacing: Spacing::Angle,
        }
    }
}

/// A PSNR cell of the reports' csv files: identical renders (an exact reconstruction) have PSNR
/// +inf; write it as `inf` (what `f64::from_str` reads back).
pub(super) fn psnr_cell<S: serde::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if *v == f64::INFINITY {
        s.serialize_str("inf")
    } else {
        s.serialize_f64(*v)
    }
}

/// One row of `plan-report.csv`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    pub material: String,
    pub estimate: String,
    pub strategy: String,
    pub spacing: String,
    pub incoming: usize,
    pub level: usize,
    pub grid_n: usize,
    pub grid_m: usize,
    pub directions: usize,
    pub gonio_seconds: f64,
    pub raster_seconds: f64,
    pub motion_seconds: f64,
    pub raster_motion_seconds: f64,
    pub lower_bound_motion_seconds: f64,
    pub rmse: f64,
    #[serde(serialize_with = "psnr_cell")]
    pub psnr: f64,
    pub flip: f64,
    pub brdf_log_err: f64,
    /// Error of the same plan simulated on the estimate (the predictive rule's input).
    pub predicted_flip: f64,
    /// FLIP between this level's render and the previous level's (the convergence rule's input).
    pub step_flip: f64,
    pub plan_ms: f64,
}

struct Evaluated {
    plan: Plan,
    rows: Vec<Row>,
}

#[allow(clippy::too_many_arguments)]
fn evaluate(
    scorer: &mut Scorer,
    instrument: &InstrumentConfig<f64>,
    spec: &str,
    truth: &dyn Material,
    truth_img: &Image,
    estimate: &Estimate,
    est_img: &Image,
    config: &PlanConfig,
) -> Result<Evaluated, PlanError> {
    let t0 = Instant::now();
    let plan = Planner::new(*instrument, estimate.clone())?.plan(config)?;
    let plan_ms = t0.elapsed().as_secs_f64() * 1e3;
    let measured = plan.measure(truth);
    let est_material = estimate.material();
    let est_measured = plan.measure(est_material.as_ref());
    let mut rows = Vec::new();
    let mut prev: Option<Image> = None;
    let (mut cum_motion, mut cum_raster_motion, mut cum_bound) = (0.0, 0.0, 0.0);
    for l in &plan.levels {
        let grid = reconstruct(&plan, l.level, &measured)?;
        let log_err = scorer.log_err(truth, &grid);
        let img = scorer.render(Box::new(grid));
        let c = score(truth_img, &img)?;
        // The predictive rule's simulation, as `predictive_level` runs it (no prior).
        let est_grid = reconstruct_with(&plan, l.level, &est_measured, &NoPrior)?;
        let est_rec = scorer.render(Box::new(est_grid));
        let predicted = score(est_img, &est_rec)?;
        let step = match &prev {
            Some(p) => score(p, &img)?.flip,
            None => f64::NAN,
        };
        cum_motion += l.motion_seconds;
        cum_raster_motion += l.raster_motion_seconds;
        cum_bound += l.lower_bound_motion_seconds;
        rows.push(Row {
            material: spec.to_string(),
            estimate: estimate.model.to_spec(),
            strategy: config.strategy.to_string(),
            spacing: config.spacing.to_string(),
            incoming: config.k,
            level: l.level,
            grid_n: l.n,
            grid_m: l.m,
            directions: l.cumulative_directions,
            gonio_seconds: l.cumulative_seconds,
            raster_seconds: l.cumulative_raster_seconds,
            motion_seconds: cum_motion,
            raster_motion_seconds: cum_raster_motion,
            lower_bound_motion_seconds: cum_bound,
            rmse: c.rmse,
            psnr: c.psnr,
            flip: c.flip,
            brdf_log_err: log_err,
            predicted_flip: predicted.flip,
            step_flip: step,
            plan_ms,
        });
        prev = Some(img);
    }
    Ok(Evaluated { plan, rows })
}

/// Which level each stopping rule picks for a FLIP target (1-based; the deepest level if none meets it).
#[derive(Clone, Debug, serde::Serialize)]
pub struct StopChoice {
    pub material: String,
    pub target_flip: f64,
    pub oracle_level: Option<usize>,
    pub predictive_level: usize,
    pub convergence_level: usize,
    pub oracle_minutes: Option<f64>,
    pub predictive_minutes: f64,
    pub convergence_minutes: f64,
    pub predictive_true_flip: f64,
    pub convergence_true_flip: f64,
}

pub fn stopping(rows: &[Row], target: f64) -> Option<StopChoice> {
    let last = rows.last()?;
    let oracle = rows.iter().find(|r| r.flip <= target);
    let predictive = rows.iter().find(|r| r.predicted_flip <= target).unwrap_or(last);
    // Stop after level k + 1 once its render differs from level k's by at most the target.
    let convergence = rows.iter().find(|r| r.step_flip <= target).unwrap_or(last);
    Some(StopChoice {
        material: last.material.clone(),
        target_flip: target,
        oracle_level: oracle.map(|r| r.level),
        predictive_level: predictive.level,
        convergence_level: convergence.level,
        oracle_minutes: oracle.map(|r| r.gonio_seconds / 60.0),
        predictive_minutes: predictive.gonio_seconds / 60.0,
        convergence_minutes: convergence.gonio_seconds / 60.0,
        predictive_true_flip: predictive.flip,
        convergence_true_flip: convergence.flip,
    })
}

/// CSV with the struct's fields as columns, in declaration order (the csv crate's serde header);
/// floats in shortest round-trip form, `None` as an empty cell.
pub(super) fn csv<T: serde::Serialize>(rows: &[T]) -> Result<Vec<u8>, PlanError> {
    let mut w = ::csv::Writer::from_writer(Vec::new());
    for r in rows {
        w.serialize(r).map_err(|e| PlanError::Invalid(e.to_string()))?;
    }
    w.into_inner().map_err(|e| PlanError::Invalid(e.to_string()))
}

pub(super) fn write(dir: &Path, name: &str, bytes: &[u8]) -> Result<(), PlanError> {
    let path = dir.join(name);
    gonio::fsio::write_bytes_atomically(&path, bytes)
        .map_err(|e| PlanError::Invalid(format!("{}: {e}", path.display())))
}

/// Run the whole report into `dir`; `progress` gets one line per finished step.
pub fn run(
    cfg: &ReportConfig,
    instrument: &InstrumentConfig<f64>,
    dir: &Path,
    progress: &dyn Fn(&str),
) -> Result<String, PlanError> {
    let mut scorer = Scorer::new(cfg.size)?;
    let mut rows: Vec<Row> = Vec::new();
    let mut stops = Vec::new();
    // Resolve every material first: a bad spec fails before any work.
    let mut inputs = Vec::new();
    for spec in &cfg.materials {
        let truth = parse_material(spec)?;
        let estimate = estimate_for(spec)?;
        inputs.push((spec.clone(), truth, estimate));
    }
    std::fs::create_dir_all(dir).map_err(|e| PlanError::Invalid(format!("{}: {e}", dir.display())))?;
    for (spec, truth, estimate) in &inputs {
        let truth_img = scorer.render(parse_material(spec)?);
        let est_img = scorer.render(estimate.material());
        for strategy in [Strategy::Mixture, Strategy::Uniform] {
            let config = PlanConfig {
                strategy,
                spacing: cfg.spacing,
                k: cfg.k,
                grids: super::square_grids(cfg.max_level),
                incoming: Vec::new(),
            };
            let e = evaluate(
                &mut scorer,
                instrument,
                spec,
                truth.as_ref(),
                &truth_img,
                estimate,
                &est_img,
                &config,
            )?;
            if strategy == Strategy::Mixture {
                for &t in &cfg.flip_targets {
                    stops.extend(stopping(&e.rows, t));
                }
            }
            progress(&format!(
                "{spec} {strategy}: {} directions, dropped {:?}",
                e.plan.directions.len(),
                e.plan.dropped
            ));
            rows.extend(e.rows);
        }
    }

    write(dir, "plan-report.csv", &csv(&rows)?)?;
    write(dir, "plan-stopping.csv", &csv(&stops)?)?;
    let md = markdown(cfg, &rows, &stops);
    write(dir, "report.md", md.as_bytes())?;
    charts(dir, cfg, &rows)?;
    Ok(md)
}

pub(super) fn short(spec: &str) -> &str {
    spec.strip_prefix("nbrdf:").unwrap_or(spec)
}

fn markdown(cfg: &ReportConfig, rows: &[Row], stops: &[StopChoice]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Planner: accuracy vs time\n\nRegenerate: `gonio-lab plan-report -o DIR --max-grid {} --incoming {} --size {}{}`.\n\
         Strategies compared with {} incoming spacing.\n\
         Ground truth: the material itself (MERL materials: their neural fits). Estimate: analytic materials are their own \
         estimate; MERL materials get the GGX fit (`gonio brdf fit`), standing in for the encoder. Scores: capture scene \
         (`examples/sphere-point.toml`, {} px) of the reconstruction against the truth (RMSE and PSNR of the 8-bit sRGB images, mean LDR FLIP), and \
         `brdf_log_err` over the fit's direction set. Times: replay of the firmware's IK with the shared motion profile \
         plus settle and exposure from `examples/gonio.toml`.\n",
        1usize << cfg.max_level,
        cfg.k,
        cfg.size,
        cfg.materials
            .iter()
            .map(|m| format!(" --material {m}"))
            .collect::<String>(),
        cfg.spacing,
        cfg.size
    );
    let _ = writeln!(s, "## Error per level\n\n| material | strategy | grid | directions | gonio min | PSNR | FLIP | brdf_log_err |\n|---|---|---|---|---|---|---|---|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {}x{} | {} | {:.1} | {:.2} | {:.4} | {:.4} |",
            short(&r.material),
            r.strategy,
            r.grid_n,
            r.grid_m,
            r.directions,
            r.gonio_seconds / 60.0,
            r.psnr,
            r.flip,
            r.brdf_log_err
        );
    }
    // Wins of the mixture over the uniform grid at equal level.
    let mut wins = [0usize; 2];
    let mut total = 0;
    for r in rows.iter().filter(|r| r.strategy == "mixture") {
        let uniform = rows
            .iter()
            .find(|o| o.strategy == "uniform" && o.material == r.material && o.level == r.level);
        if let Some(un) = uniform {
            total += 1;
            wins[0] += (r.flip <= un.flip) as usize;
            wins[1] += (r.brdf_log_err <= un.brdf_log_err) as usize;
        }
    }
    let _ = writeln!(
        s,
        "\nMixture at least as good as uniform: FLIP {}/{total}, brdf_log_err {}/{total} (material x level).\n",
        wins[0], wins[1]
    );
    let _ = writeln!(s, "## Motion time: optimised order vs raster (generation) order vs lower bound\n\n\
        Lower bound: per level, the degree bound of an open path through the level's new directions (`plan::order`): every \
        direction but the path's two ends has two moves, each end one, so the moves add up to at least half the sum over the \
        directions of their two shortest moves, less the two largest second-shortest (the entry move counts as 0), under \
        d(a, b) = the least synchronised move time over every IK pose of a and of b. Every real move costs at least d, so no \
        order can beat it.\n\n\
        | material | strategy | grid | motion s | raster s | bound s | raster/opt | opt/bound |\n|---|---|---|---|---|---|---|---|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {}x{} | {:.0} | {:.0} | {:.0} | {:.2} | {:.3} |",
            short(&r.material),
            r.strategy,
            r.grid_n,
            r.grid_m,
            r.motion_seconds,
            r.raster_motion_seconds,
            r.lower_bound_motion_seconds,
            r.raster_motion_seconds / r.motion_seconds,
            r.motion_seconds / r.lower_bound_motion_seconds
        );
    }
    let _ = writeln!(s, "\n## Stopping rules vs the oracle (mixture, FLIP target)\n\n\
        Oracle: smallest level whose true FLIP meets the target. Predictive: smallest level whose FLIP, simulated on the \
        estimate, meets it. Convergence: stop after level k + 1 once its render and level k's differ by at most the target.\n\n\
        | material | target | oracle level | predictive level (true FLIP) | convergence level (true FLIP) | oracle min | predictive min | convergence min |\n|---|---|---|---|---|---|---|---|");
    for c in stops {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} ({:.4}) | {} ({:.4}) | {} | {:.1} | {:.1} |",
            short(&c.material),
            c.target_flip,
            c.oracle_level.map_or("none".into(), |l| l.to_string()),
            c.predictive_level,
            c.predictive_true_flip,
            c.convergence_level,
            c.convergence_true_flip,
            c.oracle_minutes.map_or("-".into(), |m| format!("{m:.1}")),
            c.predictive_minutes,
            c.convergence_minutes
        );
    }
    let _ = writeln!(s, "\nFigures: `plan-flip.png`, `plan-logerr.png` (error vs gonio minutes, one panel per material), `plan-order.png` (motion minutes per strategy and order).");
    s
}

/// Errors are drawn on log axes; an exact reconstruction (an analytic material recovered by the
/// fitted prior scores 0) is drawn at this floor. The csv and the tables keep the true values.
pub(super) const PLOT_FLOOR: f64 = 1e-5;

fn charts(dir: &Path, cfg: &ReportConfig, rows: &[Row]) -> Result<(), PlanError> {
    // One panel per material (two strategies each): one chart with every material's curves had
    // too many series to read.
    let panels = |metric: fn(&Row) -> f64, label: &str| -> Result<(usize, usize, Vec<u8>), PlanError> {
        let (w, h) = (520u32, 360u32);
        let mut out = Vec::new();
        for m in &cfg.materials {
            let mut c = Chart::new(format!("{}: {label}", short(m)), "gonio minutes", label);
            c.x_log = true;
            c.y_log = true;
            c.width = w;
            c.height = h;
            for st in ["mixture", "uniform"] {
                let pts: Vec<(f64, f64)> = rows
                    .iter()
                    .filter(|r| &r.material == m && r.strategy == st)
                    .map(|r| (r.gonio_seconds / 60.0, metric(r).max(PLOT_FLOOR)))
                    .collect();
                c.series.push(Series::new(st, pts, Mark::LineAndPoints));
            }
            out.push(crate::plot::draw_rgb(&c).map_err(|e| PlanError::Invalid(e.to_string()))?);
        }
        Ok(crate::plot::tile(&out, w as usize, h as usize, 3))
    };
    let mut ord = Chart::new("Motion time per plan", "directions", "motion minutes");
    ord.x_log = true;
    ord.y_log = true;
    let pick =
        |f: fn(&Row) -> f64| -> Vec<(f64, f64)> { rows.iter().map(|r| (r.directions as f64, f(r) / 60.0)).collect() };
    ord.series = vec![
        Series::new("raster order", pick(|r| r.raster_motion_seconds), Mark::Points),
        Series::new("optimised order", pick(|r| r.motion_seconds), Mark::Points),
        Series::new("lower bound", pick(|r| r.lower_bound_motion_seconds), Mark::Points),
    ];
    let flip = panels(|r| r.flip, "mean FLIP")?;
    let log = panels(|r| r.brdf_log_err, "brdf_log_err")?;
    for ((w, h, rgb), name) in [(flip, "plan-flip.png"), (log, "plan-logerr.png")] {
        let path = dir.join(name);
        gonio::render::image::write_rgb8_png(&path, w, h, rgb)
            .map_err(|e| PlanError::Invalid(format!("{}: {e}", path.display())))?;
    }
    crate::plot::write_png(&ord, &dir.join("plan-order.png")).map_err(|e| PlanError::Invalid(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::csv;

    #[derive(serde::Serialize)]
    struct R {
        name: String,
        n: usize,
        x: f64,
        #[serde(serialize_with = "super::psnr_cell")]
        psnr: f64,
        paper: Option<f64>,
    }

    #[test]
    fn csv_rows_keep_field_order_shortest_floats_quotes_and_empty_options() {
        let rows = [
            R {
                name: "ggx:alpha=0.1,diffuse=0.2".into(),
                n: 3,
                x: 0.1 + 0.2,
                psnr: f64::INFINITY,
                paper: None,
            },
            R {
                name: "say \"hi\"".into(),
                n: 0,
                x: 1.0,
                psnr: 41.25,
                paper: Some(1e-7),
            },
        ];
        let text = String::from_utf8(csv(&rows).expect("csv")).expect("utf-8");
        assert_eq!(
            text,
            "name,n,x,psnr,paper\n\"ggx:alpha=0.1,diffuse=0.2\",3,0.30000000000000004,inf,\n\"say \"\"hi\"\"\",0,1.0,41.25,1e-7\n"
        );
        assert!(csv::<R>(&[]).expect("csv").is_empty());
    }
}
