//! `gonio render`, `gonio compare` and `gonio envmap`: thin clap layers over the library.

use anyhow::{Context, Result};
use gonio::render::effects::EffectPipeline;
use gonio::render::image::{Image, ImageFormat};
use gonio::render::metrics::compare;
use gonio::render::scene::{check_settings, Scene};
use gonio::render::sky::{sky, SkyParams};
use std::path::PathBuf;
use std::time::Instant;

/// `gonio render SCENE.toml -o OUT.exr|OUT.png [--spp N] [--seed S]`
#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// Scene file (TOML), e.g. examples/sphere-point.toml.
    pub scene: PathBuf,
    /// Output image: .exr (linear) or .png (tone-mapped sRGB); written to a temporary name, then renamed.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Environment samples per pixel (overrides the scene's [render] spp).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Random seed (overrides the scene's [render] seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Sub-pixel grid per axis (overrides the scene's [render] pixel_samples).
    #[arg(long)]
    pub pixel_samples: Option<u32>,
}

/// `gonio compare REF TEST [--flip-map OUT.png] [--json]`
#[derive(clap::Args, Debug)]
pub struct CompareArgs {
    /// Reference image (.exr or .png).
    pub reference: PathBuf,
    /// Test image, the same size as the reference.
    pub test: PathBuf,
    /// Write the FLIP error map here (PNG, magma colour map).
    #[arg(long)]
    pub flip_map: Option<PathBuf>,
    /// Print one JSON object {"rmse", "psnr", "flip"} instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `gonio envmap ...`: generate the project's environment maps.
#[derive(clap::Subcommand, Debug)]
pub enum EnvmapCmd {
    /// A procedural clear sky with a sun (what examples/sky.exr is made with).
    Sky {
        /// Output image (.exr keeps the sun's full radiance; .png clamps it).
        #[arg(short, long)]
        output: PathBuf,
        #[arg(long, default_value_t = 256)]
        width: usize,
        #[arg(long, default_value_t = 128)]
        height: usize,
        /// Sun elevation above the horizon, degrees.
        #[arg(long, default_value_t = 35.0, allow_hyphen_values = true)]
        sun_elevation: f64,
        /// Sun azimuth, degrees from +z toward +x.
        #[arg(long, default_value_t = 40.0, allow_hyphen_values = true)]
        sun_azimuth: f64,
    },
}

pub fn run_render(args: RenderArgs) -> Result<()> {
    // Refuse an unknown output format before spending time on the render.
    ImageFormat::from_path(&args.output)?;
    let scene = Scene::load(&args.scene)?;
    let mut settings = scene.settings.clone();
    settings.spp = args.spp.unwrap_or(settings.spp);
    settings.seed = args.seed.unwrap_or(settings.seed);
    settings.pixel_samples = args.pixel_samples.unwrap_or(settings.pixel_samples);
    check_settings(&settings).map_err(anyhow::Error::msg)?;
    // Hidden automatically when stderr is not a terminal (CI, pipes).
    let bar = indicatif::ProgressBar::new(scene.camera.height as u64);
    if let Ok(style) = indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} rows {elapsed_precise}") {
        bar.set_style(style);
    }
    let start = Instant::now();
    let image = gonio::render::render_with(&scene, &settings, &|| bar.inc(1))?;
    let seconds = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    image.write(&args.output)?;
    let n2 = settings.pixel_samples * settings.pixel_samples;
    let env = match scene.environment {
        Some(_) => format!(
            ", environment {} spp ({} per sub-pixel)",
            settings.spp.div_ceil(n2) * n2,
            settings.spp.div_ceil(n2)
        ),
        None => String::new(),
    };
    let effects = match &scene.effects {
        Some(cfg) => {
            let names = EffectPipeline::from_config(cfg, settings.seed)
                .map_err(anyhow::Error::msg)?
                .names();
            if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            }
        }
        None => "none".to_string(),
    };
    println!(
        "rendered {}x{} {} ({}x{} sub-pixels{env}; effects: {effects}) in {seconds:.3} s -> {}",
        image.width,
        image.height,
        scene.material_spec,
        settings.pixel_samples,
        settings.pixel_samples,
        args.output.display()
    );
    Ok(())
}

pub fn run_compare(args: CompareArgs) -> Result<()> {
    let reference = Image::read(&args.reference)?;
    let test = Image::read(&args.test)?;
    let (scores, map) = compare(&reference, &test)?;
    if let Some(path) = &args.flip_map {
        map.write_png(path)?;
    }
    if args.json {
        println!("{}", serde_json::to_string(&scores).context("json")?);
    } else {
        println!("rmse {:.6}", scores.rmse);
        println!("psnr {:.2} dB", scores.psnr);
        println!("flip {:.6}", scores.flip);
    }
    Ok(())
}

pub fn run_envmap(cmd: EnvmapCmd) -> Result<()> {
    match cmd {
        EnvmapCmd::Sky {
            output,
            width,
            height,
            sun_elevation,
            sun_azimuth,
        } => {
            if !(1..=16_384).contains(&width) || !(1..=16_384).contains(&height) {
                anyhow::bail!("width and height must be 1..=16384, got {width} x {height}");
            }
            if !(sun_elevation.is_finite() && sun_azimuth.is_finite()) {
                anyhow::bail!("sun angles must be finite");
            }
            let params = SkyParams {
                width,
                height,
                sun_elevation_deg: sun_elevation,
                sun_azimuth_deg: sun_azimuth,
                ..SkyParams::default()
            };
            sky(&params).write(&output)?;
            println!("wrote {width}x{height} sky -> {}", output.display());
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn examples() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
    }

    #[test]
    fn the_shipped_scenes_render_and_compare() {
        let dir = tempfile::tempdir().expect("temp dir");
        for name in ["sphere-point", "sphere-sky", "sphere-sensor"] {
            let output = dir.path().join(format!("{name}.png"));
            run_render(RenderArgs {
                scene: examples().join(format!("{name}.toml")),
                output: output.clone(),
                spp: Some(1),
                seed: None,
                pixel_samples: Some(1),
            })
            .unwrap_or_else(|e| panic!("{name}: {e:#}"));
            assert!(output.exists());
        }
        let png = dir.path().join("sphere-point.png");
        let map = dir.path().join("flip.png");
        run_compare(CompareArgs {
            reference: png.clone(),
            test: png,
            flip_map: Some(map.clone()),
            json: true,
        })
        .expect("same image compares");
        assert!(map.exists());
        let err = run_compare(CompareArgs {
            reference: dir.path().join("sphere-point.png"),
            test: dir.path().join("sphere-sensor.png"),
            flip_map: None,
            json: false,
        })
        .err()
        .map(|e| format!("{e:#}"))
        .unwrap_or_default();
        assert_eq!(err, "images differ in size: reference 256x256, test 128x128");
        let sky = dir.path().join("sky.exr");
        run_envmap(EnvmapCmd::Sky {
            output: sky.clone(),
            width: 32,
            height: 16,
            sun_elevation: 35.0,
            sun_azimuth: 40.0,
        })
        .expect("sky");
        assert_eq!(Image::read(&sky).expect("reads").width, 32);
    }
}
