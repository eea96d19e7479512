//! `gonio estimate`: the encoder's parameters for one capture photo.

use crate::names::parse_name;
use anyhow::{Context, Result};
use clap::Args;
use gonio::encoder::infer::Encoder;
use gonio::encoder::{load_photo, preprocess, ModelKind};
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct EstimateArgs {
    /// A photo following examples/capture.toml: PNG (8/16-bit RGB/RGBA) or EXR, any size.
    pub image: PathBuf,
    /// Which shipped model to run.
    #[arg(long, value_parser = parse_name::<ModelKind>(), default_value = "ggx")]
    pub model: ModelKind,
    /// Run this ONNX file instead of a shipped model.
    #[arg(long)]
    pub model_file: Option<PathBuf>,
    /// Print a JSON object: {"model": ..., "<param>": value, ...}.
    #[arg(long)]
    pub json: bool,
}

fn load_encoder(model: ModelKind, file: Option<&Path>) -> Result<Encoder> {
    Ok(match file {
        Some(path) => Encoder::from_file(path)?,
        None => Encoder::shipped(model).with_context(|| format!("the shipped {} model", model.name()))?,
    })
}

pub fn run_estimate(args: EstimateArgs) -> Result<()> {
    let photo = load_photo(&args.image)?;
    let input = preprocess(&photo).map_err(|e| anyhow::anyhow!("{}: {e}", args.image.display()))?;
    let encoder = load_encoder(args.model, args.model_file.as_deref())?;
    let values = encoder.estimate(&input)?;
    let kind = encoder.kind;
    if args.json {
        let mut obj = serde_json::Map::new();
        obj.insert("model".into(), kind.name().into());
        for (r, v) in kind.outputs().iter().zip(&values) {
            obj.insert(r.name.into(), serde_json::json!(v));
        }
        println!("{}", serde_json::Value::Object(obj));
    } else {
        println!("{}", kind.spec(&values));
    }
    Ok(())
}
