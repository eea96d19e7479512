//! The trade-off run's markdown report, its regenerate command and its chart.

use super::*;
use std::fmt::Write;

/// The command that regenerates this run.
pub(super) fn command(cfg: &TradeoffConfig) -> String {
    let mut c = "gonio-lab tradeoff".to_string();
    match cfg.preset {
        Some(p) => {
            let _ = write!(c, " --preset {p}");
        }
        None => {
            for m in &cfg.materials {
                let _ = write!(c, " --material {m}");
            }
        }
    }
    if cfg.strategies != ALL_STRATEGIES {
        for st in &cfg.strategies {
            let _ = write!(c, " --strategy {st}");
        }
    }
    if cfg.renders {
        c += " --renders";
    }
    let grids: Vec<String> = cfg.grids.iter().map(|(n, m)| format!("{n}x{m}")).collect();
    let _ = write!(
        c,
        " --levels {} --incoming {} --prior {} --size {} --env-size {} --env-spp {} -o DIR",
        grids.join(","),
        cfg.k,
        cfg.prior,
        cfg.size,
        cfg.env_size,
        cfg.env_spp
    );
    c
}

/// A spec with its numbers at 3 significant digits, for tables.
pub(super) fn compact(spec: &str) -> String {
    let mut out = String::new();
    let mut num = String::new();
    let flush = |num: &mut String, out: &mut String| {
        if !num.is_empty() {
            match num.parse::<f64>() {
                Ok(v) if v != 0.0 && num.contains('.') => {
                    let digits = (2 - v.abs().log10().floor() as i32).max(0) as usize;
                    let _ = write!(out, "{v:.digits$}");
                }
                _ => out.push_str(num),
            }
            num.clear();
        }
    };
    for c in spec.chars() {
        if c.is_ascii_digit() || c == '.' || ((c == 'e' || c == '-') && !num.is_empty()) {
            num.push(c);
        } else {
            flush(&mut num, &mut out);
            out.push(c);
        }
    }
    flush(&mut num, &mut out);
    out
}

pub(super) fn find<'a>(rows: &'a [TradeRow], material: &str, strategy: &str, level: usize) -> Option<&'a TradeRow> {
    rows.iter()
        .find(|r| r.material == material && r.strategy == strategy && r.level == level)
}

/// The report; `about` says how the prior fits (`Prior::about`).
pub(super) fn markdown(cfg: &TradeoffConfig, rows: &[TradeRow], about: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Accuracy vs measurement time\n\nRegenerate: `{}` (release build; instrument `examples/gonio.toml`).\n\n\
         Render setup. Point light: `examples/sphere-point.toml` (orthographic sphere, one point light), {} x {} px, \
         2 x 2 sub-pixels. Environment light: `examples/sphere-sky.toml` (sphere in the procedural sky `examples/sky.exr`, \
         perspective camera, background = the sky), {} x {} px, 2 x 2 sub-pixels, lit by deterministic quadrature over \
         the map cut into {} x {} cells (`render::quadrature`: no random numbers, `--env-spp` unused; the truth and every \
         reconstruction are lit by the same directions, so the score is free of Monte Carlo noise). Errors on the 8-bit \
         sRGB images (exposure 1, clipped, values / 255, peak 1, whole image including the background), mean LDR FLIP; \
         `brdf_log_err` = mean over the fixed direction set of `gonio brdf fit` of |log(1 + f cos) - log(1 + f_rec cos)| \
         over RGB. Ground truth: the material itself (MERL materials: their neural fits, not the raw tables). \
         Times: planned gonio minutes (IK replay, shared motion profile, settle + exposure), host seconds \
         (photo -> estimate -> ordered plan, all levels).\n\n\
         Reconstruction (the same for every strategy, so the comparison is of where the directions go): \
         lookup `query`, interpolation `ratio`, prior `{}`{}.\n",
        command(cfg),
        cfg.size,
        cfg.size,
        cfg.env_size,
        cfg.env_size,
        gonio::render::quadrature::DEFAULT_COLS,
        gonio::render::quadrature::DEFAULT_ROWS,
        cfg.prior,
        about
    );
    let _ = writeln!(
        s,
        "## Error per level\n\n| material | strategy | estimate | grid | directions | gonio min | host s | PSNR | FLIP | PSNR env | FLIP env | brdf_log_err |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {}x{} | {} | {:.1} | {:.2} | {:.2} | {:.4} | {:.2} | {:.4} | {:.4} |",
            short(&r.material),
            r.strategy,
            compact(&r.estimate),
            r.grid_n,
            r.grid_m,
            r.directions,
            r.gonio_seconds / 60.0,
            r.host_seconds,
            r.psnr,
            r.flip,
            r.psnr_env,
            r.flip_env,
            r.brdf_log_err
        );
    }
    if cfg.paper && rows.iter().any(|r| r.paper_psnr_env.is_some()) {
        table1(&mut s, cfg, rows);
    }
    versus_uniform(&mut s, cfg, rows);
    geometric_means(&mut s, cfg, rows);
    let _ = writeln!(
        s,
        "\nFigure: `tradeoff.png` (per material: FLIP under the point light, FLIP under the environment, brdf_log_err, against gonio minutes; log-log)."
    );
    s
}

pub(super) fn table1(s: &mut String, cfg: &TradeoffConfig, rows: &[TradeRow]) {
    let strategies: Vec<String> = cfg.strategies.iter().map(|x| x.to_string()).collect();
    let _ = writeln!(
        s,
        "\n## Table 1: psnr_env (dB) next to the paper\n\nThe paper's values: its adaptive method, 8-bit renders under environment light \
         (its scene, not ours: the comparison is indicative). Ours: {}.\n\n| material | grid | directions | paper |{}\n|---|---|---|---|{}",
        strategies.join(", "),
        strategies.iter().map(|x| format!(" {x} |")).collect::<String>(),
        "---|".repeat(strategies.len())
    );
    let mut meets: Vec<Vec<String>> = vec![Vec::new(); strategies.len()];
    for m in &cfg.materials {
        let mut all_ok = vec![true; strategies.len()];
        let mut any = false;
        for (li, _) in cfg.grids.iter().enumerate() {
            let level = li + 1;
            let Some(paper) = rows
                .iter()
                .find(|r| &r.material == m && r.level == level)
                .and_then(|r| r.paper_psnr_env)
            else {
                continue;
            };
            any = true;
            let base = find(rows, m, &strategies[0], level);
            let mut line = format!(
                "| {} | {}x{} | {} | {paper:.2} |",
                short(m),
                cfg.grids[li].0,
                cfg.grids[li].1,
                base.map_or(0, |r| r.directions)
            );
            for (si, st) in strategies.iter().enumerate() {
                match find(rows, m, st, level) {
                    Some(r) => {
                        let ok = r.psnr_env >= paper;
                        all_ok[si] &= ok;
                        let _ = write!(
                            line,
                            " {}{:.2}{} |",
                            if ok { "**" } else { "" },
                            r.psnr_env,
                            if ok { "**" } else { "" }
                        );
                    }
                    None => {
                        all_ok[si] = false;
                        line += " - |";
                    }
                }
            }
            let _ = writeln!(s, "{line}");
        }
        if any {
            for (si, ok) in all_ok.iter().enumerate() {
                if *ok {
                    meets[si].push(short(m).to_string());
                }
            }
        }
    }
    let _ = writeln!(
        s,
        "\nBold: at or above the paper. At or above the paper at every count:\n"
    );
    for (si, st) in strategies.iter().enumerate() {
        let _ = writeln!(
            s,
            "- {st}: {} of {} materials ({}){}",
            meets[si].len(),
            cfg.materials.len(),
            if meets[si].is_empty() {
                "none".to_string()
            } else {
                meets[si].join(", ")
            },
            if meets[si].len() >= 3 {
                ": goal (>= 3 of 4) met"
            } else {
                ": goal (>= 3 of 4) not met"
            }
        );
    }
}

/// Below this brdf_log_err both reconstructions are exact to the fit's tolerance (an analytic
/// material that the fitted prior recovers): the comparison is a tie, neither a win nor a loss.
pub(super) const EXACT_LOG_ERR: f64 = 1e-6;

/// Whether row `a` is the uniform row `u` itself: the uniform warp from the same estimate, hence
/// the same plan and the same reconstruction (`auto` on a rough estimate).
pub(super) fn is_the_uniform_plan(a: &TradeRow, u: &TradeRow) -> bool {
    a.warp == Strategy::Uniform.to_string() && a.estimate == u.estimate
}

/// FLIP of a strategy over uniform's; two identical renders (both 0) are a ratio of 1.
pub(super) fn flip_ratio(a: f64, u: f64) -> f64 {
    if u > 0.0 {
        a / u
    } else if a > 0.0 {
        f64::INFINITY
    } else {
        1.0
    }
}

/// Each mixture strategy against the uniform grid of the same size: brdf_log_err wins per material
/// (over its levels) and the worst FLIP loss.
pub(super) fn versus_uniform(s: &mut String, cfg: &TradeoffConfig, rows: &[TradeRow]) {
    if !cfg.strategies.contains(&TradeStrategy::Uniform) {
        return;
    }
    let _ = writeln!(
        s,
        "\n## Against the uniform grid of the same size\n\nPer material: levels where the strategy's brdf_log_err is lower than uniform's \
         (both below 1e-6: an exact tie; the uniform warp from the same estimate: the uniform grid itself; neither counts as a win), and the worst FLIP ratio (strategy / uniform; > 1 is a loss) over its levels, point light and environment.\n\n\
         | material | strategy | brdf_log_err wins | worst FLIP ratio | worst FLIP env ratio |\n|---|---|---|---|---|"
    );
    let levels = cfg.grids.len();
    for st in cfg.strategies.iter().filter(|s| **s != TradeStrategy::Uniform) {
        let name = st.to_string();
        let (mut materials_ok, mut wins_total, mut total) = (0, 0, 0);
        let (mut worst, mut worst_env) = (0.0f64, 0.0f64);
        for m in &cfg.materials {
            let (mut wins, mut ties, mut same) = (0, 0, 0);
            let (mut w, mut we) = (0.0f64, 0.0f64);
            for level in 1..=levels {
                if let (Some(a), Some(u)) = (find(rows, m, &name, level), find(rows, m, "uniform", level)) {
                    if a.brdf_log_err.max(u.brdf_log_err) < EXACT_LOG_ERR {
                        ties += 1;
                    } else if is_the_uniform_plan(a, u) {
                        same += 1;
                    } else {
                        wins += (a.brdf_log_err < u.brdf_log_err) as usize;
                    }
                    w = w.max(flip_ratio(a.flip, u.flip));
                    we = we.max(flip_ratio(a.flip_env, u.flip_env));
                }
            }
            let mut tied = String::new();
            if ties > 0 {
                tied += &format!(" ({ties} exact ties)");
            }
            if same > 0 {
                tied += &format!(" ({same} the uniform grid itself)");
            }
            let _ = writeln!(
                s,
                "| {} | {name} | {wins}/{levels}{tied} | {w:.3} | {we:.3} |",
                short(m)
            );
            materials_ok += (4 * wins >= 3 * levels) as usize;
            wins_total += wins;
            total += levels;
            worst = worst.max(w);
            worst_env = worst_env.max(we);
        }
        let _ = writeln!(
            s,
            "| **all** | {name} | {wins_total}/{total}; >= 3/4 of levels on {materials_ok}/{} materials | {worst:.3} | {worst_env:.3} |",
            cfg.materials.len()
        );
    }
}

/// Per strategy, the geometric mean over its rows (every material and level) of each error: one
/// number per strategy that a few large errors do not dominate. Errors are floored at
/// `PLOT_FLOOR` so that an exact reconstruction (0) keeps the mean finite.
pub(super) fn geometric_means(s: &mut String, cfg: &TradeoffConfig, rows: &[TradeRow]) {
    let _ = writeln!(
        s,
        "\n## Geometric means over materials and levels\n\n| strategy | rows | brdf_log_err | FLIP | FLIP env |\n|---|---|---|---|---|"
    );
    for st in &cfg.strategies {
        let name = st.to_string();
        // Level 0: the peer's own small counts, which no other strategy has (`peer::markdown`).
        let mine: Vec<&TradeRow> = rows.iter().filter(|r| r.strategy == name && r.level > 0).collect();
        let gm = |f: fn(&TradeRow) -> f64| -> f64 {
            let n = mine.len().max(1) as f64;
            (mine.iter().map(|r| f(r).max(PLOT_FLOOR).ln()).sum::<f64>() / n).exp()
        };
        let _ = writeln!(
            s,
            "| {name} | {} | {:.5} | {:.4} | {:.4} |",
            mine.len(),
            gm(|r| r.brdf_log_err),
            gm(|r| r.flip),
            gm(|r| r.flip_env)
        );
    }
}

pub(super) fn chart_rgb(cfg: &TradeoffConfig, rows: &[TradeRow]) -> Result<(usize, usize, Vec<u8>), PlanError> {
    let (w, h) = (520u32, 360u32);
    type Metric = (&'static str, fn(&TradeRow) -> f64);
    let metrics: [Metric; 3] = [
        ("FLIP, point light", |r| r.flip),
        ("FLIP, environment", |r| r.flip_env),
        ("brdf_log_err", |r| r.brdf_log_err),
    ];
    let mut panels = Vec::new();
    for m in &cfg.materials {
        for (label, metric) in metrics {
            let mut c = Chart::new(format!("{}: {label}", short(m)), "gonio minutes", label);
            c.x_log = true;
            c.y_log = true;
            c.width = w;
            c.height = h;
            for st in &cfg.strategies {
                let pts: Vec<(f64, f64)> = rows
                    .iter()
                    .filter(|r| &r.material == m && r.strategy == st.to_string())
                    .map(|r| (r.gonio_seconds / 60.0, metric(r).max(PLOT_FLOOR)))
                    .collect();
                c.series.push(Series::new(st.to_string(), pts, Mark::LineAndPoints));
            }
            panels.push(crate::plot::draw_rgb(&c).map_err(|e| PlanError::Invalid(e.to_string()))?);
        }
    }
    Ok(tile(&panels, w as usize, h as usize, metrics.len()))
}
