//! Scene files (TOML). Every table and key is documented in `examples/sphere-point.toml`; unknown
//! keys are refused, and every error is one line naming the file (and line, for syntax and keys).
//!
//! ```toml
//! [camera]
//! kind = "orthographic"      # or "perspective" with fov_deg (vertical), position, [look_at], [up]
//! width = 256
//! height = 256
//! [object]
//! shape = "sphere"           # unit sphere at the origin; "plane" = the square |x|,|y| <= 1 at z = 0, facing +z
//! material = "ggx:alpha=0.2"
//! [[light]]
//! kind = "point"             # radiance = f I cos(theta_i) / d^2
//! position = [2.0, 2.0, 5.0]
//! intensity = 30.0           # W/sr
//! [[light]]
//! kind = "directional"       # radiance = f E cos(theta_i)
//! direction = [0.0, 1.0, 1.0]  # toward the light (normalised on load)
//! irradiance = 2.0           # W/m^2 on a surface facing the light
//! [[light]]
//! kind = "environment"       # at most one; path relative to the scene file
//! file = "sky.exr"
//! scale = 1.0
//! [render]                   # all optional
//! spp = 64                   # environment samples per pixel (each one light + one BRDF sample, MIS)
//! pixel_samples = 2          # a 2 x 2 sub-pixel grid per pixel
//! seed = 1
//! background = "black"       # or "environment": rays that miss the object see the environment
//! [effects]                  # see `effects`: exposure, shot_noise, read_noise, dark_offset, adc, drift
//! ```

use super::brdf_sampling::BrdfSampler;
use super::effects::EffectsConfig;
use super::envmap::EnvMap;
use super::geometry::{Camera, Projection, Shape};
use super::RenderError;
use crate::brdf::{parse_material, Material};
use glam::DVec3;
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    camera: CameraFile,
    object: ObjectFile,
    #[serde(default)]
    light: Vec<LightFile>,
    #[serde(default)]
    render: RenderFile,
    effects: Option<EffectsConfig>,
}

#[derive(Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
enum CameraFile {
    Orthographic {
        width: usize,
        height: usize,
    },
    Perspective {
        width: usize,
        height: usize,
        fov_deg: f64,
        position: [f64; 3],
        #[serde(default)]
        look_at: [f64; 3],
        #[serde(default = "default_up")]
        up: [f64; 3],
    },
}

fn default_up() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectFile {
    shape: ShapeFile,
    material: String,
}

#[derive(Deserialize, Clone, Copy)]
#[serde(rename_all = "lowercase")]
enum ShapeFile {
    Sphere,
    Plane,
}

#[derive(Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
enum LightFile {
    Point {
        position: [f64; 3],
        intensity: f64,
    },
    Directional {
        direction: [f64; 3],
        irradiance: f64,
    },
    Environment {
        file: PathBuf,
        #[serde(default = "default_scale")]
        scale: f64,
    },
}

fn default_scale() -> f64 {
    1.0
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RenderFile {
    spp: Option<u32>,
    pixel_samples: Option<u32>,
    seed: Option<u64>,
    background: Option<Background>,
}

/// What a ray that misses the object sees.
#[derive(Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Background {
    #[default]
    Black,
    Environment,
}

/// Sampling settings: from the scene's `[render]`, overridable on the command line.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Environment samples per pixel (ignored without an environment light).
    pub spp: u32,
    /// Sub-pixel grid per axis: pixel_samples^2 stratum centres per pixel.
    pub pixel_samples: u32,
    pub seed: u64,
    pub background: Background,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            spp: 64,
            pixel_samples: 2,
            seed: 1,
            background: Background::Black,
        }
    }
}

/// A light evaluated exactly, without sampling.
#[derive(Clone, Debug, PartialEq)]
pub enum DeltaLight {
    /// Radiant intensity `intensity` (W/sr) at `position`.
    Point { position: DVec3, intensity: f64 },
    /// Irradiance `irradiance` (W/m^2, normal incidence) arriving from the unit `direction`.
    Directional { direction: DVec3, irradiance: f64 },
}

/// Below this squared distance a point light sits on the surface and lights nothing (1/d^2 has no value).
const MIN_LIGHT_DISTANCE_SQ: f64 = 1e-12;

impl DeltaLight {
    /// Direction toward the light from `p` and the irradiance it delivers at normal incidence there.
    pub fn incident(&self, p: DVec3) -> Option<(DVec3, f64)> {
        match self {
            DeltaLight::Point { position, intensity } => {
                let d = *position - p;
                let d2 = d.length_squared();
                if !(d2 > MIN_LIGHT_DISTANCE_SQ) {
                    return None;
                }
                Some((d / d2.sqrt(), intensity / d2))
            }
            DeltaLight::Directional { direction, irradiance } => Some((*direction, *irradiance)),
        }
    }
}

/// A loaded, validated scene.
pub struct Scene {
    pub camera: Camera,
    pub shape: Shape,
    pub material_spec: String,
    pub material: Box<dyn Material>,
    pub sampler: BrdfSampler,
    pub lights: Vec<DeltaLight>,
    pub environment: Option<EnvMap>,
    pub settings: RenderSettings,
    /// `None` when the file has no `[effects]` table; `Some(default)` for an empty one.
    pub effects: Option<EffectsConfig>,
}

/// Largest image side accepted from a scene file.
const MAX_SIDE: usize = 16_384;

impl Scene {
    /// A unit sphere of `spec` seen by a `size` x `size` orthographic camera, with no lights, default
    /// settings and no effects: the starting point of scenes built in code (tests, benches, the
    /// virtual gonio) rather than read from a file.
    pub fn orthographic_sphere(spec: &str, size: usize) -> Result<Self, crate::brdf::BrdfError> {
        Ok(Self {
            camera: Camera {
                width: size,
                height: size,
                projection: Projection::Orthographic,
            },
            shape: Shape::Sphere,
            material_spec: spec.to_string(),
            material: parse_material(spec)?,
            sampler: BrdfSampler::for_spec(spec),
            lights: Vec::new(),
            environment: None,
            settings: RenderSettings::default(),
            effects: None,
        })
    }

    /// Load a scene file; relative paths inside it (the environment map) are relative to its folder.
    pub fn load(path: &Path) -> Result<Self, RenderError> {
        let text = std::fs::read_to_string(path).map_err(|e| RenderError::scene(path, e.to_string()))?;
        Self::from_toml(&text, path)
    }

    /// Parse scene text; `path` names the file in messages and anchors relative paths.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, RenderError> {
        let file: SceneFile = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| {
                1 + text.as_bytes()[..s.start.min(text.len())]
                    .iter()
                    .filter(|&&b| b == b'\n')
                    .count()
            });
            let msg = e.message().split_whitespace().collect::<Vec<_>>().join(" ");
            match line {
                Some(l) => RenderError::scene(path, format!("line {l}: {msg}")),
                None => RenderError::scene(path, msg),
            }
        })?;
        let bad = |reason: String| RenderError::scene(path, reason);

        let camera = match file.camera {
            CameraFile::Orthographic { width, height } => {
                check_size(width, height).map_err(bad)?;
                Camera {
                    width,
                    height,
                    projection: Projection::Orthographic,
                }
            }
            CameraFile::Perspective {
                width,
                height,
                fov_deg,
                position,
                look_at,
                up,
            } => {
                check_size(width, height).map_err(bad)?;
                let v = |a: [f64; 3]| DVec3::from_array(a);
                if ![position, look_at, up].iter().all(|a| v(*a).is_finite()) {
                    return Err(bad("camera: position, look_at and up must be finite".into()));
                }
                Camera::perspective(width, height, v(position), v(look_at), v(up), fov_deg).ok_or_else(|| {
                    bad(format!(
                        "camera: needs 0 < fov_deg < 180 (got {fov_deg}), position != look_at, and up not along the view"
                    ))
                })?
            }
        };

        let material = parse_material(&file.object.material)?;
        let shape = match file.object.shape {
            ShapeFile::Sphere => Shape::Sphere,
            ShapeFile::Plane => Shape::Plane,
        };

        let mut lights = Vec::new();
        let mut environment = None;
        for (i, light) in file.light.into_iter().enumerate() {
            let n = i + 1;
            match light {
                LightFile::Point { position, intensity } => {
                    let position = DVec3::from_array(position);
                    if !position.is_finite() {
                        return Err(bad(format!("light {n} (point): position must be finite")));
                    }
                    non_negative(intensity)
                        .map_err(|v| bad(format!("light {n} (point): intensity must be finite and >= 0, got {v}")))?;
                    lights.push(DeltaLight::Point { position, intensity });
                }
                LightFile::Directional { direction, irradiance } => {
                    let direction = DVec3::from_array(direction)
                        .try_normalize()
                        .ok_or_else(|| bad(format!("light {n} (directional): direction must be a non-zero vector")))?;
                    non_negative(irradiance).map_err(|v| {
                        bad(format!(
                            "light {n} (directional): irradiance must be finite and >= 0, got {v}"
                        ))
                    })?;
                    lights.push(DeltaLight::Directional { direction, irradiance });
                }
                LightFile::Environment { file: map, scale } => {
                    if environment.is_some() {
                        return Err(bad(format!("light {n}: only one environment light is supported")));
                    }
                    non_negative(scale).map_err(|v| {
                        bad(format!(
                            "light {n} (environment): scale must be finite and >= 0, got {v}"
                        ))
                    })?;
                    let full = path.parent().map(|dir| dir.join(&map)).unwrap_or(map);
                    let env = EnvMap::read(&full, scale).map_err(|e| match e {
                        RenderError::Image { path: p, reason } => RenderError::Image {
                            path: p,
                            reason: format!("cannot use as environment map: {reason}"),
                        },
                        other => other,
                    })?;
                    environment = Some(env);
                }
            }
        }

        let defaults = RenderSettings::default();
        let settings = RenderSettings {
            spp: file.render.spp.unwrap_or(defaults.spp),
            pixel_samples: file.render.pixel_samples.unwrap_or(defaults.pixel_samples),
            seed: file.render.seed.unwrap_or(defaults.seed),
            background: file.render.background.unwrap_or(defaults.background),
        };
        check_settings(&settings).map_err(bad)?;
        if let Some(effects) = &file.effects {
            // Validate now, so a bad value is reported before a long render.
            super::effects::EffectPipeline::from_config(effects, 0).map_err(bad)?;
        }

        Ok(Self {
            camera,
            shape,
            sampler: BrdfSampler::for_spec(&file.object.material),
            material_spec: file.object.material,
            material,
            lights,
            environment,
            settings,
            effects: file.effects,
        })
    }
}

fn non_negative(v: f64) -> Result<f64, f64> {
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(v)
    }
}

fn check_size(width: usize, height: usize) -> Result<(), String> {
    if (1..=MAX_SIDE).contains(&width) && (1..=MAX_SIDE).contains(&height) {
        Ok(())
    } else {
        Err(format!(
            "camera: width and height must be 1..={MAX_SIDE}, got {width} x {height}"
        ))
    }
}

/// Limits of the sampling settings (also applied to command-line overrides).
pub fn check_settings(s: &RenderSettings) -> Result<(), String> {
    if !(1..=1 << 20).contains(&s.spp) {
        return Err(format!("render.spp must be 1..=1048576, got {}", s.spp));
    }
    if !(1..=16).contains(&s.pixel_samples) {
        return Err(format!("render.pixel_samples must be 1..=16, got {}", s.pixel_samples));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASE: &str = "[camera]\nkind = \"orthographic\"\nwidth = 8\nheight = 8\n\n[object]\nshape = \"sphere\"\nmaterial = \"lambert:albedo=0.5\"\n";

    fn err(text: &str) -> String {
        Scene::from_toml(text, Path::new("dir/s.toml"))
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    }

    #[test]
    fn parses_every_key() {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut sky = super::super::image::Image::new(4, 2);
        sky.pixels.iter_mut().for_each(|p| *p = DVec3::ONE);
        sky.write(&dir.path().join("sky.exr")).expect("write map");
        let text = "[camera]\nkind = \"perspective\"\nwidth = 6\nheight = 4\nfov_deg = 30\nposition = [0, 0, 5]\n\
            [object]\nshape = \"plane\"\nmaterial = \"ggx:alpha=0.2\"\n\
            [[light]]\nkind = \"point\"\nposition = [0, 0, 3]\nintensity = 2\n\
            [[light]]\nkind = \"directional\"\ndirection = [0, 0, 2]\nirradiance = 1\n\
            [[light]]\nkind = \"environment\"\nfile = \"sky.exr\"\nscale = 0.5\n\
            [render]\nspp = 8\npixel_samples = 3\nseed = 4\nbackground = \"environment\"\n[effects]\n";
        let scene = Scene::from_toml(text, &dir.path().join("s.toml")).expect("valid scene");
        assert_eq!((scene.camera.width, scene.camera.height), (6, 4));
        assert_eq!(scene.shape, Shape::Plane);
        assert_eq!(scene.lights.len(), 2);
        assert_eq!(
            scene.lights[1],
            DeltaLight::Directional {
                direction: DVec3::Z,
                irradiance: 1.0
            }
        );
        assert!(scene.environment.is_some());
        assert_eq!(scene.settings.pixel_samples, 3);
        assert_eq!(scene.effects, Some(EffectsConfig::default()));
    }

    #[test]
    fn bad_scenes_give_one_clear_line() {
        assert_eq!(
            err(&format!("colour = 3\n{BASE}")),
            "dir/s.toml: line 1: unknown field `colour`, expected one of `camera`, `object`, `light`, `render`, `effects`"
        );
        let e = err("[camera]\nkind = \"orthographic\"\nwidth = 8\nheight = 8\n[object]\nshape = \"sphere\"\n");
        assert_eq!(e, "dir/s.toml: line 5: missing field `material`");
        let e = err(&format!(
            "{BASE}[[light]]\nkind = \"point\"\nposition = [1, 1, 1]\nintensity = -3\n"
        ));
        assert_eq!(
            e,
            "dir/s.toml: light 1 (point): intensity must be finite and >= 0, got -3"
        );
        let e = err(&format!(
            "{BASE}[[light]]\nkind = \"environment\"\nfile = \"missing.exr\"\n"
        ));
        assert!(e.starts_with("dir/missing.exr: cannot use as environment map: "), "{e}");
        assert!(!e.contains('\n'), "{e}");
        let e = err(&format!("{BASE}[effects]\nread_noise = {{ sigma = 1, mean = 2 }}\n"));
        assert!(e.starts_with("dir/s.toml: line 10: unknown field `mean`"), "{e}");
        let e = err(&BASE.replace("lambert:albedo=0.5", "lambert:albedo=x"));
        assert_eq!(e, "bad material spec 'lambert:albedo=x': albedo: 'x' is not a number");
        let e = err(&format!("{BASE}[render]\npixel_samples = 0\n"));
        assert_eq!(e, "dir/s.toml: render.pixel_samples must be 1..=16, got 0");
        for text in [
            BASE.replace("8\n", "0\n"),
            format!("{BASE}[[light]]\nkind = \"spot\"\n"),
        ] {
            let e = err(&text);
            assert!(e.starts_with("dir/s.toml: ") && !e.contains('\n'), "{e}");
        }
    }
}
