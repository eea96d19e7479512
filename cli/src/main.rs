//! `gonio`: the command line of the gonio adaptive gonioreflectometer, a thin clap layer over the
//! `gonio` library. The research commands (tradeoff, plan-report, dataset, train, encoder-report)
//! are `gonio-lab`'s.

use anyhow::{Context, Result};
use brdf::{parse_direction, BrdfCmd, Direction};
use clap::{Parser, Subcommand};
use gonio::instrument::{self, survey};
use gonio_shared::kinematics::Kinematics;
use gonio_shared::{Axis, AXES};
use render::{CompareArgs, EnvmapCmd, RenderArgs};
use std::path::PathBuf;
use std::process::ExitCode;

mod brdf;
mod estimate;
mod measure;
mod names;
mod plan;
mod progress;
mod render;
mod scan;

#[derive(Parser)]
#[command(
    name = "gonio",
    version = gonio::VERSION,
    about = "Adaptive BRDF measurement with a motorised gonioreflectometer"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// BRDF models: evaluate, tabulate to a MERL .binary, fit GGX/Ward.
    #[command(subcommand)]
    Brdf(BrdfCmd),
    /// The instrument description (gonio.toml): check it, survey what it can reach, solve poses.
    #[command(subcommand)]
    Instrument(InstrumentCmd),
    /// The wire protocol this build speaks.
    Protocol,
    /// Render a scene file to .exr (linear) or .png (tone-mapped sRGB).
    Render(RenderArgs),
    /// Compare two images: RMSE, PSNR and mean FLIP; optionally write the FLIP error map.
    Compare(CompareArgs),
    /// Generate the project's environment maps (examples/sky.exr).
    #[command(subcommand)]
    Envmap(EnvmapCmd),
    /// Plan a measurement: ordered, timed, encoded directions for an estimated material.
    Plan(plan::PlanArgs),
    /// Run the virtual gonio (real firmware, simulated HAL) on a pseudo-terminal; prints its path.
    Sim(measure::SimArgs),
    /// Stream a plan file to a gonio (or the virtual one), journal and collect the measurements.
    Measure(measure::MeasureArgs),
    /// Photo -> estimate -> plan -> measure -> reconstruct -> exports, renders and report, in one go.
    Scan(scan::ScanArgs),
    /// Fit the counts -> BRDF conversion from a dark reading and a white reference.
    Calibrate(scan::CalibrateArgs),
    /// Render the capture photo (examples/capture.toml) of a scan scene's sample.
    Capture(scan::CaptureArgs),
    /// Estimate BRDF parameters from one photo of the sample (examples/capture.toml).
    Estimate(estimate::EstimateArgs),
}

#[derive(Subcommand)]
enum InstrumentCmd {
    /// Validate an instrument file and print its axes.
    Check {
        /// Instrument file (default: the shipped examples/gonio.toml).
        file: Option<PathBuf>,
    },
    /// Reachability of random direction pairs, FK(IK) precision, host-vs-firmware step agreement.
    Survey {
        file: Option<PathBuf>,
        #[arg(long, default_value_t = 100_000)]
        pairs: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Axis angles and step targets for one direction pair (degrees), from the rest pose.
    Pose {
        #[arg(long)]
        instrument: Option<PathBuf>,
        /// Incoming direction THETA,PHI in degrees.
        #[arg(long, value_parser = parse_direction, allow_hyphen_values = true)]
        wi: Direction,
        /// Outgoing direction THETA,PHI in degrees.
        #[arg(long, value_parser = parse_direction, allow_hyphen_values = true)]
        wo: Direction,
    },
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Brdf(cmd) => brdf::run(cmd),
        Command::Instrument(cmd) => run_instrument(cmd),
        Command::Render(args) => render::run_render(args),
        Command::Compare(args) => render::run_compare(args),
        Command::Envmap(cmd) => render::run_envmap(cmd),
        Command::Plan(args) => plan::run_plan(args),
        Command::Sim(args) => measure::run_sim(args),
        Command::Measure(args) => measure::run_measure(args),
        Command::Scan(args) => scan::run_scan(args),
        Command::Calibrate(args) => scan::run_calibrate(args),
        Command::Capture(args) => scan::run_capture(args),
        Command::Estimate(args) => estimate::run_estimate(args),
        Command::Protocol => {
            use gonio_shared::frame::{MAX_PAYLOAD, MAX_WIRE_FRAME};
            use gonio_shared::msg::{caps, PROTOCOL_VERSION, SCHEMA_HASH};
            println!("protocol version {PROTOCOL_VERSION}, schema hash {SCHEMA_HASH:#010x}");
            println!("frame: COBS(seq u16 | postcard payload <= {MAX_PAYLOAD} B | CRC-32C) 0x00, <= {MAX_WIRE_FRAME} B on the wire");
            println!(
                "plan chunk: {} directions; measurement: <= {} channels",
                caps::CHUNK_DIRECTIONS,
                caps::MAX_CHANNELS
            );
            Ok(())
        }
    }
}

fn run_instrument(cmd: InstrumentCmd) -> Result<()> {
    match cmd {
        InstrumentCmd::Check { file } => {
            let cfg = instrument::load_or_default(file.as_deref())?;
            let k = Kinematics::new(cfg).context("instrument")?;
            println!(
                "{:<9} {:>10} {:>10} {:>9} {:>10} {:>11} {:>6}",
                "axis", "min deg", "max deg", "steps/deg", "max deg/s", "max step Hz", "home"
            );
            for axis in AXES {
                let c = cfg.axis(axis);
                // steps/rad * rad/deg
                let spd = k.steps_per_radian(axis).to_radians();
                let (lo, hi) = if c.continuous {
                    ("cont.".to_string(), "cont.".to_string())
                } else {
                    (
                        format!("{:.1}", c.min.to_degrees()),
                        format!("{:.1}", c.max.to_degrees()),
                    )
                };
                println!(
                    "{:<9} {:>10} {:>10} {:>9.2} {:>10.1} {:>11.0} {:>6}",
                    axis.name(),
                    lo,
                    hi,
                    spd,
                    c.max_speed.to_degrees(),
                    c.max_speed * k.steps_per_radian(axis),
                    format!("{:?}", c.home).to_lowercase()
                );
            }
            println!(
                "blocking angle {:.1} deg, settle {} ms, exposure {} us, {}",
                cfg.blocking_angle.to_degrees(),
                cfg.settle_ms,
                cfg.exposure_us,
                if cfg.isotropic { "isotropic" } else { "anisotropic" }
            );
            Ok(())
        }
        InstrumentCmd::Survey { file, pairs, seed } => {
            let cfg = instrument::load_or_default(file.as_deref())?;
            print!("{}", survey::survey(&cfg, pairs, seed)?);
            Ok(())
        }
        InstrumentCmd::Pose {
            instrument: file,
            wi,
            wo,
        } => {
            let cfg = instrument::load_or_default(file.as_deref())?;
            let k = Kinematics::new(cfg)?;
            let r = |d: f64| d.to_radians();
            let pose = k
                .inverse_angles(
                    r(wi.theta_deg),
                    r(wi.phi_deg),
                    r(wo.theta_deg),
                    r(wo.phi_deg),
                    &k.rest_pose(),
                )
                .map_err(|e| anyhow::anyhow!("unreachable: {e:?}"))?;
            let steps = k.to_steps(&pose).map_err(|e| anyhow::anyhow!("unreachable: {e:?}"))?;
            for axis in AXES {
                let note = if axis == Axis::Azimuth && cfg.isotropic {
                    "  (isotropic: not moved)"
                } else {
                    ""
                };
                println!(
                    "{:<9} {:>10.4} deg {:>9} steps{note}",
                    axis.name(),
                    pose.get(axis).to_degrees(),
                    steps[axis.index()]
                );
            }
            Ok(())
        }
    }
}
