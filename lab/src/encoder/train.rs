//! Training (cargo feature `train`): the encoder in candle (CPU), AdamW with cosine decay, and the
//! export to ONNX through `onnx::Weights`. Weights start from our own seeded initialisation (candle's
//! CPU initialisers draw from an unseeded generator), so a run with the same seed, data and thread
//! count reproduces the same model.

use super::dataset::{self, Loaded};
use super::onnx::{Block, Model, RangeMap, Weights, BLOCKS, BN_EPS, FEATURES};
use super::{flip_vertical, preprocess, EncoderError, ModelKind, INPUT_LEN, INPUT_SIZE};
use candle_core::{DType, Device, Tensor, Var, D};
use candle_nn::{BatchNorm, Conv2d, Conv2dConfig, Linear, ModuleT, Optimizer, VarBuilder, VarMap};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::path::Path;
use std::time::Instant;

fn ce(e: candle_core::Error) -> EncoderError {
    EncoderError::Model(format!("candle: {e}"))
}

/// The network in candle; same layers and names as the ONNX graph.
pub struct Net {
    pub kind: ModelKind,
    blocks: Vec<(Conv2d, BatchNorm)>,
    fc: Linear,
    map: [Tensor; 6],
}

impl Net {
    /// Build on `varmap`, whose variables must already be set (`init_varmap`).
    pub fn new(kind: ModelKind, varmap: &VarMap) -> Result<Self, EncoderError> {
        let dev = Device::Cpu;
        let vb = VarBuilder::from_varmap(varmap, DType::F32, &dev);
        let mut blocks = Vec::new();
        for (i, &(cin, cout, stride)) in BLOCKS.iter().enumerate() {
            let p = vb.pp(format!("b{i}"));
            let cfg = Conv2dConfig {
                padding: 1,
                stride,
                ..Default::default()
            };
            let conv = candle_nn::conv2d_no_bias(cin, cout, 3, cfg, p.pp("conv")).map_err(ce)?;
            let bn = candle_nn::batch_norm(cout, BN_EPS, p.pp("bn")).map_err(ce)?;
            blocks.push((conv, bn));
        }
        let k = kind.outputs().len();
        let fc = candle_nn::linear(FEATURES, k, vb.pp("fc")).map_err(ce)?;
        let m = RangeMap::of(kind);
        let t = |v: Vec<f32>| Tensor::from_vec(v, (1, k), &dev).map_err(ce);
        let map = [
            t(m.lin_scale)?,
            t(m.lin_off)?,
            t(m.lin_mask)?,
            t(m.log_scale)?,
            t(m.log_off)?,
            t(m.log_mask)?,
        ];
        Ok(Self { kind, blocks, fc, map })
    }

    /// Logits (N, k), before the sigmoid, of inputs (N, 3, 64, 64).
    pub fn logits(&self, x: &Tensor, train: bool) -> candle_core::Result<Tensor> {
        let mut x = x.clone();
        for (conv, bn) in &self.blocks {
            x = bn.forward_t(&conv.forward_t(&x, train)?, train)?.relu()?;
        }
        let pooled = x.mean(D::Minus1)?.mean(D::Minus1)?;
        self.fc.forward_t(&pooled, train)
    }

    /// Sigmoid outputs (N, k) of inputs (N, 3, 64, 64).
    pub fn unit(&self, x: &Tensor, train: bool) -> candle_core::Result<Tensor> {
        candle_nn::ops::sigmoid(&self.logits(x, train)?)
    }

    /// Physical parameters (N, k): the same mapping as the ONNX graph.
    pub fn params_of_unit(&self, s: &Tensor) -> candle_core::Result<Tensor> {
        let [ls, lo, lm, gs, go, gm] = &self.map;
        let lin = s.broadcast_mul(ls)?.broadcast_add(lo)?.broadcast_mul(lm)?;
        let log = s.broadcast_mul(gs)?.broadcast_add(go)?.exp()?.broadcast_mul(gm)?;
        lin + log
    }

    /// Inference-mode parameters of preprocessed inputs (INPUT_LEN floats each), in chunks.
    pub fn predict(&self, inputs: &[f32]) -> Result<Vec<Vec<f32>>, EncoderError> {
        predict_ensemble(std::slice::from_ref(self), false, inputs)
    }

    /// The weights as plain arrays (batch-norm running statistics from the layers themselves:
    /// candle keeps them in their own variables, not in the VarMap).
    pub fn weights(&self) -> Result<Weights, EncoderError> {
        let v = |t: &Tensor| t.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(ce);
        let mut blocks = Vec::new();
        for (conv, bn) in &self.blocks {
            let (w, b) = bn
                .weight_and_bias()
                .ok_or_else(|| EncoderError::Model("batch norm without affine weights".into()))?;
            blocks.push(Block {
                conv: v(conv.weight())?,
                bn_weight: v(w)?,
                bn_bias: v(b)?,
                bn_mean: v(bn.running_mean())?,
                bn_var: v(bn.running_var())?,
            });
        }
        let fc_bias = self
            .fc
            .bias()
            .ok_or_else(|| EncoderError::Model("fc without bias".into()))?;
        Ok(Weights {
            kind: self.kind,
            blocks,
            fc_weight: v(self.fc.weight())?,
            fc_bias: v(fc_bias)?,
        })
    }
}

/// Inference-mode parameters of an ensemble, as its ONNX graph computes them (`onnx::Model`): the
/// logits of every net on every view (the input, and with `flip` its vertical mirror) averaged,
/// then the sigmoid and the range map.
pub fn predict_ensemble(nets: &[Net], flip: bool, inputs: &[f32]) -> Result<Vec<Vec<f32>>, EncoderError> {
    let first = nets
        .first()
        .ok_or_else(|| EncoderError::Model("an ensemble needs at least one network".into()))?;
    let mut out = Vec::new();
    for chunk in inputs.chunks(256 * INPUT_LEN) {
        let n = chunk.len() / INPUT_LEN;
        let mut views = vec![chunk.to_vec()];
        if flip {
            views.push(chunk.chunks(INPUT_LEN).flat_map(flip_vertical).collect());
        }
        let p = (|| -> candle_core::Result<Vec<Vec<f32>>> {
            let mut sum: Option<Tensor> = None;
            for view in &views {
                let x = Tensor::from_slice(view, (n, 3, INPUT_SIZE, INPUT_SIZE), &Device::Cpu)?;
                for net in nets {
                    let l = net.logits(&x, false)?;
                    sum = Some(match sum {
                        Some(s) => (s + l)?,
                        None => l,
                    });
                }
            }
            let count = (views.len() * nets.len()) as f64;
            let mean = (sum.ok_or_else(|| candle_core::Error::Msg("no branches".into()))? / count)?;
            first.params_of_unit(&candle_nn::ops::sigmoid(&mean)?)?.to_vec2::<f32>()
        })()
        .map_err(ce)?;
        out.extend(p);
    }
    Ok(out)
}

/// Fill a VarMap with `weights`, or with a seeded Kaiming-normal initialisation when `None`.
pub fn init_varmap(kind: ModelKind, weights: Option<&Weights>, seed: u64) -> Result<VarMap, EncoderError> {
    let dev = Device::Cpu;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut normal = |n: usize, fan_in: usize| -> Vec<f32> {
        let std = (2.0 / fan_in as f64).sqrt();
        let d = Normal::new(0.0, std).unwrap_or_else(|_| Normal::new(0.0, 1.0).expect("unit normal"));
        (0..n).map(|_| d.sample(&mut rng) as f32).collect()
    };
    let k = kind.outputs().len();
    let fresh = Weights {
        kind,
        blocks: BLOCKS
            .iter()
            .map(|&(cin, cout, _)| Block {
                conv: normal(cout * cin * 9, cin * 9),
                bn_weight: vec![1.0; cout],
                bn_bias: vec![0.0; cout],
                bn_mean: vec![0.0; cout],
                bn_var: vec![1.0; cout],
            })
            .collect(),
        // Small head: training starts near s = 0.5 (the middle of every range).
        fc_weight: normal(k * FEATURES, FEATURES).into_iter().map(|w| w * 0.1).collect(),
        fc_bias: vec![0.0; k],
    };
    let w = match weights {
        Some(w) if w.kind != kind => {
            return Err(EncoderError::Model(format!(
                "the initial model is {}, the data are {}",
                w.kind.name(),
                kind.name()
            )))
        }
        Some(w) => w,
        None => &fresh,
    };
    let varmap = VarMap::new();
    {
        let mut data = varmap
            .data()
            .lock()
            .map_err(|_| EncoderError::Model("poisoned var map".into()))?;
        let mut put = |name: String, v: &[f32], shape: &[usize]| -> Result<(), EncoderError> {
            let t = Tensor::from_slice(v, shape, &dev).map_err(ce)?;
            data.insert(name, Var::from_tensor(&t).map_err(ce)?);
            Ok(())
        };
        for (i, (b, &(cin, cout, _))) in w.blocks.iter().zip(&BLOCKS).enumerate() {
            put(format!("b{i}.conv.weight"), &b.conv, &[cout, cin, 3, 3])?;
            put(format!("b{i}.bn.weight"), &b.bn_weight, &[cout])?;
            put(format!("b{i}.bn.bias"), &b.bn_bias, &[cout])?;
            put(format!("b{i}.bn.running_mean"), &b.bn_mean, &[cout])?;
            put(format!("b{i}.bn.running_var"), &b.bn_var, &[cout])?;
        }
        put("fc.weight".into(), &w.fc_weight, &[k, FEATURES])?;
        put("fc.bias".into(), &w.fc_bias, &[k])?;
    }
    Ok(varmap)
}

#[derive(Clone, Debug)]
pub struct TrainConfig {
    pub epochs: usize,
    pub batch: usize,
    pub lr: f64,
    pub seed: u64,
    /// Stop after this many optimiser steps (tests); `None` = all epochs.
    pub max_steps: Option<usize>,
    /// Probability that a training image is shown as an 8-bit PNG auto-exposed at x1 and then lit
    /// by a factor log-uniform in `png_range` (`report::photo`, `Photo::Png8`): brighter
    /// light clips the highlight as a camera would, so the network learns to read clipped photos.
    /// 0 = linear images only.
    pub png_augment: f64,
    /// Light factors of the clipped-PNG augmentation (default `PNG_AUGMENT_RANGE`).
    pub png_range: (f64, f64),
    /// Weight of the range-scaled absolute error in the loss (the unit-space error, relative for
    /// the log-mapped alpha, always has weight 1). 1 = versions 1 and 2.
    pub phys_weight: f64,
    /// Images of the `mix` dataset added to every batch (rehearsal while fine-tuning); 0 = none.
    pub mix_per_batch: usize,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            epochs: 30,
            batch: 32,
            lr: 3e-3,
            seed: 1,
            max_steps: None,
            png_augment: 0.0,
            png_range: PNG_AUGMENT_RANGE,
            phys_weight: 1.0,
            mix_per_batch: 0,
        }
    }
}

/// Light factors of the clipped-PNG augmentation (the x0.25 .. x4).
pub const PNG_AUGMENT_RANGE: (f64, f64) = (0.25, 4.0);

/// What a run did: the loss of every step and per-epoch summaries.
pub struct TrainLog {
    pub step_losses: Vec<f32>,
    pub seconds: f64,
    pub images: usize,
}

/// Train on `data` (starting from `init` if given) and return the network.
pub fn train(
    data: &Loaded,
    init: Option<&Weights>,
    cfg: &TrainConfig,
    val: Option<&Loaded>,
    log: &mut dyn FnMut(&str),
) -> Result<(Net, TrainLog), EncoderError> {
    train_mixed(data, None, init, cfg, val, log)
}

/// `train`, with `cfg.mix_per_batch` random images of `mix` (same model kind) added to every batch.
pub fn train_mixed(
    data: &Loaded,
    mix: Option<&Loaded>,
    init: Option<&Weights>,
    cfg: &TrainConfig,
    val: Option<&Loaded>,
    log: &mut dyn FnMut(&str),
) -> Result<(Net, TrainLog), EncoderError> {
    let kind = data.kind;
    for (what, other) in [("validation", val), ("mix", mix)] {
        if let Some(v) = other {
            if v.kind != kind {
                return Err(EncoderError::Model(format!(
                    "the {what} data are {}, the training data {}",
                    v.kind.name(),
                    kind.name()
                )));
            }
        }
    }
    let mix = mix.filter(|_| cfg.mix_per_batch > 0);
    let varmap = init_varmap(kind, init, cfg.seed)?;
    let net = Net::new(kind, &varmap)?;
    let trainable: Vec<Var> = {
        let map = varmap
            .data()
            .lock()
            .map_err(|_| EncoderError::Model("poisoned var map".into()))?;
        let mut names: Vec<&String> = map.keys().filter(|n| !n.contains("running_")).collect();
        // Sorted, so the optimiser's order does not depend on the hash map.
        names.sort();
        names.into_iter().filter_map(|n| map.get(n).cloned()).collect()
    };
    let mut opt = candle_nn::AdamW::new(
        trainable,
        candle_nn::ParamsAdamW {
            lr: cfg.lr,
            weight_decay: 1e-4,
            ..Default::default()
        },
    )
    .map_err(ce)?;

    let inputs = data.inputs(1.0)?;
    let mix_inputs = match mix {
        Some(m) => m.inputs(1.0)?,
        None => Vec::new(),
    };
    let targets = data.targets();
    let n = targets.len();
    let outputs = kind.outputs();
    let k = outputs.len();
    let unit_targets: Vec<f32> = targets
        .iter()
        .flat_map(|t| t.iter().zip(outputs).map(|(v, r)| r.to_unit(*v) as f32))
        .collect();
    let phys_targets: Vec<f32> = targets.iter().flat_map(|t| t.iter().map(|&v| v as f32)).collect();
    let mix_targets = mix.map(|m| m.targets()).unwrap_or_default();
    // Absolute errors are weighed by the width of each range, so rho_d and alpha count alike.
    let widths: Vec<f32> = outputs.iter().map(|r| (r.hi - r.lo) as f32).collect();
    let dev = Device::Cpu;
    let inv_w = Tensor::from_vec(widths.iter().map(|w| 1.0 / w).collect::<Vec<f32>>(), (1, k), &dev).map_err(ce)?;

    let batch = cfg.batch.clamp(2, n.max(2));
    let steps_per_epoch = n.div_ceil(batch);
    let total = cfg.max_steps.unwrap_or(cfg.epochs * steps_per_epoch).max(1);
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5eed);
    let mut order: Vec<usize> = (0..n).collect();
    let mut step_losses = Vec::new();
    let start = Instant::now();
    let mut step = 0;
    let mut seen = 0;
    'epochs: for epoch in 0.. {
        order.shuffle(&mut rng);
        let mut epoch_loss = 0.0;
        let mut epoch_steps = 0;
        for idx in order.chunks(batch) {
            if step >= total {
                break 'epochs;
            }
            // Batch norm needs at least two images.
            if idx.len() < 2 {
                continue;
            }
            let lr = cfg.lr * 0.5 * (1.0 + (std::f64::consts::PI * step as f64 / total as f64).cos());
            opt.set_learning_rate(lr);
            let mut xb = Vec::with_capacity(idx.len() * INPUT_LEN);
            let mut ub = Vec::with_capacity(idx.len() * k);
            let mut pb = Vec::with_capacity(idx.len() * k);
            // (dataset, row) of every image of the batch: the epoch's rows, then the rehearsal draws.
            let mut rows: Vec<(bool, usize)> = idx.iter().map(|&i| (false, i)).collect();
            if let Some(m) = mix {
                for _ in 0..cfg.mix_per_batch {
                    rows.push((true, rng.random_range(0..m.samples.len())));
                }
            }
            for &(from_mix, i) in &rows {
                let (set, set_inputs) = match mix {
                    Some(m) if from_mix => (m, &mix_inputs),
                    _ => (data, &inputs),
                };
                let augmented;
                let mut x = &set_inputs[i * INPUT_LEN..(i + 1) * INPUT_LEN];
                if cfg.png_augment > 0.0 && rng.random::<f64>() < cfg.png_augment {
                    let (lo, hi) = cfg.png_range;
                    let light = lo * (hi / lo).powf(rng.random::<f64>());
                    let png = super::report::photo(&set.images[i], light, super::report::Photo::Png8);
                    augmented =
                        preprocess(&png).map_err(|e| EncoderError::dataset(&set.dir.join(&set.samples[i].file), e))?;
                    x = &augmented;
                }
                if rng.random::<bool>() {
                    xb.extend(flip_vertical(x));
                } else {
                    xb.extend_from_slice(x);
                }
                if from_mix {
                    let t = &mix_targets[i];
                    ub.extend(t.iter().zip(outputs).map(|(v, r)| r.to_unit(*v) as f32));
                    pb.extend(t.iter().map(|&v| v as f32));
                } else {
                    ub.extend_from_slice(&unit_targets[i * k..(i + 1) * k]);
                    pb.extend_from_slice(&phys_targets[i * k..(i + 1) * k]);
                }
            }
            let b = rows.len();
            let loss = (|| -> candle_core::Result<Tensor> {
                let x = Tensor::from_vec(xb, (b, 3, INPUT_SIZE, INPUT_SIZE), &dev)?;
                let u = Tensor::from_vec(ub, (b, k), &dev)?;
                let p = Tensor::from_vec(pb, (b, k), &dev)?;
                let s = net.unit(&x, true)?;
                let phys = net.params_of_unit(&s)?;
                // Unit-space error (relative for the log-mapped alpha) + range-scaled absolute error.
                let l_unit = (&s - &u)?.abs()?.mean_all()?;
                let l_phys = (&phys - &p)?.abs()?.broadcast_mul(&inv_w)?.mean_all()?;
                l_unit + (l_phys * cfg.phys_weight)?
            })()
            .map_err(ce)?;
            opt.backward_step(&loss).map_err(ce)?;
            let l = loss.to_scalar::<f32>().map_err(ce)?;
            if !l.is_finite() {
                return Err(EncoderError::Model(format!("the loss diverged at step {step}")));
            }
            step_losses.push(l);
            epoch_loss += l as f64;
            epoch_steps += 1;
            step += 1;
            seen += b;
        }
        let mut line = format!(
            "epoch {:3}  loss {:.5}  {:.0} s  {:.0} img/s",
            epoch + 1,
            epoch_loss / epoch_steps.max(1) as f64,
            start.elapsed().as_secs_f64(),
            seen as f64 / start.elapsed().as_secs_f64().max(1e-9)
        );
        if let Some(v) = val {
            let mae = mae(&net, v)?;
            let cols: Vec<String> = outputs
                .iter()
                .zip(&mae)
                .map(|(r, m)| format!("{} {m:.4}", r.name))
                .collect();
            line += &format!("  val MAE {}", cols.join("  "));
        }
        log(&line);
    }
    Ok((
        net,
        TrainLog {
            step_losses,
            seconds: start.elapsed().as_secs_f64(),
            images: seen,
        },
    ))
}

/// How to train a model, whatever it is trained on: what `train_model` and `cross_validate` share.
#[derive(Clone, Copy)]
pub struct Recipe<'a> {
    /// Images mixed into every batch (`TrainConfig::mix_per_batch` of them), if any.
    pub mix: Option<&'a Loaded>,
    /// Weights to start from; member j starts from member j (mod their number).
    pub init: Option<&'a Model>,
    pub cfg: &'a TrainConfig,
    /// Networks in the ensemble (member j trains with seed `cfg.seed + j`).
    pub members: usize,
    /// Average each member over the image and its mirror.
    pub flip: bool,
}

impl<'a> Recipe<'a> {
    /// One network from scratch, no mixing, no flip.
    pub fn single(cfg: &'a TrainConfig) -> Self {
        Self {
            mix: None,
            init: None,
            cfg,
            members: 1,
            flip: false,
        }
    }
}

/// Train an ensemble: member j with seed `cfg.seed + j`, from member j (mod their number) of
/// `init`; the model averages the members' logits, over the image and its mirror with `flip`.
/// Returns the model, the candle networks (same order) and the summed log.
pub fn train_model(
    data: &Loaded,
    recipe: &Recipe,
    val: Option<&Loaded>,
    log: &mut dyn FnMut(&str),
) -> Result<(Model, Vec<Net>, TrainLog), EncoderError> {
    let Recipe {
        mix,
        init,
        cfg,
        members,
        flip,
    } = *recipe;
    if members == 0 {
        return Err(EncoderError::Model("an ensemble needs at least one network".into()));
    }
    let mut nets = Vec::new();
    let mut weights = Vec::new();
    let mut total = TrainLog {
        step_losses: Vec::new(),
        seconds: 0.0,
        images: 0,
    };
    for j in 0..members {
        let c = TrainConfig {
            seed: cfg.seed + j as u64,
            ..cfg.clone()
        };
        let start = init.map(|m| &m.members[j % m.members.len()]);
        if members > 1 {
            log(&format!("member {} of {members} (seed {})", j + 1, c.seed));
        }
        let (net, l) = train_mixed(data, mix, start, &c, val, log)?;
        weights.push(net.weights()?);
        nets.push(net);
        total.step_losses.extend(l.step_losses);
        total.seconds += l.seconds;
        total.images += l.images;
    }
    Ok((Model { members: weights, flip }, nets, total))
}

/// One held-out row of a cross-validation: its predictions through the exported ONNX model (tract).
#[derive(Clone, Debug)]
pub struct CvRow {
    pub fold: usize,
    pub file: String,
    pub spec: String,
    pub truth: Vec<f64>,
    /// Linear photo (any light: the input is normalised).
    pub linear: Vec<f64>,
    /// 8-bit PNG auto-exposed at x1, then lit x0.5, x1 and x2 (`report::Photo::Png8`).
    pub png: [Vec<f64>; 3],
}

/// The PNG light factors of `CvRow::png`.
pub const CV_PNG_LIGHTS: [f64; 3] = [0.5, 1.0, 2.0];

/// K-fold cross-validation over the training rows of `data`: row i (in dataset order) is in fold
/// i mod `folds`; each fold (or only `only`) is trained on the other folds with `train_model` and
/// its rows predicted through the exported ONNX file, as `gonio-lab encoder-report` would.
pub fn cross_validate(
    data: &Loaded,
    recipe: &Recipe,
    folds: usize,
    only: Option<usize>,
    log: &mut dyn FnMut(&str),
) -> Result<(Vec<CvRow>, TrainLog), EncoderError> {
    use super::report::{predict, Photo};
    if folds < 2 || folds > data.samples.len() {
        return Err(EncoderError::Model(format!(
            "{folds} folds of {} images: need 2 <= folds <= images",
            data.samples.len()
        )));
    }
    if only.is_some_and(|f| f >= folds) {
        return Err(EncoderError::Model(format!(
            "fold {only:?} of {folds}: folds count from 0"
        )));
    }
    let mut rows = Vec::new();
    let mut total = TrainLog {
        step_losses: Vec::new(),
        seconds: 0.0,
        images: 0,
    };
    for fold in (0..folds).filter(|f| only.is_none_or(|o| o == *f)) {
        let train_part = data.subset(&|i| i % folds != fold);
        let held = data.subset(&|i| i % folds == fold);
        log(&format!(
            "fold {fold} of {folds}: training on {}, validating on {}",
            train_part.samples.len(),
            held.samples.len()
        ));
        let (model, _, l) = train_model(&train_part, recipe, None, log)?;
        total.seconds += l.seconds;
        total.images += l.images;
        let bytes = model.to_onnx("cross-validation").map_err(EncoderError::Model)?;
        let encoder = super::infer::Encoder::from_bytes(&bytes)?;
        let linear = predict(&encoder, &held, 1.0, Photo::Linear)?;
        let png: Vec<Vec<Vec<f64>>> = CV_PNG_LIGHTS
            .iter()
            .map(|&light| predict(&encoder, &held, light, Photo::Png8))
            .collect::<Result<_, _>>()?;
        for (i, s) in held.samples.iter().enumerate() {
            rows.push(CvRow {
                fold,
                file: s.file.clone(),
                spec: s.spec.clone(),
                truth: s.params.clone(),
                linear: linear[i].clone(),
                png: [png[0][i].clone(), png[1][i].clone(), png[2][i].clone()],
            });
        }
    }
    Ok((rows, total))
}

/// Threshold of the MERL goal (every |alpha error| <= 0.05), counted in the cross-validation summary.
pub const CV_MISS: f64 = 0.05;

/// The printable summary of a cross-validation: per output the linear MAE, max |err| and the count
/// above `CV_MISS`; the 8-bit PNG MAE at x1 and its change at x0.5 and x2; the misses by name.
pub fn cv_summary(kind: ModelKind, rows: &[CvRow]) -> Vec<String> {
    let n = rows.len().max(1) as f64;
    let mut lines = vec![format!("cross-validation: {} held-out images", rows.len())];
    lines.push(format!(
        "{:<8} {:>9} {:>9} {:>7}   {:>9} {:>9} {:>9}",
        "param", "MAE", "max |err|", ">0.05", "PNG x1", "x0.5 chg", "x2 chg"
    ));
    for (j, r) in kind.outputs().iter().enumerate() {
        let err =
            |p: &dyn Fn(&CvRow) -> f64| -> Vec<f64> { rows.iter().map(|row| (p(row) - row.truth[j]).abs()).collect() };
        let lin = err(&|row| row.linear[j]);
        let png: Vec<f64> = (0..3)
            .map(|v| err(&|row| row.png[v][j]).iter().sum::<f64>() / n)
            .collect();
        lines.push(format!(
            "{:<8} {:>9.4} {:>9.4} {:>7}   {:>9.4} {:>+9.4} {:>+9.4}",
            r.name,
            lin.iter().sum::<f64>() / n,
            lin.iter().copied().fold(0.0, f64::max),
            lin.iter().filter(|&&e| e > CV_MISS).count(),
            png[1],
            png[0] - png[1],
            png[2] - png[1]
        ));
    }
    let j = kind.outputs().len() - 1;
    for row in rows.iter().filter(|row| (row.linear[j] - row.truth[j]).abs() > CV_MISS) {
        lines.push(format!(
            "  miss (fold {}): {} {} true {:.3} -> {:.3}",
            row.fold, row.file, row.spec, row.truth[j], row.linear[j]
        ));
    }
    lines
}

/// The cross-validation rows as CSV: fold, file, spec, then per output true, linear and PNG values.
pub fn cv_csv(kind: ModelKind, rows: &[CvRow]) -> String {
    let mut cols = Vec::new();
    for r in kind.outputs() {
        for c in ["true", "linear", "png05", "png1", "png2"] {
            cols.push(format!("{c}_{}", r.name));
        }
    }
    let mut text = format!("fold,file,spec,{}\n", cols.join(","));
    for row in rows {
        let mut vals = Vec::new();
        for j in 0..row.truth.len() {
            vals.push(row.truth[j].to_string());
            vals.push(row.linear[j].to_string());
            for v in &row.png {
                vals.push(v[j].to_string());
            }
        }
        text += &format!("{},{},\"{}\",{}\n", row.fold, row.file, row.spec, vals.join(","));
    }
    text
}

/// Mean absolute error per output of `net` on `data` (candle, inference mode).
pub fn mae(net: &Net, data: &Loaded) -> Result<Vec<f64>, EncoderError> {
    if data.kind != net.kind {
        return Err(EncoderError::Model(format!(
            "the data are {}, the network {}",
            data.kind.name(),
            net.kind.name()
        )));
    }
    let pred = net.predict(&data.inputs(1.0)?)?;
    let k = net.kind.outputs().len();
    let mut sum = vec![0.0; k];
    for (p, t) in pred.iter().zip(data.targets()) {
        for j in 0..k {
            sum[j] += (p[j] as f64 - t[j]).abs();
        }
    }
    Ok(sum.into_iter().map(|s| s / pred.len().max(1) as f64).collect())
}

/// Load a dataset's training rows (everything but `split = test`).
pub fn load_train(dir: &Path) -> Result<Loaded, EncoderError> {
    dataset::load(dir, &|s| s != "test")
}
