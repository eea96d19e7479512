//! `gonio scan`, `gonio calibrate` and `gonio capture`: argument handling over `gonio::scan::run`
//! and `gonio::scan::calibration`.

use crate::names::parse_name;
use crate::progress::{print_run, TerminalProgress};
use anyhow::{bail, Context, Result};
use gonio::encoder::ModelKind;
use gonio::link::{self, run_options};
use gonio::plan::closed_loop::{self, StopRule};
use gonio::scan::calibration::{self, Calibration};
use gonio::scan::{FreshScan, ScanRequest, Start};
use std::io::BufRead;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ScanArgs {
    /// The capture photo of the sample (examples/capture.toml describes how to take it).
    #[arg(required_unless_present = "resume")]
    pub image: Option<PathBuf>,
    /// Serial port of the gonio (needs --calibration).
    #[arg(long, conflicts_with = "sim")]
    pub port: Option<String>,
    /// Scan the virtual gonio on this scan scene instead (calibrates itself unless --calibration).
    #[arg(long)]
    pub sim: Option<PathBuf>,
    #[command(flatten)]
    pub level: crate::plan::LevelArgs,
    /// Deepest grid the closed loop may reach when --grid is not given.
    #[arg(long, default_value_t = 16)]
    pub max_grid: usize,
    /// Instrument file (default: the shipped examples/gonio.toml).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Counts -> BRDF conversion from `gonio calibrate`.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Output folder (journal, plan, grid, exports, renders, report).
    #[arg(
        short = 'o',
        long = "out",
        required_unless_present = "resume",
        conflicts_with = "resume"
    )]
    pub out: Option<PathBuf>,
    /// Continue the scan in this folder after a crash, a kill or an unplugged cable.
    #[arg(long, value_name = "OUTDIR", conflicts_with_all = ["image", "sim", "grid", "target_psnr", "target_flip", "time_budget", "instrument", "calibration"])]
    pub resume: Option<PathBuf>,
    /// Which shipped encoder estimates the material.
    #[arg(long, value_parser = parse_name::<ModelKind>(), default_value_t = ModelKind::Ggx)]
    pub model: ModelKind,
    /// With --sim: instrument seconds per wall second while the device is busy (default 100; with
    /// --resume, the scan's own unless given).
    #[arg(long)]
    pub speedup: Option<f64>,
    /// With --sim: seed of the simulated detector's noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Seconds to wait for a lost device to come back.
    #[arg(long, default_value_t = 30.0)]
    pub reconnect_wait: f64,
    /// Seconds to wait for the device's Hello.
    #[arg(long, default_value_t = 2.0)]
    pub hello_timeout: f64,
    /// Side of the renders in pixels.
    #[arg(long, default_value_t = 256)]
    pub render_size: usize,
    /// Samples per pixel of the environment-light render.
    #[arg(long, default_value_t = 64)]
    pub env_spp: u32,
    /// Test the link: inject faults into whole frames (as `gonio measure --inject-faults`).
    #[arg(long, value_name = "SPEC")]
    pub inject_faults: Option<link::FaultConfig>,
}

pub fn run_scan(a: ScanArgs) -> Result<()> {
    let options = run_options(a.hello_timeout, a.reconnect_wait);
    let (out, start) = match (&a.resume, &a.out, &a.image) {
        (Some(dir), _, _) => (
            dir.clone(),
            Start::Resume {
                port: a.port.clone(),
                speedup: a.speedup,
            },
        ),
        (None, Some(out), Some(image)) => {
            let rule = if let Some(db) = a.level.target_psnr {
                if !db.is_finite() {
                    bail!("--target-psnr must be finite");
                }
                StopRule::TargetPsnr(db)
            } else if let Some(flip) = a.level.target_flip {
                if !(flip > 0.0 && flip < 1.0) {
                    bail!("--target-flip {flip} must be in (0, 1)");
                }
                StopRule::TargetFlip(flip)
            } else if let Some(seconds) = a.level.time_budget {
                StopRule::TimeBudget(seconds)
            } else if a.level.grid.is_some() {
                StopRule::Depth
            } else {
                StopRule::TargetFlip(closed_loop::DEFAULT_TARGET_FLIP)
            };
            let fresh = FreshScan {
                image: image.clone(),
                model: a.model,
                rule,
                max_grid: a.level.grid.unwrap_or(a.max_grid),
                instrument: a.instrument.clone(),
                calibration: a.calibration.clone(),
                port: a.port.clone(),
                sim: a.sim.clone(),
                seed: a.seed,
                speedup: a.speedup.unwrap_or(gonio::sim::DEFAULT_SPEEDUP),
                render_size: a.render_size,
                env_spp: a.env_spp,
            };
            (out.clone(), Start::Fresh(Box::new(fresh)))
        }
        _ => bail!("give IMAGE and -o OUTDIR, or --resume OUTDIR"),
    };
    let request = ScanRequest {
        out: out.clone(),
        start,
        options,
        faults: a.inject_faults,
    };
    let mut progress = TerminalProgress::new(0);
    let result = gonio::scan::run(&request, &mut progress, &mut |line| println!("{line}"));
    progress.finish();
    let outcome = result?;
    let r = &outcome.record;
    let t = &outcome.times;
    print_run(&outcome.measured);
    println!(
        "scan: {} directions (level {}, {}x{} x {} incoming; {}), estimate {}",
        outcome.levels.last().map_or(0, |l| l.directions),
        r.level,
        1 << r.level,
        1 << r.level,
        r.incoming,
        r.rule,
        r.estimate
    );
    println!(
        "host time {:.2} s: estimate {:.2}, plan {:.2}, calibrate {:.2}, stream/measure {:.2}, reconstruct and estimate between levels {:.2}, outputs {:.2}",
        t.total(),
        t.estimate,
        t.plan,
        t.calibrate,
        t.measure,
        t.reconstruct,
        t.outputs
    );
    if let Some(acc) = &outcome.report.accuracy {
        println!(
            "accuracy against the ground truth: point light PSNR {:.2} dB, FLIP {:.4}; environment PSNR {:.2} dB, FLIP {:.4}",
            acc.point.psnr, acc.point.flip, acc.env.psnr, acc.env.flip
        );
    }
    let worst = outcome.report.rgl.iter().map(|c| c.rel_diff()).fold(0.0, f64::max);
    println!(
        "measured.bsdf read back: largest relative difference from the grid {worst:.3} at {} check directions",
        outcome.report.rgl.len()
    );
    println!("wrote in {}: {}", out.display(), outcome.report.files.join(", "));
    Ok(())
}

#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// Serial port of the gonio: you are asked to mount the light trap, then the white standard.
    #[arg(long, conflicts_with = "sim", required_unless_present = "sim")]
    pub port: Option<String>,
    /// Calibrate the virtual gonio of this scan scene (its sample replaced by the references).
    #[arg(long)]
    pub sim: Option<PathBuf>,
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// The white standard (a Lambertian spec of known albedo).
    #[arg(long, default_value = calibration::DEFAULT_WHITE)]
    pub reference: String,
    #[arg(short = 'o', long = "out")]
    pub out: PathBuf,
    #[arg(long, default_value_t = gonio::sim::DEFAULT_SPEEDUP)]
    pub speedup: f64,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long, default_value_t = 2.0)]
    pub hello_timeout: f64,
}

pub fn run_calibrate(a: CalibrateArgs) -> Result<()> {
    let cfg = gonio::instrument::load_or_default(a.instrument.as_deref())?;
    gonio_shared::kinematics::Kinematics::new(cfg).map_err(|e| anyhow::anyhow!("instrument: {e}"))?;
    calibration::reference_albedo(&a.reference)?;
    let options = run_options(a.hello_timeout, 0.0);
    let cal = match (&a.sim, &a.port) {
        (Some(scene), _) => {
            let text = std::fs::read_to_string(scene).with_context(|| format!("scene {}", scene.display()))?;
            // Refuse a bad scene (material, detector, effects) before any simulation starts.
            gonio::sim::model::SimModel::from_toml(&text, scene, cfg, a.seed)?;
            gonio::scan::calibrate_sim(&text, scene, cfg, a.seed, a.speedup, &a.reference, &options)?
        }
        (None, Some(port)) => {
            let directions = calibration::directions();
            let stdin = std::io::stdin();
            let wait = |what: &str| -> Result<()> {
                eprintln!("mount {what} in the sample holder, then press Enter");
                let mut line = String::new();
                if stdin.lock().read_line(&mut line)? == 0 {
                    bail!("calibration aborted (no answer on stdin)");
                }
                Ok(())
            };
            wait("the light trap (dark reference)")?;
            let dark = calibration::measure_reference(port, &cfg, &directions, options.timing)?;
            wait(&format!("the white standard ({})", a.reference))?;
            let white = calibration::measure_reference(port, &cfg, &directions, options.timing)?;
            calibration::fit(&cfg, &a.reference, &dark, &white, port)?
        }
        (None, None) => bail!("give --port PATH or --sim SCENE"),
    };
    gonio::fsio::write_bytes_atomically(&a.out, cal.to_toml().as_bytes())
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    print_calibration(&cal);
    println!("wrote {}", a.out.display());
    Ok(())
}

fn print_calibration(c: &Calibration) {
    let list = |v: &[f64], p: usize| v.iter().map(|x| format!("{x:.p$}")).collect::<Vec<_>>().join(", ");
    println!(
        "calibration ({} readings per reference, white {}, exposure {} us): dark [{}] counts; gain [{}] counts per (1/sr x cos theta_i); white fit residual [{}] (relative RMS)",
        c.readings,
        c.reference,
        c.exposure_us,
        list(&c.dark_counts, 2),
        list(&c.gain, 1),
        list(&c.fit_rel_rms, 5)
    );
}

/// `gonio capture SCENE -o PHOTO.png`: the capture photo (`examples/capture.toml`: sphere, point
/// light 30 deg off the view axis) of a scan scene's sample, as the encoder expects it.
#[derive(clap::Args)]
pub struct CaptureArgs {
    /// Scan scene whose `[object] material` is photographed.
    pub scene: PathBuf,
    /// .png (tone-mapped sRGB) or .exr (linear).
    #[arg(short = 'o', long = "out")]
    pub out: PathBuf,
    /// Image side in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
}

pub fn run_capture(a: CaptureArgs) -> Result<()> {
    gonio::render::image::ImageFormat::from_path(&a.out)?;
    if !(16..=4096).contains(&a.size) {
        bail!("--size {} must be in 16..=4096", a.size);
    }
    let model = gonio::sim::model::SimModel::load(&a.scene, gonio::instrument::default_instrument(), 0)?;
    let image = gonio::encoder::capture::capture_photo(&model.material_spec, a.size).map_err(anyhow::Error::msg)?;
    image.write(&a.out)?;
    println!(
        "captured {} ({}x{}, examples/capture.toml) -> {}",
        model.material_spec,
        a.size,
        a.size,
        a.out.display()
    );
    Ok(())
}
