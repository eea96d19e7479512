//! The lab's encoder tests: ONNX export, datasets and the observable report.

use super::onnx::{Block, Model, Weights, BLOCKS, FEATURES};
use super::*;
use gonio::render::Image;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_weights(kind: ModelKind, seed: u64) -> Weights {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut v = |n: usize, lo: f32, hi: f32| (0..n).map(|_| rng.random_range(lo..hi)).collect::<Vec<f32>>();
    let k = kind.outputs().len();
    Weights {
        kind,
        blocks: BLOCKS
            .iter()
            .map(|&(cin, cout, _)| Block {
                conv: v(cout * cin * 9, -0.3, 0.3),
                bn_weight: v(cout, 0.5, 1.5),
                bn_bias: v(cout, -0.1, 0.1),
                bn_mean: v(cout, -0.1, 0.1),
                bn_var: v(cout, 0.5, 2.0),
            })
            .collect(),
        fc_weight: v(k * FEATURES, -0.1, 0.1),
        fc_bias: v(k, -0.1, 0.1),
    }
}

#[test]
fn onnx_export_round_trips_and_runs_in_tract() {
    for kind in [ModelKind::Ward, ModelKind::Ggx] {
        let w = random_weights(kind, 11);
        let bytes = w.to_onnx("test").expect("export");
        assert_eq!(Weights::from_onnx(&bytes).expect("read back"), w);
        let enc = infer::Encoder::from_bytes(&bytes).expect("tract loads it");
        assert_eq!(enc.kind, kind);
        let input = preprocess(&sphere_photo("ward:rho_d=0.5,alpha=0.2")).expect("preprocess");
        let out = enc.estimate(&input).expect("run");
        for (r, v) in kind.outputs().iter().zip(&out) {
            assert!(
                *v >= r.lo * 0.999 && *v <= r.hi * 1.001,
                "{} = {v} outside [{}, {}]",
                r.name,
                r.lo,
                r.hi
            );
        }
    }
}

#[test]
fn ensembles_and_flip_averaging_are_one_standard_graph() {
    let (a, b) = (random_weights(ModelKind::Ggx, 21), random_weights(ModelKind::Ggx, 22));
    let input = preprocess(&sphere_photo("ggx:alpha=0.3,diffuse=0.2/0.1/0.05")).expect("preprocess");
    // An asymmetric input, so that a network and its mirror really differ.
    let ramp: Vec<f32> = (0..INPUT_LEN).map(|i| (i % 97) as f32 / 97.0).collect();
    let run = |m: &Model, x: &[f32]| {
        let bytes = m.to_onnx("test").expect("export");
        assert_eq!(&Model::from_onnx(&bytes).expect("read back"), m);
        infer::Encoder::from_bytes(&bytes)
            .expect("tract loads it")
            .run(x)
            .expect("run")[0]
    };
    let single = Model::single(a.clone());
    // A file of versions 1 and 2 (one network, no ensemble metadata) reads as one network.
    assert_eq!(
        Model::from_onnx(&a.to_onnx("v2").expect("export")).expect("read"),
        single
    );
    // Two copies of one network are that network.
    let twice = Model {
        members: vec![a.clone(), a.clone()],
        flip: false,
    };
    assert!((run(&twice, &ramp) - run(&single, &ramp)).abs() < 1e-5);
    // Flip averaging makes the output the same for the input and its mirror; a single network
    // on this input is not.
    let flip = Model {
        members: vec![a.clone(), b.clone()],
        flip: true,
    };
    let mirrored = flip_vertical(&ramp);
    assert!((run(&flip, &ramp) - run(&flip, &mirrored)).abs() < 1e-5);
    assert!((run(&single, &ramp) - run(&single, &mirrored)).abs() > 1e-4);
    // The mean is over logits: sigmoid(mean of the four branches' logits), mapped to alpha.
    let r = ModelKind::Ggx.outputs()[0];
    let logit = |w: &Weights, x: &[f32]| {
        let s = run(&Model::single(w.clone()), x) as f64;
        let u = r.to_unit(s);
        (u / (1.0 - u)).ln()
    };
    let mean =
        (logit(&a, &input) + logit(&a, &flip_vertical(&input)) + logit(&b, &input) + logit(&b, &flip_vertical(&input)))
            / 4.0;
    let want = r.from_unit(1.0 / (1.0 + (-mean).exp()));
    let got = run(&flip, &input) as f64;
    assert!((got - want).abs() < 1e-4 * want.max(1e-3), "{got} vs {want}");
    assert_eq!(flip.evaluations(), 4);
    // Weights::from_onnx refuses an ensemble rather than silently taking one member.
    let err = Weights::from_onnx(&flip.to_onnx("x").expect("export")).expect_err("refused");
    assert!(err.to_string().contains("ensemble"), "{err}");
}

#[test]
fn bad_model_bytes_are_clear_errors() {
    let err = infer::Encoder::from_bytes(b"not a model").err().expect("rejected");
    assert!(err.to_string().contains("ONNX"), "{err}");
    // A valid ONNX file without our metadata.
    let mut w = random_weights(ModelKind::Ggx, 1).to_onnx("x").expect("export");
    let proto = <tract_onnx::pb::ModelProto as prost::Message>::decode(&w[..]).expect("decode");
    let mut stripped = proto.clone();
    stripped.metadata_props.clear();
    w = prost::Message::encode_to_vec(&stripped);
    let err = infer::Encoder::from_bytes(&w).err().expect("rejected");
    assert!(err.to_string().contains("gonio.model"), "{err}");
}

#[test]
fn datasets_are_written_and_read_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    let samples = dataset::generate(ModelKind::Ward, 3, false, 5, dir.path()).expect("generate");
    let again = dataset::generate(ModelKind::Ward, 3, false, 5, &dir.path().join("again")).expect("generate");
    assert_eq!(samples, again, "the seed fixes the dataset");
    let loaded = dataset::load(dir.path(), &|_| true).expect("load");
    assert_eq!(loaded.kind, ModelKind::Ward);
    assert_eq!(loaded.samples, samples);
    assert_eq!(loaded.inputs(1.0).expect("inputs").len(), 3 * INPUT_LEN);
    for s in &samples {
        assert!((0.05..0.95).contains(&s.params[0]) && (0.02..0.5).contains(&s.params[1]));
        assert!((dataset::INTENSITY_RANGE.0..=dataset::INTENSITY_RANGE.1).contains(&s.intensity));
    }
    let missing = dataset::load(&dir.path().join("nope"), &|_| true).err().expect("error");
    assert!(missing.to_string().contains("labels.csv"), "{missing}");
}

#[test]
fn two_lobe_datasets_are_labelled_by_the_ggx_fit() {
    // The label of a material that is one GGX lobe is that lobe's alpha: the fit recovers it.
    let one = gonio::brdf::parse_material("ggx:alpha=0.12,diffuse=0.1/0.1/0.1").expect("spec");
    let a = capture::ggx_fit_alpha(one.as_ref()).expect("fit");
    assert!((a - 0.12).abs() < 0.005, "fit alpha {a}");
    let dir = tempfile::tempdir().expect("tempdir");
    let samples =
        dataset::generate_family(ModelKind::Ggx, 3, dataset::Family::TwoLobes, 9, dir.path()).expect("generate");
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for s in &samples {
        // The same draws as the generator: material, then intensity.
        let lobes = dataset::sample_two_lobes(&mut rng);
        let _intensity: f64 = rng.random();
        assert!(lobes.sharp_alpha < lobes.broad_alpha && lobes.broad_alpha <= 1.0);
        assert_eq!(s.spec, format!("twolobes: {}", lobes.describe()));
        assert_eq!(s.params, vec![capture::ggx_fit_alpha(&lobes).expect("fit")]);
    }
    let loaded = dataset::load(dir.path(), &|_| true).expect("load");
    assert_eq!(loaded.kind, ModelKind::Ggx);
    assert_eq!(loaded.samples, samples);
    let ward = dataset::generate_family(ModelKind::Ward, 1, dataset::Family::TwoLobes, 1, &dir.path().join("w"));
    assert!(ward.expect_err("refused").to_string().contains("GGX"));
}

#[test]
fn the_observable_report_counts_labels_the_photo_cannot_show() {
    // A GGX lobe is observed as itself: label and observable agree, so a prediction 0.1 off is a
    // miss of the network, not a label the photo cannot show.
    let rows = vec![
        (
            "a.exr".to_string(),
            "ggx:alpha=0.1,diffuse=0.1".to_string(),
            vec![0.1],
            vec![0.2],
        ),
        (
            "b.exr".to_string(),
            "ggx:alpha=0.3,diffuse=0.1".to_string(),
            vec![0.3],
            vec![0.31],
        ),
    ];
    let alphas = report::observable_alphas(&rows).expect("observable fits");
    assert!(
        (alphas[0] - 0.1).abs() < 0.005 && (alphas[1] - 0.3).abs() < 0.015,
        "{alphas:?}"
    );
    let lines = report::observable_lines(&rows, &alphas);
    let summary = lines
        .iter()
        .find(|l| l.starts_with("|observable - label|"))
        .expect("summary line");
    assert!(
        summary.contains(": 0 of 2;") && summary.contains("by > 0.05: 1, 0 of them"),
        "{summary}"
    );
    assert!(lines
        .iter()
        .any(|l| l.starts_with("ggx:alpha=0.1,") && l.ends_with("miss")));
    assert!(lines
        .iter()
        .any(|l| l.starts_with("ggx:alpha=0.3,") && !l.ends_with("miss")));
    // A spec that is no material is a clear error, not a panic.
    let bad = vec![("c.exr".to_string(), "twolobes: x".to_string(), vec![0.1], vec![0.1])];
    let err = report::observable_alphas(&bad).expect_err("refused").to_string();
    assert!(err.contains("c.exr"), "{err}");
}

fn sphere_photo(spec: &str) -> Image {
    capture::render_capture(spec, 1.0).expect("render")
}
