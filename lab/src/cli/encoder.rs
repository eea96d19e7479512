//! `gonio-lab dataset | train | encoder-report`.

use super::parse_name;
use anyhow::{bail, Context, Result};
use clap::Args;
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio_lab::encoder::dataset;
use gonio_lab::encoder::report::{self, Photo};
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct DatasetArgs {
    /// Which model's parameters to draw and label.
    #[arg(long, value_parser = parse_name::<ModelKind>())]
    pub model: ModelKind,
    /// Number of synthetic images (ignored with --merl: one image per bundled material).
    #[arg(long, default_value_t = 100)]
    pub count: usize,
    /// Render the 90 bundled MERL fits with their fitted GGX alpha (15 held out as `test`).
    #[arg(long)]
    pub merl: bool,
    /// Render Lambert + two GGX lobes (GGX only), labelled by the GGX fit like the MERL images.
    #[arg(long, conflicts_with = "merl")]
    pub two_lobes: bool,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output folder (created; labels.csv is written last).
    #[arg(short, long)]
    pub output: PathBuf,
}

#[derive(Args)]
pub struct TrainArgs {
    /// Dataset folder (`gonio-lab dataset`); rows with split = test are left out.
    pub data: PathBuf,
    /// The ONNX file to write (required unless --cv).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    #[arg(long, default_value_t = 30)]
    pub epochs: usize,
    #[arg(long, default_value_t = 32)]
    pub batch: usize,
    /// Peak learning rate (AdamW, cosine decay to 0).
    #[arg(long, default_value_t = 3e-3)]
    pub lr: f64,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Start from this model (fine-tuning) instead of a fresh initialisation.
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Print the MAE on this dataset's test rows (or all rows) after every epoch.
    #[arg(long)]
    pub val: Option<PathBuf>,
    /// Show this fraction of training images as clipped 8-bit PNGs under x0.25 .. x4 light.
    #[arg(long, default_value_t = 0.0)]
    pub png_augment: f64,
    /// Light range of --png-augment, as LO,HI (log-uniform).
    #[arg(long, value_delimiter = ',', default_values_t = [0.25, 4.0])]
    pub png_range: Vec<f64>,
    /// Weight of the range-scaled absolute error in the loss (beside the unit-space error).
    #[arg(long, default_value_t = 1.0)]
    pub phys_weight: f64,
    /// Train this many networks (seeds SEED, SEED+1, ...) and average their logits in one ONNX graph.
    #[arg(long, default_value_t = 1)]
    pub members: usize,
    /// Average every network over the image and its vertical mirror, inside the ONNX graph.
    #[arg(long)]
    pub tta_flip: bool,
    /// Rehearsal: add --mix-per-batch random images of this dataset (its training rows) to every batch.
    #[arg(long)]
    pub mix: Option<PathBuf>,
    #[arg(long, default_value_t = 8)]
    pub mix_per_batch: usize,
    /// K-fold cross-validation over the training rows (row i in fold i mod K): train on K-1 folds,
    /// report the held-out fold through the exported ONNX file; writes no model.
    #[arg(long)]
    pub cv: Option<usize>,
    /// With --cv, run only this fold (0-based), e.g. a 1-in-10 validation slice of a large set.
    #[arg(long)]
    pub cv_fold: Option<usize>,
    /// With --cv, write the held-out predictions here (CSV).
    #[arg(long)]
    pub cv_csv: Option<PathBuf>,
}

#[derive(Args)]
pub struct ReportArgs {
    /// Dataset folder; its `test` rows if it has any, else all rows (see --split).
    pub data: PathBuf,
    /// Evaluate the rows of this split instead (e.g. `train`: validation of a model that never saw
    /// the dataset).
    #[arg(long)]
    pub split: Option<String>,
    /// Which shipped model to evaluate.
    #[arg(long, value_parser = parse_name::<ModelKind>(), default_value = "ggx")]
    pub model: ModelKind,
    #[arg(long)]
    pub model_file: Option<PathBuf>,
    /// Feed the network 8-bit PNG photos (auto-exposed at x1, clipped and quantised) instead of EXR.
    #[arg(long)]
    pub png: bool,
    /// Write the per-image predictions here.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Plot predicted against true alpha (PNG), like the paper's Fig. 5.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Also fit GGX to the directions the capture photo itself sees (`encoder::observable`) and
    /// print, per image, how far the label lies from what the photo shows (GGX datasets).
    #[arg(long)]
    pub observable: bool,
}

fn load_encoder(model: ModelKind, file: Option<&Path>) -> Result<Encoder> {
    Ok(match file {
        Some(path) => Encoder::from_file(path)?,
        None => Encoder::shipped(model).with_context(|| format!("the shipped {} model", model.name()))?,
    })
}

pub fn run_dataset(args: DatasetArgs) -> Result<()> {
    if !args.merl && args.count == 0 {
        bail!("--count must be at least 1");
    }
    let start = std::time::Instant::now();
    let family = match (args.merl, args.two_lobes) {
        (true, _) => dataset::Family::Merl,
        (false, true) => dataset::Family::TwoLobes,
        (false, false) => dataset::Family::Analytic,
    };
    let samples = dataset::generate_family(args.model, args.count, family, args.seed, &args.output)?;
    println!(
        "{} images in {} ({:.1} s)",
        samples.len(),
        args.output.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The test rows of a dataset, or all of them when it has no `test` split.
pub fn load_eval(dir: &Path) -> Result<dataset::Loaded> {
    match dataset::load(dir, &|s| s == "test") {
        Ok(d) => Ok(d),
        Err(_) => Ok(dataset::load(dir, &|_| true)?),
    }
}

#[cfg(feature = "train")]
pub fn run_train(args: TrainArgs) -> Result<()> {
    use gonio_lab::encoder::train;
    let data = train::load_train(&args.data)?;
    let init = match &args.init {
        Some(p) => {
            let bytes = std::fs::read(p).with_context(|| format!("{}", p.display()))?;
            Some(gonio_lab::encoder::onnx::Model::from_onnx(&bytes).with_context(|| format!("{}", p.display()))?)
        }
        None => None,
    };
    let val = args.val.as_deref().map(load_eval).transpose()?;
    let mix = args.mix.as_deref().map(train::load_train).transpose()?;
    if args.epochs == 0 || args.batch < 2 || args.members == 0 {
        bail!("--epochs and --members must be >= 1 and --batch >= 2");
    }
    if !(0.0..=1.0).contains(&args.png_augment) {
        bail!("--png-augment must be a probability in [0, 1]");
    }
    let (lo, hi) = match args.png_range[..] {
        [lo, hi] => (lo, hi),
        _ => bail!("--png-range must be LO,HI"),
    };
    if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
        bail!("--png-range must be LO,HI with 0 < LO <= HI");
    }
    if !(args.phys_weight >= 0.0 && args.phys_weight.is_finite()) {
        bail!("--phys-weight must be >= 0");
    }
    if args.cv.is_none() && args.output.is_none() {
        bail!("give -o MODEL.onnx (or --cv K to cross-validate without writing a model)");
    }
    if args.cv.is_none() && (args.cv_fold.is_some() || args.cv_csv.is_some()) {
        bail!("--cv-fold and --cv-csv need --cv K");
    }
    println!(
        "training {} on {} images of {} (epochs {}, batch {}, lr {}, seed {}, members {}, flip {})",
        data.kind.name(),
        data.samples.len(),
        args.data.display(),
        args.epochs,
        args.batch,
        args.lr,
        args.seed,
        args.members,
        args.tta_flip
    );
    let cfg = train::TrainConfig {
        epochs: args.epochs,
        batch: args.batch,
        lr: args.lr,
        seed: args.seed,
        max_steps: None,
        png_augment: args.png_augment,
        png_range: (lo, hi),
        phys_weight: args.phys_weight,
        mix_per_batch: if mix.is_some() { args.mix_per_batch } else { 0 },
    };
    let mut print = |l: &str| println!("{l}");
    let recipe = train::Recipe {
        mix: mix.as_ref(),
        init: init.as_ref(),
        cfg: &cfg,
        members: args.members,
        flip: args.tta_flip,
    };
    if let Some(folds) = args.cv {
        let (rows, log) = train::cross_validate(&data, &recipe, folds, args.cv_fold, &mut print)?;
        for l in train::cv_summary(data.kind, &rows) {
            println!("{l}");
        }
        if let Some(path) = &args.cv_csv {
            gonio::fsio::write_bytes_atomically(path, train::cv_csv(data.kind, &rows).as_bytes())
                .with_context(|| format!("{}", path.display()))?;
            println!("wrote {}", path.display());
        }
        println!(
            "training wall time {:.0} s for {} images ({:.0} img/s)",
            log.seconds,
            log.images,
            log.images as f64 / log.seconds.max(1e-9)
        );
        return Ok(());
    }
    let output = args.output.as_ref().context("-o MODEL.onnx")?;
    let (model, _, log) = train::train_model(&data, &recipe, val.as_ref(), &mut print)?;
    let mut options = format!(
        "epochs {}, batch {}, lr {}, seed {}, png-augment {}",
        args.epochs, args.batch, args.lr, args.seed, args.png_augment
    );
    if (lo, hi) != train::PNG_AUGMENT_RANGE {
        options += &format!(", png-range {lo},{hi}");
    }
    if args.phys_weight != 1.0 {
        options += &format!(", phys-weight {}", args.phys_weight);
    }
    if args.members > 1 {
        options += &format!(", members {}", args.members);
    }
    if args.tta_flip {
        options += ", tta-flip";
    }
    if let Some(m) = &args.mix {
        options += &format!(", mix {} x{}", m.display(), args.mix_per_batch);
    }
    if let Some(p) = &args.init {
        options += &format!(", init {}", p.display());
    }
    let doc = format!(
        "gonio encoder ({}), trained by `gonio-lab train {}` ({options})",
        data.kind.name(),
        args.data.display(),
    );
    let bytes = model.to_onnx(&doc).map_err(anyhow::Error::msg)?;
    gonio::fsio::write_bytes_atomically(output, &bytes).with_context(|| format!("{}", output.display()))?;
    println!(
        "wrote {} ({} bytes); training wall time {:.0} s for {} images ({:.0} img/s)",
        output.display(),
        bytes.len(),
        log.seconds,
        log.images,
        log.images as f64 / log.seconds.max(1e-9)
    );
    Ok(())
}

#[cfg(not(feature = "train"))]
pub fn run_train(_args: TrainArgs) -> Result<()> {
    bail!("this gonio-lab was built without training: rebuild with `cargo run --release -p gonio-lab --features train -- train ...`")
}

pub fn run_report(args: ReportArgs) -> Result<()> {
    let encoder = load_encoder(args.model, args.model_file.as_deref())?;
    let data = match &args.split {
        Some(split) => dataset::load(&args.data, &|s| s == split)?,
        None => load_eval(&args.data)?,
    };
    let mode = if args.png { Photo::Png8 } else { Photo::Linear };
    let rep = report::report(&encoder, &data, mode)?;
    for l in &rep.lines {
        println!("{l}");
    }
    let observable = if args.observable {
        if encoder.kind != ModelKind::Ggx {
            bail!("--observable compares GGX alphas: use --model ggx");
        }
        let alphas = report::observable_alphas(&rep.rows)?;
        for l in report::observable_lines(&rep.rows, &alphas) {
            println!("{l}");
        }
        Some(alphas)
    } else {
        None
    };
    if let Some(path) = &args.csv {
        gonio::fsio::write_bytes_atomically(
            path,
            report::csv(encoder.kind, &rep.rows, observable.as_deref()).as_bytes(),
        )
        .with_context(|| format!("{}", path.display()))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.plot {
        gonio_lab::plot::write_png(&report::chart(encoder.kind, &rep.rows, &args.data), path)
            .with_context(|| format!("{}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
