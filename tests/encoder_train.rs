//! A tiny training run (issue 6): a few steps on a handful of rendered images. The loss must go
//! down, and the exported ONNX, reloaded in tract, must give the training framework's outputs.

use gonio::encoder::infer::Encoder;
use gonio::encoder::{ModelKind, INPUT_LEN};
use gonio_lab::encoder::dataset;
use gonio_lab::encoder::onnx::Weights;
use gonio_lab::encoder::train::{mae, train, TrainConfig};

/// `count` synthetic renders of `kind` (seed `seed`), loaded; the directory lives as long as the
/// returned guard.
fn tiny_dataset(kind: ModelKind, count: usize, seed: u64) -> (tempfile::TempDir, dataset::Loaded) {
    let dir = tempfile::tempdir().expect("tempdir");
    dataset::generate(kind, count, false, seed, dir.path()).expect("dataset");
    let data = dataset::load(dir.path(), &|_| true).expect("load");
    (dir, data)
}

#[test]
fn tiny_training_lowers_the_loss_and_exports_what_candle_computes() {
    let (_dir, data) = tiny_dataset(ModelKind::Ward, 8, 7);
    let cfg = TrainConfig {
        epochs: 100,
        batch: 8,
        lr: 3e-3,
        seed: 3,
        max_steps: Some(40),
        ..TrainConfig::default()
    };
    let (net, log) = train(&data, None, &cfg, None, &mut |_| {}).expect("train");
    let l = &log.step_losses;
    assert_eq!(l.len(), 40);
    let head: f32 = l[..5].iter().sum::<f32>() / 5.0;
    let tail: f32 = l[l.len() - 5..].iter().sum::<f32>() / 5.0;
    assert!(tail < 0.7 * head, "loss {head} -> {tail}: {l:?}");

    let weights = net.weights().expect("weights");
    let bytes = weights.to_onnx("tiny").expect("export");
    assert_eq!(Weights::from_onnx(&bytes).expect("read back"), weights);
    let onnx = Encoder::from_bytes(&bytes).expect("tract loads the export");
    let inputs = data.inputs(1.0).expect("inputs");
    let candle = net.predict(&inputs).expect("candle inference");
    for (i, c) in candle.iter().enumerate() {
        let t = onnx.run(&inputs[i * INPUT_LEN..(i + 1) * INPUT_LEN]).expect("tract");
        for (a, b) in c.iter().zip(&t) {
            assert!((a - b).abs() <= 1e-5, "image {i}: candle {c:?} vs tract {t:?}");
        }
    }
    // Fine-tuning starts exactly where the file left off.
    let (again, _) = train(
        &data,
        Some(&weights),
        &TrainConfig {
            max_steps: Some(1),
            lr: 0.0,
            ..cfg
        },
        None,
        &mut |_| {},
    )
    .expect("fine-tune");
    let before = mae(&net, &data).expect("mae");
    let after = mae(&again, &data).expect("mae");
    for (b, a) in before.iter().zip(&after) {
        // One step at lr 0 only moves the batch-norm running statistics (momentum 0.1).
        assert!((a - b).abs() < 0.05, "{before:?} vs {after:?}");
    }
}

#[test]
fn png_augmentation_feeds_clipped_photos_and_still_trains() {
    let (_dir, data) = tiny_dataset(ModelKind::Ggx, 6, 11);
    let cfg = |png_augment| TrainConfig {
        epochs: 100,
        batch: 6,
        lr: 3e-3,
        seed: 5,
        max_steps: Some(4),
        png_augment,
        ..TrainConfig::default()
    };
    let (plain, plain_log) = train(&data, None, &cfg(0.0), None, &mut |_| {}).expect("train");
    let (clipped, clipped_log) = train(&data, None, &cfg(1.0), None, &mut |_| {}).expect("train, png");
    assert!(clipped_log.step_losses.iter().all(|l| l.is_finite()));
    // Same seed and data: the first step's loss differs only if the network saw other inputs.
    assert_ne!(plain_log.step_losses[0], clipped_log.step_losses[0]);
    assert_ne!(plain.weights().expect("w"), clipped.weights().expect("w"));
}

#[test]
fn an_ensemble_with_flip_averaging_exports_what_candle_computes() {
    use gonio_lab::encoder::onnx::Model;
    use gonio_lab::encoder::train::{predict_ensemble, train_model, Recipe};
    let (_dir, data) = tiny_dataset(ModelKind::Ggx, 6, 13);
    let cfg = TrainConfig {
        batch: 6,
        max_steps: Some(3),
        ..TrainConfig::default()
    };
    let recipe = Recipe {
        members: 2,
        flip: true,
        ..Recipe::single(&cfg)
    };
    let (model, nets, _) = train_model(&data, &recipe, None, &mut |_| {}).expect("train");
    assert_eq!(nets.len(), 2);
    assert_ne!(model.members[0], model.members[1], "members have their own seeds");
    let bytes = model.to_onnx("ensemble").expect("export");
    assert_eq!(Model::from_onnx(&bytes).expect("read back"), model);
    let onnx = Encoder::from_bytes(&bytes).expect("tract loads the ensemble");
    let inputs = data.inputs(1.0).expect("inputs");
    let candle = predict_ensemble(&nets, true, &inputs).expect("candle");
    let one = predict_ensemble(&nets[..1], false, &inputs).expect("candle, one net");
    let mut differs = false;
    for (i, c) in candle.iter().enumerate() {
        let t = onnx.run(&inputs[i * INPUT_LEN..(i + 1) * INPUT_LEN]).expect("tract");
        assert!(
            (c[0] - t[0]).abs() <= 1e-5 * c[0].max(1.0),
            "image {i}: candle {c:?} vs tract {t:?}"
        );
        differs |= (c[0] - one[i][0]).abs() > 1e-6;
    }
    assert!(differs, "the ensemble is not just its first member");
}

#[test]
fn cross_validation_predicts_every_row_from_a_model_that_never_saw_it() {
    use gonio_lab::encoder::train::{cross_validate, cv_csv, cv_summary, Recipe};
    let (_dir, data) = tiny_dataset(ModelKind::Ggx, 6, 17);
    let cfg = TrainConfig {
        batch: 2,
        max_steps: Some(2),
        ..TrainConfig::default()
    };
    let (rows, _) = cross_validate(&data, &Recipe::single(&cfg), 3, None, &mut |_| {}).expect("cv");
    assert_eq!(rows.len(), 6, "every row is held out once");
    for row in &rows {
        let i = data
            .samples
            .iter()
            .position(|s| s.file == row.file)
            .expect("a dataset row");
        assert_eq!(row.fold, i % 3, "{}", row.file);
        assert_eq!(row.truth, data.samples[i].params);
        assert!(row.linear[0].is_finite() && row.png.iter().all(|p| p[0].is_finite()));
    }
    // A model trained on folds 1 and 2 only predicts fold 0 as the cross-validation did.
    let (only, _) = cross_validate(&data, &Recipe::single(&cfg), 3, Some(0), &mut |_| {}).expect("cv");
    assert_eq!(only.len(), 2);
    for (a, b) in only.iter().zip(rows.iter().filter(|r| r.fold == 0)) {
        assert_eq!(a.file, b.file);
        assert!(
            (a.linear[0] - b.linear[0]).abs() <= 1e-6 * b.linear[0],
            "same seed, same folds, same model"
        );
    }
    assert!(cv_summary(ModelKind::Ggx, &rows)[0].contains("6 held-out"));
    assert_eq!(cv_csv(ModelKind::Ggx, &rows).lines().count(), 7);
    assert!(cross_validate(&data, &Recipe::single(&cfg), 1, None, &mut |_| {}).is_err());
    assert!(cross_validate(&data, &Recipe::single(&cfg), 3, Some(3), &mut |_| {}).is_err());
}
