//! Fixtures of the link tests: a coarse instrument (few steps, fast to simulate), small plans,
//! scan scenes, and the `gonio` binary.
#![allow(dead_code)]

use gonio_shared::msg::Direction;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

/// The shipped instrument with ~100x fewer steps per degree and short settle/exposure.
pub fn coarse_instrument_toml() -> String {
    gonio::instrument::DEFAULT_INSTRUMENT_TOML
        .replace("microsteps = 16", "microsteps = 1")
        .replace("gear_ratio = 45.0", "gear_ratio = 4.0")
        .replace("gear_ratio = 30.0", "gear_ratio = 3.0")
        .replace("gear_ratio = 10.0", "gear_ratio = 2.0")
        .replace("settle_ms = 50", "settle_ms = 5")
        .replace("exposure_us = 10000", "exposure_us = 1000")
}

/// `n` reachable directions: a serpentine over outgoing theta in the plane of incidence, the
/// incoming theta stepping every 10.
pub fn plan(n: usize) -> Vec<Direction> {
    (0..n)
        .map(|i| {
            let row = i / 10;
            let col = if row % 2 == 0 { i % 10 } else { 9 - i % 10 };
            Direction {
                theta_i: (20.0 + 10.0 * (row % 3) as f32).to_radians(),
                phi_i: 0.0,
                theta_o: (10.0 + 4.0 * col as f32).to_radians(),
                phi_o: std::f32::consts::PI,
            }
        })
        .collect()
}

pub const SCENE: &str = r#"
[camera]
kind = "orthographic"
width = 8
height = 8
[object]
shape = "sphere"
material = "ggx:alpha=0.2,diffuse=0.15/0.08/0.04"
"#;

pub struct Fixture {
    pub dir: tempfile::TempDir,
    pub instrument: PathBuf,
    pub plan: PathBuf,
    pub scene: PathBuf,
}

impl Fixture {
    pub fn new(n: usize, scene_extra: &str) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let instrument = dir.path().join("gonio.toml");
        std::fs::write(&instrument, coarse_instrument_toml()).unwrap();
        let plan_path = dir.path().join("plan.bin");
        gonio::plan::file::write_plan_file(&plan_path, &plan(n)).unwrap();
        let scene = dir.path().join("scene.toml");
        std::fs::write(&scene, format!("{SCENE}{scene_extra}")).unwrap();
        Self {
            dir,
            instrument,
            plan: plan_path,
            scene,
        }
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// `gonio measure` of `plan` on this fixture's virtual gonio into `out`, 10,000x faster than real time.
    pub fn measure_sim(&self, plan: &Path, out: &Path) -> Output {
        run(&[
            "measure",
            "--sim",
            s(&self.scene),
            "--plan",
            s(plan),
            "--instrument",
            s(&self.instrument),
            "-o",
            s(out),
            "--speedup",
            "10000",
        ])
    }

    pub fn instrument_config(&self) -> gonio_shared::InstrumentConfig<f64> {
        gonio::instrument::load(&self.instrument).unwrap()
    }
}

pub fn gonio() -> Command {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
}

pub fn run(args: &[&str]) -> Output {
    gonio().args(args).output().unwrap()
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The rows of a measurements.csv without the columns that depend on when (timestamp, session).
pub fn csv_without_time(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let skip: Vec<usize> = header
        .iter()
        .enumerate()
        .filter(|(_, h)| **h == "timestamp_us" || **h == "session")
        .map(|(i, _)| i)
        .collect();
    assert_eq!(skip.len(), 2, "{header:?}");
    lines
        .map(|l| {
            l.split(',')
                .enumerate()
                .filter(|(i, _)| !skip.contains(i))
                .map(|(_, f)| f)
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}

/// Record lines of a journal (`m ...`).
pub fn journal_records(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join("journal"))
        .unwrap_or_default()
        .lines()
        .filter(|l| l.starts_with("m "))
        .map(str::to_string)
        .collect()
}

/// Plan indices of the journal's records, in file order.
pub fn journal_indices(dir: &Path) -> Vec<u32> {
    journal_records(dir)
        .iter()
        .map(|l| l.split(' ').nth(1).unwrap().parse().unwrap())
        .collect()
}

/// Wait until the journal in `out` holds `n` readings; fails if the child exits first or nothing
/// happens for two minutes.
pub fn wait_for_records(out: &Path, n: usize, child: &mut Child) {
    let start = Instant::now();
    while journal_records(out).len() < n {
        assert!(start.elapsed() < Duration::from_secs(120), "the scan made no progress");
        if let Ok(Some(status)) = child.try_wait() {
            panic!("gonio ended early: {status}");
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// One line on stderr, a failure exit, and the output folder never created.
pub fn assert_clean_failure(args: &[&str], out: &Path, expect: &str) {
    let o = run(args);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{args:?} succeeded");
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(stderr.contains(expect), "expected {expect:?} in {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(!out.exists(), "{} was created", out.display());
}
