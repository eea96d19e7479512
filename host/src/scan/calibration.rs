//! Counts -> BRDF: a dark reading and a white reference, fitted per detector channel.
//!
//! The detector model (`sim::model`, and what a real photodiode + collimated source obey) is
//!
//! ```text
//! counts_c = dark_c + gain_c * f_r,c(wi, wo) * cos(theta_i) * exposure / exposure_ref
//! ```
//!
//! where `gain_c` lumps the source irradiance, the detector's solid angle and responsivity and the
//! reference exposure. Calibration measures
//!
//! 1. a **dark reading**: a light trap (a black sample, `lambert:albedo=0` in the simulation) at the
//!    calibration directions; `dark_c` is the mean, which also takes in the stray light the
//!    instrument adds to every reading;
//! 2. a **white reference**: a Lambertian standard of known albedo `rho_c` (f_r = rho_c / pi) at the
//!    same directions; `gain_c` is the least-squares slope through the origin of
//!    `counts_c - dark_c` against `x = rho_c / pi * cos(theta_i reached) * exposure / exposure_ref`.
//!
//! `theta_i` is that of the pose the axes reached (forward kinematics of the reported steps), as in
//! a scan. The inverse, [`Calibration::brdf`], is what a scan applies to every reading.

use crate::link::{reached, Link, LinkError, MeasurementSink, SerialTransport};
use glam::DVec3;
use gonio_shared::instrument::InstrumentConfig;
use gonio_shared::kinematics::Kinematics;
use gonio_shared::msg::{Direction, Measurement};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Below this cos(theta_i) a reading carries no reflectance information (the light grazes the
/// sample): its BRDF is reported as 0 rather than a division by ~0.
pub const COS_THETA_I_MIN: f64 = 1e-6;

/// The default white standard: a Spectralon-like diffuse reflector.
pub const DEFAULT_WHITE: &str = "lambert:albedo=0.99";
/// The dark reference of the simulation: a perfect light trap.
pub const DARK_TRAP: &str = "lambert:albedo=0";

#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    #[error("calibration {path}: {reason}")]
    File { path: String, reason: String },
    #[error("calibration: {0}")]
    Fit(String),
    #[error("calibration: {0}")]
    Link(#[from] LinkError),
    #[error("calibration: cannot open port {port}: {error}")]
    Open { port: String, error: std::io::Error },
}

/// A fitted counts -> BRDF conversion (`calibration.toml`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// Format version of this file.
    pub format: u32,
    /// The white reference's material spec (its albedo is what the gains are relative to).
    pub reference: String,
    /// Exposure the gains refer to (microseconds).
    pub exposure_us: u32,
    /// Dark counts per channel.
    pub dark_counts: Vec<f64>,
    /// Counts per (1/sr x cos theta_i) at `exposure_us`, per channel.
    pub gain: Vec<f64>,
    /// Readings of each reference.
    pub readings: usize,
    /// RMS of the white fit's residuals relative to the mean white signal, per channel.
    pub fit_rel_rms: Vec<f64>,
    /// Where it was measured (a port or a simulated scene).
    pub source: String,
}

pub const FORMAT: u32 = 1;

impl Calibration {
    pub fn read(path: &Path) -> Result<Self, CalibrationError> {
        let bad = |reason: String| CalibrationError::File {
            path: path.display().to_string(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
        let cal: Calibration =
            toml::from_str(&text).map_err(|e| bad(e.message().lines().next().unwrap_or("invalid TOML").to_string()))?;
        cal.check().map_err(bad)?;
        Ok(cal)
    }

    pub fn to_toml(&self) -> String {
        // Plain data (numbers, strings, arrays): serialisation cannot fail.
        toml::to_string(self).unwrap_or_default()
    }

    /// Refuse a calibration that cannot convert readings (what a hand-edited file could hold).
    pub fn check(&self) -> Result<(), String> {
        if self.format != FORMAT {
            return Err(format!("format {} is not {FORMAT}", self.format));
        }
        let channels = self.gain.len();
        if channels == 0 || channels > gonio_shared::msg::caps::MAX_CHANNELS || self.dark_counts.len() != channels {
            return Err("needs one dark count and one gain per channel".into());
        }
        if !self.gain.iter().all(|g| g.is_finite() && *g > 0.0) {
            return Err("every gain must be finite and > 0".into());
        }
        if !self.dark_counts.iter().all(|d| d.is_finite() && *d >= 0.0) {
            return Err("every dark count must be finite and >= 0".into());
        }
        if self.exposure_us == 0 {
            return Err("exposure_us must be > 0".into());
        }
        Ok(())
    }

    /// The BRDF (1/sr, RGB) of one reading at a reached `cos_theta_i`. A single-channel detector
    /// reads grey. Values below the dark level (noise) are clamped to 0: a BRDF is never negative.
    pub fn brdf(&self, counts: &[u32], cos_theta_i: f64, exposure_us: u32) -> Result<DVec3, String> {
        if counts.len() != self.gain.len() {
            return Err(format!(
                "a reading has {} channels, the calibration {}",
                counts.len(),
                self.gain.len()
            ));
        }
        if !(cos_theta_i > COS_THETA_I_MIN) || exposure_us == 0 {
            return Ok(DVec3::ZERO);
        }
        let scale = cos_theta_i * f64::from(exposure_us) / f64::from(self.exposure_us);
        let f: Vec<f64> = counts
            .iter()
            .zip(self.gain.iter().zip(&self.dark_counts))
            .map(|(&c, (&g, &d))| ((f64::from(c) - d) / (g * scale)).max(0.0))
            .collect();
        Ok(match f.as_slice() {
            [v] => DVec3::splat(*v),
            [r, g, b, ..] => DVec3::new(*r, *g, *b),
            [r, g] => DVec3::new(*r, *g, *g),
            [] => DVec3::ZERO,
        })
    }
}

/// The albedo of a Lambertian reference spec, per channel.
pub fn reference_albedo(spec: &str) -> Result<DVec3, CalibrationError> {
    match crate::brdf::spec::parse_analytic(spec) {
        Ok(crate::brdf::spec::Analytic::Lambert(m)) if m.albedo.min_element() > 0.0 => Ok(m.albedo),
        _ => Err(CalibrationError::Fit(format!(
            "the white reference must be a Lambertian spec with albedo > 0 (lambert:albedo=R/G/B), got {spec:?}"
        ))),
    }
}

/// The calibration directions: incoming theta 0..70 deg in 10 deg steps, each seen at 15 and
/// 35 deg on the far side of the normal (in the plane of incidence, away from the blocked cone and
/// the tilt limits), ordered as a serpentine so the arms move little.
pub fn directions() -> Vec<Direction> {
    let mut out = Vec::new();
    for (row, ti) in (0..8).map(|r| (r, 10.0f32 * r as f32)) {
        let outs: [f32; 2] = if row % 2 == 0 { [15.0, 35.0] } else { [35.0, 15.0] };
        for to in outs {
            out.push(Direction {
                theta_i: ti.to_radians(),
                phi_i: 0.0,
                theta_o: to.to_radians(),
                phi_o: std::f32::consts::PI,
            });
        }
    }
    out
}

struct Collect(Vec<Measurement>);

impl MeasurementSink for Collect {
    fn record(&mut self, m: &Measurement) -> Result<(), String> {
        self.0.push(m.clone());
        Ok(())
    }
    fn sync(&mut self) -> Result<(), String> {
        Ok(())
    }
}

/// Measure `directions` on whatever sample is in the gonio at `port` (handshake, configure, home,
/// stream, collect), in plan order.
pub fn measure_reference(
    port: &str,
    cfg: &InstrumentConfig<f64>,
    directions: &[Direction],
    timing: crate::link::LinkTiming,
) -> Result<Vec<Measurement>, CalibrationError> {
    let t = SerialTransport::open(port).map_err(|error| CalibrationError::Open {
        port: port.to_string(),
        error,
    })?;
    let mut link = Link::connect(t, timing)?;
    link.prepare(&cfg.cast::<f32>())?;
    let mut sink = Collect(Vec::new());
    link.scan(directions, &mut sink)?;
    let mut readings = sink.0;
    readings.sort_by_key(|m| m.index);
    Ok(readings)
}

/// Fit dark levels and gains from a dark and a white set of readings (see the module doc).
pub fn fit(
    cfg: &InstrumentConfig<f64>,
    reference: &str,
    dark: &[Measurement],
    white: &[Measurement],
    source: &str,
) -> Result<Calibration, CalibrationError> {
    let albedo = reference_albedo(reference)?;
    let kin = Kinematics::new(*cfg).map_err(|e| CalibrationError::Fit(format!("instrument: {e}")))?;
    let channels = white.first().map_or(0, |m| m.counts.len());
    if dark.is_empty() || white.is_empty() || channels == 0 {
        return Err(CalibrationError::Fit("no readings".into()));
    }
    if dark.iter().chain(white).any(|m| m.counts.len() != channels) {
        return Err(CalibrationError::Fit(
            "readings differ in their number of channels".into(),
        ));
    }
    let exposure_us = white[0].exposure_us;
    if exposure_us == 0 {
        return Err(CalibrationError::Fit("the device reported a zero exposure".into()));
    }
    let dark_counts: Vec<f64> = (0..channels)
        .map(|c| dark.iter().map(|m| f64::from(m.counts[c])).sum::<f64>() / dark.len() as f64)
        .collect();
    let rho = |c: usize| albedo.to_array().get(c).copied().unwrap_or(albedo.y);
    let mut gain = Vec::with_capacity(channels);
    let mut fit_rel_rms = Vec::with_capacity(channels);
    for (c, &dark_c) in dark_counts.iter().enumerate() {
        let points: Vec<(f64, f64)> = white
            .iter()
            .map(|m| {
                let cos_i = reached(&kin, &m.steps)[0].cos();
                let x =
                    rho(c) / std::f64::consts::PI * cos_i.max(0.0) * f64::from(m.exposure_us) / f64::from(exposure_us);
                (x, f64::from(m.counts[c]) - dark_c)
            })
            .collect();
        let sxx: f64 = points.iter().map(|(x, _)| x * x).sum();
        let sxy: f64 = points.iter().map(|(x, y)| x * y).sum();
        // sxx = 0 only if every reading had the light at grazing incidence.
        let g = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        if !(g.is_finite() && g > 0.0) {
            return Err(CalibrationError::Fit(format!(
                "channel {c}: the white reference reads no signal above the dark level"
            )));
        }
        let mean_y = points.iter().map(|(_, y)| y).sum::<f64>() / points.len() as f64;
        let rms = (points.iter().map(|(x, y)| (y - g * x).powi(2)).sum::<f64>() / points.len() as f64).sqrt();
        gain.push(g);
        fit_rel_rms.push(rms / mean_y.abs().max(1e-12));
    }
    let cal = Calibration {
        format: FORMAT,
        reference: reference.to_string(),
        exposure_us,
        dark_counts,
        gain,
        readings: white.len(),
        fit_rel_rms,
        source: source.to_string(),
    };
    cal.check().map_err(CalibrationError::Fit)?;
    Ok(cal)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cal() -> Calibration {
        Calibration {
            format: FORMAT,
            reference: DEFAULT_WHITE.into(),
            exposure_us: 10_000,
            dark_counts: vec![100.0, 50.0, 0.0],
            gain: vec![6000.0, 3000.0, 1500.0],
            readings: 16,
            fit_rel_rms: vec![0.0; 3],
            source: "test".into(),
        }
    }

    #[test]
    fn brdf_inverts_the_detector_model() {
        let c = cal();
        // f = 0.5 at cos 0.5 and twice the exposure: counts = dark + gain * 0.5 * 0.5 * 2.
        let f = c.brdf(&[100 + 3000, 50 + 1500, 750], 0.5, 20_000).unwrap();
        assert!((f - DVec3::splat(0.5)).abs().max_element() < 1e-12, "{f}");
        // Below the dark level: 0, never negative; grazing light: 0, never a division by ~0.
        assert_eq!(c.brdf(&[0, 0, 0], 0.5, 10_000).unwrap(), DVec3::ZERO);
        assert_eq!(c.brdf(&[9000, 9000, 9000], 0.0, 10_000).unwrap(), DVec3::ZERO);
        assert!(c.brdf(&[1, 2], 0.5, 10_000).is_err());
    }

    #[test]
    fn the_file_round_trips_and_bad_values_are_refused() {
        let c = cal();
        let back: Calibration = toml::from_str(&c.to_toml()).unwrap();
        assert_eq!(back, c);
        let mut bad = c.clone();
        bad.gain[1] = 0.0;
        assert!(bad.check().is_err());
        let mut bad = c;
        bad.dark_counts.pop();
        assert!(bad.check().is_err());
    }

    #[test]
    fn the_white_reference_must_be_lambertian() {
        assert!(reference_albedo("lambert:albedo=0.9").is_ok());
        assert!(reference_albedo("lambert:albedo=0").is_err());
        assert!(reference_albedo("ggx:alpha=0.1").is_err());
    }
}
