//! `gonio-lab encoder-report`: a model's accuracy on a dataset's test images, its error across light
//! intensities, and the per-image predictions (CSV) behind the predicted-vs-true plot.

use super::dataset::Loaded;
use super::infer::Encoder;
use super::{preprocess, EncoderError, INPUT_LEN};
use gonio::render::image::{srgb_to_linear, tone_map};
use gonio::render::Image;

/// Light-intensity factors of the sweep: the x0.25 .. x4, with factors that are not powers of
/// two (multiplying by a power of two is exact in floating point and would test nothing).
pub const SWEEP: [f64; 9] = [0.25, 0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, 4.0];

/// How the test images reach the network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Photo {
    /// Linear floating point (EXR): no clipping, no quantisation.
    Linear,
    /// An 8-bit sRGB PNG exposed so that the brightest pixel is white at x1: brighter light clips
    /// the highlight, dimmer light loses the dark parts to quantisation.
    Png8,
}

/// The image as the network would get it under `scale` x the light.
pub fn photo(image: &Image, scale: f64, mode: Photo) -> Image {
    let mut out = image.clone();
    match mode {
        Photo::Linear => {
            for p in &mut out.pixels {
                *p *= scale;
            }
        }
        Photo::Png8 => {
            let peak = image.pixels.iter().map(|p| p.max_element()).fold(0.0, f64::max);
            let exposure = if peak > 0.0 { scale / peak } else { scale };
            let q = |v: f64| srgb_to_linear((tone_map(v * exposure) * 255.0).round() / 255.0);
            for p in &mut out.pixels {
                *p = glam::DVec3::new(q(p.x), q(p.y), q(p.z));
            }
        }
    }
    out
}

/// Predictions of `encoder` for every image of `data` under `scale` x the light.
pub fn predict(encoder: &Encoder, data: &Loaded, scale: f64, mode: Photo) -> Result<Vec<Vec<f64>>, EncoderError> {
    data.images
        .iter()
        .zip(&data.samples)
        .map(|(img, s)| {
            let input =
                preprocess(&photo(img, scale, mode)).map_err(|e| EncoderError::dataset(&data.dir.join(&s.file), e))?;
            debug_assert_eq!(input.len(), INPUT_LEN);
            encoder.estimate(&input)
        })
        .collect()
}

/// Per-output mean absolute error and max absolute error.
pub fn errors(pred: &[Vec<f64>], truth: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>) {
    let k = truth.first().map_or(0, |t| t.len());
    let mut mae = vec![0.0; k];
    let mut max = vec![0.0f64; k];
    for (p, t) in pred.iter().zip(truth) {
        for j in 0..k {
            let e = (p[j] - t[j]).abs();
            mae[j] += e;
            max[j] = max[j].max(e);
        }
    }
    let n = pred.len().max(1) as f64;
    (mae.into_iter().map(|s| s / n).collect(), max)
}

pub struct Report {
    pub lines: Vec<String>,
    /// (file, spec, truth, prediction at x1)
    pub rows: Vec<(String, String, Vec<f64>, Vec<f64>)>,
}

/// The accuracy table and the intensity sweep, as printable lines.
pub fn report(encoder: &Encoder, data: &Loaded, mode: Photo) -> Result<Report, EncoderError> {
    if encoder.kind != data.kind {
        return Err(EncoderError::Model(format!(
            "the model is {}, the dataset is {}",
            encoder.kind.name(),
            data.kind.name()
        )));
    }
    let outputs = encoder.kind.outputs();
    let truth = data.targets();
    let mut lines = Vec::new();
    lines.push(format!(
        "{} model on {} test images of {} ({})",
        encoder.kind.name(),
        truth.len(),
        data.dir.display(),
        match mode {
            Photo::Linear => "linear EXR",
            Photo::Png8 => "8-bit PNG, auto-exposed at x1",
        }
    ));
    let nominal = predict(encoder, data, 1.0, mode)?;
    let (mae, max) = errors(&nominal, &truth);
    lines.push(format!("{:<8} {:>9} {:>9}", "param", "MAE", "max |err|"));
    for ((r, m), x) in outputs.iter().zip(&mae).zip(&max) {
        lines.push(format!("{:<8} {m:>9.4} {x:>9.4}", r.name));
    }
    lines.push(String::new());
    let header: Vec<String> = outputs
        .iter()
        .map(|r| format!("{:>12}", format!("MAE {}", r.name)))
        .collect();
    lines.push(format!(
        "{:<10} {}  {:>14}",
        "intensity",
        header.join(" "),
        "vs x1 (last)"
    ));
    for &scale in &SWEEP {
        let pred = if scale == 1.0 {
            nominal.clone()
        } else {
            predict(encoder, data, scale, mode)?
        };
        let (m, _) = errors(&pred, &truth);
        let cols: Vec<String> = m.iter().map(|v| format!("{v:>12.4}")).collect();
        let last = m.len() - 1;
        lines.push(format!(
            "x{scale:<9} {}  {:>+14.4}",
            cols.join(" "),
            m[last] - mae[last]
        ));
    }
    let rows = data
        .samples
        .iter()
        .zip(&truth)
        .zip(&nominal)
        .map(|((s, t), p)| (s.file.clone(), s.spec.clone(), t.clone(), p.clone()))
        .collect();
    Ok(Report { lines, rows })
}

/// The per-image CSV: file, spec, then true and predicted values of each output, then (when given)
/// the observable alpha of each row (`observable_alphas`).
pub fn csv(
    kind: super::ModelKind,
    rows: &[(String, String, Vec<f64>, Vec<f64>)],
    observable: Option<&[f64]>,
) -> String {
    let mut names: Vec<String> = kind
        .outputs()
        .iter()
        .flat_map(|r| [format!("true_{}", r.name), format!("pred_{}", r.name)])
        .collect();
    if observable.is_some() {
        names.push("observable_alpha".into());
    }
    let mut text = format!("file,spec,{}\n", names.join(","));
    for (i, (file, spec, t, p)) in rows.iter().enumerate() {
        let mut vals: Vec<String> = t
            .iter()
            .zip(p)
            .flat_map(|(a, b)| [a.to_string(), b.to_string()])
            .collect();
        if let Some(&obs) = observable.and_then(|o| o.get(i)) {
            vals.push(obs.to_string());
        }
        text += &format!("{file},\"{spec}\",{}\n", vals.join(","));
    }
    text
}

/// The label's distance from what the photo shows, per row: the alpha of a GGX fit to the capture
/// photo's own direction pairs (`observable::observable_alpha`) of each row's material.
pub fn observable_alphas(rows: &[(String, String, Vec<f64>, Vec<f64>)]) -> Result<Vec<f64>, EncoderError> {
    use rayon::prelude::*;
    rows.par_iter()
        .map(|(file, spec, _, _)| {
            let material = gonio::brdf::spec::parse_material(spec)
                .map_err(|e| EncoderError::Model(format!("{file}: material {spec}: {e}")))?;
            super::observable::observable_alpha(material.as_ref())
                .map_err(|e| EncoderError::Model(format!("{file}: {e}")))
        })
        .collect()
}

/// Where the photo cannot tell the label: a table of label, observable and predicted alpha per row,
/// and the counts beside the goal's 0.05.
pub fn observable_lines(rows: &[(String, String, Vec<f64>, Vec<f64>)], observable: &[f64]) -> Vec<String> {
    const GOAL: f64 = 0.05;
    let mut lines = vec![
        String::new(),
        "what the photo shows: alpha of a GGX fit to the capture photo's own directions (theta_d ~ 15 deg)".into(),
        format!(
            "{:<34} {:>7} {:>10} {:>9} {:>12} {:>12}",
            "material", "label", "observable", "predicted", "|obs-label|", "|pred-label|"
        ),
    ];
    let (mut apart, mut missed, mut missed_apart) = (0, 0, 0);
    let (mut to_label, mut to_obs) = (0.0, 0.0);
    for ((_, spec, t, p), &o) in rows.iter().zip(observable) {
        // alpha is the last output of both models; a row without outputs has nothing to compare.
        let (Some(&label), Some(&pred)) = (t.last(), p.last()) else {
            continue;
        };
        let far = (o - label).abs() > GOAL;
        let miss = (pred - label).abs() > GOAL;
        apart += far as usize;
        missed += miss as usize;
        missed_apart += (far && miss) as usize;
        to_label += (pred - label).abs();
        to_obs += (pred - o).abs();
        lines.push(format!(
            "{:<34} {label:>7.3} {o:>10.3} {pred:>9.3} {:>12.3} {:>12.3}{}",
            spec.trim_start_matches("nbrdf:"),
            (o - label).abs(),
            (pred - label).abs(),
            if miss { "  miss" } else { "" }
        ));
    }
    let n = rows.len().max(1) as f64;
    lines.push(format!(
        "|observable - label| > {GOAL}: {apart} of {}; predictions missing the label by > {GOAL}: {missed}, {missed_apart} of them where the observable fit is apart too",
        rows.len()
    ));
    lines.push(format!(
        "mean |predicted - label| {:.4}, mean |predicted - observable| {:.4}",
        to_label / n,
        to_obs / n
    ));
    lines
}

/// Predicted against true alpha (the last output of both models), with the y = x line.
pub fn chart(
    kind: super::ModelKind,
    rows: &[(String, String, Vec<f64>, Vec<f64>)],
    data: &std::path::Path,
) -> crate::plot::Chart {
    use crate::plot::{Chart, Mark, Series};
    let j = kind.outputs().len() - 1;
    let points: Vec<(f64, f64)> = rows.iter().map(|(_, _, t, p)| (t[j], p[j])).collect();
    let name = data
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut chart = Chart::new(
        format!(
            "{} encoder: predicted vs true alpha ({name}, {} images)",
            kind.name(),
            rows.len()
        ),
        "true alpha",
        "predicted alpha",
    )
    .with_series(Series::new("test images", points, Mark::Points));
    chart.diagonal = true;
    chart
}
