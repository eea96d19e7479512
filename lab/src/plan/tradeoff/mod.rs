//! The trade-off report (`gonio-lab tradeoff`): what each level of accuracy costs in measurement time,
//! per material and strategy, and the paper's Table 1.
//!
//! For each material: plan every strategy at the same nested levels, measure the ground truth at the
//! planned directions (the virtual scan without effects), reconstruct each level and score it
//! (`report::Scorer`): under the capture point light (`examples/sphere-point.toml`) and under the
//! environment light (`examples/sphere-sky.toml` by default), RMSE / PSNR of the 8-bit sRGB images
//! and mean LDR FLIP, plus `brdf_log_err` over the fit's direction set.
//!
//! Strategies: `adaptive` (the planner's default, `auto`, from the encoder's estimate on a capture
//! photo of the material rendered per `examples/capture.toml`: the mixture warp for a sharp
//! estimate, the uniform grid for a rough one), `adaptive-true` (the same from the true parameters:
//! analytic materials themselves, others their GGX fit), `mixture` (the mixture warp from the
//! encoder's estimate whatever its roughness), `uniform` (equal steps in theta_o and phi_o, the same
//! grids, hence the same count: see the planner's nudge rule; its reconstruction reads the same
//! photo estimate as `adaptive`'s).

use super::predict::{score, Scorer};
use super::report::{csv, short, write, PLOT_FLOOR};
use super::{estimate_for, trials, Estimate, PlanConfig, PlanError, Planner, Spacing, Strategy};
use crate::plot::{tile, Chart, Mark, Series};
use gonio::brdf::parse_material;
use gonio::encoder::capture::capture_scene;
use gonio::encoder::infer::Encoder;
use gonio::encoder::ModelKind;
use gonio::reconstruct::reconstruct_with;
use gonio::render::render_with;
use gonio::render::{Image, Scene};
use gonio_shared::instrument::InstrumentConfig;
use std::fmt;
use std::path::Path;
use std::time::Instant;

pub mod choose;
pub mod closed_loop;
pub mod designed;
pub mod liu;
mod markdown;
pub mod peer;
mod presets;
pub mod reseed;

use markdown::*;
pub use presets::*;

/// A strategy of the trade-off report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TradeStrategy {
    /// The planner's default (`auto`) from the encoder's estimate on a capture photo: the mixture
    /// warp for a sharp estimate, the uniform grid for a rough one.
    Adaptive,
    /// `adaptive` from the true parameters (analytic: itself; others: GGX fit).
    AdaptiveTrue,
    /// The mixture warp from the encoder's estimate, whatever its roughness.
    Mixture,
    /// Equal steps in (theta_o, phi_o).
    Uniform,
    /// The data-driven peer, Nielsen et al. 2015 (`peer`, docs/nielsen2015.md).
    Nielsen2015,
}

pub const ALL_STRATEGIES: [TradeStrategy; 4] = [
    TradeStrategy::Adaptive,
    TradeStrategy::AdaptiveTrue,
    TradeStrategy::Mixture,
    TradeStrategy::Uniform,
];

impl fmt::Display for TradeStrategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            TradeStrategy::Adaptive => "adaptive",
            TradeStrategy::AdaptiveTrue => "adaptive-true",
            TradeStrategy::Mixture => "mixture",
            TradeStrategy::Uniform => "uniform",
            TradeStrategy::Nielsen2015 => peer::NAME,
        })
    }
}

impl TradeStrategy {
    fn planner_strategy(self) -> Strategy {
        match self {
            TradeStrategy::Adaptive | TradeStrategy::AdaptiveTrue => Strategy::Auto,
            TradeStrategy::Mixture => Strategy::Mixture,
            // The peer places its own directions (`peer`); no plan is built from this.
            TradeStrategy::Uniform | TradeStrategy::Nielsen2015 => Strategy::Uniform,
        }
    }
    /// Whether the plan is built from the photo estimate (else from the true parameters). The
    /// uniform grid places nothing by its estimate, but its reconstruction reads one (the prior's
    /// sharp-lobe floor, `reconstruct::prior::sharp_lobe_floor`): it gets the photo's, the information a real
    /// scan has, so that it and `adaptive` differ only in where the directions go.
    fn uses_photo(self) -> bool {
        matches!(
            self,
            TradeStrategy::Adaptive | TradeStrategy::Mixture | TradeStrategy::Uniform
        )
    }
}

/// Named configurations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    /// The paper's Table 1: four MERL fits at 2x2, 4x4, 8x4, 8x8, 8 incoming, 256 px renders.
    Table1,
    /// The encoder's 15 held-out MERL materials at 2x2 .. 16x16 (the "beyond the paper" test).
    Heldout,
    /// 14 MERL materials the encoder trained on, at 2x2 .. 16x16: where constants are chosen.
    Training,
    /// 26 further MERL materials the encoder trained on (mostly sharp), at 2x2 .. 16x16.
    TrainingPool,
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Preset::Table1 => "table1",
            Preset::Heldout => "heldout",
            Preset::Training => "training",
            Preset::TrainingPool => "training-pool",
        })
    }
}

#[derive(Clone, Debug)]
pub struct TradeoffConfig {
    pub materials: Vec<String>,
    pub strategies: Vec<TradeStrategy>,
    pub grids: Vec<(usize, usize)>,
    pub k: usize,
    pub spacing: Spacing,
    /// Side of the point-light render (pixels).
    pub size: usize,
    /// Side of the environment render (pixels), its environment samples per pixel.
    pub env_size: usize,
    pub env_spp: u32,
    /// Compare psnr_env with the paper's Table 1 (only for its materials and grids).
    pub paper: bool,
    /// The preset this config came from (for the regenerate line), if any.
    pub preset: Option<Preset>,
    /// The name of the prior every strategy's reconstruction interpolates on top of
    /// (`trials::PRIOR_NAMES`; the same for all, so the comparison is of where the directions go).
    pub prior: String,
    /// Also write `renders/<material>.png`: every reconstruction's point-light and environment
    /// renders beside the truth's (`render_sheet`).
    pub renders: bool,
}

impl Default for TradeoffConfig {
    fn default() -> Self {
        Self {
            materials: super::report::DEFAULT_MATERIALS.iter().map(|s| s.to_string()).collect(),
            strategies: ALL_STRATEGIES.to_vec(),
            grids: super::square_grids(4),
            k: 8,
            spacing: Spacing::Angle,
            size: 128,
            env_size: 256,
            env_spp: 64,
            paper: false,
            preset: None,
            // The product's prior, so the report scores what a scan would produce.
            prior: crate::plan::trials::PRIOR_NAMES[0].to_string(),
            renders: false,
        }
    }
}

impl TradeoffConfig {
    pub fn preset(p: Preset) -> Self {
        match p {
            Preset::Table1 => Self {
                materials: TABLE1_MATERIALS.iter().map(|s| s.to_string()).collect(),
                grids: TABLE1_GRIDS.to_vec(),
                // The paper rendered 256 x 256 images.
                size: 256,
                paper: true,
                preset: Some(p),
                ..Self::default()
            },
            Preset::Heldout => Self {
                materials: HELDOUT_MATERIALS.iter().map(|s| s.to_string()).collect(),
                preset: Some(p),
                ..Self::default()
            },
            Preset::Training => Self {
                materials: TRAINING_MATERIALS.iter().map(|s| s.to_string()).collect(),
                preset: Some(p),
                ..Self::default()
            },
            Preset::TrainingPool => Self {
                materials: TRAINING_POOL_MATERIALS.iter().map(|s| s.to_string()).collect(),
                preset: Some(p),
                ..Self::default()
            },
        }
    }
}

/// A checked list of nested levels (N x M outgoing per incoming theta), as the CLI takes it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Grids(pub Vec<(usize, usize)>);

/// "2x2,4x4,8x4" -> [(2, 2), (4, 4), (8, 4)], checked to nest (`check_grids`).
pub fn parse_grids(s: &str) -> Result<Grids, String> {
    let grids = s
        .split(',')
        .map(|g| {
            let (n, m) = g
                .trim()
                .split_once(['x', 'X'])
                .ok_or_else(|| format!("'{g}' is not a grid like 8x4"))?;
            let p = |v: &str| {
                v.trim()
                    .parse::<usize>()
                    .map_err(|_| format!("'{g}' is not a grid like 8x4"))
            };
            Ok((p(n)?, p(m)?))
        })
        .collect::<Result<Vec<_>, String>>()?;
    super::check_grids(&grids).map_err(|e| e.to_string())?;
    Ok(Grids(grids))
}

/// One row of `tradeoff.csv`: one material x strategy x level.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TradeRow {
    pub material: String,
    pub strategy: String,
    /// The analytic estimate the plan was built from (uniform: places nothing by it; its
    /// reconstruction's sharp-lobe floor reads it).
    pub estimate: String,
    /// The warp the plan used (`plan::Plan::warp`: `auto` resolved to mixture or uniform).
    pub warp: String,
    pub incoming: usize,
    pub level: usize,
    pub grid_n: usize,
    pub grid_m: usize,
    pub directions: usize,
    /// Planned gonio time up to this level (move + settle + exposure, optimised order).
    pub gonio_seconds: f64,
    pub rmse: f64,
    #[serde(serialize_with = "super::report::psnr_cell")]
    pub psnr: f64,
    pub flip: f64,
    pub rmse_env: f64,
    #[serde(serialize_with = "super::report::psnr_cell")]
    pub psnr_env: f64,
    pub flip_env: f64,
    pub brdf_log_err: f64,
    /// Liu et al. 2023's metric over 25,000 random pairs (`liu`).
    pub liu_log_err: f64,
    /// Host compute before the scan: photo -> estimate (encoder; the GGX fit for adaptive-true of a
    /// non-analytic material; 0 otherwise) and estimate -> ordered, timed plan (all levels).
    pub estimate_seconds: f64,
    pub plan_seconds: f64,
    pub host_seconds: f64,
    /// The paper's psnr_env for this material and grid (Table 1 only).
    pub paper_psnr_env: Option<f64>,
}

/// The encoder's estimate (`encoder::photo::estimate_from_image`, GGX model) from a capture photo of
/// `spec` (`capture_photo`), and the host time it took (s).
pub fn photo_estimate(photo: &Image, encoder: &Encoder) -> Result<(Estimate, f64), PlanError> {
    let t0 = Instant::now();
    let est = gonio::encoder::photo::estimate_from_image(photo, encoder, None)?;
    Ok((est.estimate, t0.elapsed().as_secs_f64()))
}

/// The capture photo of `spec` and its scene, rendered per `examples/capture.toml` (256 px, linear:
/// it stands in for the camera and is not timed).
pub fn capture_photo(spec: &str) -> Result<(Scene, Image), PlanError> {
    let scene = capture_scene(spec, CAPTURE_SIZE).map_err(PlanError::Invalid)?;
    let photo = render_with(&scene, &scene.settings, &|| {}).map_err(|e| PlanError::Invalid(e.to_string()))?;
    Ok((scene, photo))
}

/// Every `PHOTO_STRIDE`-th pixel of the 256 px capture photo in x and y feeds
/// the two-lobes-photo prior (about 2600 samples; with every 8th the environment FLIP was worse on training and its pool,
/// docs/tradeoff/README.md).
const PHOTO_STRIDE: usize = 4;

/// Side of the rendered capture photo (as `examples/capture.toml`).
const CAPTURE_SIZE: usize = 256;

fn paper_psnr(material: &str, grid: (usize, usize)) -> Option<f64> {
    let col = TABLE1_GRIDS.iter().position(|&g| g == grid)?;
    TABLE1_PAPER_PSNR
        .iter()
        .find(|(m, _)| *m == material)
        .map(|(_, v)| v[col])
}

/// Run the report into `dir` (`tradeoff.csv`, `tradeoff.md`, `tradeoff.png`); `env_scene` is the
/// environment-lit scene (its camera is resized to `env_size`, its spp set to `env_spp`).
/// `progress` is called once per scored level. Returns the markdown.
pub fn run(
    cfg: &TradeoffConfig,
    instrument: &InstrumentConfig<f64>,
    mut env_scene: Scene,
    dir: &Path,
    progress: &dyn Fn(&str),
) -> Result<String, PlanError> {
    super::check_grids(&cfg.grids)?;
    if cfg.materials.is_empty() || cfg.strategies.is_empty() {
        return Err(PlanError::Invalid(
            "tradeoff needs at least one material and one strategy".into(),
        ));
    }
    env_scene.camera.width = cfg.env_size;
    env_scene.camera.height = cfg.env_size;
    env_scene.settings.spp = cfg.env_spp;
    let mut scorer = Scorer::new(cfg.size)?.with_env(env_scene);
    let liu = liu::liu_pairs();
    let peer = match cfg.strategies.contains(&TradeStrategy::Nielsen2015) {
        true => Some(peer::Peer::new(cfg, instrument)?),
        false => None,
    };
    // Resolve every material and estimate first: a bad spec fails before any long work.
    let needs_photo = cfg.strategies.iter().any(|s| s.uses_photo());
    let encoder = if needs_photo {
        Some(Encoder::shipped(ModelKind::Ggx).map_err(|e| PlanError::Invalid(e.to_string()))?)
    } else {
        None
    };
    // The photo prior reads the capture photo's pixels (`photo_samples`), for every strategy.
    let needs_samples = trials::needs_photo(&cfg.prior);
    let mut inputs = Vec::new();
    for spec in &cfg.materials {
        let truth = parse_material(spec)?;
        let t0 = Instant::now();
        let true_estimate = estimate_for(spec)?;
        let fit_seconds = if gonio::brdf::spec::parse_analytic(spec).is_ok() {
            0.0
        } else {
            t0.elapsed().as_secs_f64()
        };
        let capture = if encoder.is_some() || needs_samples {
            Some(capture_photo(spec)?)
        } else {
            None
        };
        let photo = match (&encoder, &capture) {
            (Some(e), Some((_, img))) => Some(photo_estimate(img, e)?),
            _ => None,
        };
        let prior = trials::prior_by_name(&cfg.prior, || match &capture {
            Some((scene, img)) => super::photo_samples::photo_samples(scene, img, None, PHOTO_STRIDE),
            None => Err("no capture photo".into()),
        })
        .map_err(|e| PlanError::Invalid(format!("{spec}: {e}")))?;
        inputs.push((spec.clone(), truth, (true_estimate, fit_seconds), photo, prior));
    }
    std::fs::create_dir_all(dir).map_err(|e| PlanError::Invalid(format!("{}: {e}", dir.display())))?;
    let mut rows: Vec<TradeRow> = Vec::new();
    let mut sheets: Vec<(String, Vec<u8>, usize, usize)> = Vec::new();
    for (spec, truth, true_est, photo, prior) in &inputs {
        let truth_img = scorer.render(parse_material(spec)?);
        let truth_env = scorer
            .render_env(parse_material(spec)?, spec)
            .ok_or_else(|| PlanError::Invalid("no environment scene".into()))?;
        // One sheet row per strategy: its levels' point-light renders, then their environment renders.
        let mut sheet_rows: Vec<Vec<Image>> = Vec::new();
        for &strategy in &cfg.strategies {
            let mut sheet_row: Vec<Image> = Vec::new();
            let mut sheet_env: Vec<Image> = Vec::new();
            if let (TradeStrategy::Nielsen2015, Some(p)) = (strategy, &peer) {
                let truths = (&truth_img, &truth_env);
                rows.extend(p.rows(spec, truth.as_ref(), &mut scorer, truths, &liu, cfg.k, progress)?);
                sheet_rows.push(Vec::new());
                continue;
            }
            let (estimate, estimate_seconds) = match (strategy.uses_photo(), photo) {
                (true, Some((e, s))) => (e, *s),
                (false, _) => (&true_est.0, true_est.1),
                (true, None) => unreachable!("photo estimates are made whenever a strategy needs one"),
            };
            let config = PlanConfig {
                strategy: strategy.planner_strategy(),
                spacing: cfg.spacing,
                k: cfg.k,
                grids: cfg.grids.clone(),
                incoming: Vec::new(),
            };
            let t0 = Instant::now();
            let plan = Planner::new(*instrument, estimate.clone())?.plan(&config)?;
            let plan_seconds = t0.elapsed().as_secs_f64();
            let measured = plan.measure(truth.as_ref());
            for l in &plan.levels {
                let grid = reconstruct_with(&plan, l.level, &measured, prior.as_ref())?;
                let log_err = scorer.log_err(truth.as_ref(), &grid);
                let liu_log_err = super::predict::log_err_over(&liu, truth.as_ref(), &grid);
                let point_img = scorer.render(Box::new(grid.clone()));
                let point = score(&truth_img, &point_img)?;
                let env_img = scorer
                    .render_env(Box::new(grid), spec)
                    .ok_or_else(|| PlanError::Invalid("no environment scene".into()))?;
                let env = score(&truth_env, &env_img)?;
                if cfg.renders {
                    sheet_row.push(point_img);
                    sheet_env.push(env_img);
                }
                let paper_psnr_env = if cfg.paper { paper_psnr(spec, (l.n, l.m)) } else { None };
                rows.push(TradeRow {
                    material: spec.clone(),
                    strategy: strategy.to_string(),
                    estimate: estimate.model.to_spec(),
                    warp: plan.warp.to_string(),
                    incoming: cfg.k,
                    level: l.level,
                    grid_n: l.n,
                    grid_m: l.m,
                    directions: l.cumulative_directions,
                    gonio_seconds: l.cumulative_seconds,
                    rmse: point.rmse,
                    psnr: point.psnr,
                    flip: point.flip,
                    rmse_env: env.rmse,
                    psnr_env: env.psnr,
                    flip_env: env.flip,
                    brdf_log_err: log_err,
                    liu_log_err,
                    estimate_seconds,
                    plan_seconds,
                    host_seconds: estimate_seconds + plan_seconds,
                    paper_psnr_env,
                });
                progress(&format!(
                    "{} {strategy} {}x{}: {} directions, {:.1} min, psnr_env {:.2}, flip {:.4}, brdf_log_err {:.4}",
                    short(spec),
                    l.n,
                    l.m,
                    l.cumulative_directions,
                    l.cumulative_seconds / 60.0,
                    env.psnr,
                    point.flip,
                    log_err
                ));
            }
            sheet_row.append(&mut sheet_env);
            sheet_rows.push(sheet_row);
        }
        if cfg.renders {
            let (w, h, rgb) = render_sheet(&truth_img, &truth_env, &sheet_rows);
            let taken: Vec<&str> = sheets.iter().map(|(name, ..)| name.as_str()).collect();
            let name = sheet_name(spec, &taken);
            sheets.push((name, rgb, w, h));
        }
    }
    let about = inputs.first().map_or("", |i| i.4.about());
    let md = markdown(cfg, &rows, about) + &peer.map_or(String::new(), |_| peer::markdown(cfg, &rows));
    let (tw, th, rgb) = chart_rgb(cfg, &rows)?;
    let table = csv(&rows)?;
    // Every output is computed before the first write; each is written atomically.
    let png = dir.join("tradeoff.png");
    gonio::render::image::write_rgb8_png(&png, tw, th, rgb)
        .map_err(|e| PlanError::Invalid(format!("{}: {e}", png.display())))?;
    write(dir, "tradeoff.csv", &table)?;
    write(dir, "tradeoff.md", md.as_bytes())?;
    if !sheets.is_empty() {
        let renders = dir.join("renders");
        std::fs::create_dir_all(&renders).map_err(|e| PlanError::Invalid(format!("{}: {e}", renders.display())))?;
    }
    for (name, rgb, w, h) in sheets {
        let path = dir.join(&name);
        gonio::render::image::write_rgb8_png(&path, w, h, rgb)
            .map_err(|e| PlanError::Invalid(format!("{}: {e}", path.display())))?;
    }
    Ok(md)
}

/// A material spec as a file name: letters, digits, '-' and '.' kept, anything else '_'.
pub fn file_stem(spec: &str) -> String {
    short(spec)
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// The render sheet's path (under the run's folder) for `spec`: `renders/STEM.png`, or, when a spec
/// before it in the run took that name (two specs that differ only in characters the stem replaces),
/// `renders/STEM-2.png`, `-3`, ...: every material keeps its own sheet.
fn sheet_name(spec: &str, taken: &[&str]) -> String {
    let stem = file_stem(spec);
    let mut name = format!("renders/{stem}.png");
    let mut n = 1;
    while taken.contains(&name.as_str()) {
        n += 1;
        name = format!("renders/{stem}-{n}.png");
    }
    name
}

/// The renders of one material as one sRGB sheet: row 0 is the truth (point light, then environment),
/// each further row one strategy, its levels' point-light renders coarsest first, then their
/// environment renders in the same order (the order of `strategies` and of the levels in the csv).
/// Every panel is the truth's point-light render's side; other renders (the environment's are
/// `--env-size`) are area-resampled to it (`encoder::resample_square`).
pub fn render_sheet(truth: &Image, truth_env: &Image, rows: &[Vec<Image>]) -> (usize, usize, Vec<u8>) {
    let side = truth.width.min(truth.height);
    let blank = vec![255u8; side * side * 3];
    let fit = |img: &Image| -> Vec<u8> {
        // Guard: an empty render (none is made; sizes are checked at the CLI) stays a blank panel.
        if img.width == 0 || img.height == 0 {
            return blank.clone();
        }
        crate::encoder::resample_square(img, side).to_srgb8()
    };
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0).max(2);
    let mut panels = vec![fit(truth), fit(truth_env)];
    panels.resize(cols, blank.clone());
    for row in rows {
        let mut p: Vec<Vec<u8>> = row.iter().map(fit).collect();
        p.resize(cols, blank.clone());
        panels.extend(p);
    }
    tile(&panels, side, side, cols)
}

/// Tests' plan: the product's (`auto`) from a GGX estimate of roughness `alpha` (diffuse 0.5) on
/// the default instrument, `levels` square levels.
#[cfg(test)]
pub(crate) fn auto_plan(alpha: f64, levels: usize) -> gonio::plan::Plan {
    let config = PlanConfig {
        strategy: Strategy::Auto,
        grids: gonio::plan::square_grids(levels),
        ..PlanConfig::default()
    };
    Planner::new(
        gonio::instrument::default_instrument(),
        gonio::plan::ggx_estimate(alpha, 0.5),
    )
    .expect("planner")
    .plan(&config)
    .expect("plan")
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio::instrument::default_instrument;

    const REQUIRED: [&str; 15] = [
        "material",
        "strategy",
        "warp",
        "incoming",
        "grid_n",
        "grid_m",
        "directions",
        "gonio_seconds",
        "rmse",
        "psnr",
        "flip",
        "rmse_env",
        "psnr_env",
        "flip_env",
        "brdf_log_err",
    ];

    fn env_scene() -> Scene {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/sphere-sky.toml");
        Scene::load(&path).expect("examples/sphere-sky.toml")
    }

    /// A tiny run: two analytic materials, the paper's Table 1 grids, 16 px renders.
    fn tiny(strategies: Vec<TradeStrategy>) -> TradeoffConfig {
        TradeoffConfig {
            materials: vec![
                "ggx:alpha=0.2,diffuse=0.1,specular=1".into(),
                "ggx:alpha=0.04,diffuse=0.3,specular=1".into(),
            ],
            strategies,
            size: 16,
            env_size: 16,
            env_spp: 1,
            paper: true,
            ..TradeoffConfig::preset(Preset::Table1)
        }
    }

    #[test]
    fn render_sheets_hold_the_truth_and_every_strategy_and_level() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = TradeoffConfig {
            materials: vec!["ggx:alpha=0.04,diffuse=0.3,specular=1".into()],
            grids: vec![(2, 2), (4, 4)],
            renders: true,
            ..tiny(vec![TradeStrategy::Mixture, TradeStrategy::Uniform])
        };
        run(&cfg, &default_instrument(), env_scene(), dir.path(), &|_| {}).expect("run");
        let path = dir.path().join("renders/ggx_alpha_0.04_diffuse_0.3_specular_1.png");
        let sheet = Image::read(&path).expect("the sheet is written");
        // 2 levels x (point, environment) = 4 columns of 16 px; the truth's row and one per strategy.
        assert_eq!((sheet.width, sheet.height), (4 * 16, 3 * 16));
        // The truth's row: the lit sphere in both panels, then blank (white) panels.
        let centre = |col: usize, row: usize| sheet.get(col * 16 + 8, row * 16 + 8);
        assert!(centre(0, 0).max_element() > 0.0 && centre(0, 0).max_element() < 1.0);
        assert_eq!(centre(2, 0), glam::DVec3::ONE);
        // A strategy's row is all renders: no blank panel.
        for col in 0..4 {
            assert!(centre(col, 1) != glam::DVec3::ONE, "panel {col}");
        }
    }

    #[test]
    fn render_sheet_scales_environment_panels_and_pads_short_rows() {
        let mut truth = Image::new(4, 4);
        truth.pixels.iter_mut().for_each(|p| *p = glam::DVec3::splat(0.5));
        let env = Image::new(8, 8);
        let (w, h, rgb) = render_sheet(&truth, &env, &[vec![truth.clone()], vec![]]);
        assert_eq!((w, h, rgb.len()), (8, 12, 8 * 12 * 3));
        // Row 1 has one panel and a blank one; row 2 (no renders) is blank.
        assert_eq!(&rgb[(4 * 8 + 4) * 3..(4 * 8 + 5) * 3], &[255, 255, 255]);
        assert_eq!(&rgb[(8 * 8) * 3..(8 * 8 + 1) * 3], &[255, 255, 255]);
        assert!(rgb[0] < 255 && rgb[(4 * 8) * 3] < 255);
    }

    #[test]
    fn csv_has_the_columns_and_one_row_per_material_strategy_level() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = tiny(vec![
            TradeStrategy::AdaptiveTrue,
            TradeStrategy::Mixture,
            TradeStrategy::Uniform,
        ]);
        let md = run(&cfg, &default_instrument(), env_scene(), dir.path(), &|_| {}).expect("run");
        let text = std::fs::read_to_string(dir.path().join("tradeoff.csv")).unwrap();
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        for c in REQUIRED {
            assert!(header.contains(&c), "missing column {c} in {header:?}");
        }
        let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
        let rows: Vec<Vec<String>> = lines
            .map(|l| {
                // Material specs hold commas: the csv quotes them.
                let mut cells = Vec::new();
                let (mut cur, mut quoted) = (String::new(), false);
                for ch in l.chars() {
                    match ch {
                        '"' => quoted = !quoted,
                        ',' if !quoted => cells.push(std::mem::take(&mut cur)),
                        c => cur.push(c),
                    }
                }
                cells.push(cur);
                cells
            })
            .collect();
        assert_eq!(rows.len(), cfg.materials.len() * cfg.strategies.len() * cfg.grids.len());
        for m in &cfg.materials {
            for st in &cfg.strategies {
                let mine: Vec<&Vec<String>> = rows
                    .iter()
                    .filter(|r| &r[col("material")] == m && r[col("strategy")] == st.to_string())
                    .collect();
                // One row per level, with the Table 1 grids N x M in order.
                let grids: Vec<(usize, usize)> = mine
                    .iter()
                    .map(|r| (r[col("grid_n")].parse().unwrap(), r[col("grid_m")].parse().unwrap()))
                    .collect();
                assert_eq!(grids, TABLE1_GRIDS.to_vec(), "{m} {st}");
                for r in &mine {
                    for c in ["psnr", "flip", "psnr_env", "flip_env", "brdf_log_err", "gonio_seconds"] {
                        let v: f64 = r[col(c)].parse().unwrap();
                        // PSNR is +inf for an exact reconstruction (these are analytic materials,
                        // which the fitted prior can recover exactly); everything else is finite.
                        let ok = if c.starts_with("psnr") {
                            v >= 0.0
                        } else {
                            v.is_finite() && v >= 0.0
                        };
                        assert!(ok, "{m} {st} {c} = {v}");
                    }
                }
            }
            // The adaptive plan measures no more directions than the uniform grid, level by level
            // (the mixture drops the nodes its warp puts below the horizon), the same where it is
            // the uniform grid.
            let dirs = |st: &str| -> Vec<usize> {
                rows.iter()
                    .filter(|r| &r[col("material")] == m && r[col("strategy")] == st)
                    .map(|r| r[col("directions")].parse().unwrap())
                    .collect()
            };
            let (uniform, adaptive) = (dirs("uniform"), dirs("adaptive-true"));
            assert_eq!(uniform.len(), adaptive.len(), "{m}");
            assert!(
                uniform.iter().zip(&adaptive).all(|(u, a)| a <= u),
                "{m}: {adaptive:?} vs {uniform:?}"
            );
            if !m.contains("alpha=0.04") {
                assert_eq!(uniform, adaptive, "{m}");
            }
            // adaptive-true is `auto` on the true alpha: it follows the 0.04 lobe and takes equal
            // angles for the 0.2 one; the other strategies name their own warp.
            for r in rows.iter().filter(|r| &r[col("material")] == m) {
                let want = match r[col("strategy")].as_str() {
                    "adaptive-true" if m.contains("alpha=0.04") => "mixture",
                    "adaptive-true" => "uniform",
                    other => other,
                };
                assert_eq!(r[col("warp")], want, "{m}");
            }
        }
        // A custom material list compares with nobody's Table 1.
        assert!(!md.contains("## Table 1") && md.contains("## Against the uniform grid"));
        assert!(
            md.contains("## Geometric means") && md.contains("| uniform | 8 |"),
            "{md}"
        );
        assert!(dir.path().join("tradeoff.png").exists() && dir.path().join("tradeoff.md").exists());
    }

    #[test]
    fn table1_preset_is_the_papers_setup() {
        let cfg = TradeoffConfig::preset(Preset::Table1);
        assert_eq!(cfg.grids, vec![(2, 2), (4, 4), (8, 4), (8, 8)]);
        assert_eq!(cfg.k, 8);
        assert_eq!(cfg.materials.len(), 4);
        for m in &cfg.materials {
            for &g in &cfg.grids {
                assert!(paper_psnr(m, g).is_some(), "{m} {g:?}");
            }
        }
        // The preset's levels nest (8x4 inside 8x8, 4x4 inside 8x4).
        super::super::check_grids(&cfg.grids).expect("nested");
        assert_eq!(paper_psnr("nbrdf:red-fabric2", (8, 4)), Some(39.88));
    }

    #[test]
    fn render_sheets_of_specs_with_one_stem_get_their_own_names() {
        let a = sheet_name("ggx:alpha=0.1", &[]);
        assert_eq!(file_stem("ggx:alpha=0.1"), file_stem("ggx:alpha+0.1"));
        let b = sheet_name("ggx:alpha+0.1", &[&a]);
        let c = sheet_name("ggx:alpha_0.1", &[&a, &b]);
        assert_ne!(a, b);
        assert_eq!(b, a.replace(".png", "-2.png"));
        assert_eq!(c, a.replace(".png", "-3.png"));
    }

    #[test]
    fn compact_rounds_the_numbers_of_a_spec() {
        assert_eq!(
            compact("ggx:alpha=0.0156064,diffuse=30.8368/5.3386/0,specular=1"),
            "ggx:alpha=0.0156,diffuse=30.8/5.34/0,specular=1"
        );
    }

    /// Constants are chosen on the training preset and judged on the held-out one: the two never share a material.
    #[test]
    fn training_heldout_and_pool_presets_are_disjoint() {
        for m in TRAINING_MATERIALS {
            assert!(!HELDOUT_MATERIALS.contains(&m), "{m}");
            assert!(parse_material(m).is_ok(), "{m}");
        }
        assert_eq!(TradeoffConfig::preset(Preset::Training).materials.len(), 14);
        for m in TRAINING_POOL_MATERIALS {
            assert!(!HELDOUT_MATERIALS.contains(&m), "{m}");
            assert!(!TRAINING_MATERIALS.contains(&m), "{m}");
            assert!(parse_material(m).is_ok(), "{m}");
        }
        let pool = TradeoffConfig::preset(Preset::TrainingPool).materials;
        assert_eq!(pool.len(), 26);
        assert!(
            pool.iter().enumerate().all(|(i, m)| !pool[..i].contains(m)),
            "no material twice"
        );
    }

    #[test]
    fn grids_parse_and_must_nest() {
        assert_eq!(parse_grids("2x2,4x4,8x4,8x8").unwrap().0, TABLE1_GRIDS.to_vec());
        assert_eq!(parse_grids(" 4X2 ").unwrap().0, vec![(4, 2)]);
        for bad in ["", "8x", "4x4,6x6", "8x8,4x4", "4x4,4x4", "1x1", "axb"] {
            assert!(parse_grids(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_bad_material_fails_before_any_output() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let mut cfg = tiny(vec![TradeStrategy::Uniform]);
        cfg.materials.push("nbrdf:no-such-material".into());
        assert!(run(&cfg, &default_instrument(), env_scene(), &out, &|_| {}).is_err());
        assert!(!out.exists());
    }
}
