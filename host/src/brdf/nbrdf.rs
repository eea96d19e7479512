//! The neural MERL fits of Sztrajman et al. 2021 (6 -> 21 -> 21 -> 3 ReLU network per material),
//! evaluated exactly as `host/data/merl-nbrdf/README.md` says. The 90 fits are compiled in.

use super::half_diff::to_half_diff;
use super::nbrdf_bundled::BUNDLED;
use super::{BrdfError, Material};
use glam::DVec3;
use serde::Deserialize;
use std::path::Path;

/// The encoder's held-out MERL test materials (`host/models/README.md`): no model the product ships
/// (the encoder, the reconstruction's PCA basis) is trained on them; every claim is tested on them.
pub const HELDOUT_MATERIALS: [&str; 15] = [
    "nbrdf:black-oxidized-steel",
    "nbrdf:blue-metallic-paint2",
    "nbrdf:color-changing-paint1",
    "nbrdf:delrin",
    "nbrdf:gray-plastic",
    "nbrdf:green-metallic-paint2",
    "nbrdf:maroon-plastic",
    "nbrdf:pearl-paint",
    "nbrdf:polyurethane-foam",
    "nbrdf:red-metallic-paint",
    "nbrdf:special-walnut-224",
    "nbrdf:specular-violet-phenolic",
    "nbrdf:tungsten-carbide",
    "nbrdf:white-fabric2",
    "nbrdf:yellow-plastic",
];

const SIZES: [usize; 4] = [6, 21, 21, 3];

#[derive(Deserialize)]
struct FileLayer {
    weight: Vec<Vec<f64>>,
    bias: Vec<f64>,
}

#[derive(Deserialize)]
struct File {
    material: String,
    layers: Vec<FileLayer>,
}

/// One dense layer, weights stored input-major as in the file (W[i][j]: input i to output j).
#[derive(Clone, Debug)]
struct Layer {
    inputs: usize,
    outputs: usize,
    weight: Vec<f64>,
    bias: Vec<f64>,
}

impl Layer {
    fn forward(&self, x: &[f64], y: &mut [f64], relu: bool) {
        y.copy_from_slice(&self.bias);
        for (i, xi) in x.iter().enumerate().take(self.inputs) {
            let row = &self.weight[i * self.outputs..(i + 1) * self.outputs];
            for (yj, w) in y.iter_mut().zip(row) {
                *yj += xi * w;
            }
        }
        if relu {
            y.iter_mut().for_each(|v| *v = v.max(0.0));
        }
    }
}

#[derive(Clone, Debug)]
pub struct NeuralBrdf {
    pub name: String,
    layers: [Layer; 3],
}

impl NeuralBrdf {
    /// Names of the bundled materials, sorted.
    pub fn bundled_names() -> impl Iterator<Item = &'static str> {
        BUNDLED.iter().map(|(n, _)| *n)
    }

    /// A bundled material by name (e.g. "alum-bronze").
    pub fn bundled(name: &str) -> Result<Self, BrdfError> {
        let (_, json) = BUNDLED
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| BrdfError::UnknownNbrdf {
                name: name.to_string(),
                count: BUNDLED.len(),
            })?;
        Self::from_json(json, Path::new(&format!("<bundled {name}.json>")))
    }

    pub fn read(path: &Path) -> Result<Self, BrdfError> {
        let text = std::fs::read_to_string(path).map_err(|e| BrdfError::io(path, e))?;
        Self::from_json(&text, path)
    }

    /// Parse and check the shapes (6 -> 21 -> 21 -> 3) and that every number is finite.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, BrdfError> {
        let file: File =
            serde_json::from_str(text).map_err(|e| BrdfError::format(path, format!("not an nbrdf JSON file: {e}")))?;
        if file.layers.len() != 3 {
            return Err(BrdfError::format(
                path,
                format!("expected 3 layers, found {}", file.layers.len()),
            ));
        }
        let mut layers = Vec::with_capacity(3);
        for (k, l) in file.layers.into_iter().enumerate() {
            let (inputs, outputs) = (SIZES[k], SIZES[k + 1]);
            let rows_ok = l.weight.len() == inputs && l.weight.iter().all(|r| r.len() == outputs);
            if !rows_ok || l.bias.len() != outputs {
                return Err(BrdfError::format(
                    path,
                    format!("layer {} is not {inputs} -> {outputs}", k + 1),
                ));
            }
            let weight: Vec<f64> = l.weight.into_iter().flatten().collect();
            if !weight.iter().chain(&l.bias).all(|v| v.is_finite()) {
                return Err(BrdfError::format(
                    path,
                    format!("layer {} has a non-finite weight", k + 1),
                ));
            }
            layers.push(Layer {
                inputs,
                outputs,
                weight,
                bias: l.bias,
            });
        }
        let layers: [Layer; 3] = layers
            .try_into()
            .map_err(|_| BrdfError::format(path, "expected 3 layers"))?;
        Ok(Self {
            name: file.material,
            layers,
        })
    }
}

impl Material for NeuralBrdf {
    fn eval(&self, wi: DVec3, wo: DVec3) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let Some(hd) = to_half_diff(wi, wo) else {
            return DVec3::ZERO;
        };
        let (st, ct) = hd.theta_h.sin_cos();
        let x = [st, 0.0, ct, hd.d.x, hd.d.y, hd.d.z];
        let (mut a1, mut a2, mut y) = ([0.0; 21], [0.0; 21], [0.0; 3]);
        self.layers[0].forward(&x, &mut a1, true);
        self.layers[1].forward(&a1, &mut a2, true);
        self.layers[2].forward(&a2, &mut y, false);
        // exp(y) - 1 via exp_m1 (exact near 0); a huge y saturates to inf, which is clamped so a
        // corrupt network cannot return inf or NaN.
        let f = |v: f64| v.exp_m1().clamp(0.0, f64::MAX);
        DVec3::new(f(y[0]), f(y[1]), f(y[2]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::frame::from_spherical;

    #[test]
    fn bundle_lists_every_data_file() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/merl-nbrdf");
        let mut on_disk: Vec<String> = std::fs::read_dir(&dir)
            .expect("data folder")
            .filter_map(|e| e.ok()?.file_name().to_str()?.strip_suffix(".json").map(str::to_string))
            .collect();
        on_disk.sort();
        let bundled: Vec<&str> = NeuralBrdf::bundled_names().collect();
        assert_eq!(on_disk, bundled);
        assert_eq!(bundled.len(), 90);
        for name in bundled {
            let m = NeuralBrdf::bundled(name).expect("bundled file parses");
            assert_eq!(m.name, name);
        }
    }

    /// A shiny fit peaks at the mirror direction and is far lower off it; values finite, >= 0,
    /// 0 below the horizon; reciprocal to 10% (the fit is trained on reciprocal data but is not
    /// reciprocal by construction: swapping wi and wo flips the sign of d.x and d.y).
    #[test]
    fn shiny_material_behaves() {
        let m = NeuralBrdf::bundled("gold-metallic-paint").expect("bundled");
        let wi = from_spherical(0.5, 0.0);
        let peak = m.eval(wi, from_spherical(0.5, std::f64::consts::PI));
        let off = m.eval(wi, from_spherical(1.2, 0.6));
        assert!(peak.is_finite() && off.is_finite() && off.min_element() >= 0.0);
        assert!(peak.x > 5.0 * off.x, "peak {peak} off {off}");
        let (a, b) = (from_spherical(0.3, 0.0), from_spherical(0.9, 2.0));
        let (f1, f2) = (m.eval(a, b), m.eval(b, a));
        assert!(((f1 - f2).length() / f1.length()) < 0.1, "{f1} vs {f2}");
        // A matte material sits at a plausible albedo / pi.
        let matte = NeuralBrdf::bundled("white-diffuse-bball")
            .expect("bundled")
            .eval(from_spherical(0.2, 0.0), from_spherical(0.3, 2.0));
        assert!(matte.min_element() > 0.05 && matte.max_element() < 0.35, "{matte}");
        assert_eq!(m.eval(wi, -wi), DVec3::ZERO);
        assert!(matches!(
            NeuralBrdf::bundled("nope"),
            Err(BrdfError::UnknownNbrdf { .. })
        ));
        let bad = NeuralBrdf::from_json(r#"{"material":"x","layers":[]}"#, Path::new("x.json"));
        assert_eq!(
            bad.err().map(|e| e.to_string()),
            Some("x.json: expected 3 layers, found 0".into())
        );
    }
}
