//! The files a scan leaves in OUTDIR (format of `grid.json` in `docs/scan-outputs.md`). Every file
//! is written to a temporary name and renamed, so a reader or a crash never sees half of one.

use super::{calibration::Calibration, PhaseTimes, ScanRecord};
use crate::brdf::frame::{phi_of, theta_of};
use crate::brdf::merl::MerlTable;
use crate::brdf::rgl::RglBsdf;
use crate::brdf::{parse_material, Material};
use crate::journal::Journal;
use crate::plan::predict::{score, Scorer};
use crate::plan::Plan;
use crate::render::brdf_sampling::BrdfSampler;
use crate::render::metrics::{compare, Comparison};
use crate::render::{render_plain, Image, Scene};
use glam::DVec3;
use gonio_shared::instrument::InstrumentConfig;
use std::fmt::Write as _;
use std::path::Path;

/// The environment-light scene of the renders (the README's sky picture), anchored at its real
/// path so its `sky.exr` is found from any working directory.
const ENV_SCENE: &str = include_str!("../../../examples/sphere-sky.toml");
const ENV_SCENE_PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/sphere-sky.toml");

/// The `.bsdf` file's layout: incident elevations (RGL sigma rule), vndf/ndf table side, rgb grid side.
pub const RGL_INCIDENT: usize = 16;
pub const RGL_TABLE: usize = 64;
pub const RGL_GRID: usize = 32;
/// Directions (theta_i, theta_o, phi_o in degrees; phi_i = 0) at which the written `.bsdf` is read
/// back and compared with the grid: the specular peak and an off-specular point at three elevations.
pub const RGL_CHECKS: [(f64, f64, f64); 6] = [
    (15.0, 15.0, 180.0),
    (15.0, 40.0, 90.0),
    (35.0, 35.0, 180.0),
    (35.0, 20.0, 120.0),
    (55.0, 55.0, 180.0),
    (55.0, 30.0, 150.0),
];

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("cannot write {path}: {reason}")]
    Write { path: String, reason: String },
    #[error("{0}")]
    Render(String),
    #[error("measured.bsdf does not read back: {0}")]
    RglReadBack(String),
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> OutputError {
    OutputError::Write {
        path: path.display().to_string(),
        reason: e.to_string(),
    }
}

fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    crate::fsio::write_bytes_atomically(path, bytes).map_err(|e| write_err(path, e))
}

pub struct OutputInputs<'a> {
    pub out: &'a Path,
    pub record: &'a ScanRecord,
    pub plan: &'a Plan,
    /// Calibrated BRDF per plan direction.
    pub values: &'a [DVec3],
    pub journal: &'a Journal,
    pub instrument: &'a InstrumentConfig<f64>,
    pub calibration: &'a Calibration,
    /// The chosen level's reconstruction.
    pub grid: &'a crate::reconstruct::Reconstruction,
    /// The ground truth's material spec (the simulated scene's sample).
    pub truth: Option<&'a str>,
}

/// One render's scores against the ground truth.
#[derive(Clone, Copy, Debug)]
pub struct Accuracy {
    pub point: Comparison,
    pub env: Comparison,
}

/// The `.bsdf` read back at one check direction.
#[derive(Clone, Copy, Debug)]
pub struct RglCheck {
    pub theta_i_deg: f64,
    pub theta_o_deg: f64,
    pub phi_o_deg: f64,
    pub grid: DVec3,
    pub bsdf: DVec3,
}

impl RglCheck {
    /// |bsdf - grid| / grid, on the mean of the channels (guarded for a black grid value).
    pub fn rel_diff(&self) -> f64 {
        let (a, b) = (self.grid.element_sum() / 3.0, self.bsdf.element_sum() / 3.0);
        (b - a).abs() / a.abs().max(1e-6)
    }
}

pub struct Report {
    /// Host wall seconds of each output step, in order.
    pub output_seconds: Vec<(&'static str, f64)>,
    pub accuracy: Option<Accuracy>,
    pub rgl: Vec<RglCheck>,
    pub files: Vec<String>,
    pub markdown: String,
}

/// Render `material` in the point-light capture scene and in the environment scene.
fn renders(
    scorer: &mut Scorer,
    env: &mut Scene,
    materials: [Box<dyn Material>; 2],
    sampler_spec: &str,
) -> (Image, Image) {
    let [for_point, for_env] = materials;
    let point = scorer.render(for_point);
    env.material = for_env;
    env.sampler = BrdfSampler::for_spec(sampler_spec);
    let env_image = render_plain(env, &env.settings, &|| {});
    (point, env_image)
}

/// Write grid.json, measured.binary, measured.bsdf, the renders and, in simulation, the truth's
/// renders and FLIP maps. report.md comes after, from [`finish_report`].
pub fn write_all(i: &OutputInputs) -> Result<Report, OutputError> {
    let out = i.out;
    let mut files = Vec::new();
    let mut output_seconds = Vec::new();
    let mut clock = std::time::Instant::now();
    let mut lap = |name: &'static str| {
        output_seconds.push((name, clock.elapsed().as_secs_f64()));
        clock = std::time::Instant::now();
    };
    // 1. The adaptive grid.
    let grid_json = grid_json(i).map_err(|e| write_err(&out.join("grid.json"), e))?;
    write_bytes(&out.join("grid.json"), grid_json.as_bytes())?;
    files.push("grid.json".to_string());
    lap("grid.json");
    // 2. MERL table (90 x 90 x 180 half/difference bins).
    let merl = MerlTable::tabulate(i.grid);
    let merl_path = out.join("measured.binary");
    merl.write(&merl_path).map_err(|e| write_err(&merl_path, e))?;
    files.push("measured.binary".to_string());
    lap("measured.binary (MERL tabulation)");
    // 3. RGL .bsdf, validated by reading it back before it is written.
    let rgl_alpha = rgl_alpha(i.record);
    let bytes = crate::brdf::rgl::tabulate_ggx(i.grid, rgl_alpha, RGL_INCIDENT, RGL_TABLE, RGL_GRID);
    let bsdf_path = out.join("measured.bsdf");
    let back = RglBsdf::from_bytes(&bytes, &bsdf_path).map_err(|e| OutputError::RglReadBack(e.to_string()))?;
    let rgl: Vec<RglCheck> = RGL_CHECKS
        .iter()
        .map(|&(ti, to, po)| {
            let wi = crate::brdf::frame::from_spherical(ti.to_radians(), 0.0);
            let wo = crate::brdf::frame::from_spherical(to.to_radians(), po.to_radians());
            RglCheck {
                theta_i_deg: ti,
                theta_o_deg: to,
                phi_o_deg: po,
                grid: i.grid.eval(wi, wo),
                bsdf: back.eval(wi, wo),
            }
        })
        .collect();
    write_bytes(&bsdf_path, &bytes)?;
    files.push("measured.bsdf".to_string());
    lap("measured.bsdf (RGL tabulation, read back)");
    // 4. Renders, and the truth's with scores and FLIP maps.
    let size = i.record.render_size;
    let mut scorer = Scorer::new(size).map_err(|e| OutputError::Render(e.to_string()))?;
    let mut env =
        Scene::from_toml(ENV_SCENE, Path::new(ENV_SCENE_PATH)).map_err(|e| OutputError::Render(e.to_string()))?;
    env.camera.width = size;
    env.camera.height = size;
    env.settings.spp = i.record.env_spp;
    let grid = i.grid.clone();
    let (point, env_image) = renders(
        &mut scorer,
        &mut env,
        [Box::new(grid.clone()), Box::new(grid)],
        &i.record.estimate,
    );
    for (name, image) in [("render-point.png", &point), ("render-env.png", &env_image)] {
        image
            .write(&out.join(name))
            .map_err(|e| write_err(&out.join(name), e))?;
        files.push(name.to_string());
    }
    lap("renders of the measurement");
    let accuracy = match i.truth {
        None => None,
        Some(spec) => {
            let parse = || parse_material(spec).map_err(|e| OutputError::Render(e.to_string()));
            let (truth_point, truth_env) = renders(&mut scorer, &mut env, [parse()?, parse()?], spec);
            let mut scores = Vec::new();
            for (tag, truth, test) in [("point", &truth_point, &point), ("env", &truth_env, &env_image)] {
                let truth_name = format!("truth-{tag}.png");
                truth
                    .write(&out.join(&truth_name))
                    .map_err(|e| write_err(&out.join(&truth_name), e))?;
                let (_, map) = compare(truth, test).map_err(|e| OutputError::Render(e.to_string()))?;
                let flip_name = format!("flip-{tag}.png");
                map.write_png(&out.join(&flip_name))
                    .map_err(|e| write_err(&out.join(&flip_name), e))?;
                scores.push(score(truth, test).map_err(|e| OutputError::Render(e.to_string()))?);
                files.push(truth_name);
                files.push(flip_name);
            }
            lap("renders of the truth, scores, FLIP maps");
            Some(Accuracy {
                point: scores[0],
                env: scores[1],
            })
        }
    };
    Ok(Report {
        output_seconds,
        accuracy,
        rgl,
        files,
        markdown: String::new(),
    })
}

/// The GGX alpha the `.bsdf` warp is built with: the estimate's, clamped to where the planner's
/// warps are defined (a mirror-like estimate would leave the file no width to interpolate over).
fn rgl_alpha(record: &ScanRecord) -> f64 {
    let alpha = record
        .estimate()
        .map(|e| e.alpha())
        .unwrap_or(crate::plan::PLAN_ALPHA_MIN);
    alpha.clamp(crate::plan::PLAN_ALPHA_MIN, 1.0)
}

fn deg(x: f64) -> f64 {
    x.to_degrees()
}

/// `grid.json` (see docs/scan-outputs.md).
fn grid_json(i: &OutputInputs) -> Result<String, serde_json::Error> {
    let plan = i.plan;
    let level = i.record.level;
    let summary = plan.level(level);
    let n = summary.map_or(0, |l| l.n);
    let finest = plan.config.grids.last().map_or(1, |g| g.0);
    let stride = finest / n.max(1);
    let planned: std::collections::HashSet<(usize, usize, usize)> = plan
        .directions
        .iter()
        .filter(|d| d.level <= level)
        .map(|d| (d.k, d.i, d.j))
        .collect();
    let mut nodes = Vec::new();
    for k in 0..plan.thetas.len() {
        for j in 0..n {
            for ii in 0..n {
                let dirs = i.grid.grid().node_directions(k, ii, j);
                let value = i.grid.node_value(k, ii, j);
                nodes.push(serde_json::json!({
                    "k": k,
                    "i": ii,
                    "j": j,
                    "theta_o_deg": dirs.map(|(_, wo)| deg(theta_of(wo))),
                    "phi_o_deg": dirs.map(|(_, wo)| deg(phi_of(wo))),
                    "rgb": value.map(|v| v.to_array()),
                    "planned": planned.contains(&(k, ii * stride, j * stride)),
                }));
            }
        }
    }
    let kin = gonio_shared::kinematics::Kinematics::new(*i.instrument).ok();
    let measurements: Vec<serde_json::Value> = plan
        .directions
        .iter()
        .enumerate()
        .filter_map(|(index, d)| {
            let r = i.journal.records().get(&(index as u32))?;
            let reached = kin.as_ref().map(|k| crate::link::reached(k, &r.steps).map(deg));
            Some(serde_json::json!({
                "index": index,
                "level": d.level,
                "k": d.k,
                "i": d.i,
                "j": d.j,
                "theta_i_deg": deg(theta_of(d.wi)),
                "phi_i_deg": deg(phi_of(d.wi)),
                "theta_o_deg": deg(theta_of(d.wo)),
                "phi_o_deg": deg(phi_of(d.wo)),
                "reached_deg": reached,
                "steps": r.steps,
                "counts": r.counts,
                "exposure_us": r.exposure_us,
                "rgb": i.values.get(index).map(|v| v.to_array()),
            }))
        })
        .collect();
    let v = serde_json::json!({
        "format": "gonio-grid",
        "version": 1,
        "units": "BRDF in 1/sr, linear RGB; angles in degrees",
        "estimate": i.record.estimate,
        "strategy": i.record.strategy,
        "warp": plan.warp.to_string(),
        "spacing": i.record.spacing,
        "layout": plan.layout().name(),
        "max_level": plan.config.grids.len(),
        "level": level,
        "n": n,
        "theta_i_deg": plan.thetas.iter().map(|t| deg(*t)).collect::<Vec<_>>(),
        "calibration": {
            "reference": i.calibration.reference,
            "exposure_us": i.calibration.exposure_us,
            "dark_counts": i.calibration.dark_counts,
            "gain": i.calibration.gain,
        },
        "nodes": nodes,
        "measurements": measurements,
    });
    serde_json::to_string_pretty(&v)
}

/// Compose and write report.md; returns the report with its markdown.
pub fn finish_report(
    out: &Path,
    mut report: Report,
    record: &ScanRecord,
    plan: &Plan,
    measured: &crate::link::Measured,
    times: &PhaseTimes,
    levels_md: &str,
) -> Result<Report, OutputError> {
    let mut md = String::new();
    let _ = writeln!(md, "# gonio scan report\n");
    let _ = writeln!(md, "- photo: `{}`", record.image);
    let _ = writeln!(
        md,
        "- estimate ({} encoder, outputs {:?}): `{}`",
        record.encoder, record.encoder_outputs, record.estimate
    );
    match (&record.source.sim_scene, &record.source.port) {
        (Some(scene), _) => {
            let _ = writeln!(
                md,
                "- device: the virtual gonio on `{scene}` (speedup {}x)",
                record.source.speedup
            );
        }
        (None, Some(port)) => {
            let _ = writeln!(md, "- device: `{port}`");
        }
        _ => {}
    }
    let _ = writeln!(
        md,
        "- plan: {} strategy, {} spacing, {} incoming elevations; stopped at level {} ({}x{} outgoing); rule: {}",
        plan.strategy_label(),
        record.spacing,
        record.incoming,
        record.level,
        1 << record.level,
        1 << record.level,
        record.rule
    );
    let _ = writeln!(md, "\n{levels_md}");
    let _ = writeln!(md, "\n## Counts\n");
    let _ = writeln!(
        md,
        "| level | N | directions | cumulative | planned instrument time (s) |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|");
    for l in &plan.levels {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {:.1} |",
            l.level, l.n, l.count, l.cumulative_directions, l.cumulative_seconds
        );
    }
    let _ = writeln!(
        md,
        "\ndropped as unreachable: {} below the horizon, {} in the blocked cone, {} beyond a limit",
        plan.dropped.below_horizon, plan.dropped.blocked, plan.dropped.limit
    );
    let s = &measured.summary;
    let _ = writeln!(
        md,
        "\nmeasured {} directions in this run ({} resumed from the journal); instrument time of this run {:.1} s (planned up to the stop level {:.1} s); {} reconnects, {} retransmitted frames",
        s.measured_now,
        measured.resumed,
        s.instrument_s,
        plan.total_seconds(),
        s.reconnects,
        s.stats.retransmits
    );
    let _ = writeln!(md, "\n## Host time (wall, this run)\n");
    let _ = writeln!(md, "| phase | seconds |\n|---|---|");
    for (name, t) in [
        ("estimate", times.estimate),
        ("plan", times.plan),
        ("calibrate", times.calibrate),
        ("stream / measure", times.measure),
        ("reconstruct", times.reconstruct),
        ("outputs", times.outputs),
        ("total", times.total()),
    ] {
        let _ = writeln!(md, "| {name} | {t:.3} |");
    }
    let _ = writeln!(md, "\nOutputs by step:\n\n| output step | seconds |\n|---|---|");
    for (name, t) in &report.output_seconds {
        let _ = writeln!(md, "| {name} | {t:.3} |");
    }
    if let Some(a) = &report.accuracy {
        let _ = writeln!(
            md,
            "\n## Accuracy against the ground truth (the simulated scene's material)\n"
        );
        let _ = writeln!(
            md,
            "Renders at {0}x{0} of the measured grid against the truth; RMSE and PSNR of the 8-bit sRGB images, mean LDR FLIP. FLIP maps: `flip-point.png`, `flip-env.png`.\n",
            record.render_size
        );
        let _ = writeln!(md, "| scene | RMSE | PSNR (dB) | FLIP |\n|---|---|---|---|");
        for (name, c) in [
            ("point light (render-point.png)", a.point),
            ("environment (render-env.png)", a.env),
        ] {
            let _ = writeln!(md, "| {name} | {:.4} | {:.2} | {:.4} |", c.rmse, c.psnr, c.flip);
        }
    }
    let _ = writeln!(md, "\n## measured.bsdf read back\n");
    let _ = writeln!(
        md,
        "| theta_i | theta_o | phi_o | grid (mean RGB, 1/sr) | .bsdf | rel. diff |\n|---|---|---|---|---|---|"
    );
    for c in &report.rgl {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.4} | {:.4} | {:.3} |",
            c.theta_i_deg,
            c.theta_o_deg,
            c.phi_o_deg,
            c.grid.element_sum() / 3.0,
            c.bsdf.element_sum() / 3.0,
            c.rel_diff()
        );
    }
    let _ = writeln!(md, "\n## Files\n");
    for f in &report.files {
        let _ = writeln!(md, "- `{f}`");
    }
    write_bytes(&out.join("report.md"), md.as_bytes())?;
    report.files.push("report.md".into());
    report.markdown = md;
    Ok(report)
}
