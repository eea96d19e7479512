//! `gonio-lab peer`: the `nielsen2015` side-by-side run (issue 28) in one command: the trade-off
//! report of `adaptive`, `uniform` and `nielsen2015` on the encoder's held-out MERL materials and
//! on the three real RGL measurements, into OUTPUT/heldout and OUTPUT/real.

use anyhow::{bail, Context, Result};
use gonio_lab::plan::tradeoff::{self, Preset, TradeStrategy, TradeoffConfig, REAL_MATERIALS};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct PeerArgs {
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Environment-lit scene (its environment map is read relative to it).
    #[arg(long, default_value = super::plan::DEFAULT_ENV_SCENE)]
    pub env_scene: PathBuf,
    /// Environment render side in pixels.
    #[arg(long, default_value_t = 128)]
    pub env_size: usize,
    /// Nested levels instead of the default 2x2,4x4,8x8,16x16 (e.g. 2x2,4x4,8x8 to fit a time budget).
    #[arg(long, value_parser = tradeoff::parse_grids)]
    pub levels: Option<tradeoff::Grids>,
    /// Only the held-out MERL run, or only the real one.
    #[arg(long, value_parser = ["heldout", "real"])]
    pub only: Option<String>,
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run_peer(args: PeerArgs) -> Result<()> {
    let instrument = gonio::instrument::load_or_default(args.instrument.as_deref())?;
    if !(16..=1024).contains(&args.env_size) {
        bail!("--env-size {} must be in 16..=1024", args.env_size);
    }
    let strategies = vec![
        TradeStrategy::Adaptive,
        TradeStrategy::Uniform,
        TradeStrategy::Nielsen2015,
    ];
    let grids = args.levels.map_or_else(|| TradeoffConfig::default().grids, |g| g.0);
    let runs = [
        (
            "heldout",
            TradeoffConfig {
                strategies: strategies.clone(),
                grids: grids.clone(),
                env_size: args.env_size,
                ..TradeoffConfig::preset(Preset::Heldout)
            },
        ),
        (
            "real",
            TradeoffConfig {
                materials: REAL_MATERIALS.iter().map(|s| s.to_string()).collect(),
                strategies,
                grids,
                env_size: args.env_size,
                ..TradeoffConfig::default()
            },
        ),
    ];
    for (name, cfg) in runs {
        if args.only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        let env = gonio::render::Scene::load(&args.env_scene).with_context(|| "--env-scene".to_string())?;
        let dir = args.output.join(name);
        eprintln!("== {name}: {} materials -> {}", cfg.materials.len(), dir.display());
        let md = tradeoff::run(&cfg, &instrument, env, &dir, &|line| eprintln!("{line}"))?;
        // The command line as run, so a folder made with --only/--env-size/--levels says so.
        let command: Vec<String> = std::env::args().skip(1).collect();
        let note = format!(
            "\nRegenerate this folder with the command that made it: `gonio-lab {}` (release build, from the repository root).\n",
            command.join(" ")
        );
        std::fs::write(dir.join("tradeoff.md"), md.clone() + &note)
            .with_context(|| format!("{}", dir.join("tradeoff.md").display()))?;
        print!("{md}");
    }
    Ok(())
}
