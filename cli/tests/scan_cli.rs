//! `gonio scan`, `gonio calibrate` and `gonio capture` as a user runs them, against the virtual
//! gonio on the coarse test instrument with small grids and renders: outputs present and readable,
//! a kill and `--resume` giving identical outputs, a limit fault, bad inputs, the calibration
//! recovering a known BRDF, and the shipped sample photo matching a fresh render.

mod common_link;

use common_link::*;
use gonio::brdf::{parse_material, Material};
use gonio::link::reached;
use gonio::scan::calibration::{self, Calibration};
use gonio::sim::{model::SimModel, SimHandle};
use gonio_shared::kinematics::Kinematics;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::Arc;

const SAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/sample.png");
const SCENE_FILE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/scene.toml");

/// The link tests' coarse instrument at full microstepping (0.03 deg per step): with 0.45 deg steps a
/// planned pair just outside the arms' blocked cone can round into it, which the firmware refuses
/// and `Plan::check_encoded` (unrounded poses) does not foresee.
fn fixture(scene_extra: &str) -> Fixture {
    let fx = Fixture::new(1, scene_extra);
    std::fs::write(
        &fx.instrument,
        coarse_instrument_toml().replace("microsteps = 1", "microsteps = 16"),
    )
    .unwrap();
    fx
}

/// Outputs that depend only on the readings, the plan and the calibration (not on timing).
const DETERMINISTIC: [&str; 11] = [
    "grid.json",
    "levels.png",
    "measured.binary",
    "measured.bsdf",
    "render-point.png",
    "render-env.png",
    "truth-point.png",
    "truth-env.png",
    "flip-point.png",
    "flip-env.png",
    "plan.bin",
];

fn small(fx: &Fixture, out: &Path) -> Vec<String> {
    [
        "scan",
        SAMPLE,
        "--sim",
        s(&fx.scene),
        "--instrument",
        s(&fx.instrument),
        "--grid",
        "4",
        "--render-size",
        "32",
        "--env-spp",
        "4",
        "-o",
        s(out),
    ]
    .iter()
    .map(|a| a.to_string())
    .collect()
}

fn args(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

fn scan_ok(fx: &Fixture, out: &Path, extra: &[&str]) -> String {
    let mut a = small(fx, out);
    a.extend(extra.iter().map(|x| x.to_string()));
    let o = run(&args(&a));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn scan_against_the_sim_writes_every_output_and_the_bsdf_reads_back() {
    let fx = fixture("");
    let out = fx.path("out");
    let stdout = scan_ok(&fx, &out, &["--speedup", "10000"]);
    assert!(stdout.contains("accuracy against the ground truth"), "{stdout}");
    // --grid alone measures every level up to it, one line per level, and says why it stopped.
    for needle in [
        "level 1 (2x2)",
        "level 2 (4x4)",
        "estimated FLIP",
        "true FLIP",
        "deepest level asked for",
    ] {
        assert!(stdout.contains(needle), "{needle} not in {stdout}");
    }
    for f in DETERMINISTIC
        .iter()
        .chain(&["report.md", "scan.toml", "calibration.toml", "journal"])
    {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    // No temporary file is left behind.
    for e in std::fs::read_dir(&out).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        assert!(!name.starts_with('.'), "left over: {name}");
    }
    // The exports read back and follow the truth off the specular peak, at a few directions. A
    // 4x4 grid is coarse (its error there reaches ~40%, see report.md), so this catches a wrong
    // scale, a lost channel or an empty table, not the accuracy, which report.md measures. The
    // directions have theta_i = theta_o: MERL's table assumes reciprocity, which a reconstruction
    // interpolated between incoming slices only approximates.
    let truth = parse_material("ggx:alpha=0.2,diffuse=0.15/0.08/0.04").unwrap();
    let bsdf = gonio::brdf::rgl::RglBsdf::read(&out.join("measured.bsdf")).unwrap();
    let merl = gonio::brdf::merl::MerlTable::read(&out.join("measured.binary")).unwrap();
    let dir = |t: f64, p: f64| gonio::brdf::frame::from_spherical(t.to_radians(), p.to_radians());
    for (ti, to, po) in [(20.0, 20.0, 90.0), (40.0, 40.0, 60.0), (30.0, 30.0, 120.0)] {
        let (wi, wo) = (dir(ti, 0.0), dir(to, po));
        let want = truth.eval(wi, wo);
        for (name, got) in [("bsdf", bsdf.eval(wi, wo)), ("merl", merl.eval(wi, wo))] {
            assert!(got.is_finite(), "{name} at {ti},{to},{po}: {got}");
            let rel = (got - want).abs().element_sum() / want.element_sum();
            assert!(rel < 0.6, "{name} at {ti},{to},{po}: {got} vs truth {want}");
        }
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for needle in [
        "## Counts",
        "## Host time",
        "PSNR",
        "measured.bsdf read back",
        "## Levels (closed loop)",
    ] {
        assert!(report.contains(needle), "{needle} not in report.md");
    }
    // The grid file names its nodes and every measured direction.
    let grid: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("grid.json")).unwrap()).unwrap();
    assert_eq!(grid["format"], "gonio-grid");
    assert_eq!(grid["n"], 4);
    let measurements = grid["measurements"].as_array().unwrap().len();
    assert_eq!(measurements, journal_records(&out).len());
    assert_eq!(grid["nodes"].as_array().unwrap().len(), 8 * 4 * 4);
}

fn listing(dir: &Path) -> Vec<(String, u64)> {
    let mut v: Vec<(String, u64)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (e.file_name().into_string().unwrap(), e.metadata().unwrap().len())
        })
        .collect();
    v.sort();
    v
}

#[test]
fn a_killed_scan_resumes_to_identical_outputs_and_a_corrupt_plan_is_refused() {
    let fx = fixture("");
    let reference = fx.path("reference");
    scan_ok(&fx, &reference, &["--speedup", "10000"]);
    // A slow device, so the kill lands mid-measurement.
    let killed = fx.path("killed");
    let mut a = small(&fx, &killed);
    a.extend(["--speedup".to_string(), "5".to_string()]);
    let mut child = gonio()
        .args(args(&a))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_for_records(&killed, 10, &mut child);
    child.kill().unwrap();
    child.wait().unwrap();
    let before = journal_records(&killed).len();
    let total: usize = std::fs::read_to_string(killed.join("scan.toml"))
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("directions = ").map(|v| v.trim().parse().unwrap()))
        .unwrap();
    assert!(
        before < total,
        "the kill came after the last reading ({before} of {total})"
    );
    assert!(!killed.join("grid.json").exists());
    let o = run(&["scan", "--resume", s(&killed), "--speedup", "10000"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains(&format!("({before} resumed from the journal)")),
        "{stdout}"
    );
    for f in DETERMINISTIC {
        let (a, b) = (
            std::fs::read(reference.join(f)).unwrap(),
            std::fs::read(killed.join(f)).unwrap(),
        );
        assert!(a == b, "{f} differs between the uninterrupted and the resumed scan");
    }
    // A resumed folder whose plan file was damaged: one line, nothing written.
    let plan = killed.join("plan.bin");
    let mut bytes = std::fs::read(&plan).unwrap();
    bytes[5] ^= 0x40;
    std::fs::write(&plan, bytes).unwrap();
    let files = listing(&killed);
    let o = run(&["scan", "--resume", s(&killed)]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(stderr.contains("plan.bin"), "{stderr}");
    assert_eq!(listing(&killed), files);
}

#[test]
fn a_scan_cut_between_levels_resumes_to_identical_outputs() {
    let fx = fixture("");
    let reference = fx.path("reference");
    scan_ok(&fx, &reference, &["--speedup", "10000"]);
    let grid: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(reference.join("grid.json")).unwrap()).unwrap();
    let level1 = grid["measurements"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["level"] == 1)
        .count();
    assert!(level1 > 0 && level1 < journal_records(&reference).len());
    // The state of a scan stopped right after level 1: its inputs and only level 1's readings.
    let cut = fx.path("cut");
    std::fs::create_dir_all(&cut).unwrap();
    for f in ["scan.toml", "plan.bin", "calibration.toml"] {
        std::fs::copy(reference.join(f), cut.join(f)).unwrap();
    }
    let journal: String = std::fs::read_to_string(reference.join("journal"))
        .unwrap()
        .lines()
        .filter(|l| match l.strip_prefix("m ") {
            Some(rest) => rest.split(' ').next().unwrap().parse::<usize>().unwrap() < level1,
            None => true,
        })
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(cut.join("journal"), journal).unwrap();
    assert_eq!(journal_records(&cut).len(), level1);
    let o = run(&["scan", "--resume", s(&cut), "--speedup", "10000"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains(&format!("({level1} resumed from the journal)")),
        "{stdout}"
    );
    for f in DETERMINISTIC {
        let (a, b) = (
            std::fs::read(reference.join(f)).unwrap(),
            std::fs::read(cut.join(f)).unwrap(),
        );
        assert!(
            a == b,
            "{f} differs between the uninterrupted scan and the one resumed between levels"
        );
    }
}

/// Every file of `dir` with its bytes, sorted by name.
fn contents(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (e.file_name().into_string().unwrap(), std::fs::read(e.path()).unwrap())
        })
        .collect();
    v.sort();
    v
}

#[test]
fn a_resume_by_another_build_or_reconstruction_is_refused_in_one_line() {
    let fx = fixture("");
    let out = fx.path("out");
    scan_ok(&fx, &out, &["--speedup", "10000"]);
    let record = out.join("scan.toml");
    let original = std::fs::read_to_string(&record).unwrap();
    let line = |key: &str| {
        original
            .lines()
            .find(|l| l.starts_with(&format!("{key} = ")))
            .unwrap_or_else(|| panic!("scan.toml has no {key}"))
            .to_string()
    };
    let (version, settings) = (line("gonio_version"), line("reconstruction"));
    assert!(version.contains(env!("CARGO_PKG_VERSION")), "{version}");
    assert!(settings.contains("prior"), "{settings}");
    for (from, to, named) in [
        (&version, "gonio_version = \"0.0.0-other\"", "0.0.0-other"),
        (
            &settings,
            "reconstruction = \"lookup slice, interp linear, prior none\"",
            "prior none",
        ),
    ] {
        std::fs::write(&record, original.replace(from.as_str(), to)).unwrap();
        let before = contents(&out);
        let o = run(&["scan", "--resume", s(&out), "--speedup", "10000"]);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "a resume with {named} went on");
        assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
        assert!(
            stderr.contains(named) && stderr.contains("the build that made it"),
            "{stderr}"
        );
        assert!(contents(&out) == before, "a refused resume wrote to {}", out.display());
    }
    // The untouched record resumes (the finished scan's outputs are written again).
    std::fs::write(&record, &original).unwrap();
    let o = run(&["scan", "--resume", s(&out), "--speedup", "10000"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn a_limit_fault_mid_scan_stops_it_with_the_pose_and_keeps_the_journal() {
    let clean = fixture("");
    let cal = clean.path("cal.toml");
    let o = run(&[
        "calibrate",
        "--sim",
        s(&clean.scene),
        "--instrument",
        s(&clean.instrument),
        "--speedup",
        "10000",
        "-o",
        s(&cal),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let fx = fixture("[effects]\nlimit_fault = { axis = \"detector\", after_readings = 7 }\n");
    let out = fx.path("out");
    let mut a = small(&fx, &out);
    a.extend(["--calibration", s(&cal), "--speedup", "10000"].map(String::from));
    let o = run(&args(&a));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("LimitSwitch(Detector)") && stderr.contains("deg"),
        "{stderr}"
    );
    assert!(stderr.contains("7 of"), "{stderr}");
    assert_eq!(journal_indices(&out), (0..7).collect::<Vec<u32>>());
    for f in ["grid.json", "measured.binary", "measured.bsdf", "report.md"] {
        assert!(!out.join(f).exists(), "{f} written after a fault");
    }
}

#[test]
fn bad_inputs_fail_with_one_line_and_write_nothing() {
    let fx = fixture("");
    let out = fx.path("out");
    let o = s(&out);
    let (inst, scene) = (s(&fx.instrument), s(&fx.scene));
    let cal = fx.path("cal.toml");
    let c = Calibration {
        format: calibration::FORMAT,
        reference: calibration::DEFAULT_WHITE.into(),
        exposure_us: 1000,
        dark_counts: vec![0.0; 3],
        gain: vec![600.0; 3],
        readings: 16,
        fit_rel_rms: vec![0.0; 3],
        source: "test".into(),
    };
    std::fs::write(&cal, c.to_toml()).unwrap();
    let common = ["--grid", "2", "--instrument", inst, "-o", o];
    let with = |head: &[&str]| -> Vec<String> { head.iter().chain(&common).map(|x| x.to_string()).collect() };
    // A port without a calibration is refused before anything else.
    assert_clean_failure(
        &args(&with(&["scan", SAMPLE, "--port", "/dev/ttyACM0"])),
        &out,
        "needs --calibration",
    );
    // Missing port.
    assert_clean_failure(
        &args(&with(&[
            "scan",
            SAMPLE,
            "--port",
            "/dev/does-not-exist",
            "--calibration",
            s(&cal),
        ])),
        &out,
        "cannot open port /dev/does-not-exist",
    );
    // A port with no gonio behind it.
    let pty = nix::pty::openpty(None, None).unwrap();
    let silent = nix::unistd::ttyname(pty.slave).unwrap();
    assert_clean_failure(
        &args(&with(&[
            "scan",
            SAMPLE,
            "--port",
            s(&silent),
            "--calibration",
            s(&cal),
            "--hello-timeout",
            "0.5",
        ])),
        &out,
        "no gonio answered",
    );
    let _ = nix::unistd::close(pty.master);
    let _ = nix::unistd::close(pty.slave);
    // An instrument file with impossible values.
    let bad_inst = fx.path("bad.toml");
    std::fs::write(
        &bad_inst,
        coarse_instrument_toml().replace("max_deg = 85.0", "max_deg = 95.0"),
    )
    .unwrap();
    assert_clean_failure(
        &["scan", SAMPLE, "--sim", scene, "--instrument", s(&bad_inst), "-o", o],
        &out,
        "tilt limits",
    );
    // A scene whose material does not parse.
    let bad_scene = fx.path("bad-scene.toml");
    std::fs::write(&bad_scene, SCENE.replace("ggx:alpha=0.2", "ggx:alpha=banana")).unwrap();
    assert_clean_failure(
        &args(&with(&["scan", SAMPLE, "--sim", s(&bad_scene)])),
        &out,
        "bad-scene.toml",
    );
    // Bad images: not an image, and a missing file.
    let not_png = fx.path("photo.png");
    std::fs::write(&not_png, "not a png").unwrap();
    assert_clean_failure(&args(&with(&["scan", s(&not_png), "--sim", scene])), &out, "photo.png");
    assert_clean_failure(
        &args(&with(&["scan", s(&fx.path("missing.png")), "--sim", scene])),
        &out,
        "missing.png",
    );
    // A damaged calibration file.
    let bad_cal = fx.path("bad-cal.toml");
    std::fs::write(&bad_cal, c.to_toml().replace("gain = [600.0", "gain = [-600.0")).unwrap();
    assert_clean_failure(
        &args(&with(&["scan", SAMPLE, "--sim", scene, "--calibration", s(&bad_cal)])),
        &out,
        "bad-cal.toml",
    );
    // --resume of a folder that holds no scan.
    assert_clean_failure(&["scan", "--resume", o], &out, "no journal");
}

/// The calibration, fitted on a white standard through an instrument with a dark offset and its
/// own gain, turns a known material's readings back into that material's BRDF.
#[test]
fn calibrated_readings_of_a_known_material_match_its_brdf() {
    let detector = "[detector]\ndark_level = 250.0\ngain = 9.0e7\nsolid_angle_sr = 2e-3\n";
    let fx = fixture(detector);
    let cfg = fx.instrument_config();
    let text = std::fs::read_to_string(&fx.scene).unwrap();
    let opts = gonio::link::RunOptions::default();
    let cal =
        gonio::scan::calibrate_sim(&text, &fx.scene, cfg, 1, 10_000.0, calibration::DEFAULT_WHITE, &opts).unwrap();
    for c in 0..3 {
        assert!((cal.dark_counts[c] - 250.0).abs() < 0.51, "{cal:?}");
        assert!(cal.fit_rel_rms[c] < 1e-3, "{cal:?}");
    }
    // Measure the scene's own sample at directions the calibration never saw.
    let model = SimModel::load(&fx.scene, cfg, 1).unwrap();
    let truth = parse_material(&model.material_spec).unwrap();
    let sim = SimHandle::spawn(Arc::new(model), 10_000.0, None).unwrap();
    let port = sim.path().display().to_string();
    let dirs = plan(30);
    let readings = calibration::measure_reference(&port, &cfg, &dirs, opts.timing).unwrap();
    sim.stop();
    assert_eq!(readings.len(), dirs.len());
    let kin = Kinematics::new(cfg).unwrap();
    let mut worst: f64 = 0.0;
    for m in &readings {
        let [ti, pi, to, po] = reached(&kin, &m.steps);
        let wi = gonio::brdf::frame::from_spherical(ti, pi);
        let wo = gonio::brdf::frame::from_spherical(to, po);
        let want = truth.eval(wi, wo);
        let counts: Vec<u32> = m.counts.iter().copied().collect();
        let got = cal.brdf(&counts, ti.cos(), m.exposure_us).unwrap();
        // One count of rounding is 1 / (gain cos theta_i) in BRDF; allow two.
        for c in 0..3 {
            let quantum = 2.0 / (cal.gain[c] * ti.cos());
            let err = (got[c] - want[c]).abs();
            assert!(
                err <= quantum + 1e-3 * want[c],
                "channel {c} at {:?}: {got} vs {want}",
                m.index
            );
            worst = worst.max(err / want[c].max(1e-9));
        }
    }
    assert!(worst < 0.05, "{worst}");
}

/// `examples/sample.png` is the capture photo of `examples/scene.toml`'s sample, regenerable by
/// `gonio capture examples/scene.toml -o examples/sample.png`.
#[test]
fn the_shipped_sample_photo_equals_a_fresh_capture() {
    let model = SimModel::load(Path::new(SCENE_FILE), gonio::instrument::default_instrument(), 0).unwrap();
    let fresh = gonio::encoder::capture::capture_photo(&model.material_spec, 256)
        .unwrap()
        .to_srgb8();
    let shipped = image::ImageReader::open(PathBuf::from(SAMPLE))
        .unwrap()
        .decode()
        .unwrap()
        .to_rgb8()
        .into_raw();
    assert_eq!(fresh.len(), shipped.len());
    let worst = fresh.iter().zip(&shipped).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
    assert!(worst <= 1, "largest 8-bit difference {worst}");
}
