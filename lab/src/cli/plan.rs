//! `gonio-lab plan-report` and `gonio-lab tradeoff`: argument handling over
//! `gonio_lab::plan::{report, tradeoff}`.

use anyhow::{bail, Context, Result};
use gonio::plan::{PlanError, MAX_LEVEL};
use gonio_lab::plan::report::{self, ReportConfig};
use gonio_lab::plan::{tradeoff, trials};
use std::path::{Path, PathBuf};

fn level_of(n: usize, what: &str) -> Result<usize> {
    if n < 2 || !n.is_power_of_two() || n.trailing_zeros() as usize > MAX_LEVEL {
        bail!("{what} {n} must be a power of two from 2 to {}", 1usize << MAX_LEVEL);
    }
    Ok(n.trailing_zeros() as usize)
}

#[derive(clap::Args)]
pub struct PlanReportArgs {
    /// Material specs (repeatable); default: four MERL fits and two analytic lobes.
    #[arg(long = "material")]
    pub materials: Vec<String>,
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Finest grid (power of two). 16 takes minutes on 2 cores; 32 costs ~4x the planning per level.
    #[arg(long, default_value_t = 16)]
    pub max_grid: usize,
    #[arg(long, default_value_t = 8)]
    pub incoming: usize,
    /// Render side in pixels.
    #[arg(long, default_value_t = 128)]
    pub size: usize,
    #[arg(short, long)]
    pub output: PathBuf,
}

#[derive(clap::Args)]
pub struct TradeoffArgs {
    /// Material specs (repeatable); default: four MERL fits and two analytic lobes.
    #[arg(long = "material", value_name = "SPEC")]
    pub materials: Vec<String>,
    /// A named run: table1 (the paper's Table 1), heldout (the encoder's 15 held-out MERL materials),
    /// training (14 MERL materials the encoder trained on, where the planner's constants are chosen)
    /// or training-pool (26 further training materials, mostly sharp: metals, phenolics, paints).
    #[arg(long, value_enum, conflicts_with = "materials")]
    pub preset: Option<tradeoff::Preset>,
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Nested levels, N x M outgoing per incoming theta, each dividing the next: e.g. 2x2,4x4,8x4,8x8.
    /// Default 2x2,4x4,8x8,16x16 (table1: 2x2,4x4,8x4,8x8).
    #[arg(long, value_parser = tradeoff::parse_grids)]
    pub levels: Option<tradeoff::Grids>,
    /// Strategies (repeatable); default all four.
    #[arg(long = "strategy", value_enum)]
    pub strategies: Vec<tradeoff::TradeStrategy>,
    #[arg(long, default_value_t = 8)]
    pub incoming: usize,
    /// What the reconstruction interpolates on top of: Lambert plus two GGX lobes with a bounded
    /// Fresnel rise fitted to each level's own measurements (two-lobes), the same without the rise
    /// (two-lobes-plain), two-lobes with the Lambert term under the darkest measurement
    /// (two-lobes-capped, a trial: docs/tradeoff/README.md), two-lobes fitted to the capture photo's
    /// pixels too (two-lobes-photo, a trial: the photo shares the point-light score's light), one
    /// lobe (fit), or nothing (none). The same for every strategy.
    #[arg(
        long,
        default_value = trials::PRIOR_NAMES[0],
        value_parser = clap::builder::PossibleValuesParser::new(trials::PRIOR_NAMES)
    )]
    pub prior: String,
    /// Point-light render side in pixels (default 128; table1: 256).
    #[arg(long)]
    pub size: Option<usize>,
    /// Environment-lit scene (its environment map is read relative to it).
    #[arg(long, default_value = DEFAULT_ENV_SCENE)]
    pub env_scene: PathBuf,
    /// Environment render side in pixels.
    #[arg(long, default_value_t = 256)]
    pub env_size: usize,
    /// Environment samples per pixel: unused since the score renders by quadrature (`render::quadrature`); kept for old command lines.
    #[arg(long, default_value_t = 64)]
    pub env_spp: u32,
    /// Also write DIR/renders/MATERIAL.png per material: the truth's renders on the first row, then one
    /// row per strategy with each level's point-light render, then each level's environment render
    /// (MATERIAL is the spec as a file name; a second spec with the same name gets MATERIAL-2).
    #[arg(long)]
    pub renders: bool,
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run_plan_report(args: PlanReportArgs) -> Result<()> {
    let instrument = gonio::instrument::load_or_default(args.instrument.as_deref())?;
    let max_level = level_of(args.max_grid, "--max-grid")?;
    if !(16..=1024).contains(&args.size) {
        bail!("--size {} must be in 16..=1024", args.size);
    }
    let mut cfg = ReportConfig {
        max_level,
        k: args.incoming,
        size: args.size,
        ..ReportConfig::default()
    };
    if !args.materials.is_empty() {
        cfg.materials = args.materials;
    }
    let bar = indicatif::ProgressBar::new((cfg.materials.len() * 4) as u64);
    with_progress(bar, |progress| report::run(&cfg, &instrument, &args.output, progress))
}

/// Run a report with `bar` ticking once per line it reports (each printed above the bar), then
/// print the report's markdown.
fn with_progress(
    bar: indicatif::ProgressBar,
    run: impl FnOnce(&dyn Fn(&str)) -> Result<String, PlanError>,
) -> Result<()> {
    let md = run(&|line| {
        bar.println(line);
        bar.inc(1);
    })?;
    bar.finish_and_clear();
    print!("{md}");
    Ok(())
}

pub fn run_tradeoff(args: TradeoffArgs) -> Result<()> {
    let instrument = gonio::instrument::load_or_default(args.instrument.as_deref())?;
    let mut cfg = match args.preset {
        Some(p) => tradeoff::TradeoffConfig::preset(p),
        None => tradeoff::TradeoffConfig::default(),
    };
    if !args.materials.is_empty() {
        cfg.materials = args.materials;
    }
    if let Some(levels) = args.levels {
        cfg.grids = levels.0;
    }
    if !args.strategies.is_empty() {
        cfg.strategies = args.strategies;
        cfg.strategies.dedup();
    }
    cfg.k = args.incoming;
    cfg.prior = args.prior;
    if let Some(size) = args.size {
        cfg.size = size;
    }
    cfg.env_size = args.env_size;
    cfg.env_spp = args.env_spp;
    cfg.renders = args.renders;
    for (name, v) in [("--size", cfg.size), ("--env-size", cfg.env_size)] {
        if !(16..=1024).contains(&v) {
            bail!("{name} {v} must be in 16..=1024");
        }
    }
    if !(1..=4096).contains(&cfg.env_spp) {
        bail!("--env-spp {} must be in 1..=4096", cfg.env_spp);
    }
    let env = gonio::render::Scene::load(&args.env_scene).with_context(|| "--env-scene".to_string())?;
    if env.environment.is_none() {
        bail!(
            "--env-scene {}: the scene has no environment light",
            args.env_scene.display()
        );
    }
    let steps = cfg.materials.len() * cfg.strategies.len() * cfg.grids.len();
    let bar = indicatif::ProgressBar::new(steps as u64).with_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} levels scored, {elapsed} (eta {eta})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    with_progress(bar, |progress| {
        tradeoff::run(&cfg, &instrument, env, &args.output, progress)
    })
}

/// `closed-loop`'s finest grid unless given (its regenerate line names others).
const DEFAULT_MAX_GRID: usize = 16;
/// The environment-lit scene the lab's commands score in unless given.
pub const DEFAULT_ENV_SCENE: &str = "examples/sphere-sky.toml";

#[derive(clap::Args)]
pub struct ClosedLoopArgs {
    /// Material set (training: where the estimator's constants are chosen).
    #[arg(long, value_enum)]
    pub preset: tradeoff::closed_loop::LoopPreset,
    /// Material specs instead of the preset's (repeatable).
    #[arg(long = "material")]
    pub materials: Vec<String>,
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Finest grid (power of two).
    #[arg(long, default_value_t = DEFAULT_MAX_GRID)]
    pub max_grid: usize,
    /// Summarise the rows of an earlier run's closed-loop.csv (with the product's current
    /// constants) instead of running the loop again.
    #[arg(long, value_name = "CSV")]
    pub rows: Option<PathBuf>,
    /// The environment-lit scene the env FLIP is scored in (noise-free quadrature render).
    #[arg(long, default_value = DEFAULT_ENV_SCENE)]
    pub env_scene: PathBuf,
    /// Lab trials beside the loop and the uniform grid (repeatable): `reseed` (the default when
    /// none is given), `confirm` (the lobe-following plan kept only if level 1's fit confirms a
    /// sharp lobe), `schedule:KxN,KxN,...` (incoming elevations x outgoing grid per level),
    /// `choose:C,C,...` (the measurements choose elevations or outgoing grid per level, one row
    /// set per constant C; `inf`: never elevations), `none`.
    #[arg(long = "trial")]
    pub trials: Vec<String>,
    #[arg(short, long)]
    pub output: PathBuf,
}

/// The options of a `closed-loop` command line that shape its rows, as its report's regenerate
/// line repeats them (defaults left out).
fn regenerate_options(args: &ClosedLoopArgs) -> String {
    let mut given: Vec<String> = args.materials.iter().map(|m| format!(" --material {m}")).collect();
    given.extend(
        args.instrument
            .as_ref()
            .map(|p| format!(" --instrument {}", p.display())),
    );
    if args.max_grid != DEFAULT_MAX_GRID {
        given.push(format!(" --max-grid {}", args.max_grid));
    }
    if args.env_scene != Path::new(DEFAULT_ENV_SCENE) {
        given.push(format!(" --env-scene {}", args.env_scene.display()));
    }
    given.extend(args.trials.iter().map(|t| format!(" --trial {t}")));
    given.concat()
}

pub fn run_closed_loop(args: ClosedLoopArgs) -> Result<()> {
    let instrument = gonio::instrument::load_or_default(args.instrument.as_deref())?;
    let max_level = level_of(args.max_grid, "--max-grid")?;
    let options = regenerate_options(&args);
    let materials = if args.materials.is_empty() {
        args.preset.materials()
    } else {
        args.materials
    };
    let trials = if args.trials.is_empty() {
        vec![tradeoff::closed_loop::Trial::Reseed]
    } else {
        args.trials
            .iter()
            .filter(|t| t.as_str() != "none")
            .map(|t| tradeoff::closed_loop::Trial::parse(t).map_err(anyhow::Error::msg))
            .collect::<Result<Vec<_>>>()?
    };
    let source = match args.rows.as_deref() {
        Some(csv) => tradeoff::closed_loop::RowSource::Csv(csv),
        None => tradeoff::closed_loop::RowSource::Simulate {
            materials: &materials,
            instrument: &instrument,
            max_level,
            env_scene: Box::new(
                gonio::render::Scene::load(&args.env_scene).with_context(|| "--env-scene".to_string())?,
            ),
            trials: &trials,
        },
    };
    let bar = indicatif::ProgressBar::new(materials.len() as u64);
    with_progress(bar, |progress| {
        tradeoff::closed_loop::run(args.preset, source, &args.output, &options, progress)
    })
}

#[derive(clap::Args)]
pub struct StopReplayArgs {
    /// The training run's closed-loop.csv: the estimator's ratio is chosen on its rows.
    #[arg(long, value_name = "CSV")]
    pub train: PathBuf,
    /// The rows' strategy (`adaptive`, or a trial's, e.g. `adaptive grids`).
    #[arg(long)]
    pub strategy: String,
    /// The quantile of true / change FLIP used as the ratio (0.5: the product's rule).
    #[arg(long, default_value_t = 0.5)]
    pub quantile: f64,
    /// The quantile of level 1's true / split change FLIP used as its ratio (0.9: the product's rule).
    #[arg(long, default_value_t = 0.9)]
    pub first_quantile: f64,
    /// Other runs' closed-loop.csv to replay on (the training run is replayed first).
    #[arg(value_name = "CSV")]
    pub runs: Vec<PathBuf>,
}

pub fn run_stop_replay(args: StopReplayArgs) -> Result<()> {
    for (name, q) in [("--quantile", args.quantile), ("--first-quantile", args.first_quantile)] {
        if !(q > 0.0 && q < 1.0) {
            bail!("{name} {q} must be in (0, 1)");
        }
    }
    let read = |p: &PathBuf| tradeoff::closed_loop::read_rows(p).map(|rows| (p.display().to_string(), rows));
    let train = read(&args.train)?;
    let mut runs = vec![train.clone()];
    for p in &args.runs {
        runs.push(read(p)?);
    }
    let md = tradeoff::closed_loop::stop_replay(&train.1, &args.strategy, (args.quantile, args.first_quantile), &runs)
        .map_err(anyhow::Error::msg)?;
    print!("{md}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cmd {
        #[command(flatten)]
        args: ClosedLoopArgs,
    }

    fn options(line: &[&str]) -> String {
        let cmd = Cmd::try_parse_from(["closed-loop"].iter().chain(line)).expect("parses");
        regenerate_options(&cmd.args)
    }

    /// A report regenerated from its own line must see the same rows: every option that shapes
    /// them is repeated, and defaults are left out.
    #[test]
    fn the_regenerate_line_repeats_the_options_that_shape_the_rows() {
        assert_eq!(options(&["--preset", "real", "-o", "d"]), "");
        let line = options(&[
            "--preset",
            "real",
            "--max-grid",
            "32",
            "--env-scene",
            "other.toml",
            "--instrument",
            "i.toml",
            "--material",
            "nbrdf:pvc",
            "--trial",
            "none",
            "--rows",
            "old.csv",
            "-o",
            "d",
        ]);
        assert_eq!(
            line,
            " --material nbrdf:pvc --instrument i.toml --max-grid 32 --env-scene other.toml --trial none"
        );
        assert_eq!(options(&["--preset", "real", "--max-grid", "16", "-o", "d"]), "");
    }
}
