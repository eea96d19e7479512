//! The `closed-loop.md` report from a run's rows (`closed_loop::run`): estimator ratios and
//! calibration, stop-rule replays, errors, equal-directions ratios, monotonicity, the goal minutes.

use super::{LoopRow, GOAL_MINUTES};
use gonio::plan::closed_loop::{self, StopRule};
use std::fmt::Write as _;

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

/// Whether row `r` meets `rule`'s target by its estimate or, with `truth`, by its true error
/// (the PSNR estimate from the recorded change PSNR, as the product derives it).
fn meets(r: &LoopRow, rule: StopRule, truth: bool) -> bool {
    match rule {
        StopRule::TargetFlip(f) => if truth { r.true_flip } else { r.est_flip }.is_some_and(|e| e <= f),
        StopRule::TargetPsnr(db) => if truth {
            r.true_psnr
        } else {
            r.change_psnr.map(|c| closed_loop::estimated_psnr(r.level == 1, c))
        }
        .is_some_and(|e| e >= db),
        StopRule::Depth | StopRule::TimeBudget(_) => false,
    }
}

/// Replay a target on one material's adaptive levels: (whether the stop level truly meets it, its
/// minutes, the oracle's minutes: the first level whose true error meets the target, if any).
pub fn replay(levels: &[&LoopRow], rule: StopRule) -> Option<(bool, f64, Option<f64>)> {
    let last = levels.last()?;
    let stop = levels.iter().find(|r| meets(r, rule, false)).unwrap_or(last);
    let oracle = levels.iter().find(|r| meets(r, rule, true));
    Some((meets(stop, rule, true), stop.minutes, oracle.map(|r| r.minutes)))
}

/// Rows with their estimates re-derived from the recorded change FLIP with the product's current
/// constants (so a csv made before a constant changed is summarised as the product now estimates).
pub fn with_current_constants(mut rows: Vec<LoopRow>) -> Vec<LoopRow> {
    for r in &mut rows {
        if let Some(d) = r.change_flip {
            let (e, lo, hi) = closed_loop::estimated_flip(r.level == 1, d);
            (r.est_flip, r.est_lo, r.est_hi) = (Some(e), Some(lo), Some(hi));
        }
    }
    rows
}

/// True / change FLIP of `rows` at level 1 (`first`: its split change) or at levels 2.. (the
/// change between consecutive levels): the two estimators have their own ratios.
fn ratios(rows: &[&LoopRow], first: bool) -> Vec<f64> {
    rows.iter()
        .filter(|r| (r.level == 1) == first)
        .filter_map(|r| Some(r.true_flip? / r.change_flip?.max(1e-9)))
        .collect()
}

/// True / change RMSE of `rows`, 10^((change - true PSNR) / 20), at level 1 (`first`) or at levels 2..
fn rmse_ratios(rows: &[&LoopRow], first: bool) -> Vec<f64> {
    rows.iter()
        .filter(|r| (r.level == 1) == first)
        .filter_map(|r| Some(10f64.powf((r.change_psnr? - r.true_psnr?) / 20.0)))
        .collect()
}

/// Median, 5% and 95% quantiles of `v`, as the report prints them.
fn quantiles(v: &[f64]) -> String {
    format!(
        "median {:.3}, 5% {:.3}, 95% {:.3}",
        quantile(v.to_vec(), 0.5),
        quantile(v.to_vec(), 0.05),
        quantile(v.to_vec(), 0.95)
    )
}

/// The targets the stop rule is replayed at (point FLIP, and point PSNR in dB).
const STOP_TARGETS: [f64; 2] = [0.02, 0.01];
const PSNR_TARGETS: [f64; 2] = [45.0, 50.0];

/// The stop rule replayed at `target` on `rows` (one strategy, their estimates set): scans meeting
/// it at the stop level, time / oracle (geometric mean, max), scans whose target no level met.
fn stop_cells(rows: &[&LoopRow], rule: StopRule) -> String {
    let mut materials: Vec<&str> = rows.iter().map(|r| r.material.as_str()).collect();
    materials.dedup();
    let (mut hit, mut n, mut ratios, mut unmet) = (0, 0, Vec::new(), 0);
    for m in &materials {
        let levels: Vec<&LoopRow> = rows.iter().copied().filter(|r| r.material == *m).collect();
        if let Some((met, minutes, oracle)) = replay(&levels, rule) {
            n += 1;
            hit += usize::from(met);
            match oracle {
                Some(o) => ratios.push(minutes / o),
                None => unmet += 1,
            }
        }
    }
    if ratios.is_empty() {
        return format!("{hit} of {n} | - | {unmet}");
    }
    format!(
        "{hit} of {n} | {:.2}, {:.2} | {unmet}",
        geomean(&ratios),
        quantile(ratios.clone(), 1.0)
    )
}

/// The stop rule on `strategy`'s rows of other runs, its ratios the `q.0` quantile of true / change
/// FLIP over `train`'s rows of that strategy at levels 2.. and the `q.1` quantile at level 1 (a
/// schedule with other level steps needs its own ratio; with the product's rows and q = (0.5, 0.9)
/// these are `FLIP_RATIO`, `FIRST_FLIP_RATIO` and the reports' stop tables).
pub fn stop_replay(
    train: &[LoopRow],
    strategy: &str,
    (q, q_first): (f64, f64),
    runs: &[(String, Vec<LoopRow>)],
) -> Result<String, String> {
    let of = |rows: &[LoopRow]| -> Vec<LoopRow> { rows.iter().filter(|r| r.strategy == strategy).cloned().collect() };
    let train = of(train);
    let train: Vec<&LoopRow> = train.iter().collect();
    let (later, first) = (ratios(&train, false), ratios(&train, true));
    if later.is_empty() {
        return Err(format!(
            "the training rows have no level of strategy {strategy:?} with a change FLIP"
        ));
    }
    let ratio = quantile(later.clone(), q);
    // A level 1 without a split change (rows made before it existed) keeps no estimate.
    let first_ratio = quantile(first.clone(), q_first);
    let mut md = format!(
        "{strategy}: true / change FLIP over {} training levels 2..: {}; the rule's ratio ({q} quantile) {ratio:.3}\n\n\
         level 1 (split change) over {} training levels: {}; the rule's ratio ({q_first} quantile) {first_ratio:.3}\n\n\
         | run | target FLIP | scans meeting it at the stop level | time / oracle (geomean, max) | scans no level met |\n|---|---|---|---|---|\n",
        later.len(),
        quantiles(&later),
        first.len(),
        quantiles(&first),
    );
    for (name, rows) in runs {
        let mut mine = of(rows);
        if mine.is_empty() {
            return Err(format!("{name}: no rows of strategy {strategy:?}"));
        }
        for r in &mut mine {
            let k = if r.level == 1 { first_ratio } else { ratio };
            r.est_flip = r.change_flip.map(|d| d * k).filter(|e| e.is_finite());
        }
        let refs: Vec<&LoopRow> = mine.iter().collect();
        for target in STOP_TARGETS {
            let _ = writeln!(
                md,
                "| {name} | {target} | {} |",
                stop_cells(&refs, StopRule::TargetFlip(target))
            );
        }
    }
    Ok(md)
}

/// The report's markdown from its rows.
pub fn summary(rows: &[LoopRow], title: &str, regenerate: &str) -> String {
    let rows = &with_current_constants(rows.to_vec());
    let mut md = String::new();
    let _ = writeln!(md, "# Closed loop: {title}\n\nRegenerate: `{regenerate}`\n");
    let adaptive: Vec<&LoopRow> = rows.iter().filter(|r| r.strategy == "adaptive").collect();
    let (later, first) = (ratios(&adaptive, false), ratios(&adaptive, true));
    let _ = writeln!(
        md,
        "## Estimator\n\ntrue point FLIP / change FLIP over {} levels 2..: {} \
         (product constants: {} [{}, {}]); level 1, true / split change over {} levels: {} \
         (product constants: {} [{}, {}]).\n",
        later.len(),
        quantiles(&later),
        closed_loop::FLIP_RATIO,
        closed_loop::FLIP_RATIO_LO,
        closed_loop::FLIP_RATIO_HI,
        first.len(),
        quantiles(&first),
        closed_loop::FIRST_FLIP_RATIO,
        closed_loop::FIRST_FLIP_RATIO_LO,
        closed_loop::FIRST_FLIP_RATIO_HI
    );
    let (later, first) = (rmse_ratios(&adaptive, false), rmse_ratios(&adaptive, true));
    let _ = writeln!(
        md,
        "PSNR estimate: true render RMSE / change RMSE over {} levels 2..: {} (product constant \
         `RMSE_RATIO`: {}); level 1, true / split change RMSE over {} levels: {} (product constant \
         `FIRST_RMSE_RATIO`: {}).\n",
        later.len(),
        quantiles(&later),
        closed_loop::RMSE_RATIO,
        first.len(),
        quantiles(&first),
        closed_loop::FIRST_RMSE_RATIO
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
    priors_chosen(&mut md, rows);
    let mut materials: Vec<&str> = rows.iter().map(|r| r.material.as_str()).collect();
    materials.dedup();
    let _ = writeln!(md, "## Stop rules (replayed on the recorded estimates)\n");
    for (unit, targets, psnr) in [("FLIP", STOP_TARGETS, false), ("PSNR (dB)", PSNR_TARGETS, true)] {
        let sep = if psnr { "\n" } else { "" };
        let _ = writeln!(md, "{sep}| target {unit} | scans meeting it at the stop level | time / oracle (geomean, max) | scans whose target no level met |\n|---|---|---|---|");
        for target in targets {
            let rule = if psnr {
                StopRule::TargetPsnr(target)
            } else {
                StopRule::TargetFlip(target)
            };
            let _ = writeln!(md, "| {target} | {} |", stop_cells(&adaptive, rule));
        }
    }
    absolute_errors(&mut md, rows);
    equal_directions(&mut md, rows, &materials, "adaptive", "closed loop");
    for strategy in strategies(rows)
        .into_iter()
        .filter(|s| *s != "adaptive" && *s != "uniform")
    {
        let title = if strategy == "reseed" {
            "re-seeded from level 1's fit (lab trial)".to_string()
        } else if strategy.ends_with(" grids") {
            format!("{strategy} (lab trial: other outgoing grids per level, compared level by level with the uniform grid's N x N levels, so not at equal directions)")
        } else if strategy == "designed" {
            "level 1 the peer's design, levels 2.. the photo plan's (lab trial)".to_string()
        } else if strategy.contains(" mix ") {
            format!("{strategy} (lab trial: the mixture warp's specular and uniform weights)")
        } else if strategy.contains("choose") {
            format!("{strategy} (lab trial: the measurements choose elevations or outgoing grid per level)")
        } else {
            format!("{strategy} (lab trial, incoming K x outgoing N per level)")
        };
        equal_directions(&mut md, rows, &materials, strategy, &title);
    }
    monotonicity(&mut md, rows, &materials);
    within_goal_minutes(&mut md, rows, &materials);
    per_level_table(&mut md, rows);
    md
}

/// The rows' strategies in order of first appearance.
fn strategies(rows: &[LoopRow]) -> Vec<&str> {
    let mut out: Vec<&str> = Vec::new();
    for r in rows {
        if !out.contains(&r.strategy.as_str()) {
            out.push(&r.strategy);
        }
    }
    out
}

/// One error metric of a row.
type Metric = fn(&LoopRow) -> Option<f64>;

/// The error metrics of a row, by name (`liu_log_err` is absent from csvs made before it was
/// recorded: its cells read `-` and its monotonicity row is left out).
const METRICS: [(&str, Metric); 4] = [
    ("point FLIP", |r| r.true_flip),
    ("env FLIP", |r| r.env_flip),
    ("brdf_log_err", |r| r.brdf_log_err),
    ("liu_log_err", |r| r.liu_log_err),
];

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.4}"))
}

/// The row of `material`, `strategy`, `level`.
fn row_of<'a>(rows: &'a [LoopRow], material: &str, strategy: &str, level: usize) -> Option<&'a LoopRow> {
    rows.iter()
        .find(|r| r.material == material && r.strategy == strategy && r.level == level)
}

/// Per strategy: at how many levels the reconstruction chose each prior, and per level how many
/// materials chose the PCA basis (rows from csvs that predate the column are left out).
fn priors_chosen(md: &mut String, rows: &[LoopRow]) {
    let max_level = rows.iter().map(|r| r.level).max().unwrap_or(0);
    let mut lines = Vec::new();
    for strategy in strategies(rows) {
        let at = |level: usize| {
            rows.iter()
                .filter(move |r| r.strategy == strategy && (level == 0 || r.level == level))
                .filter_map(|r| r.prior.as_deref())
        };
        let total = at(0).count();
        if total == 0 {
            continue;
        }
        let per_level: Vec<String> = (1..=max_level)
            .map(|l| format!("{} of {}", at(l).filter(|p| *p == "pca").count(), at(l).count()))
            .collect();
        lines.push(format!(
            "{strategy}: pca at {} of {total} levels (levels 1.. : {})",
            at(0).filter(|p| *p == "pca").count(),
            per_level.join(", ")
        ));
    }
    if !lines.is_empty() {
        let _ = writeln!(
            md,
            "Prior chosen per level (two lobes or the PCA basis): {}.\n",
            lines.join("; ")
        );
    }
}

/// Per strategy and level: each metric's geometric mean over the materials (the figures the ratios
/// below are made of, comparable across runs).
fn absolute_errors(md: &mut String, rows: &[LoopRow]) {
    let _ = writeln!(
        md,
        "\n## Errors (geometric mean over materials)\n\n| strategy | level | directions (max) | point FLIP | env FLIP | brdf_log_err | liu_log_err |\n|---|---|---|---|---|---|---|"
    );
    let max_level = rows.iter().map(|r| r.level).max().unwrap_or(0);
    for strategy in strategies(rows) {
        for level in 1..=max_level {
            let at: Vec<&LoopRow> = rows
                .iter()
                .filter(|r| r.strategy == strategy && r.level == level)
                .collect();
            let Some(directions) = at.iter().map(|r| r.directions).max() else {
                continue;
            };
            let cells: Vec<String> = METRICS
                .iter()
                .map(|(_, metric)| {
                    let v: Vec<f64> = at.iter().filter_map(|r| metric(r)).collect();
                    // Five decimals: brdf_log_err is ~0.001.
                    if v.is_empty() {
                        "-".into()
                    } else {
                        format!("{:.5}", geomean(&v))
                    }
                })
                .collect();
            let _ = writeln!(md, "| {strategy} | {level} | {directions} | {} |", cells.join(" | "));
        }
    }
}

/// Per level and metric: geometric mean over materials of closed loop / uniform, and the worst material.
fn equal_directions(md: &mut String, rows: &[LoopRow], materials: &[&str], strategy: &str, title: &str) {
    let _ = writeln!(
        md,
        "\n## Equal directions: {title} / uniform (geometric mean over materials; worst material)\n\n\
         Goal (issue 25): geometric mean <= 1.0 on point FLIP, env FLIP and brdf_log_err at every level, \
         no material above 1.25 (liu_log_err beside them).\n"
    );
    let _ = writeln!(
        md,
        "| level | point FLIP | worst | env FLIP | worst | brdf_log_err | worst | liu_log_err | worst | adaptive directions <= uniform |\n|---|---|---|---|---|---|---|---|---|---|"
    );
    let max_level = rows.iter().map(|r| r.level).max().unwrap_or(0);
    for level in 1..=max_level {
        let mut cells = Vec::new();
        for (_, metric) in METRICS {
            let ratios: Vec<f64> = materials
                .iter()
                .filter_map(|m| {
                    let (a, u) = (row_of(rows, m, strategy, level)?, row_of(rows, m, "uniform", level)?);
                    Some(metric(a)? / metric(u)?.max(1e-9))
                })
                .collect();
            cells.push(if ratios.is_empty() {
                "- | -".to_string()
            } else {
                format!("{:.3} | {:.3}", geomean(&ratios), quantile(ratios, 1.0))
            });
        }
        let equal = materials
            .iter()
            .all(|m| row_of(rows, m, strategy, level).is_none_or(|a| a.directions <= a.uniform_directions));
        let _ = writeln!(md, "| {level} | {} | {equal} |", cells.join(" | "));
    }
}

/// Per strategy and metric: the largest level-to-level error ratio over materials, and how many
/// steps exceed the goal's 1.05.
fn monotonicity(md: &mut String, rows: &[LoopRow], materials: &[&str]) {
    let _ = writeln!(
        md,
        "\n## Monotonicity: error of level L / level L-1 (goal <= 1.05 on every material)\n\n\
         | strategy | metric | largest ratio | where | steps above 1.05 |\n|---|---|---|---|---|"
    );
    for strategy in strategies(rows) {
        for (name, metric) in METRICS {
            let (mut worst, mut at, mut above, mut steps) = (0.0f64, String::new(), 0, 0);
            for m in materials {
                let levels: Vec<&LoopRow> = rows
                    .iter()
                    .filter(|r| r.material == *m && r.strategy == strategy)
                    .collect();
                for w in levels.windows(2) {
                    if let (Some(a), Some(b)) = (metric(w[0]), metric(w[1])) {
                        let r = b / a.max(1e-12);
                        steps += 1;
                        above += usize::from(r > 1.05);
                        if r > worst {
                            (worst, at) = (r, format!("{} level {}", short_name(m), w[1].level));
                        }
                    }
                }
            }
            if steps > 0 {
                let _ = writeln!(md, "| {strategy} | {name} | {worst:.3} | {at} | {above} of {steps} |");
            }
        }
    }
}

/// A material spec without its directory (`rgl:../x/y.bsdf` -> `y.bsdf`).
fn short_name(spec: &str) -> &str {
    spec.rsplit(['/', ':']).next().unwrap_or(spec)
}

/// A level's cells: level, directions, minutes, point FLIP, env FLIP, brdf_log_err.
fn level_cells(r: &LoopRow) -> String {
    format!(
        "{} | {} | {:.1} | {} | {} | {}",
        r.level,
        r.directions,
        r.minutes,
        fmt_opt(r.true_flip),
        fmt_opt(r.env_flip),
        fmt_opt(r.brdf_log_err)
    )
}

/// Per material: the deepest level within `GOAL_MINUTES` of instrument time, both strategies.
fn within_goal_minutes(md: &mut String, rows: &[LoopRow], materials: &[&str]) {
    let _ = writeln!(
        md,
        "\n## Within {GOAL_MINUTES} min of instrument time (deepest level that fits)\n\n\
         Goal on the real materials (issue 25): point FLIP <= 0.01 and env FLIP <= 0.02.\n\n\
         | material | strategy | level | directions | min | point FLIP | env FLIP | brdf_log_err |\n|---|---|---|---|---|---|---|---|"
    );
    for m in materials {
        for strategy in strategies(rows) {
            let best = rows
                .iter()
                .filter(|r| r.material == *m && r.strategy == strategy && r.minutes <= GOAL_MINUTES)
                .max_by_key(|r| r.level);
            if let Some(r) = best {
                let _ = writeln!(md, "| {} | {strategy} | {} |", short_name(m), level_cells(r));
            }
        }
    }
}

/// Every material, strategy and level.
fn per_level_table(md: &mut String, rows: &[LoopRow]) {
    let _ = writeln!(
        md,
        "\n## Per material and level\n\n\
         | material | strategy | level | directions | min | point FLIP | env FLIP | brdf_log_err | estimated FLIP [90%] |\n|---|---|---|---|---|---|---|---|---|"
    );
    for r in rows {
        let est = match (r.est_flip, r.est_lo, r.est_hi) {
            (Some(e), Some(lo), Some(hi)) => format!("{e:.4} [{lo:.4}, {hi:.4}]"),
            _ => "-".into(),
        };
        let strategy = match (&r.schedule, r.e_in, r.e_out) {
            (Some(s), Some(i), Some(o)) => format!("{} ({s}; e_in {i:.4}, e_out {o:.4})", r.strategy),
            (Some(s), _, _) => format!("{} ({s})", r.strategy),
            _ => r.strategy.clone(),
        };
        let _ = writeln!(
            md,
            "| {} | {strategy} | {} | {est} |",
            short_name(&r.material),
            level_cells(r)
        );
    }
}
