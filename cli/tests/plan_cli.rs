//! `gonio plan IMAGE` as a user meets it: a committed capture photo gives a checked plan; bad input
//! gives a clear error, a non-zero exit and no output file.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn photo(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/encoder")
        .join(name)
}

fn gonio(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join(".."))
        .output()
        .expect("run gonio")
}

#[test]
fn plan_from_a_photo_writes_a_checked_plan() {
    let dir = tempfile::tempdir().unwrap();
    let (bin, json) = (dir.path().join("plan.bin"), dir.path().join("plan.json"));
    let out = gonio(&[
        "plan",
        photo("merl-00005.exr").to_str().unwrap(),
        "--grid",
        "4",
        "-o",
        bin.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("estimate from"), "{stdout}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    // The plan's alpha is the encoder's documented output for this photo (expected.csv).
    let expected = std::fs::read_to_string(photo("expected.csv")).unwrap();
    let documented: f64 = expected
        .lines()
        .find_map(|l| l.strip_prefix("merl-00005.exr,ggx,"))
        .and_then(|rest| rest.split(',').next())
        .and_then(|a| a.parse().ok())
        .expect("expected.csv documents merl-00005.exr");
    let estimate = v["estimate"].as_str().unwrap();
    let alpha: f64 = estimate
        .strip_prefix("ggx:alpha=")
        .and_then(|rest| rest.split(',').next())
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("not a GGX estimate: {estimate}"));
    assert!(
        (alpha - documented).abs() < 2e-4,
        "{estimate} vs documented alpha {documented}"
    );
    assert!(v["directions"].as_array().unwrap().len() > 8);
    assert!(std::fs::metadata(&bin).unwrap().len() > 0);
}

#[test]
fn bad_plan_inputs_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let bin = dir.path().join("plan.bin");
    let missing = dir.path().join("missing.exr");
    for args in [
        // A photo that is not there.
        vec!["plan", missing.to_str().unwrap(), "-o", bin.to_str().unwrap()],
        // A photo and a model at once.
        vec![
            "plan",
            missing.to_str().unwrap(),
            "--material-model",
            "ggx:alpha=0.1",
            "-o",
            bin.to_str().unwrap(),
        ],
        // Neither.
        vec!["plan", "-o", bin.to_str().unwrap()],
    ] {
        let out = gonio(&args);
        assert!(!out.status.success(), "{args:?}");
        assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"), "{args:?}");
        assert!(!bin.exists(), "{args:?} left an output");
    }
}
