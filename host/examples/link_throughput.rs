//! Host-side throughput of the link: an N-direction plan (default 8192) streamed to the virtual
//! gonio over its pseudo-terminal with a fast instrument (coarse steps, 100 us exposure, no
//! settle), so the link and the firmware logic, not motion, set the pace.
//!
//!     cargo run -p gonio --example link_throughput [N] [SPEEDUP] [PLAN.bin]
//!
//! With a third argument the plan is also written there (a plan file for `gonio measure`).
//! Prints directions/s in wall time and in instrument time and the link's counters.

use gonio::journal::Journal;
use gonio::link::{self, Quiet, ReopenPath, RunOptions, SerialTransport};
use gonio::sim::{model::SimModel, SimHandle};
use gonio_shared::msg::Direction;
use std::sync::Arc;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().map(|a| a.parse()).transpose()?.unwrap_or(8192);
    let speedup: f64 = args.next().map(|a| a.parse()).transpose()?.unwrap_or(1e6);
    let text = gonio::instrument::DEFAULT_INSTRUMENT_TOML
        .replace("microsteps = 16", "microsteps = 1")
        .replace("gear_ratio = 45.0", "gear_ratio = 4.0")
        .replace("gear_ratio = 30.0", "gear_ratio = 3.0")
        .replace("gear_ratio = 10.0", "gear_ratio = 2.0")
        .replace("settle_ms = 50", "settle_ms = 0")
        .replace("exposure_us = 10000", "exposure_us = 100");
    let cfg = gonio::instrument::parse(&text, std::path::Path::new("fast.toml"))?;
    // A serpentine of small steps in the plane of incidence.
    let plan: Vec<Direction> = (0..n)
        .map(|i| {
            let row = i / 100;
            let col = if row % 2 == 0 { i % 100 } else { 99 - i % 100 };
            Direction {
                theta_i: (20.0 + 10.0 * (row % 5) as f32).to_radians(),
                phi_i: 0.0,
                theta_o: (10.0 + 0.6 * col as f32).to_radians(),
                phi_o: std::f32::consts::PI,
            }
        })
        .collect();
    if let Some(path) = args.next() {
        gonio::plan::file::write_plan_file(std::path::Path::new(&path), &plan)?;
    }
    let model = SimModel::ideal("ggx:alpha=0.2,diffuse=0.1", cfg)?;
    let sim = SimHandle::spawn(Arc::new(model), speedup, None)?;
    let port = sim.path().display().to_string();
    let dir = tempfile::tempdir()?;
    let mut journal = Journal::create(dir.path(), 0, u32::try_from(n)?)?;
    let t = Box::new(SerialTransport::open(&port)?);
    let wall = Instant::now();
    let summary = link::run_plan(
        t,
        &mut ReopenPath(port),
        &cfg,
        &plan,
        &mut journal,
        &mut Quiet,
        &RunOptions::default(),
    )?;
    let wall_s = wall.elapsed().as_secs_f64();
    let report = sim.stop();
    println!(
        "{n} directions over the pty in {wall_s:.2} s wall ({:.0} directions/s), {:.1} s instrument ({:.0} directions/s); handshake + configure + homing included in wall",
        n as f64 / wall_s,
        summary.instrument_s,
        n as f64 / summary.instrument_s.max(1e-9),
    );
    println!(
        "device: {} readings, {} steps, {} bytes in, {} bytes out; link: {:?}",
        report.readings, report.steps, report.bytes_in, report.bytes_out, summary.stats
    );
    Ok(())
}
