//! What the virtual gonio's detector sees: the scene's material at the pose the axes reached,
//! turned into counts by a light-source + detector model, through the effects the scene lists.
//!
//! ## Light source and detector (the `[detector]` table of the scene, every key optional)
//!
//! ```text
//! signal = gain * irradiance * cos(theta_i) * f_r(wi, wo) * solid_angle * exposure_s   (counts)
//! counts = clamp(round(pipeline(signal) + dark_level), 0, full_scale)
//! ```
//!
//! `irradiance` (W/m^2) is what the collimated source delivers on a surface facing it; the sample
//! reflects radiance `f_r E cos(theta_i)`; the detector collects it over `solid_angle` (sr) for the
//! exposure; `gain` converts the radiant exposure (J/m^2) to counts. The defaults put a reading of
//! 1/sr at normal incidence with the reference 10 ms exposure at 6,000 counts, a 16-bit full scale.
//! `pipeline` is the renderer's per-reading effect chain (`gonio::render::effects`) built from the
//! scene's `[effects]`; with none listed it is the identity.
//!
//! ## Instrument effects (keys of the scene's `[effects]` beside the renderer's ones)
//!
//! - `misalignment = { light_deg, detector_deg, tilt_deg, azimuth_deg }`: each axis's true angle
//!   is its step angle plus this offset (a mis-mounted encoder / arm).
//! - `backlash = { light_deg, detector_deg, tilt_deg, azimuth_deg }`: the axis output lags the
//!   motor by up to this much after a reversal (a dead band), so the pose reached depends on the
//!   side it was approached from.
//! - `aperture = { half_angle_deg, samples }`: a finite detector averages the BRDF over a cone of
//!   directions around the nominal `wo` (a fixed, deterministic sample pattern).
//! - `stray_light = { brdf }`: light reaching the detector by other paths, as a BRDF-equivalent
//!   floor (1/sr) added to every channel.
//! - `limit_fault = { axis, after_readings }`: a test hook: the axis's switch closes (once) at the
//!   first step after that many readings, as a snagged cable would.
//!
//! Noise is seeded by the pose reached (its step counts), so measuring the same pose again gives
//! the same reading: a resumed scan reproduces an uninterrupted one.

use crate::brdf::Material;
use crate::render::effects::{EffectPipeline, Reading};
use glam::DVec3;
use gonio_shared::instrument::{Axis, InstrumentConfig, AXES, AXIS_COUNT};
use gonio_shared::kinematics::{Kinematics, Pose};
use serde::Deserialize;
use std::path::Path;

/// The light source + detector model (the scene's `[detector]` table).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorModel {
    pub irradiance_w_m2: f64,
    pub solid_angle_sr: f64,
    /// Counts per J/m^2 of radiant exposure.
    pub gain: f64,
    pub full_scale: u32,
    pub dark_level: f64,
    /// Detector channels (RGB = 3).
    pub channels: usize,
}

impl Default for DetectorModel {
    fn default() -> Self {
        Self {
            irradiance_w_m2: 10.0,
            solid_angle_sr: 1e-3,
            // 6000 counts = gain * 10 W/m^2 * 1e-3 sr * 0.01 s at f_r = 1/sr, normal incidence.
            gain: 6.0e7,
            full_scale: 65_535,
            dark_level: 0.0,
            channels: 3,
        }
    }
}

#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerAxisDeg {
    pub light_deg: f64,
    pub detector_deg: f64,
    pub tilt_deg: f64,
    pub azimuth_deg: f64,
}

impl PerAxisDeg {
    /// Radians, in `Axis::index` order.
    pub fn radians(&self) -> [f64; AXIS_COUNT] {
        [self.light_deg, self.detector_deg, self.tilt_deg, self.azimuth_deg].map(f64::to_radians)
    }
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ApertureConfig {
    pub half_angle_deg: f64,
    #[serde(default = "default_aperture_samples")]
    pub samples: usize,
}

fn default_aperture_samples() -> usize {
    16
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StrayLightConfig {
    pub brdf: f64,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitFaultConfig {
    pub axis: String,
    pub after_readings: u64,
}

/// The instrument's own effects, from the scene's `[effects]` (none = ideal).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InstrumentEffects {
    pub misalignment: Option<PerAxisDeg>,
    pub backlash: Option<PerAxisDeg>,
    pub aperture: Option<ApertureConfig>,
    pub stray_light: Option<StrayLightConfig>,
    pub limit_fault: Option<LimitFaultConfig>,
}

/// The keys of `[effects]` that are ours rather than the renderer's.
const INSTRUMENT_EFFECT_KEYS: [&str; 5] = ["misalignment", "backlash", "aperture", "stray_light", "limit_fault"];

/// Why a scan scene was refused (one line, naming the file).
#[derive(Debug, thiserror::Error)]
#[error("scene {path}: {reason}")]
pub struct SceneError {
    pub path: String,
    pub reason: String,
}

/// Everything the simulated detector needs, shared read-only with the simulation thread.
pub struct SimModel {
    pub material_spec: String,
    material: Box<dyn Material>,
    pipeline: EffectPipeline,
    pub detector: DetectorModel,
    pub effects: InstrumentEffects,
    /// The physical instrument (what the switches and the arms really are).
    pub instrument: InstrumentConfig<f64>,
    kin: Kinematics<f64>,
    pub limit_fault: Option<(Axis, u64)>,
}

impl std::fmt::Debug for SimModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimModel")
            .field("material", &self.material_spec)
            .field("detector", &self.detector)
            .field("effects", &self.effects)
            .finish()
    }
}

pub fn axis_by_name(name: &str) -> Option<Axis> {
    AXES.into_iter().find(|a| a.name().eq_ignore_ascii_case(name))
}

impl SimModel {
    /// Load a scan scene: the renderer's scene file plus an optional `[detector]` table and the
    /// instrument effects above in `[effects]`.
    pub fn load(path: &Path, instrument: InstrumentConfig<f64>, seed: u64) -> Result<Self, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|e| SceneError {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        Self::from_toml(&text, path, instrument, seed)
    }

    pub fn from_toml(
        text: &str,
        path: &Path,
        instrument: InstrumentConfig<f64>,
        seed: u64,
    ) -> Result<Self, SceneError> {
        let bad = |reason: String| SceneError {
            path: path.display().to_string(),
            reason,
        };
        let mut table: toml::Table =
            toml::from_str(text).map_err(|e| bad(e.message().lines().next().unwrap_or("invalid TOML").to_string()))?;
        let detector = match table.remove("detector") {
            None => DetectorModel::default(),
            Some(v) => v
                .try_into()
                .map_err(|e: toml::de::Error| bad(format!("[detector]: {}", e.message())))?,
        };
        let mut ours = toml::Table::new();
        if let Some(toml::Value::Table(effects)) = table.get_mut("effects") {
            for key in INSTRUMENT_EFFECT_KEYS {
                if let Some(v) = effects.remove(key) {
                    ours.insert(key.to_string(), v);
                }
            }
        }
        let effects: InstrumentEffects = toml::Value::Table(ours)
            .try_into()
            .map_err(|e: toml::de::Error| bad(format!("[effects]: {}", e.message())))?;
        // The rest is a renderer scene: the renderer validates the material and its effects.
        let rest = toml::to_string(&table).map_err(|e| bad(e.to_string()))?;
        let scene = crate::render::scene::Scene::from_toml(&rest, path).map_err(|e| match e {
            crate::render::RenderError::Scene { reason, .. } => bad(reason),
            other => bad(other.to_string()),
        })?;
        let pipeline = match &scene.effects {
            Some(cfg) => EffectPipeline::from_config(cfg, seed).map_err(bad)?,
            None => EffectPipeline::default(),
        };
        check_detector(&detector).map_err(bad)?;
        let limit_fault = match &effects.limit_fault {
            None => None,
            Some(l) => Some((
                axis_by_name(&l.axis)
                    .ok_or_else(|| bad(format!("effects.limit_fault.axis: no axis named {:?}", l.axis)))?,
                l.after_readings,
            )),
        };
        if let Some(a) = &effects.aperture {
            let ok = (0.0..45.0).contains(&a.half_angle_deg) && (1..=1024).contains(&a.samples);
            if !ok {
                return Err(bad(
                    "effects.aperture: needs 0 <= half_angle_deg < 45 and 1 <= samples <= 1024".into(),
                ));
            }
        }
        if let Some(s) = &effects.stray_light {
            if !(s.brdf.is_finite() && s.brdf >= 0.0) {
                return Err(bad("effects.stray_light.brdf must be finite and >= 0".into()));
            }
        }
        for (key, v) in [("misalignment", &effects.misalignment), ("backlash", &effects.backlash)] {
            if let Some(v) = v {
                if !v.radians().iter().all(|x| x.is_finite() && x.abs() < 0.5) {
                    return Err(bad(format!(
                        "effects.{key}: every angle must be finite and below 28 degrees"
                    )));
                }
            }
        }
        let kin = Kinematics::new(instrument).map_err(|e| bad(format!("instrument: {e}")))?;
        Ok(Self {
            material_spec: scene.material_spec,
            material: scene.material,
            pipeline,
            detector,
            effects,
            instrument,
            kin,
            limit_fault,
        })
    }

    /// The same scene (detector, effects, instrument) with another sample in the holder: what a
    /// calibration reference is measured with.
    pub fn from_toml_with_material(
        text: &str,
        path: &Path,
        instrument: InstrumentConfig<f64>,
        seed: u64,
        material: &str,
    ) -> Result<Self, SceneError> {
        let bad = |reason: String| SceneError {
            path: path.display().to_string(),
            reason,
        };
        let mut table: toml::Table =
            toml::from_str(text).map_err(|e| bad(e.message().lines().next().unwrap_or("invalid TOML").to_string()))?;
        match table.get_mut("object") {
            Some(toml::Value::Table(object)) => {
                object.insert("material".into(), toml::Value::String(material.to_string()));
            }
            _ => return Err(bad("no [object] table".into())),
        }
        let text = toml::to_string(&table).map_err(|e| bad(e.to_string()))?;
        Self::from_toml(&text, path, instrument, seed)
    }

    /// An ideal model of a material (no effects), for tests and code-built scans.
    pub fn ideal(spec: &str, instrument: InstrumentConfig<f64>) -> Result<Self, SceneError> {
        let text = format!(
            "[camera]\nkind = \"orthographic\"\nwidth = 8\nheight = 8\n[object]\nshape = \"sphere\"\nmaterial = {spec:?}\n"
        );
        Self::from_toml(&text, Path::new("<built-in>"), instrument, 0)
    }

    pub fn kinematics(&self) -> &Kinematics<f64> {
        &self.kin
    }

    /// Backlash dead band per axis, in steps.
    pub fn backlash_steps(&self) -> [f64; AXIS_COUNT] {
        match &self.effects.backlash {
            None => [0.0; AXIS_COUNT],
            Some(b) => {
                let r = b.radians();
                AXES.map(|a| r[a.index()] * self.kin.steps_per_radian(a))
            }
        }
    }

    /// The true pose of axis outputs at (fractional) step positions, misalignment included.
    pub fn pose_at(&self, out_steps: &[f64; AXIS_COUNT]) -> Pose<f64> {
        let offset = self
            .effects
            .misalignment
            .as_ref()
            .map_or([0.0; AXIS_COUNT], PerAxisDeg::radians);
        Pose::from_array(AXES.map(|a| out_steps[a.index()] / self.kin.steps_per_radian(a) + offset[a.index()]))
    }

    /// The BRDF the detector sees at a true pose (aperture averaging and stray light included).
    pub fn brdf_seen(&self, pose: &Pose<f64>) -> (DVec3, f64) {
        let (wi, wo) = self.kin.forward(pose);
        let wi = DVec3::new(wi.x, wi.y, wi.z);
        let wo = DVec3::new(wo.x, wo.y, wo.z);
        let mut f = match &self.effects.aperture {
            Some(a) if a.half_angle_deg > 0.0 => {
                let cone = cone_directions(wo, a.half_angle_deg.to_radians(), a.samples);
                let n = cone.len().max(1) as f64;
                cone.iter().map(|&w| self.material.eval(wi, w)).sum::<DVec3>() / n
            }
            _ => self.material.eval(wi, wo),
        };
        if let Some(s) = &self.effects.stray_light {
            f += DVec3::splat(s.brdf);
        }
        (f, wi.z.max(0.0))
    }

    /// Detector counts for one exposure at a true pose. `reading_key` seeds the noise.
    pub fn counts(&self, pose: &Pose<f64>, exposure_us: u32, time_s: f64, reading_key: u64) -> Vec<u32> {
        let (f, cos_i) = self.brdf_seen(pose);
        let d = &self.detector;
        let scale = d.gain * d.irradiance_w_m2 * cos_i * d.solid_angle_sr * f64::from(exposure_us) * 1e-6;
        let rgb = [f.x, f.y, f.z];
        let mut channels: Vec<f64> = (0..d.channels)
            .map(|c| rgb.get(c).copied().unwrap_or(f.y) * scale)
            .collect();
        self.pipeline.apply_reading(
            &mut channels,
            Reading {
                index: reading_key,
                time_s,
            },
        );
        channels
            .iter()
            .map(|&v| {
                let v = (v + d.dark_level).round();
                // NaN (cannot come from a material, which never returns NaN) reads as 0.
                if v.is_nan() {
                    0
                } else {
                    v.clamp(0.0, f64::from(d.full_scale)) as u32
                }
            })
            .collect()
    }
}

fn check_detector(d: &DetectorModel) -> Result<(), String> {
    let ok = |v: f64| v.is_finite() && v >= 0.0;
    if !(ok(d.irradiance_w_m2) && ok(d.solid_angle_sr) && ok(d.gain) && ok(d.dark_level)) {
        return Err("[detector]: irradiance_w_m2, solid_angle_sr, gain and dark_level must be finite and >= 0".into());
    }
    if d.full_scale == 0 || !(1..=gonio_shared::msg::caps::MAX_CHANNELS).contains(&d.channels) {
        return Err(format!(
            "[detector]: needs full_scale > 0 and 1..={} channels",
            gonio_shared::msg::caps::MAX_CHANNELS
        ));
    }
    Ok(())
}

/// `n` directions spread over a cone of half-angle `half` around `axis`: the axis itself, then a
/// Fibonacci spiral with equal solid angle per sample (deterministic, so readings repeat).
pub fn cone_directions(axis: DVec3, half: f64, n: usize) -> Vec<DVec3> {
    let axis = axis.normalize_or_zero();
    if n <= 1 || axis == DVec3::ZERO {
        return vec![axis];
    }
    let helper = if axis.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let t = axis.cross(helper).normalize();
    let b = axis.cross(t);
    let cos_max = half.cos();
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|k| {
            let u = (k as f64 + 0.5) / n as f64;
            let cos_t = 1.0 - u * (1.0 - cos_max);
            let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
            let phi = golden * k as f64;
            (axis * cos_t + t * (sin_t * phi.cos()) + b * (sin_t * phi.sin())).normalize()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_shared::kinematics::Pose;

    fn cfg() -> InstrumentConfig<f64> {
        crate::instrument::default_instrument()
    }

    fn scene(material: &str, effects: &str) -> SimModel {
        let text = format!(
            "[camera]\nkind = \"orthographic\"\nwidth = 8\nheight = 8\n[object]\nshape = \"sphere\"\nmaterial = \"{material}\"\n{effects}"
        );
        SimModel::from_toml(&text, Path::new("t.toml"), cfg(), 3).unwrap()
    }

    /// A pose in the plane of incidence: wi at theta_i, wo at theta_o on the other side.
    fn pose(theta_i_deg: f64, theta_o_deg: f64) -> Pose<f64> {
        let m = scene("lambert:albedo=0.5", "");
        let k = m.kinematics();
        k.inverse_angles(
            theta_i_deg.to_radians(),
            0.0,
            theta_o_deg.to_radians(),
            std::f64::consts::PI,
            &k.rest_pose(),
        )
        .unwrap()
    }

    #[test]
    fn ideal_counts_follow_the_documented_formula() {
        let m = scene("lambert:albedo=0.5", "");
        let p = pose(30.0, 20.0);
        let got = m.counts(&p, 10_000, 0.0, 0);
        let d = DetectorModel::default();
        let want = d.gain
            * d.irradiance_w_m2
            * 30f64.to_radians().cos()
            * (0.5 / std::f64::consts::PI)
            * d.solid_angle_sr
            * 0.01;
        assert_eq!(got.len(), 3);
        for c in got {
            assert!((f64::from(c) - want).abs() <= 1.0, "{c} vs {want}");
        }
        // Full scale clamps; dark level adds.
        let bright = scene("lambert:albedo=0.5", "[detector]\ngain = 1e12\ndark_level = 5.0\n");
        assert_eq!(bright.counts(&p, 10_000, 0.0, 0), vec![65_535; 3]);
        let dark = scene("lambert:albedo=0.5", "[detector]\ngain = 0.0\ndark_level = 5.0\n");
        assert_eq!(dark.counts(&p, 10_000, 0.0, 0), vec![5; 3]);
    }

    #[test]
    fn misalignment_moves_the_true_pose() {
        let ideal = scene("ggx:alpha=0.1", "");
        let tilted = scene("ggx:alpha=0.1", "[effects]\nmisalignment = { tilt_deg = 2.0 }\n");
        let steps = [1000.0, -1000.0, 0.0, 0.0];
        let a = ideal.pose_at(&steps);
        let b = tilted.pose_at(&steps);
        assert!((b.tilt - a.tilt - 2f64.to_radians()).abs() < 1e-12);
        assert_eq!(a.light, b.light);
        // At the specular peak, the same step positions read less on the misaligned instrument.
        let k = ideal.kinematics();
        let p = pose(30.0, 30.0);
        let at = k.to_steps(&p).unwrap().map(f64::from);
        let peak = ideal.brdf_seen(&ideal.pose_at(&at)).0.x;
        let off = tilted.brdf_seen(&tilted.pose_at(&at)).0.x;
        assert!(off < 0.9 * peak, "{off} vs {peak}");
    }

    #[test]
    fn aperture_averages_a_sharp_peak_down_and_leaves_lambert_alone() {
        let p = pose(30.0, 30.0);
        let sharp = scene("ggx:alpha=0.05", "").brdf_seen(&p).0.x;
        let wide = scene(
            "ggx:alpha=0.05",
            "[effects]\naperture = { half_angle_deg = 5.0, samples = 32 }\n",
        )
        .brdf_seen(&p)
        .0
        .x;
        assert!(wide < 0.8 * sharp, "{wide} vs {sharp}");
        let l0 = scene("lambert:albedo=0.5", "").brdf_seen(&p).0.x;
        let l1 = scene("lambert:albedo=0.5", "[effects]\naperture = { half_angle_deg = 5.0 }\n")
            .brdf_seen(&p)
            .0
            .x;
        assert!((l0 - l1).abs() < 1e-12);
        // The cone's directions are within the half angle.
        let axis = DVec3::new(0.3, 0.1, 0.9).normalize();
        for w in cone_directions(axis, 0.1, 50) {
            assert!(w.dot(axis) >= 0.1f64.cos() - 1e-12);
        }
    }

    #[test]
    fn stray_light_adds_a_floor() {
        let p = pose(30.0, 20.0);
        let a = scene("lambert:albedo=0.5", "").brdf_seen(&p).0;
        let b = scene("lambert:albedo=0.5", "[effects]\nstray_light = { brdf = 0.01 }\n")
            .brdf_seen(&p)
            .0;
        assert!((b - a - DVec3::splat(0.01)).abs().max_element() < 1e-12);
    }

    #[test]
    fn renderer_effects_apply_per_reading_and_repeat_for_the_same_key() {
        let p = pose(30.0, 20.0);
        let noisy = scene(
            "lambert:albedo=0.5",
            "[effects]\nshot_noise = { photons_per_unit = 1.0 }\n",
        );
        let a = noisy.counts(&p, 10_000, 0.0, 7);
        assert_eq!(a, noisy.counts(&p, 10_000, 0.0, 7), "same pose key, same noise");
        let ideal = scene("lambert:albedo=0.5", "").counts(&p, 10_000, 0.0, 7);
        let others: Vec<Vec<u32>> = (0..8).map(|k| noisy.counts(&p, 10_000, 0.0, k)).collect();
        assert!(others.iter().any(|c| *c != ideal), "shot noise changed nothing");
    }

    #[test]
    fn scene_errors_are_one_line_and_name_the_file() {
        let bad = |text: &str| {
            SimModel::from_toml(text, Path::new("s.toml"), cfg(), 0)
                .unwrap_err()
                .to_string()
        };
        let base = "[camera]\nkind = \"orthographic\"\nwidth = 8\nheight = 8\n[object]\nshape = \"sphere\"\n";
        for (text, expect) in [
            (format!("{base}material = \"ggx:alpha=x\"\n"), "s.toml"),
            (format!("{base}material = \"lambert:albedo=0.5\"\n[detector]\ngain = -1.0\n"), "gain"),
            (format!("{base}material = \"lambert:albedo=0.5\"\n[effects]\nbacklash = {{ tilt_deg = 90.0 }}\n"), "backlash"),
            (format!("{base}material = \"lambert:albedo=0.5\"\n[effects]\nlimit_fault = {{ axis = \"elbow\", after_readings = 1 }}\n"), "elbow"),
        ] {
            let e = bad(&text);
            assert!(e.contains(expect) && e.starts_with("scene s.toml") && !e.contains('\n'), "{e}");
        }
    }
}
