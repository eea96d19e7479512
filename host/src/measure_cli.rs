//! `gonio sim` and `gonio measure`: the command-line edge of the virtual gonio and the link.

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use gonio::journal::Journal;
use gonio::link::{self, Progress, ReopenPath, RunOptions, SerialTransport};
use gonio::sim::{model::SimModel, SimHandle, DEFAULT_SPEEDUP};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

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

struct Bar {
    bar: indicatif::ProgressBar,
    start: Instant,
}

impl Progress for Bar {
    fn update(&mut self, done: u32, total: u32, instrument_s: f64) {
        self.bar.set_length(u64::from(total));
        self.bar.set_position(u64::from(done));
        let eta = if done > 0 {
            let per = self.start.elapsed().as_secs_f64() / f64::from(done.max(1));
            format!("{:.0} s", per * f64::from(total - done))
        } else {
            "?".into()
        };
        self.bar
            .set_message(format!("instrument {instrument_s:.1} s, ETA {eta}"));
    }
    fn note(&mut self, line: &str) {
        self.bar.suspend(|| eprintln!("{line}"));
    }
}

pub fn run_measure(a: MeasureArgs) -> Result<()> {
    // Every input is checked before anything is written.
    let cfg = gonio::instrument::load_or_default(a.instrument.as_deref())?;
    gonio_shared::kinematics::Kinematics::new(cfg).map_err(|e| anyhow!("instrument: {e}"))?;
    let plan_bytes = std::fs::read(&a.plan).with_context(|| format!("plan file {}", a.plan.display()))?;
    let plan = gonio::plan::file::decode_plan(&plan_bytes).with_context(|| a.plan.display().to_string())?;
    let total = u32::try_from(plan.len()).map_err(|_| anyhow!("plan too long"))?;
    let hash = link::plan_hash(&plan).with_context(|| a.plan.display().to_string())?;
    let journal_path = Journal::path_in(&a.out);
    if a.resume && !journal_path.exists() {
        bail!("--resume: {} has no journal to continue", a.out.display());
    }
    if !a.resume && journal_path.exists() {
        bail!(
            "{} already holds a scan journal; continue it with --resume or choose another -o",
            a.out.display()
        );
    }
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
    let mut opts = RunOptions::default();
    opts.timing.hello_timeout = Duration::from_secs_f64(a.hello_timeout.clamp(0.1, 600.0));
    opts.reconnect_wait = Duration::from_secs_f64(a.reconnect_wait.clamp(0.0, 86_400.0));
    let transport = SerialTransport::open(&port).map_err(|e| anyhow!("cannot open port {port}: {e}"))?;
    let fault_counts = link::SharedFaultCounts::default();
    let transport: Box<dyn link::Transport> = match a.inject_faults {
        Some(f) => Box::new(link::FaultyTransport::new(transport, f).with_shared_counts(fault_counts.clone())),
        None => Box::new(transport),
    };
    // The handshake happens before the output folder is touched: a port that is not a gonio
    // leaves nothing behind.
    let first = gonio::link::Link::connect(transport, opts.timing)
        .map_err(|e| anyhow!("{port}: {e}"))?
        .into_inner();
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut journal = if a.resume {
        Journal::resume(&a.out, hash, total)?
    } else {
        Journal::create(&a.out, hash, total)?
    };
    let already = journal.records().len();
    let bar = indicatif::ProgressBar::new(u64::from(total)).with_style(
        indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} directions, {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_position(already as u64);
    let mut progress = Bar {
        bar,
        start: Instant::now(),
    };
    let wall = Instant::now();
    let mut reopen_plain = ReopenPath(port.clone());
    let mut reopen_faulty = a.inject_faults.map(|faults| link::ReopenFaulty {
        path: port.clone(),
        faults,
        counts: fault_counts.clone(),
    });
    let reopen: &mut dyn link::Reconnect = match &mut reopen_faulty {
        Some(r) => r,
        None => &mut reopen_plain,
    };
    let result = link::run_plan(first, reopen, &cfg, &plan, &mut journal, &mut progress, &opts);
    progress.bar.finish_and_clear();
    let summary = result.map_err(|e| {
        anyhow!(
            "{port}: {e} ({} of {total} directions are in the journal)",
            journal.records().len()
        )
    })?;
    let csv = a.out.join("measurements.csv");
    link::write_csv(&csv, &cfg, &plan, &journal).with_context(|| format!("cannot write {}", csv.display()))?;
    let wall_s = wall.elapsed().as_secs_f64();
    let n = summary.measured_now;
    println!(
        "measured {n} directions ({} resumed from the journal) in {:.1} s instrument time, {wall_s:.2} s wall: {:.1} directions/s instrument, {:.1} directions/s wall",
        already,
        summary.instrument_s,
        f64::from(n) / summary.instrument_s.max(1e-9),
        f64::from(n) / wall_s.max(1e-9)
    );
    let s = summary.stats;
    println!(
        "link: {} frames sent, {} retransmitted ({} timeouts, {} NAKs), {} bad frames in, {} duplicate measurements, {} resend requests, {} reconnects",
        s.frames_sent, s.retransmits, s.timeouts, s.naks, s.bad_frames_in, s.duplicate_measurements, s.resend_requests, summary.reconnects
    );
    if a.inject_faults.is_some() {
        if let Ok(c) = fault_counts.lock() {
            println!("injected faults: host->device {:?}; device->host {:?}", c.0, c.1);
        }
    }
    println!("wrote {}", csv.display());
    if let Some(sim) = sim {
        sim.stop();
    }
    Ok(())
}
