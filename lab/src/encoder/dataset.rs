//! `gonio-lab dataset`: training and test images rendered from `examples/capture.toml`.
//!
//! A dataset is a folder of 64 x 64 linear EXR images (rendered at 256 x 256, box-averaged 4 x 4) and
//! `labels.csv`: `file,split,intensity,<parameters>,spec`. `intensity` is the light-intensity factor
//! the image was multiplied by (log-uniform in [0.25, 4]); the renderer is linear in the light, so
//! this is exactly the photo under a brighter or dimmer light.
//!
//! Parameter distributions (the output ranges of `ModelKind::outputs` are a little wider):
//! * Ward: rho_d ~ U[0.05, 0.95], alpha ~ U[0.02, 0.5], rho_s = 1 - rho_d (the paper's Ward).
//! * GGX: alpha log-uniform in [0.002, 1] (the MERL fits span 0.002 .. 0.85); diffuse = d x tint with
//!   d log-uniform in [0.003, 0.5]; specular = k x tint with k log-uniform in [0.02, 1]; tints are
//!   random colours with channels in [0.5, 1] (diffuse) and [0.8, 1] (specular).
//! * MERL (`--merl`, GGX only): the 90 bundled neural fits, ground-truth alpha from `brdf::fit`
//!   (GGX); every 6th material in name order is held out for test (15 materials, `split = test`).
//! * Two lobes (`--two-lobes`, GGX only): Lambert + a sharp and a broad GGX lobe
//!   (`sample_two_lobes`), labelled like MERL by the GGX fit: pretraining for the MERL labels.
//!
//! With the light intensity unknown, only ratios of reflectance are observable: Ward's rho_d is
//! identifiable because rho_s = 1 - rho_d ties the specular-to-diffuse ratio to it; GGX's diffuse
//! and specular scales are not (only their ratio), so the GGX network predicts alpha alone.

use super::capture::{ggx_fit_alpha, render_capture, render_capture_material};
use super::{preprocess, EncoderError, ModelKind, INPUT_LEN};
use glam::DVec3;
use gonio::brdf::fit_lobes::TwoLobes;
use gonio::brdf::parse_material;
use gonio::render::Image;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

pub const INTENSITY_RANGE: (f64, f64) = (0.25, 4.0);
pub const LABELS: &str = "labels.csv";
/// Every MERL_TEST_EVERY-th bundled material (name order, starting at index MERL_TEST_EVERY - 1) is a test material.
pub const MERL_TEST_EVERY: usize = 6;

/// One labelled image.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    pub file: String,
    pub split: String,
    pub intensity: f64,
    pub params: Vec<f64>,
    pub spec: String,
}

fn log_uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    lo * (hi / lo).powf(rng.random::<f64>())
}

/// Draw one synthetic material: (parameters in `kind.outputs()` order, spec).
pub fn sample_params(kind: ModelKind, rng: &mut ChaCha8Rng) -> (Vec<f64>, String) {
    match kind {
        ModelKind::Ward => {
            let rho_d = rng.random_range(0.05..0.95);
            let alpha = rng.random_range(0.02..0.5);
            (vec![rho_d, alpha], format!("ward:rho_d={rho_d},alpha={alpha}"))
        }
        ModelKind::Ggx => {
            let alpha = log_uniform(rng, 0.002, 1.0);
            let d = log_uniform(rng, 0.003, 0.5);
            let k = log_uniform(rng, 0.02, 1.0);
            let mut tint = |lo: f64| [0; 3].map(|_| rng.random_range(lo..1.0));
            let (td, ts) = (tint(0.5), tint(0.8));
            let rgb = |s: f64, t: [f64; 3]| format!("{}/{}/{}", s * t[0], s * t[1], s * t[2]);
            (
                vec![alpha],
                format!("ggx:alpha={alpha},diffuse={},specular={}", rgb(d, td), rgb(k, ts)),
            )
        }
    }
}

/// Draw one synthetic two-lobe material (GGX pretraining beside the one-lobe family): Lambert plus
/// a sharp and a broad GGX lobe, the shape of most MERL paints and plastics. sharp alpha
/// log-uniform in [0.002, 0.5], broad alpha = sharp x log-uniform [2.5, 50] (at most 1); diffuse
/// d log-uniform [0.003, 0.5], sharp and broad weights each log-uniform [0.02, 1]; tints as the
/// one-lobe family's. Its label is what a MERL material's is: the alpha of `brdf::fit` (GGX).
pub fn sample_two_lobes(rng: &mut ChaCha8Rng) -> TwoLobes {
    let sharp_alpha = log_uniform(rng, 0.002, 0.5);
    let broad_alpha = (sharp_alpha * log_uniform(rng, 2.5, 50.0)).min(1.0);
    let d = log_uniform(rng, 0.003, 0.5);
    let ks = log_uniform(rng, 0.02, 1.0);
    let kb = log_uniform(rng, 0.02, 1.0);
    let mut tint = |lo: f64| {
        let [r, g, b] = [0; 3].map(|_| rng.random_range(lo..1.0));
        DVec3::new(r, g, b)
    };
    let (td, ts, tb) = (tint(0.5), tint(0.8), tint(0.8));
    TwoLobes {
        diffuse: d * td,
        sharp_alpha,
        sharp: ks * ts,
        broad_alpha,
        broad: kb * tb,
        // No Fresnel rise: the family the shipped models were trained on.
        sharp_grazing: ks * ts,
        broad_grazing: kb * tb,
        coated: DVec3::ZERO,
    }
}

/// The bundled MERL fits with their GGX alpha and split: (name, alpha, split).
pub fn merl_materials() -> Result<Vec<(String, f64, &'static str)>, String> {
    let mut names: Vec<String> = gonio::brdf::nbrdf::NeuralBrdf::bundled_names()
        .map(str::to_string)
        .collect();
    names.sort();
    names
        .into_par_iter()
        .enumerate()
        .map(|(i, name)| {
            let material = parse_material(&format!("nbrdf:{name}")).map_err(|e| e.to_string())?;
            let alpha = ggx_fit_alpha(material.as_ref()).map_err(|e| format!("{name}: {e}"))?;
            let split = if i % MERL_TEST_EVERY == MERL_TEST_EVERY - 1 {
                "test"
            } else {
                "train"
            };
            Ok((name, alpha, split))
        })
        .collect()
}

/// One image to render: (spec, parameters, split, light intensity, the material when it has no spec).
type Job = (String, Vec<f64>, String, f64, Option<TwoLobes>);

/// Which materials a dataset draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// `sample_params`: the model itself (Ward or one GGX lobe), exact labels.
    Analytic,
    /// The 90 bundled MERL fits, labelled by `brdf::fit` (GGX).
    Merl,
    /// `sample_two_lobes`, labelled by `brdf::fit` (GGX).
    TwoLobes,
}

/// Render a dataset into `dir` (created if needed); `labels.csv` is written last, through a
/// temporary name (`fsio`), so a folder with labels is complete.
pub fn generate(kind: ModelKind, count: usize, merl: bool, seed: u64, dir: &Path) -> Result<Vec<Sample>, EncoderError> {
    let family = if merl { Family::Merl } else { Family::Analytic };
    generate_family(kind, count, family, seed, dir)
}

/// `generate` for any `Family` (`count` is ignored for MERL: one image per bundled material).
pub fn generate_family(
    kind: ModelKind,
    count: usize,
    family: Family,
    seed: u64,
    dir: &Path,
) -> Result<Vec<Sample>, EncoderError> {
    let err = |e: String| EncoderError::dataset(dir, e);
    if family != Family::Analytic && kind != ModelKind::Ggx {
        return Err(err(
            "MERL and two-lobe images have GGX ground truth: use --model ggx".into()
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| err(e.to_string()))?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    // (spec, params, split, intensity, two-lobe material) of every image, drawn up front so the
    // result does not depend on threads.
    let mut jobs: Vec<Job> = match family {
        Family::Merl => merl_materials()
            .map_err(err)?
            .into_iter()
            .map(|(name, alpha, split)| {
                let i = log_uniform(&mut rng, INTENSITY_RANGE.0, INTENSITY_RANGE.1);
                (format!("nbrdf:{name}"), vec![alpha], split.to_string(), i, None)
            })
            .collect(),
        Family::Analytic => (0..count)
            .map(|_| {
                let (params, spec) = sample_params(kind, &mut rng);
                let i = log_uniform(&mut rng, INTENSITY_RANGE.0, INTENSITY_RANGE.1);
                (spec, params, "all".to_string(), i, None)
            })
            .collect(),
        Family::TwoLobes => (0..count)
            .map(|_| {
                let lobes = sample_two_lobes(&mut rng);
                let i = log_uniform(&mut rng, INTENSITY_RANGE.0, INTENSITY_RANGE.1);
                (
                    format!("twolobes: {}", lobes.describe()),
                    Vec::new(),
                    "all".to_string(),
                    i,
                    Some(lobes),
                )
            })
            .collect(),
    };
    if family == Family::TwoLobes {
        let alphas: Vec<Result<f64, String>> = jobs
            .par_iter()
            .map(|j| match &j.4 {
                Some(m) => ggx_fit_alpha(m),
                None => Err("a two-lobe image without its material".into()),
            })
            .collect();
        for (job, alpha) in jobs.iter_mut().zip(alphas) {
            job.1 = vec![alpha.map_err(err)?];
        }
    }
    let bar = indicatif::ProgressBar::new(jobs.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} ({eta})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("rendering");
    let mut samples = Vec::with_capacity(jobs.len());
    for (i, (spec, params, split, intensity, lobes)) in jobs.into_iter().enumerate() {
        let file = format!("{i:05}.exr");
        let image = match lobes {
            Some(m) => render_capture_material(Box::new(m), intensity),
            None => render_capture(&spec, intensity),
        }
        .map_err(err)?;
        image.write(&dir.join(&file)).map_err(|e| err(e.to_string()))?;
        samples.push(Sample {
            file,
            split,
            intensity,
            params,
            spec,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    write_labels(kind, &samples, dir)?;
    Ok(samples)
}

fn write_labels(kind: ModelKind, samples: &[Sample], dir: &Path) -> Result<(), EncoderError> {
    let names: Vec<&str> = kind.outputs().iter().map(|p| p.name).collect();
    let mut text = format!("file,split,intensity,{},spec\n", names.join(","));
    for s in samples {
        let params: Vec<String> = s.params.iter().map(|v| v.to_string()).collect();
        // The spec contains commas: quote it.
        text += &format!(
            "{},{},{},{},\"{}\"\n",
            s.file,
            s.split,
            s.intensity,
            params.join(","),
            s.spec
        );
    }
    gonio::fsio::write_bytes_atomically(&dir.join(LABELS), text.as_bytes()).map_err(|e| EncoderError::dataset(dir, e))
}

/// A dataset read back: its kind (from the header), labels and preprocessed inputs.
pub struct Loaded {
    pub kind: ModelKind,
    pub dir: PathBuf,
    pub samples: Vec<Sample>,
    /// The linear 64 x 64 images, in sample order.
    pub images: Vec<Image>,
}

impl Loaded {
    /// Preprocessed inputs (INPUT_LEN floats per image), each image multiplied by `scale` first.
    pub fn inputs(&self, scale: f64) -> Result<Vec<f32>, EncoderError> {
        let per: Result<Vec<Vec<f32>>, String> = self
            .images
            .par_iter()
            .map(|img| {
                let mut img = img.clone();
                for p in &mut img.pixels {
                    *p *= scale;
                }
                preprocess(&img)
            })
            .collect();
        let per = per.map_err(|e| EncoderError::dataset(&self.dir, e))?;
        let mut out = Vec::with_capacity(per.len() * INPUT_LEN);
        for v in per {
            out.extend_from_slice(&v);
        }
        Ok(out)
    }

    pub fn targets(&self) -> Vec<Vec<f64>> {
        self.samples.iter().map(|s| s.params.clone()).collect()
    }

    /// The rows whose index (in this set's order) `keep` accepts.
    pub fn subset(&self, keep: &dyn Fn(usize) -> bool) -> Loaded {
        let rows: Vec<usize> = (0..self.samples.len()).filter(|&i| keep(i)).collect();
        Loaded {
            kind: self.kind,
            dir: self.dir.clone(),
            samples: rows.iter().map(|&i| self.samples[i].clone()).collect(),
            images: rows.iter().map(|&i| self.images[i].clone()).collect(),
        }
    }
}

/// Read `dir/labels.csv` and its images, keeping the rows `keep` accepts (by split).
pub fn load(dir: &Path, keep: &dyn Fn(&str) -> bool) -> Result<Loaded, EncoderError> {
    let err = |e: String| EncoderError::dataset(dir, e);
    let text = std::fs::read_to_string(dir.join(LABELS)).map_err(|e| err(format!("{LABELS}: {e}")))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .ok_or_else(|| err(format!("{LABELS} is empty")))?
        .split(',')
        .collect();
    let kind = [ModelKind::Ward, ModelKind::Ggx]
        .into_iter()
        .find(|k| {
            let names: Vec<&str> = k.outputs().iter().map(|p| p.name).collect();
            header.len() == 4 + names.len() && header[3..3 + names.len()] == names[..]
        })
        .ok_or_else(|| err(format!("{LABELS}: unexpected header {header:?}")))?;
    let k = kind.outputs().len();
    let mut samples = Vec::new();
    for (n, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let bad = |what: &str| err(format!("{LABELS} line {}: {what}", n + 2));
        let (head, spec) = line.split_once(",\"").ok_or_else(|| bad("no quoted spec"))?;
        let cols: Vec<&str> = head.split(',').collect();
        if cols.len() != 3 + k {
            return Err(bad("wrong number of columns"));
        }
        let num = |s: &str| s.parse::<f64>().ok().filter(|v| v.is_finite());
        let intensity = num(cols[2]).ok_or_else(|| bad("intensity is not a number"))?;
        let params = cols[3..]
            .iter()
            .map(|s| num(s))
            .collect::<Option<Vec<f64>>>()
            .ok_or_else(|| bad("a parameter is not a number"))?;
        if cols[0].contains('/') || cols[0].contains("..") {
            return Err(bad("file names must be plain names"));
        }
        samples.push(Sample {
            file: cols[0].to_string(),
            split: cols[1].to_string(),
            intensity,
            params,
            spec: spec.trim_end_matches('"').to_string(),
        });
    }
    samples.retain(|s| keep(&s.split));
    if samples.is_empty() {
        return Err(err("no images (for this split)".into()));
    }
    let images: Result<Vec<Image>, EncoderError> = samples
        .par_iter()
        .map(|s| super::load_photo(&dir.join(&s.file)))
        .collect();
    Ok(Loaded {
        kind,
        dir: dir.to_path_buf(),
        samples,
        images: images?,
    })
}
