//! The `nielsen2015` strategy of the trade-off report (issue 28): the data-driven peer
//! (`plan::nielsen`) at the uniform grid's direction counts (its rows take those levels' numbers,
//! so they compare level by level) and at Nielsen's own small counts (`SMALL_COUNTS`, level 0),
//! measured, reconstructed and scored exactly as every other strategy. Each set is ordered and
//! timed for motion as a plan is (`plan::order`).

use super::{TradeRow, TradeStrategy, TradeoffConfig};
use crate::plan::nielsen::{self, basis::Basis, select, Design, RIDGE};
use crate::plan::predict::{log_err_over, score, Scorer};
use crate::plan::{ggx_estimate, PlanConfig, PlanError, Planner, Strategy};
use glam::DVec3;
use gonio::brdf::Material;
use gonio::plan::order::{optimise, simulate, Candidates};
use gonio::render::Image;
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::kinematics::Kinematics;
use std::fmt::Write as _;
use std::time::Instant;

/// The strategy's name in the csv.
pub const NAME: &str = "nielsen2015";

/// Nielsen et al.'s own small counts, below the uniform grid's 2x2 level.
pub const SMALL_COUNTS: [usize; 4] = [5, 10, 20, 40];

/// One selected set: the level it compares with (0: a small count), its ridge system, its time.
struct PeerSet {
    level: usize,
    design: Design,
    gonio_seconds: f64,
    select_seconds: f64,
}

/// The basis and every count's selected set, built (or read from the cache) once per run.
pub struct Peer {
    basis: Basis,
    sets: Vec<PeerSet>,
}

impl Peer {
    pub fn new(cfg: &TradeoffConfig, instrument: &InstrumentConfig<f64>) -> Result<Self, PlanError> {
        let basis = nielsen::training_basis().map_err(PlanError::Invalid)?;
        let kin = Kinematics::new(*instrument).map_err(|e| PlanError::Invalid(format!("instrument: {e:?}")))?;
        // The uniform grid's cumulative counts at the run's levels.
        let uniform = Planner::new(*instrument, ggx_estimate(0.2, 0.1))?.plan(&PlanConfig {
            strategy: Strategy::Uniform,
            spacing: cfg.spacing,
            k: cfg.k,
            grids: cfg.grids.clone(),
            incoming: Vec::new(),
        })?;
        let mut counts: Vec<(usize, usize)> = SMALL_COUNTS
            .iter()
            .filter(|&&n| uniform.levels.first().is_none_or(|l| n < l.cumulative_directions))
            .map(|&n| (0, n))
            .collect();
        counts.extend(uniform.levels.iter().map(|l| (l.level, l.cumulative_directions)));
        let candidates = select::reachable_bins(&basis, &kin);
        let tag = selection_tag(&basis, instrument);
        let mut sets = Vec::new();
        for (level, n) in counts {
            let t0 = Instant::now();
            let bins = cached_selection(&basis, &candidates, n, &tag)?;
            let select_seconds = t0.elapsed().as_secs_f64();
            let design = Design::new(&basis, bins, RIDGE).map_err(PlanError::Invalid)?;
            let gonio_seconds = timed(&kin, &design.pairs)?;
            sets.push(PeerSet {
                level,
                design,
                gonio_seconds,
                select_seconds,
            });
        }
        Ok(Self { basis, sets })
    }

    /// Every set's row for one material (`truths`: its point-light and environment renders).
    #[allow(clippy::too_many_arguments)]
    pub fn rows(
        &self,
        spec: &str,
        truth: &dyn Material,
        scorer: &mut Scorer,
        (truth_img, truth_env): (&Image, &Image),
        liu: &[(DVec3, DVec3)],
        k: usize,
        progress: &dyn Fn(&str),
    ) -> Result<Vec<TradeRow>, PlanError> {
        let mut rows = Vec::new();
        for set in &self.sets {
            let values: Vec<DVec3> = set.design.pairs.iter().map(|&(wi, wo)| truth.eval(wi, wo)).collect();
            let t0 = Instant::now();
            let rec = set.design.fit(&self.basis, &values);
            let fit_seconds = t0.elapsed().as_secs_f64();
            let brdf_log_err = scorer.log_err(truth, &rec);
            let liu_log_err = log_err_over(liu, truth, &rec);
            let point = score(truth_img, &scorer.render(Box::new(rec.clone())))?;
            let env_img = scorer
                .render_env(Box::new(rec), spec)
                .ok_or_else(|| PlanError::Invalid("no environment scene".into()))?;
            let env = score(truth_env, &env_img)?;
            let n = set.design.bins.len();
            progress(&format!(
                "{} {NAME} {n} directions: {:.1} min, flip {:.4}, flip_env {:.4}, brdf_log_err {:.4}, fit {:.0} ms",
                super::short(spec),
                set.gonio_seconds / 60.0,
                point.flip,
                env.flip,
                brdf_log_err,
                fit_seconds * 1e3
            ));
            rows.push(TradeRow {
                material: spec.to_string(),
                strategy: NAME.to_string(),
                estimate: "-".into(),
                warp: NAME.to_string(),
                incoming: k,
                level: set.level,
                grid_n: 0,
                grid_m: 0,
                directions: n,
                gonio_seconds: set.gonio_seconds,
                rmse: point.rmse,
                psnr: point.psnr,
                flip: point.flip,
                rmse_env: env.rmse,
                psnr_env: env.psnr,
                flip_env: env.flip,
                brdf_log_err,
                liu_log_err,
                estimate_seconds: 0.0,
                plan_seconds: set.select_seconds,
                host_seconds: set.select_seconds + fit_seconds,
                paper_psnr_env: None,
            });
        }
        Ok(rows)
    }
}

/// The peer's design of `n` directions (the `nielsen2015` rows' set at that count) and the
/// instrument seconds of measuring it from the rest pose.
pub fn design(instrument: &InstrumentConfig<f64>, n: usize) -> Result<(Vec<(DVec3, DVec3)>, f64), PlanError> {
    let basis = nielsen::training_basis().map_err(PlanError::Invalid)?;
    let kin = Kinematics::new(*instrument).map_err(|e| PlanError::Invalid(format!("instrument: {e:?}")))?;
    let candidates = select::reachable_bins(&basis, &kin);
    let bins = cached_selection(&basis, &candidates, n, &selection_tag(&basis, instrument))?;
    let design = Design::new(&basis, bins, RIDGE).map_err(PlanError::Invalid)?;
    let seconds = timed(&kin, &design.pairs)?;
    Ok((design.pairs, seconds))
}

/// What a cached selection was made for (a selection made for anything else is made again).
fn selection_tag(basis: &Basis, instrument: &InstrumentConfig<f64>) -> String {
    format!("k={} ridge={RIDGE} instrument={instrument:?}", basis.k())
}

/// The selection for `n` from the cache (`nielsen::cache_dir`), else computed and cached.
fn cached_selection(basis: &Basis, candidates: &[usize], n: usize, tag: &str) -> Result<Vec<usize>, PlanError> {
    let path = nielsen::cache_dir().join(format!("nielsen-select-{n}.json"));
    if let Ok(text) = std::fs::read_to_string(&path) {
        if let Ok(v) = serde_json::from_str::<serde_json::Value>(&text) {
            if v["tag"] == tag {
                if let Some(bins) = v["bins"].as_array() {
                    let bins: Vec<usize> = bins.iter().filter_map(|b| b.as_u64().map(|b| b as usize)).collect();
                    if bins.len() == n.min(candidates.len()) {
                        return Ok(bins);
                    }
                }
            }
        }
    }
    let bins = select::select(basis, candidates, n);
    let text = serde_json::json!({ "tag": tag, "bins": bins }).to_string();
    let bad = |e: std::io::Error| PlanError::Invalid(format!("{}: {e}", path.display()));
    std::fs::create_dir_all(nielsen::cache_dir()).map_err(bad)?;
    crate::plan::report::write(
        &nielsen::cache_dir(),
        &format!("nielsen-select-{n}.json"),
        text.as_bytes(),
    )?;
    Ok(bins)
}

/// Instrument time of measuring `pairs` in an optimised order from the rest pose: moves (replayed
/// as the firmware's IK would) plus settle and exposure per direction, as a plan is timed.
fn timed(kin: &Kinematics<f64>, pairs: &[(DVec3, DVec3)]) -> Result<f64, PlanError> {
    let cfg = kin.config();
    let rest = kin.rest_pose();
    let items = pairs
        .iter()
        .map(|&(wi, wo)| Candidates::of(kin, wi, wo))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| PlanError::Invalid(format!("a selected direction is unreachable: {e:?}")))?;
    let ordered = optimise(cfg, &Candidates(vec![rest]), &items);
    let order: Vec<(DVec3, DVec3)> = ordered.perm.iter().map(|&i| pairs[i]).collect();
    let (_, moves) = simulate(kin, rest, &order)
        .map_err(|(i, e)| PlanError::Invalid(format!("direction {i} of the selected set: {e:?}")))?;
    let per_direction = cfg.settle_ms as f64 * 1e-3 + cfg.exposure_us as f64 * 1e-6;
    Ok(moves.iter().sum::<f64>() + pairs.len() as f64 * per_direction)
}

/// Geometric mean (floored at `PLOT_FLOOR`) of a metric over rows.
fn gmean(rows: &[&TradeRow], f: fn(&TradeRow) -> f64) -> f64 {
    let n = rows.len().max(1) as f64;
    (rows.iter().map(|r| f(r).max(super::PLOT_FLOOR).ln()).sum::<f64>() / n).exp()
}

/// The side-by-side table: per direction count (the peer's levels; each other strategy at the
/// level with the same number), geometric means over materials of every metric.
pub fn markdown(cfg: &TradeoffConfig, rows: &[TradeRow]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\n## {NAME} side by side (geometric means over the {} materials)\n\n\
         Levels 1..: each strategy at the uniform grid's level (at most the same number of directions); \
         level 0: Nielsen et al.'s own small counts (the peer alone). `liu_log_err`: Liu et al. 2023, 25,000 \
         random pairs (seed {}).\n\n\
         | level | directions | strategy | brdf_log_err | liu_log_err | FLIP | FLIP env | gonio min |\n|---|---|---|---|---|---|---|---|",
        cfg.materials.len(),
        super::liu::SEED
    );
    let mut levels: Vec<(usize, usize)> = rows
        .iter()
        .filter(|r| r.strategy == NAME)
        .map(|r| (r.level, r.directions))
        .collect();
    levels.sort_unstable();
    levels.dedup();
    for (level, dirs) in levels {
        let mut means: Vec<(String, [f64; 4])> = Vec::new();
        for st in &cfg.strategies {
            let name = st.to_string();
            let mine: Vec<&TradeRow> = rows
                .iter()
                .filter(|r| r.strategy == name && r.level == level && (level > 0 || r.directions == dirs))
                .collect();
            if mine.is_empty() {
                continue;
            }
            let n = mine.iter().map(|r| r.directions).max().unwrap_or(0);
            let m = [
                gmean(&mine, |r| r.brdf_log_err),
                gmean(&mine, |r| r.liu_log_err),
                gmean(&mine, |r| r.flip),
                gmean(&mine, |r| r.flip_env),
            ];
            let _ = writeln!(
                s,
                "| {level} | {n} | {name} | {:.5} | {:.5} | {:.4} | {:.4} | {:.1} |",
                m[0],
                m[1],
                m[2],
                m[3],
                gmean(&mine, |r| r.gonio_seconds / 60.0)
            );
            means.push((name, m));
        }
        // Below 1: the product's default beats the peer at this count.
        let of = |name: &str| means.iter().find(|(n, _)| n == name).map(|(_, m)| *m);
        if let (Some(a), Some(p)) = (of(&TradeStrategy::Adaptive.to_string()), of(NAME)) {
            let r: Vec<f64> = a.iter().zip(&p).map(|(a, p)| a / p).collect();
            let _ = writeln!(
                s,
                "| {level} | | adaptive / {NAME} | {:.2} | {:.2} | {:.2} | {:.2} | |",
                r[0], r[1], r[2], r[3]
            );
        }
    }
    s
}
