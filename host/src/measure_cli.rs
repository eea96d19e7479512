//! `gonio sim` and `gonio measure`: the command-line edge of the virtual gonio and the link.

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use gonio::link::{self, Connection};
use gonio::progress_bar::{print_run, TerminalProgress};
use gonio::sim::{model::SimModel, SimHandle, DEFAULT_SPEEDUP};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

#[derive(Args)]
pub struct SimArgs {
    /// Scan scene: `[object] material` is the virtual sample; `[effects]` and `[detector]` as in the README.
    #[arg(long)]
    scene: PathBuf,
    #[arg(long)]
    instrument: Option<PathBuf>,
    /// Instrument seconds per wall second while the device is busy.
    #[arg(long, default_value_t = DEFAULT_SPEEDUP)]
    speedup: f64,
    /// Also publish the port under this fixed path (a symlink to the pty).
    #[arg(long)]
    link: Option<PathBuf>,
    /// Seed of the simulated detector's noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(Args)]
pub struct MeasureArgs {
    /// Serial port of the gonio (or of `gonio sim`).
    #[arg(long, conflicts_with = "sim", required_unless_present = "sim")]
    port: Option<String>,
    /// Run the virtual gonio on this scan scene instead of using a port.
    #[arg(long)]
    sim: Option<PathBuf>,
    #[arg(long)]
    plan: PathBuf,
    #[arg(long)]
    instrument: Option<PathBuf>,
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    /// Continue the scan journaled in OUTDIR.
    #[arg(long)]
    resume: bool,
    /// With --sim: instrument seconds per wall second while the device is busy.
    #[arg(long, default_value_t = DEFAULT_SPEEDUP)]
    speedup: f64,
    /// Seconds to wait for a lost device to come back.
    #[arg(long, default_value_t = 30.0)]
    reconnect_wait: f64,
    /// Seconds to wait for the device's Hello.
    #[arg(long, default_value_t = 2.0)]
    hello_timeout: f64,
    /// With --sim: seed of the simulated detector's noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Test the link: inject faults into whole frames, e.g.
    /// `drop=0.05,corrupt=0.05,duplicate=0.05,delay=0.05,seed=1,dir=both`.
    #[arg(long, value_name = "SPEC")]
    inject_faults: Option<link::FaultConfig>,
}

pub fn run_sim(a: SimArgs) -> Result<()> {
    let cfg = gonio::instrument::load_or_default(a.instrument.as_deref())?;
    let model = SimModel::load(&a.scene, cfg, a.seed)?;
    let handle = SimHandle::spawn(Arc::new(model), a.speedup, a.link.clone())?;
    println!("{}", handle.path().display());
    eprintln!("virtual gonio running ({}x speedup); Ctrl-C to stop", a.speedup);
    loop {
        std::thread::sleep(Duration::from_secs(3600));
    }
}

pub fn run_measure(a: MeasureArgs) -> Result<()> {
    // Every input is checked before anything is written.
    let cfg = gonio::instrument::load_or_default(a.instrument.as_deref())?;
    gonio_shared::kinematics::Kinematics::new(cfg).map_err(|e| anyhow!("instrument: {e}"))?;
    let plan_bytes = std::fs::read(&a.plan).with_context(|| format!("plan file {}", a.plan.display()))?;
    let plan = gonio::plan::file::decode_plan(&plan_bytes).with_context(|| a.plan.display().to_string())?;
    link::plan_hash(&plan).with_context(|| a.plan.display().to_string())?;
    link::check_journal_state(&a.out, a.resume)?;
    let sim = match &a.sim {
        Some(scene) => {
            let model = SimModel::load(scene, cfg, a.seed)?;
            Some(SimHandle::spawn(Arc::new(model), a.speedup, None)?)
        }
        None => None,
    };
    let port = match (&sim, &a.port) {
        (Some(s), _) => s.path().display().to_string(),
        (None, Some(p)) => p.clone(),
        (None, None) => bail!("give --port PATH or --sim SCENE"),
    };
    let opts = link::run_options(a.hello_timeout, a.reconnect_wait);
    // The handshake happens before the output folder is touched: a port that is not a gonio
    // leaves nothing behind.
    let connection = Connection::open(&port, a.inject_faults, &opts)?;
    let mut progress = TerminalProgress::new(plan.len());
    let result = connection.measure(&cfg, &plan, &a.out, a.resume, &opts, &mut progress);
    progress.finish();
    let measured = result?;
    let csv = a.out.join("measurements.csv");
    link::write_csv(&csv, &cfg, &plan, &measured.journal).with_context(|| format!("cannot write {}", csv.display()))?;
    print_run(&measured);
    println!("wrote {}", csv.display());
    if let Some(sim) = sim {
        sim.stop();
    }
    Ok(())
}
