//! The encoder network as plain weight arrays, and its ONNX graph (opset 13) written with the
//! protobuf types of `tract_onnx::pb` and prost at tract's version. Training fills `Weights`
//! from candle; `from_onnx` reads them back (fine-tuning starts from a pretrained file).
//!
//! Graph (Cao, Fig. 3): 5 x [Conv 3x3 (no bias) -> BatchNormalization -> Relu], GlobalAveragePool,
//! Flatten, Gemm (the logits), Sigmoid, then the range mapping of `ModelKind::outputs`:
//! params = (s * lin_scale + lin_off) * lin_mask + exp(s * log_scale + log_off) * log_mask,
//! so the file outputs physical parameters and any ONNX runtime can use it without our code.
//! A `Model` may hold several networks (an ensemble) and average their logits over the image and its
//! vertical mirror (test-time augmentation) with standard ops (Gather, Mean) in the same one file.

use super::{EncoderError, ModelKind, CHANNELS, INPUT_SIZE};
use prost::Message;
use tract_onnx::pb;

/// (in channels, out channels, stride) of each conv block: 64 -> 32 -> 16 -> 8 -> 8 -> 4 pixels.
pub const BLOCKS: [(usize, usize, usize); 5] = [(CHANNELS, 16, 2), (16, 32, 2), (32, 64, 2), (64, 64, 1), (64, 96, 2)];
/// Width of the pooled feature vector.
pub const FEATURES: usize = 96;
pub const BN_EPS: f64 = 1e-5;
pub const OPSET: i64 = 13;
pub const INPUT_NAME: &str = "image";
pub const OUTPUT_NAME: &str = "params";

#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// (out, in, 3, 3), row-major.
    pub conv: Vec<f32>,
    pub bn_weight: Vec<f32>,
    pub bn_bias: Vec<f32>,
    pub bn_mean: Vec<f32>,
    pub bn_var: Vec<f32>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Weights {
    pub kind: ModelKind,
    pub blocks: Vec<Block>,
    /// (outputs, FEATURES), row-major.
    pub fc_weight: Vec<f32>,
    pub fc_bias: Vec<f32>,
}

fn f32_tensor(name: &str, dims: &[usize], data: Vec<f32>) -> pb::TensorProto {
    pb::TensorProto {
        name: name.to_string(),
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: pb::tensor_proto::DataType::Float as i32,
        float_data: data,
        ..Default::default()
    }
}

fn ints(name: &str, v: &[i64]) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Ints as i32,
        ints: v.to_vec(),
        ..Default::default()
    }
}

fn int(name: &str, v: i64) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Int as i32,
        i: v,
        ..Default::default()
    }
}

fn float(name: &str, v: f32) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Float as i32,
        f: v,
        ..Default::default()
    }
}

fn node(op: &str, name: &str, inputs: &[&str], output: &str, attribute: Vec<pb::AttributeProto>) -> pb::NodeProto {
    pb::NodeProto {
        op_type: op.into(),
        name: name.into(),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        attribute,
        ..Default::default()
    }
}

fn value_info(name: &str, dims: &[pb::tensor_shape_proto::dimension::Value]) -> pb::ValueInfoProto {
    pb::ValueInfoProto {
        name: name.into(),
        r#type: Some(pb::TypeProto {
            value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                elem_type: pb::tensor_proto::DataType::Float as i32,
                shape: Some(pb::TensorShapeProto {
                    dim: dims
                        .iter()
                        .map(|v| pb::tensor_shape_proto::Dimension {
                            value: Some(v.clone()),
                            ..Default::default()
                        })
                        .collect(),
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

impl Weights {
    /// Check every array has the size the architecture implies.
    pub fn check(&self) -> Result<(), String> {
        if self.blocks.len() != BLOCKS.len() {
            return Err(format!("{} conv blocks, expected {}", self.blocks.len(), BLOCKS.len()));
        }
        for (i, (b, &(cin, cout, _))) in self.blocks.iter().zip(&BLOCKS).enumerate() {
            let ok = b.conv.len() == cout * cin * 9
                && [&b.bn_weight, &b.bn_bias, &b.bn_mean, &b.bn_var]
                    .iter()
                    .all(|v| v.len() == cout);
            if !ok {
                return Err(format!("block {i} has arrays of the wrong size"));
            }
        }
        let k = self.kind.outputs().len();
        if self.fc_weight.len() != k * FEATURES || self.fc_bias.len() != k {
            return Err("the fully connected layer has the wrong size".into());
        }
        Ok(())
    }

    /// The ONNX file (opset 13) of this network alone (`Model::single`).
    pub fn to_onnx(&self, doc: &str) -> Result<Vec<u8>, String> {
        Model::single(self.clone()).to_onnx(doc)
    }

    /// Read the weights back from one of our single-network ONNX files (an ensemble is refused:
    /// read it with `Model::from_onnx`).
    pub fn from_onnx(bytes: &[u8]) -> Result<Self, EncoderError> {
        let mut model = Model::from_onnx(bytes)?;
        if model.members.len() != 1 || model.flip {
            return Err(EncoderError::Model(format!(
                "an ensemble of {} networks{}, not one network",
                model.members.len(),
                if model.flip { " with flip averaging" } else { "" }
            )));
        }
        Ok(model.members.remove(0))
    }
}

/// What one ONNX file computes: the logits of every member network on the image and, with `flip`,
/// on its vertical mirror (the capture light lies in y = 0, so an isotropic sample's photo is
/// symmetric top to bottom: the mirror is another view of the same material) are averaged with an
/// ONNX `Mean`, then go through the sigmoid and the range map once. One member without flip is
/// the plain network. Member j's initializers are named like the plain network's, prefixed with
/// `m{j}.` for j >= 1, so a single-network file keeps the names of version 1 and 2.
#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    pub members: Vec<Weights>,
    pub flip: bool,
}

/// Metadata keys of the ensemble layout.
pub const META_MEMBERS: &str = "gonio.members";
pub const META_TTA: &str = "gonio.tta";

/// The initializer prefix of member j.
fn member_prefix(j: usize) -> String {
    if j == 0 {
        String::new()
    } else {
        format!("m{j}.")
    }
}

impl Model {
    pub fn single(w: Weights) -> Self {
        Self {
            members: vec![w],
            flip: false,
        }
    }

    pub fn kind(&self) -> Result<ModelKind, String> {
        let kind = self.members.first().ok_or("a model needs at least one network")?.kind;
        if self.members.iter().any(|m| m.kind != kind) {
            return Err("the ensemble mixes Ward and GGX networks".into());
        }
        Ok(kind)
    }

    /// Network evaluations per image (members x views): the inference cost relative to one network.
    pub fn evaluations(&self) -> usize {
        self.members.len() * if self.flip { 2 } else { 1 }
    }

    /// The ONNX file (opset 13), with `gonio.model` metadata naming the model kind.
    pub fn to_onnx(&self, doc: &str) -> Result<Vec<u8>, String> {
        use pb::tensor_shape_proto::dimension::Value as D;
        let kind = self.kind()?;
        for w in &self.members {
            w.check()?;
        }
        let k = kind.outputs().len();
        let mut init = Vec::new();
        let mut nodes = Vec::new();
        for (j, w) in self.members.iter().enumerate() {
            let m = member_prefix(j);
            for (i, (b, &(cin, cout, _))) in w.blocks.iter().zip(&BLOCKS).enumerate() {
                let p = format!("{m}b{i}");
                init.push(f32_tensor(
                    &format!("{p}.conv.weight"),
                    &[cout, cin, 3, 3],
                    b.conv.clone(),
                ));
                for (n, v) in ["weight", "bias", "running_mean", "running_var"].iter().zip([
                    &b.bn_weight,
                    &b.bn_bias,
                    &b.bn_mean,
                    &b.bn_var,
                ]) {
                    init.push(f32_tensor(&format!("{p}.bn.{n}"), &[cout], v.clone()));
                }
            }
            init.push(f32_tensor(
                &format!("{m}fc.weight"),
                &[k, FEATURES],
                w.fc_weight.clone(),
            ));
            init.push(f32_tensor(&format!("{m}fc.bias"), &[k], w.fc_bias.clone()));
        }
        let mut views = vec![INPUT_NAME.to_string()];
        if self.flip {
            // Row r of the mirror is row (S - 1 - r) of the image: Gather on the height axis.
            let rows: Vec<i64> = (0..INPUT_SIZE as i64).rev().collect();
            init.push(pb::TensorProto {
                name: "flip_rows".into(),
                dims: vec![INPUT_SIZE as i64],
                data_type: pb::tensor_proto::DataType::Int64 as i32,
                int64_data: rows,
                ..Default::default()
            });
            nodes.push(node(
                "Gather",
                "flip",
                &[INPUT_NAME, "flip_rows"],
                "image.flip",
                vec![int("axis", 2)],
            ));
            views.push("image.flip".into());
        }
        let branches = self.members.len() * views.len();
        let mut logits = Vec::new();
        for j in 0..self.members.len() {
            let m = member_prefix(j);
            for (v, view) in views.iter().enumerate() {
                // Node and value names: the plain network's when there is one branch.
                let q = if branches == 1 {
                    String::new()
                } else {
                    format!("m{j}v{v}.")
                };
                let mut x = view.clone();
                for (i, &(_, _, stride)) in BLOCKS.iter().enumerate() {
                    let p = format!("{m}b{i}");
                    let o = format!("{q}b{i}");
                    let s = stride as i64;
                    nodes.push(node(
                        "Conv",
                        &format!("{o}.conv"),
                        &[&x, &format!("{p}.conv.weight")],
                        &format!("{o}.conv.out"),
                        vec![
                            ints("kernel_shape", &[3, 3]),
                            ints("pads", &[1, 1, 1, 1]),
                            ints("strides", &[s, s]),
                            ints("dilations", &[1, 1]),
                            int("group", 1),
                        ],
                    ));
                    nodes.push(node(
                        "BatchNormalization",
                        &format!("{o}.bn"),
                        &[
                            &format!("{o}.conv.out"),
                            &format!("{p}.bn.weight"),
                            &format!("{p}.bn.bias"),
                            &format!("{p}.bn.running_mean"),
                            &format!("{p}.bn.running_var"),
                        ],
                        &format!("{o}.bn.out"),
                        vec![float("epsilon", BN_EPS as f32)],
                    ));
                    nodes.push(node(
                        "Relu",
                        &format!("{o}.relu"),
                        &[&format!("{o}.bn.out")],
                        &format!("{o}.out"),
                        vec![],
                    ));
                    x = format!("{o}.out");
                }
                nodes.push(node(
                    "GlobalAveragePool",
                    &format!("{q}pool"),
                    &[&x],
                    &format!("{q}pool.out"),
                    vec![],
                ));
                nodes.push(node(
                    "Flatten",
                    &format!("{q}flatten"),
                    &[&format!("{q}pool.out")],
                    &format!("{q}features"),
                    vec![int("axis", 1)],
                ));
                nodes.push(node(
                    "Gemm",
                    &format!("{q}fc"),
                    &[
                        &format!("{q}features"),
                        &format!("{m}fc.weight"),
                        &format!("{m}fc.bias"),
                    ],
                    &format!("{q}logits"),
                    vec![int("transB", 1)],
                ));
                logits.push(format!("{q}logits"));
            }
        }
        if branches > 1 {
            let inputs: Vec<&str> = logits.iter().map(String::as_str).collect();
            nodes.push(node("Mean", "mean", &inputs, "logits", vec![]));
        }
        nodes.push(node("Sigmoid", "sigmoid", &["logits"], "unit", vec![]));
        let m = RangeMap::of(kind);
        for (name, v) in [
            ("lin_scale", m.lin_scale),
            ("lin_off", m.lin_off),
            ("lin_mask", m.lin_mask),
            ("log_scale", m.log_scale),
            ("log_off", m.log_off),
            ("log_mask", m.log_mask),
        ] {
            init.push(f32_tensor(name, &[k], v));
        }
        nodes.push(node("Mul", "lin_mul", &["unit", "lin_scale"], "lin_a", vec![]));
        nodes.push(node("Add", "lin_add", &["lin_a", "lin_off"], "lin_b", vec![]));
        nodes.push(node("Mul", "lin_masked", &["lin_b", "lin_mask"], "lin", vec![]));
        nodes.push(node("Mul", "log_mul", &["unit", "log_scale"], "log_a", vec![]));
        nodes.push(node("Add", "log_add", &["log_a", "log_off"], "log_b", vec![]));
        nodes.push(node("Exp", "log_exp", &["log_b"], "log_c", vec![]));
        nodes.push(node("Mul", "log_masked", &["log_c", "log_mask"], "log", vec![]));
        nodes.push(node("Add", "params", &["lin", "log"], OUTPUT_NAME, vec![]));

        let batch = D::DimParam("batch".into());
        let s = INPUT_SIZE as i64;
        let graph = pb::GraphProto {
            name: format!("gonio-encoder-{}", kind.name()),
            node: nodes,
            initializer: init,
            input: vec![value_info(
                INPUT_NAME,
                &[
                    batch.clone(),
                    D::DimValue(CHANNELS as i64),
                    D::DimValue(s),
                    D::DimValue(s),
                ],
            )],
            output: vec![value_info(OUTPUT_NAME, &[batch, D::DimValue(k as i64)])],
            ..Default::default()
        };
        let names: Vec<&str> = kind.outputs().iter().map(|p| p.name).collect();
        let meta = |k: &str, v: String| pb::StringStringEntryProto {
            key: k.into(),
            value: v,
        };
        let model = pb::ModelProto {
            // IR version 7 is the one that goes with opset 13.
            ir_version: 7,
            opset_import: vec![pb::OperatorSetIdProto {
                domain: String::new(),
                version: OPSET,
            }],
            producer_name: "gonio".into(),
            producer_version: env!("CARGO_PKG_VERSION").into(),
            doc_string: doc.into(),
            graph: Some(graph),
            metadata_props: vec![
                meta(super::infer::META_MODEL, kind.name().into()),
                meta("gonio.outputs", names.join(",")),
                meta("gonio.input", super::INPUT_DOC.into()),
                meta(META_MEMBERS, self.members.len().to_string()),
                meta(META_TTA, if self.flip { "flip" } else { "none" }.into()),
            ],
            ..Default::default()
        };
        Ok(model.encode_to_vec())
    }

    /// Read the networks back from one of our ONNX files (by initializer name). Files without the
    /// ensemble metadata (versions 1 and 2) are one network without flip.
    pub fn from_onnx(bytes: &[u8]) -> Result<Self, EncoderError> {
        let bad = |s: String| EncoderError::Model(s);
        let proto = pb::ModelProto::decode(bytes).map_err(|e| bad(format!("not an ONNX file ({e})")))?;
        let meta = |key: &str| {
            proto
                .metadata_props
                .iter()
                .find(|p| p.key == key)
                .map(|p| p.value.as_str())
        };
        let kind = meta(super::infer::META_MODEL)
            .and_then(ModelKind::from_name)
            .ok_or_else(|| bad("not a gonio encoder (no gonio.model metadata)".into()))?;
        let members = match meta(META_MEMBERS) {
            None => 1,
            Some(v) => v
                .parse::<usize>()
                .ok()
                .filter(|&n| (1..=64).contains(&n))
                .ok_or_else(|| bad(format!("bad {META_MEMBERS} metadata '{v}'")))?,
        };
        let flip = match meta(META_TTA) {
            None | Some("none") => false,
            Some("flip") => true,
            Some(other) => return Err(bad(format!("unknown {META_TTA} metadata '{other}'"))),
        };
        let graph = proto.graph.as_ref().ok_or_else(|| bad("no graph".into()))?;
        let get = |name: &str| -> Result<Vec<f32>, EncoderError> {
            let t = graph
                .initializer
                .iter()
                .find(|t| t.name == name)
                .ok_or_else(|| bad(format!("no initializer '{name}'")))?;
            if !t.float_data.is_empty() {
                Ok(t.float_data.clone())
            } else {
                Ok(t.raw_data
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect())
            }
        };
        let mut nets = Vec::with_capacity(members);
        for j in 0..members {
            let m = member_prefix(j);
            let mut blocks = Vec::new();
            for i in 0..BLOCKS.len() {
                let p = format!("{m}b{i}");
                blocks.push(Block {
                    conv: get(&format!("{p}.conv.weight"))?,
                    bn_weight: get(&format!("{p}.bn.weight"))?,
                    bn_bias: get(&format!("{p}.bn.bias"))?,
                    bn_mean: get(&format!("{p}.bn.running_mean"))?,
                    bn_var: get(&format!("{p}.bn.running_var"))?,
                });
            }
            let w = Weights {
                kind,
                blocks,
                fc_weight: get(&format!("{m}fc.weight"))?,
                fc_bias: get(&format!("{m}fc.bias"))?,
            };
            w.check().map_err(bad)?;
            nets.push(w);
        }
        Ok(Self { members: nets, flip })
    }
}

/// The per-output constants of the range mapping (see the module doc).
pub struct RangeMap {
    pub lin_scale: Vec<f32>,
    pub lin_off: Vec<f32>,
    pub lin_mask: Vec<f32>,
    pub log_scale: Vec<f32>,
    pub log_off: Vec<f32>,
    pub log_mask: Vec<f32>,
}

impl RangeMap {
    pub fn of(kind: ModelKind) -> Self {
        let o = kind.outputs();
        let pick = |f: &dyn Fn(&super::ParamRange) -> f64| o.iter().map(|p| f(p) as f32).collect();
        Self {
            lin_scale: pick(&|p| if p.log { 0.0 } else { p.hi - p.lo }),
            lin_off: pick(&|p| if p.log { 0.0 } else { p.lo }),
            lin_mask: pick(&|p| if p.log { 0.0 } else { 1.0 }),
            log_scale: pick(&|p| if p.log { (p.hi / p.lo).ln() } else { 0.0 }),
            log_off: pick(&|p| if p.log { p.lo.ln() } else { 0.0 }),
            log_mask: pick(&|p| if p.log { 1.0 } else { 0.0 }),
        }
    }
}
