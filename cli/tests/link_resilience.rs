//! The link against the virtual gonio through a seeded fault injector: with 5% of frames dropped,
//! corrupted, duplicated or delayed (each alone, and all together, both directions) the scan
//! completes and every measurement arrives exactly once, with the readings of a clean run.

mod common_link;

use common_link::*;
use gonio::journal::Journal;
use gonio::link::{
    self, FaultConfig, FaultyTransport, Quiet, ReopenPath, RunOptions, SerialTransport, SharedFaultCounts,
};
use gonio::sim::{model::SimModel, SimHandle};
use std::sync::Arc;
use std::time::Duration;

const N: usize = 160;
const SPEEDUP: f64 = 1e4;

/// Run the plan over a fault-injected link; returns the journal's records and the link counters.
/// (plan index, counts, steps) of every journaled reading.
type Readings = Vec<(u32, Vec<u32>, [i32; 4])>;

fn scan_with(
    fx: &Fixture,
    n: usize,
    faults: FaultConfig,
    out: &str,
) -> (Readings, link::RunSummary, (link::FaultCounts, link::FaultCounts)) {
    let cfg = fx.instrument_config();
    let model = SimModel::load(&fx.scene, cfg, 1).unwrap();
    let sim = SimHandle::spawn(Arc::new(model), SPEEDUP, None).unwrap();
    let port = sim.path().display().to_string();
    let plan = plan(n);
    let out = fx.path(out);
    std::fs::create_dir_all(&out).unwrap();
    let mut journal = Journal::create(&out, 1, n as u32).unwrap();
    let serial = SerialTransport::open(&port).unwrap();
    let counts = SharedFaultCounts::default();
    let faulty = FaultyTransport::new(serial, faults).with_shared_counts(counts.clone());
    let opts = RunOptions {
        reconnect_wait: Duration::from_secs(0),
        ..RunOptions::default()
    };
    let summary = link::run_plan(
        Box::new(faulty),
        &mut ReopenPath(port),
        &cfg,
        &plan,
        &mut journal,
        &mut Quiet,
        &opts,
    )
    .unwrap_or_else(|e| panic!("scan under {faults:?} failed: {e}"));
    let counts = *counts.lock().unwrap();
    sim.stop();
    // Exactly once: one journal line per plan direction, each index once.
    let mut indices = journal_indices(&out);
    assert_eq!(indices.len(), n, "journal lines under {faults:?}");
    indices.sort_unstable();
    assert_eq!(indices, (0..n as u32).collect::<Vec<_>>());
    let records = journal
        .records()
        .values()
        .map(|r| (r.index, r.counts.clone(), r.steps))
        .collect();
    (records, summary, counts)
}

fn faults(drop: f64, corrupt: f64, duplicate: f64, delay: f64, seed: u64) -> FaultConfig {
    FaultConfig {
        drop,
        corrupt,
        duplicate,
        delay,
        seed,
        ..FaultConfig::NONE
    }
}

#[test]
fn five_percent_faults_each_and_all_together_lose_and_duplicate_nothing() {
    let fx = Fixture::new(N, "");
    let (clean, clean_summary, _) = scan_with(&fx, N, FaultConfig::NONE, "clean");
    assert_eq!(clean_summary.stats.retransmits, 0, "{:?}", clean_summary.stats);
    assert!(
        clean.iter().all(|(_, c, _)| c.iter().any(|&v| v > 0)),
        "readings are all dark"
    );
    // Each seed's first fault falls within the first 25 frames of both lanes (a scan sends at least
    // 35 frames each way), so every case injects in both directions on every run.
    let cases = [
        ("drop", faults(0.05, 0.0, 0.0, 0.0, 11)),
        ("corrupt", faults(0.0, 0.05, 0.0, 0.0, 12)),
        ("duplicate", faults(0.0, 0.0, 0.05, 0.0, 23)),
        ("delay", faults(0.0, 0.0, 0.0, 0.05, 14)),
        ("all", faults(0.05, 0.05, 0.05, 0.05, 15)),
    ];
    for (name, f) in cases {
        let (got, summary, (tx, rx)) = scan_with(&fx, N, f, name);
        eprintln!(
            "{name}: host->device {tx:?}, device->host {rx:?}; link {:?}",
            summary.stats
        );
        // The injector did inject, in both directions.
        let hit = |c: &link::FaultCounts| c.dropped + c.corrupted + c.duplicated + c.delayed;
        assert!(
            hit(&tx) > 0 && hit(&rx) > 0,
            "{name}: nothing injected ({tx:?}, {rx:?})"
        );
        assert_eq!(got, clean, "{name}: readings differ from the clean run");
    }
}

/// Every `Credit` after the configuration's first is lost, on a plan three times the firmware's
/// plan buffer (so the scan needs many fresh grants): the host takes them from the `Status` it
/// polls, and every measurement still arrives exactly once (checked in `scan_with`).
#[test]
fn with_every_credit_lost_the_scan_completes_on_status_alone() {
    const BIG: usize = 3 * gonio_firmware::capacity::PLAN_CAPACITY;
    let fx = Fixture::new(BIG, "");
    let f = FaultConfig {
        drop_credits: u32::MAX,
        ..FaultConfig::NONE
    };
    let (got, summary, (_, rx)) = scan_with(&fx, BIG, f, "no-credit");
    eprintln!("device->host {rx:?}; link {:?}", summary.stats);
    assert_eq!(got.len(), BIG);
    // Each accepted chunk is answered with a Credit: all of them were dropped.
    let chunks = BIG.div_ceil(gonio_shared::msg::caps::CHUNK_DIRECTIONS) as u64;
    assert!(rx.dropped >= chunks - 1, "{rx:?}");
    assert!(summary.stats.status_requests > 0);
}

/// A port that goes away (a USB replug) once `after` bytes came from the device.
struct CutAfter {
    inner: SerialTransport,
    after: usize,
}

impl link::Transport for CutAfter {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.inner.write_all(bytes)
    }
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        if self.after == 0 {
            return Err(std::io::Error::new(std::io::ErrorKind::BrokenPipe, "unplugged"));
        }
        let n = buf.len().min(self.after);
        let got = self.inner.read(&mut buf[..n], timeout)?;
        self.after -= got;
        Ok(got)
    }
}

/// The port goes away mid-scan while the device keeps measuring: on reconnect the host takes the
/// readings the device kept before anything resets it, so no direction is measured twice.
#[test]
fn a_reconnect_collects_the_readings_the_device_kept() {
    let n = 120;
    let fx = Fixture::new(n, "");
    let cfg = fx.instrument_config();
    let model = SimModel::load(&fx.scene, cfg, 1).unwrap();
    let sim = SimHandle::spawn(Arc::new(model), SPEEDUP, None).unwrap();
    let port = sim.path().display().to_string();
    let plan = plan(n);
    let out = fx.path("replug");
    std::fs::create_dir_all(&out).unwrap();
    let mut journal = Journal::create(&out, 1, n as u32).unwrap();
    // Enough bytes for the handshake, configuration, homing and a few dozen readings.
    let cut = CutAfter {
        inner: SerialTransport::open(&port).unwrap(),
        after: 4_000,
    };
    let summary = link::run_plan(
        Box::new(cut),
        &mut ReopenPath(port),
        &cfg,
        &plan,
        &mut journal,
        &mut Quiet,
        &RunOptions::default(),
    )
    .unwrap();
    let readings = sim.counters().readings.load(std::sync::atomic::Ordering::Relaxed);
    sim.stop();
    assert_eq!(summary.reconnects, 1, "{summary:?}");
    let mut indices = journal_indices(&out);
    indices.sort_unstable();
    assert_eq!(indices, (0..n as u32).collect::<Vec<_>>(), "journaled exactly once");
    assert_eq!(readings, n as u64, "directions measured again after the reconnect");
}
