//! `gonio plan`: argument handling and output files. Every output is written atomically and only
//! after the plan has passed its re-simulation check.

use crate::names::parse_name;
use anyhow::{bail, Context, Result};
use gonio::encoder::ModelKind;
use gonio::plan::{estimate_for, predict, Plan, PlanConfig, PlanError, Planner, Spacing, Strategy, MAX_LEVEL};
use gonio_shared::instrument::AXES;
use std::path::PathBuf;

/// How deep a plan goes: at most one of a grid, a predictive target or a time budget. Shared by
/// `gonio plan` and `gonio scan`.
#[derive(clap::Args, Clone, Debug)]
#[group(id = "size", multiple = false)]
pub struct LevelArgs {
    /// Outgoing grid N (N x N per incoming elevation; a power of two, 2..=64). Default 16. `gonio
    /// scan`: the deepest level; alone, every level up to it is measured.
    #[arg(long)]
    pub grid: Option<usize>,
    /// Smallest level whose point-light PSNR (dB) reaches this: `gonio plan` simulates it on the
    /// estimate; `gonio scan` stops at the first level whose estimated PSNR does (closed loop).
    #[arg(long)]
    pub target_psnr: Option<f64>,
    /// Smallest level whose mean point-light FLIP is at most this: `gonio plan` simulates it on the
    /// estimate; `gonio scan` stops at the first level whose estimated FLIP is (closed loop;
    /// its default without a rule: 0.01).
    #[arg(long)]
    pub target_flip: Option<f64>,
    /// Deepest level whose whole plan fits this time: 90, 90s, 15m, 2h, 1h30m (`gonio scan`:
    /// the levels are measured one by one up to it).
    #[arg(long, value_parser = parse_duration)]
    pub time_budget: Option<f64>,
}

#[derive(clap::Args)]
#[command(group = clap::ArgGroup::new("input").args(["photo", "material_model"]).required(true))]
pub struct PlanArgs {
    /// A capture photo of the sample (examples/capture.toml; EXR linear, or PNG): the encoder
    /// estimates the material from it (`encoder::photo`).
    #[arg(value_name = "IMAGE")]
    pub photo: Option<PathBuf>,
    /// The encoder model for IMAGE.
    #[arg(long, value_parser = parse_name::<ModelKind>(), default_value_t = ModelKind::Ggx, requires = "photo")]
    pub model: ModelKind,
    /// The estimated material as an analytic spec (e.g. "ggx:alpha=0.1,diffuse=0.2"); other specs
    /// (nbrdf:, merl:, rgl:) are fitted with GGX first.
    #[arg(long = "material-model", value_name = "SPEC")]
    pub material_model: Option<String>,
    /// Instrument file (default: the shipped examples/gonio.toml).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    #[command(flatten)]
    pub level: LevelArgs,
    /// Deepest level the target and budget modes consider (a power of two).
    #[arg(long, default_value_t = 16)]
    pub max_grid: usize,
    #[arg(long, value_parser = parse_name::<Strategy>(), default_value_t = Strategy::Auto)]
    pub strategy: Strategy,
    #[arg(long, value_parser = parse_name::<Spacing>(), default_value_t = Spacing::Angle)]
    pub spacing: Spacing,
    /// Number of incoming elevations.
    #[arg(long, default_value_t = 8)]
    pub incoming: usize,
    /// Plan file (postcard wire frames, what the firmware consumes).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Readable copy with per-direction axis targets and times.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Seconds from "90" (plain seconds) or a humantime duration: "90s", "15m", "2h", "1h30m".
pub fn parse_duration(s: &str) -> Result<f64, String> {
    let s = s.trim();
    let seconds = match s.parse::<f64>() {
        Ok(v) => v,
        Err(_) => humantime::parse_duration(s)
            .map_err(|e| format!("'{s}' is not a duration (e.g. 90s, 15m, 2h, 1h30m): {e}"))?
            .as_secs_f64(),
    };
    if !(seconds.is_finite() && seconds > 0.0) {
        return Err(format!("'{s}' is not a positive duration (e.g. 90s, 15m, 2h, 1h30m)"));
    }
    Ok(seconds)
}

fn level_of(n: usize, what: &str) -> Result<usize> {
    if n < 2 || !n.is_power_of_two() || n.trailing_zeros() as usize > MAX_LEVEL {
        bail!("{what} {n} must be a power of two from 2 to {}", 1usize << MAX_LEVEL);
    }
    Ok(n.trailing_zeros() as usize)
}

pub fn run_plan(args: PlanArgs) -> Result<()> {
    let instrument = gonio::instrument::load_or_default(args.instrument.as_deref())?;
    let t_estimate = std::time::Instant::now();
    let estimate = match (&args.photo, &args.material_model) {
        (Some(photo), _) => {
            // The photo error names the file already.
            let e = gonio::encoder::photo::estimate_from_photo(photo, args.model)?;
            println!(
                "estimate from {} ({} model): {} in {:.2} s",
                photo.display(),
                args.model.name(),
                e.spec(),
                t_estimate.elapsed().as_secs_f64()
            );
            e.estimate
        }
        (None, Some(spec)) => estimate_for(spec).context("--material-model")?,
        (None, None) => bail!("give a photo (IMAGE) or --material-model"),
    };
    let targeted =
        args.level.target_psnr.is_some() || args.level.target_flip.is_some() || args.level.time_budget.is_some();
    let max_level = if targeted {
        level_of(args.max_grid, "--max-grid")?
    } else {
        level_of(args.level.grid.unwrap_or(16), "--grid")?
    };
    if let Some(t) = args.level.target_flip {
        if !(t > 0.0 && t < 1.0) {
            bail!("--target-flip {t} must be in (0, 1)");
        }
    }
    if let Some(t) = args.level.target_psnr {
        if !t.is_finite() {
            bail!("--target-psnr must be finite");
        }
    }
    let config = PlanConfig {
        strategy: args.strategy,
        spacing: args.spacing,
        k: args.incoming,
        grids: gonio::plan::square_grids(max_level),
        incoming: Vec::new(),
    };
    let planner = Planner::new(instrument, estimate.clone())?;
    let t0 = std::time::Instant::now();
    let plan = planner.plan(&config)?;
    let (level, rule) = if let Some(budget) = args.level.time_budget {
        let l = plan.level_within_budget(budget).with_context(|| {
            format!(
                "--time-budget {budget:.0} s: even the first level needs {:.0} s",
                plan.levels[0].cumulative_seconds
            )
        })?;
        (l, format!("time budget {budget:.0} s"))
    } else if args.level.target_psnr.is_some() || args.level.target_flip.is_some() {
        let chosen = predict::predictive_level(&plan, &estimate, |c| {
            args.level.target_psnr.is_none_or(|t| c.psnr >= t) && args.level.target_flip.is_none_or(|t| c.flip <= t)
        })?;
        match chosen {
            Some(l) => (l, "predictive (simulated on the estimate)".to_string()),
            None => {
                eprintln!(
                    "warning: no level up to --max-grid {} meets the target; using the deepest",
                    args.max_grid
                );
                (max_level, "predictive: target not met, deepest level".to_string())
            }
        }
    } else {
        (max_level, "grid".to_string())
    };
    let plan = plan.truncate(level);
    let plan_seconds = t0.elapsed().as_secs_f64();
    let wire = plan.wire();
    let bytes = gonio::plan::file::encode_plan(&wire)?;
    let replay = plan.check_encoded(&instrument, &bytes)?;
    let summary = plan.summary();
    // Everything is computed before the first write, so a failure leaves no output behind.
    let json = match &args.json {
        Some(_) => Some(plan_json(&plan, &estimate.model.to_spec(), &rule, replay)?),
        None => None,
    };
    gonio::plan::file::write_plan_file(&args.output, &wire)?;
    if let (Some(path), Some(json)) = (&args.json, json) {
        gonio::fsio::write_bytes_atomically(path, json.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let l = plan.levels.last().context("empty plan")?;
    println!(
        "{} directions ({}x{} x {} incoming, {} strategy, {} spacing; {rule}); dropped: {} below horizon, {} blocked, {} limits; nudged {}",
        wire.len(),
        l.n,
        l.m,
        plan.thetas.len(),
        plan.strategy_label(),
        config.spacing,
        plan.dropped.below_horizon,
        plan.dropped.blocked,
        plan.dropped.limit,
        plan.dropped.nudged
    );
    println!(
        "time {:.1} min (motion {:.1} min); raster order {:.1} min (motion {:.1}); motion lower bound {:.1} min; raster/optimised motion {:.2}x, optimised/bound {:.3}x; planned in {:.2} s",
        summary.total_seconds / 60.0,
        summary.motion_seconds / 60.0,
        summary.raster_total_seconds / 60.0,
        summary.raster_motion_seconds / 60.0,
        summary.lower_bound_motion_seconds / 60.0,
        summary.raster_motion_seconds / summary.motion_seconds,
        summary.motion_seconds / summary.lower_bound_motion_seconds,
        plan_seconds
    );
    Ok(())
}

fn plan_json(plan: &Plan, estimate: &str, rule: &str, replay_motion: f64) -> Result<String, PlanError> {
    let s = plan.summary();
    let directions: Vec<serde_json::Value> = plan
        .directions
        .iter()
        .map(|d| {
            let w = d.wire();
            let axes: serde_json::Map<String, serde_json::Value> = AXES
                .iter()
                .map(|a| (format!("{}_deg", a.name()), d.pose.get(*a).to_degrees().into()))
                .collect();
            serde_json::json!({
                "level": d.level,
                "theta_i_deg": (w.theta_i as f64).to_degrees(),
                "phi_i_deg": (w.phi_i as f64).to_degrees(),
                "theta_o_deg": (w.theta_o as f64).to_degrees(),
                "phi_o_deg": (w.phi_o as f64).to_degrees(),
                "axes": axes,
                "move_seconds": d.move_seconds,
                "seconds": d.seconds,
            })
        })
        .collect();
    let v = serde_json::json!({
        "estimate": estimate,
        "strategy": plan.config.strategy.to_string(),
        "warp": plan.warp.to_string(),
        "spacing": plan.config.spacing.to_string(),
        "incoming_theta_deg": plan.thetas.iter().map(|t| t.to_degrees()).collect::<Vec<_>>(),
        "rule": rule,
        "levels": plan.levels,
        "dropped": plan.dropped,
        "total_seconds": s.total_seconds,
        "motion_seconds": s.motion_seconds,
        "raster_total_seconds": s.raster_total_seconds,
        "raster_motion_seconds": s.raster_motion_seconds,
        "lower_bound_motion_seconds": s.lower_bound_motion_seconds,
        "replayed_motion_seconds_f32": replay_motion,
        "directions": directions,
    });
    serde_json::to_string_pretty(&v).map_err(|e| PlanError::Invalid(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::parse_duration;

    #[test]
    fn durations() {
        assert_eq!(parse_duration("90"), Ok(90.0));
        assert_eq!(parse_duration("90s"), Ok(90.0));
        assert_eq!(parse_duration("15m"), Ok(900.0));
        assert_eq!(parse_duration("1h30m"), Ok(5400.0));
        assert!(parse_duration("").is_err());
        assert!(parse_duration("5x").is_err());
        assert!(parse_duration("0s").is_err());
        assert!(parse_duration("m").is_err());
        assert!(parse_duration("-5").is_err());
        assert_eq!(parse_duration("2h 5s"), Ok(7205.0));
    }
}
