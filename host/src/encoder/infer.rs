//! ONNX inference with tract: the one module that knows tract exists. Everything else hands it
//! preprocessed inputs (`super::preprocess`) and gets parameters back.

use super::{EncoderError, ModelKind, INPUT_LEN, INPUT_SIZE};
use prost::Message;
use std::sync::Arc;
use tract_onnx::prelude::*;

/// The shipped models, embedded so that `gonio estimate` works from any directory.
pub const WARD_ONNX: &[u8] = include_bytes!("../../models/ward.onnx");
pub const GGX_ONNX: &[u8] = include_bytes!("../../models/ggx.onnx");

/// Metadata keys the lab's exporter writes (`gonio_lab::encoder::onnx`).
pub const META_MODEL: &str = "gonio.model";

pub fn shipped(kind: ModelKind) -> &'static [u8] {
    match kind {
        ModelKind::Ward => WARD_ONNX,
        ModelKind::Ggx => GGX_ONNX,
    }
}

/// A loaded, optimised model for batch-1 inference.
pub struct Encoder {
    pub kind: ModelKind,
    plan: Arc<TypedSimplePlan>,
}

impl Encoder {
    /// Load ONNX bytes; the model kind comes from the file's `gonio.model` metadata.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, EncoderError> {
        let bad = |e: &dyn std::fmt::Display| EncoderError::Model(e.to_string());
        let proto = tract_onnx::pb::ModelProto::decode(bytes).map_err(|e| bad(&format!("not an ONNX file ({e})")))?;
        let kind_name = proto
            .metadata_props
            .iter()
            .find(|p| p.key == META_MODEL)
            .map(|p| p.value.clone())
            .ok_or_else(|| bad(&format!("no '{META_MODEL}' metadata: not a gonio encoder")))?;
        let kind = ModelKind::from_name(&kind_name)
            .ok_or_else(|| bad(&format!("unknown model kind '{kind_name}' in metadata")))?;
        let plan = tract_onnx::onnx()
            .model_for_proto_model(&proto)
            .and_then(|m| m.with_input_fact(0, f32::fact([1, 3, INPUT_SIZE, INPUT_SIZE]).into()))
            .and_then(|m| m.into_optimized())
            .and_then(|m| m.into_runnable())
            .map_err(|e| bad(&format!("{e:#}")))?;
        let encoder = Self { kind, plan };
        // A model whose output does not have one value per documented parameter is rejected now.
        encoder.run_unit_check()?;
        Ok(encoder)
    }

    pub fn from_file(path: &std::path::Path) -> Result<Self, EncoderError> {
        let bytes = std::fs::read(path).map_err(|e| EncoderError::Model(format!("{}: {e}", path.display())))?;
        Self::from_bytes(&bytes).map_err(|e| EncoderError::Model(format!("{}: {e}", path.display())))
    }

    pub fn shipped(kind: ModelKind) -> Result<Self, EncoderError> {
        Self::from_bytes(shipped(kind))
    }

    fn run_unit_check(&self) -> Result<(), EncoderError> {
        self.run(&vec![0.0; INPUT_LEN]).map(|_| ())
    }

    /// The raw network outputs (physical parameters, in `kind.outputs()` order) of one input.
    pub fn run(&self, input: &[f32]) -> Result<Vec<f32>, EncoderError> {
        if input.len() != INPUT_LEN {
            return Err(EncoderError::Model(format!(
                "input has {} values, expected {INPUT_LEN}",
                input.len()
            )));
        }
        let tensor = tract_ndarray::Array4::from_shape_vec((1, 3, INPUT_SIZE, INPUT_SIZE), input.to_vec())
            .map_err(|e| EncoderError::Model(e.to_string()))?;
        let out = self
            .plan
            .run(tvec!(Tensor::from(tensor).into()))
            .map_err(|e| EncoderError::Model(format!("{e:#}")))?;
        let view = out[0]
            .to_plain_array_view::<f32>()
            .map_err(|e| EncoderError::Model(format!("{e:#}")))?;
        let values: Vec<f32> = view.iter().copied().collect();
        let n = self.kind.outputs().len();
        if values.len() != n || values.iter().any(|v| !v.is_finite()) {
            return Err(EncoderError::Model(format!(
                "the model gave {values:?}, expected {n} finite values"
            )));
        }
        Ok(values)
    }

    /// Parameters of one preprocessed input, as f64 in `kind.outputs()` order.
    pub fn estimate(&self, input: &[f32]) -> Result<Vec<f64>, EncoderError> {
        Ok(self.run(input)?.into_iter().map(f64::from).collect())
    }
}
