//! The instrument description file (`gonio.toml`): degrees at the user's edge, radians inside.
//!
//! The file maps one-to-one onto `gonio_shared::InstrumentConfig`; the host validates it with the
//! same `validate()` the firmware runs on the wire copy, so both refuse the same instruments.

pub mod survey;

use gonio_shared::instrument::ConfigError;
use gonio_shared::{AxisConfig, HomeSide, InstrumentConfig};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Why an instrument file was refused.
#[derive(Debug, thiserror::Error)]
pub enum InstrumentFileError {
    #[error("cannot read instrument file {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("instrument file {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("instrument file {path}: {source}")]
    Invalid { path: PathBuf, source: ConfigError },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisFile {
    steps_per_rev: u16,
    microsteps: u16,
    gear_ratio: f64,
    max_speed_deg_s: f64,
    max_accel_deg_s2: f64,
    #[serde(default)]
    min_deg: f64,
    #[serde(default)]
    max_deg: f64,
    #[serde(default)]
    continuous: bool,
    home: HomeFile,
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "lowercase")]
enum HomeFile {
    Min,
    Max,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxesFile {
    light: AxisFile,
    detector: AxisFile,
    tilt: AxisFile,
    azimuth: AxisFile,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct InstrumentFile {
    blocking_angle_deg: f64,
    settle_ms: u32,
    exposure_us: u32,
    isotropic: bool,
    axes: AxesFile,
}

impl AxisFile {
    fn to_config(&self) -> AxisConfig<f64> {
        AxisConfig {
            steps_per_rev: self.steps_per_rev,
            microsteps: self.microsteps,
            gear_ratio: self.gear_ratio,
            max_speed: self.max_speed_deg_s.to_radians(),
            max_accel: self.max_accel_deg_s2.to_radians(),
            min: self.min_deg.to_radians(),
            max: self.max_deg.to_radians(),
            continuous: self.continuous,
            home: match self.home {
                HomeFile::Min => HomeSide::Min,
                HomeFile::Max => HomeSide::Max,
            },
        }
    }
}

/// Parse and validate an instrument description from TOML text (`origin` names it in errors).
pub fn parse(text: &str, origin: &Path) -> Result<InstrumentConfig<f64>, InstrumentFileError> {
    let file: InstrumentFile = toml::from_str(text).map_err(|e| InstrumentFileError::Parse {
        path: origin.to_path_buf(),
        // toml's message spans several lines (a source excerpt); keep the first for one-line errors.
        message: e.message().lines().next().unwrap_or("invalid TOML").to_string(),
    })?;
    let a = &file.axes;
    let cfg = InstrumentConfig {
        axes: [
            a.light.to_config(),
            a.detector.to_config(),
            a.tilt.to_config(),
            a.azimuth.to_config(),
        ],
        blocking_angle: file.blocking_angle_deg.to_radians(),
        settle_ms: file.settle_ms,
        exposure_us: file.exposure_us,
        isotropic: file.isotropic,
    };
    cfg.validate().map_err(|source| InstrumentFileError::Invalid {
        path: origin.to_path_buf(),
        source,
    })?;
    Ok(cfg)
}

/// Read, parse and validate an instrument file.
pub fn load(path: &Path) -> Result<InstrumentConfig<f64>, InstrumentFileError> {
    let text = std::fs::read_to_string(path).map_err(|source| InstrumentFileError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    parse(&text, path)
}

/// The shipped default instrument file, `examples/gonio.toml`, compiled in for when none is given.
pub const DEFAULT_INSTRUMENT_TOML: &str = include_str!("../../../examples/gonio.toml");

/// The default instrument (the one `examples/gonio.toml` describes).
pub fn default_instrument() -> InstrumentConfig<f64> {
    // The test below checks the shipped file parses; a failure here is a build defect, not input.
    parse(DEFAULT_INSTRUMENT_TOML, Path::new("examples/gonio.toml")).expect("shipped examples/gonio.toml is valid")
}

/// `path` if given, else the default instrument.
pub fn load_or_default(path: Option<&Path>) -> Result<InstrumentConfig<f64>, InstrumentFileError> {
    match path {
        Some(p) => load(p),
        None => Ok(default_instrument()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_file_is_the_reference_instrument() {
        let cfg = default_instrument();
        let reference = InstrumentConfig::<f64>::reference();
        // Same instrument up to the degree -> radian conversion's last bit.
        assert_eq!(cfg.cast::<f32>(), reference.cast::<f32>());
        for (a, b) in cfg.axes.iter().zip(reference.axes.iter()) {
            assert!((a.max_speed - b.max_speed).abs() < 1e-15 && (a.min - b.min).abs() < 1e-15);
        }
    }

    #[test]
    fn bad_files_get_one_line_errors() {
        let p = Path::new("x.toml");
        let e = parse("blocking_angle_deg = 5", p).unwrap_err().to_string();
        assert!(e.starts_with("instrument file x.toml: missing field"), "{e}");
        assert!(!e.contains('\n'), "{e}");
        let bad_tilt = DEFAULT_INSTRUMENT_TOML.replace("max_deg = 85.0", "max_deg = 95.0");
        assert_ne!(bad_tilt, DEFAULT_INSTRUMENT_TOML);
        let e = parse(&bad_tilt, p).unwrap_err().to_string();
        assert!(e.contains("tilt limits"), "{e}");
        let typo = DEFAULT_INSTRUMENT_TOML.replace("settle_ms", "setle_ms");
        let e = parse(&typo, p).unwrap_err().to_string();
        assert!(e.contains("unknown field"), "{e}");
        let e = load(Path::new("/nonexistent/gonio.toml")).unwrap_err().to_string();
        assert!(e.starts_with("cannot read instrument file"), "{e}");
    }
}
