//! `levels.png`: what accuracy cost in time during one scan. The estimated point FLIP of each level
//! with its 90% interval and, in simulation, the true FLIP, against cumulative instrument minutes.
//! Drawn with plotters into a buffer that the renderer's PNG writer saves atomically; the font
//! (DejaVu Sans, `host/assets/fonts`, Bitstream Vera licence) is compiled in.

use crate::plan::closed_loop::LevelAssessment;
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

const FONT_FAMILY: &str = "sans-serif";
static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
const WIDTH: u32 = 720;
const HEIGHT: u32 = 440;

fn register_font() {
    static REGISTER: Once = Once::new();
    // A bad font would make plotters draw no text, not fail.
    REGISTER.call_once(|| {
        let _ = plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, FONT);
    });
}

/// Draw the levels' chart into 8-bit RGB (row 0 at the top).
pub fn draw_levels(levels: &[LevelAssessment]) -> Result<Vec<u8>, String> {
    register_font();
    let minutes = |a: &LevelAssessment| a.cumulative_seconds / 60.0;
    let est: Vec<(f64, f64, f64, f64)> = levels
        .iter()
        .filter_map(|a| a.est_flip.map(|(e, lo, hi)| (minutes(a), e, lo, hi)))
        .collect();
    let truth: Vec<(f64, f64)> = levels
        .iter()
        .filter_map(|a| a.true_flip.map(|t| (minutes(a), t)))
        .collect();
    let ys = est
        .iter()
        .flat_map(|p| [p.1, p.2, p.3])
        .chain(truth.iter().map(|p| p.1))
        .filter(|v| v.is_finite() && *v > 0.0);
    let (y0, y1) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    let (y0, y1) = if y0 <= y1 { (y0 / 1.5, y1 * 1.5) } else { (1e-4, 1.0) };
    let x1 = levels.iter().map(minutes).fold(0.0, f64::max).max(1e-3) * 1.05;
    let err = |e: &dyn std::fmt::Display| format!("levels.png: {e}");
    let mut buffer = vec![255u8; WIDTH as usize * HEIGHT as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (WIDTH, HEIGHT)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let mut ctx = ChartBuilder::on(&root)
            .caption("point FLIP per level", (FONT_FAMILY, 22))
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..x1, (y0..y1).log_scale())
            .map_err(|e| err(&e))?;
        ctx.configure_mesh()
            .x_desc("cumulative instrument time (min)")
            .y_desc("mean FLIP (capture light)")
            .label_style((FONT_FAMILY, 14))
            .axis_desc_style((FONT_FAMILY, 16))
            .light_line_style(RGBColor(242, 242, 242))
            .draw()
            .map_err(|e| err(&e))?;
        let blue = RGBColor(0, 114, 178);
        let orange = RGBColor(213, 94, 0);
        ctx.draw_series(
            est.iter()
                .map(|&(x, _, lo, hi)| PathElement::new(vec![(x, lo), (x, hi)], blue)),
        )
        .map_err(|e| err(&e))?
        .label("90% interval")
        .legend(move |(x, y)| PathElement::new(vec![(x + 9, y - 6), (x + 9, y + 6)], blue));
        ctx.draw_series(LineSeries::new(est.iter().map(|p| (p.0, p.1)), blue.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label("estimated (no ground truth)")
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], blue.stroke_width(2)));
        if !truth.is_empty() {
            ctx.draw_series(LineSeries::new(truth.iter().copied(), orange.stroke_width(2)))
                .map_err(|e| err(&e))?
                .label("true (simulation)")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], orange.stroke_width(2)));
            ctx.draw_series(truth.iter().map(|&p| Circle::new(p, 3, orange.filled())))
                .map_err(|e| err(&e))?;
        }
        ctx.configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font((FONT_FAMILY, 14))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(buffer)
}

/// Write `levels.png` into `path`.
pub fn write_levels(path: &Path, levels: &[LevelAssessment]) -> Result<(), String> {
    let rgb = draw_levels(levels)?;
    crate::render::image::write_rgb8_png(path, WIDTH as usize, HEIGHT as usize, rgb)
        .map_err(|e| format!("{}: {e}", path.display()))
}
