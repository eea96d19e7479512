//! `gonio brdf ...`: evaluate, tabulate and fit materials given as spec strings (see `gonio::brdf::spec`).
//! Degrees at this edge, radians inside.

use anyhow::{Context, Result};
use gonio::brdf::fit::{fit, FitModel};
use gonio::brdf::frame::from_spherical;
use gonio::brdf::merl::{MerlTable, FILE_BYTES};
use gonio::brdf::parse_material;
use std::path::PathBuf;

#[derive(clap::Subcommand, Debug)]
pub enum BrdfCmd {
    /// Evaluate a material for one direction pair; prints R G B in 1/sr.
    Eval {
        /// Material spec, e.g. ggx:alpha=0.2,diffuse=0.1/0.2/0.3 or nbrdf:alum-bronze.
        material: String,
        /// Direction toward the light: THETA,PHI in degrees.
        #[arg(long, value_parser = parse_direction, allow_hyphen_values = true)]
        wi: Direction,
        /// Direction toward the detector: THETA,PHI in degrees.
        #[arg(long, value_parser = parse_direction, allow_hyphen_values = true)]
        wo: Direction,
        /// Print one JSON object instead of plain numbers.
        #[arg(long)]
        json: bool,
    },
    /// Tabulate a material into a MERL .binary file (90 x 90 x 180 bins, evaluated at bin centres).
    Tabulate {
        material: String,
        /// Output file; written to a temporary name beside it, then renamed.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Fit an analytic model to a material (least squares on log(1 + f cos theta_o)); prints its spec.
    Fit {
        material: String,
        #[arg(long, value_enum)]
        model: ModelArg,
        /// Which direction pairs the fit sees: `hemisphere`, the documented set of `brdf::fit` (the
        /// encoder's MERL labels), or `capture`, one pair per lit pixel of the 64 x 64 capture photo
        /// (`examples/capture.toml`): what the encoder's photo can show of the material.
        #[arg(long, value_enum, default_value = "hemisphere")]
        directions: FitDirections,
    },
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitDirections {
    Hemisphere,
    Capture,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum ModelArg {
    Ggx,
    Ward,
}

/// A direction as given on the command line, in degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Direction {
    pub theta_deg: f64,
    pub phi_deg: f64,
}

/// Parse `THETA,PHI` in degrees (the form every `--wi`/`--wo` option of the CLI takes).
pub fn parse_direction(s: &str) -> Result<Direction, String> {
    let (t, p) = s
        .split_once(',')
        .ok_or_else(|| format!("expected THETA,PHI in degrees, got '{s}'"))?;
    let num = |x: &str| {
        x.trim()
            .parse::<f64>()
            .map_err(|_| format!("'{}' is not a number (in '{s}')", x.trim()))
    };
    let (theta_deg, phi_deg) = (num(t)?, num(p)?);
    if !theta_deg.is_finite() || !phi_deg.is_finite() {
        return Err(format!("direction '{s}' is not finite"));
    }
    if !(0.0..=180.0).contains(&theta_deg) {
        return Err(format!("theta {theta_deg} is outside [0, 180] degrees"));
    }
    Ok(Direction { theta_deg, phi_deg })
}

pub fn run(cmd: BrdfCmd) -> Result<()> {
    match cmd {
        BrdfCmd::Eval { material, wi, wo, json } => {
            let m = parse_material(&material)?;
            let dir = |d: Direction| from_spherical(d.theta_deg.to_radians(), d.phi_deg.to_radians());
            let f = m.eval(dir(wi), dir(wo));
            if json {
                let out = serde_json::json!({
                    "material": material,
                    "wi_deg": [wi.theta_deg, wi.phi_deg],
                    "wo_deg": [wo.theta_deg, wo.phi_deg],
                    "rgb_per_sr": [f.x, f.y, f.z],
                });
                println!("{out}");
            } else {
                println!("{} {} {}", f.x, f.y, f.z);
            }
            Ok(())
        }
        BrdfCmd::Tabulate { material, output } => {
            let m = parse_material(&material)?;
            let table = MerlTable::tabulate(m.as_ref());
            table.write(&output).with_context(|| format!("tabulating {material}"))?;
            println!("wrote {} ({} bytes)", output.display(), FILE_BYTES);
            Ok(())
        }
        BrdfCmd::Fit {
            material,
            model,
            directions,
        } => {
            let m = parse_material(&material)?;
            let model = match model {
                ModelArg::Ggx => FitModel::Ggx,
                ModelArg::Ward => FitModel::Ward,
            };
            let r = match directions {
                FitDirections::Hemisphere => fit(m.as_ref(), model),
                FitDirections::Capture => {
                    gonio::encoder::observable::observable_fit(m.as_ref(), model).map_err(anyhow::Error::msg)?
                }
            };
            println!("{}", r.model.to_spec());
            println!(
                "rms log(1 + f cos) residual {:.5} over {} direction pairs",
                r.rms_log_error, r.pairs
            );
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(subcommand)]
        cmd: BrdfCmd,
    }

    #[test]
    fn parses_and_runs_the_subcommands() {
        let cli = Cli::try_parse_from([
            "x",
            "eval",
            "lambert:albedo=0.5",
            "--wi",
            "30,0",
            "--wo",
            "45,-90",
            "--json",
        ]);
        let cmd = cli.expect("parses").cmd;
        assert!(matches!(&cmd, BrdfCmd::Eval { wo, json: true, .. } if wo.phi_deg == -90.0));
        run(cmd).expect("eval runs");
        assert!(Cli::try_parse_from(["x", "eval", "lambert:albedo=0.5", "--wi", "30", "--wo", "0,0"]).is_err());
        assert!(Cli::try_parse_from(["x", "eval", "lambert:albedo=0.5", "--wi", "200,0", "--wo", "0,0"]).is_err());
        let err = run(BrdfCmd::Fit {
            material: "ggx:alpha=x".into(),
            model: ModelArg::Ggx,
            directions: FitDirections::Capture,
        })
        .err()
        .map(|e| format!("{e:#}"));
        assert_eq!(
            err.as_deref(),
            Some("bad material spec 'ggx:alpha=x': alpha: 'x' is not a number")
        );
        let dir = tempfile::tempdir().expect("temp dir");
        let out = dir.path().join("l.binary");
        run(BrdfCmd::Tabulate {
            material: "lambert:albedo=0.5".into(),
            output: out.clone(),
        })
        .expect("tabulate");
        assert_eq!(
            std::fs::metadata(&out).map(|m| m.len()).ok(),
            Some(super::FILE_BYTES as u64)
        );
        // Only the output remains: the temporary file was renamed.
        assert_eq!(std::fs::read_dir(dir.path()).map(|d| d.count()).ok(), Some(1));
    }
}
