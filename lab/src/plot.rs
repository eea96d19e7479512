//! Charts as PNG files: line charts (cost against accuracy, convergence) and scatter plots
//! (predicted against true, with the y = x line), for reports people would rather look at than read.
//!
//! One small description ([`Chart`]) in, one PNG out, through plotters' bitmap backend drawing into a
//! memory buffer that the project's own PNG writer saves atomically. The font (DejaVu Sans,
//! `host/assets/fonts`, Bitstream Vera licence) is compiled in, so charts look the same on every
//! machine and the build needs no system font packages.

use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    Line,
    Points,
    LineAndPoints,
}

#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub mark: Mark,
}

impl Series {
    pub fn new(label: impl Into<String>, points: Vec<(f64, f64)>, mark: Mark) -> Self {
        Self {
            label: label.into(),
            points,
            mark,
        }
    }
}

/// Everything one chart shows.
#[derive(Clone, Debug)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub x_log: bool,
    pub y_log: bool,
    /// Draw the y = x line (predicted against true).
    pub diagonal: bool,
    /// Fixed axis ranges; `None` fits the data (with a margin).
    pub x_range: Option<(f64, f64)>,
    pub y_range: Option<(f64, f64)>,
    pub width: u32,
    pub height: u32,
    pub series: Vec<Series>,
}

impl Chart {
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            x_log: false,
            y_log: false,
            diagonal: false,
            x_range: None,
            y_range: None,
            width: 800,
            height: 600,
            series: Vec::new(),
        }
    }

    pub fn with_series(mut self, series: Series) -> Self {
        self.series.push(series);
        self
    }
}

#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("chart '{0}': no finite points to plot")]
    NoData(String),
    #[error("chart '{0}': a logarithmic axis needs positive values")]
    NonPositiveLog(String),
    #[error("chart '{title}': {message}")]
    Draw { title: String, message: String },
    #[error(transparent)]
    Write(#[from] gonio::render::RenderError),
}

const FONT_FAMILY: &str = "sans-serif";
static FONT: &[u8] = include_bytes!("../../host/assets/fonts/DejaVuSans.ttf");

fn register_font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // The bundled file is a valid TrueType font (the tests draw text with it); were it not,
        // plotters would fall back to drawing no text, not fail.
        let _ = plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, FONT);
    });
}

/// A colour-blind-safe palette (Okabe and Ito), cycled by series index.
const PALETTE: [RGBColor; 7] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(0, 0, 0),
];

/// Fit a range to the data: a 5 % margin (a decade fraction on log axes), never empty.
fn fit_range(values: impl Iterator<Item = f64>, log: bool) -> Option<(f64, f64)> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !(lo <= hi) {
        return None;
    }
    if log {
        let (llo, lhi) = (lo.log10(), hi.log10());
        let pad = ((lhi - llo) * 0.05).max(0.05);
        Some((10f64.powf(llo - pad), 10f64.powf(lhi + pad)))
    } else {
        // A flat series still needs a range of non-zero width to draw into.
        let pad = ((hi - lo) * 0.05).max(1e-9_f64.max(hi.abs() * 0.05));
        Some((lo - pad, hi + pad))
    }
}

/// Tick labels of a log axis: only at 1, 2 and 5 times a power of ten, so the crowded ticks near
/// each decade's end stay unlabelled; compact numbers otherwise.
fn log_tick_label(v: &f64) -> String {
    let mantissa = *v / 10f64.powf(v.log10().floor());
    if [1.0, 2.0, 5.0, 10.0].iter().any(|m| (mantissa - m).abs() < 1e-6 * m) {
        tick_label(v)
    } else {
        String::new()
    }
}

fn tick_label(v: &f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.0e}")
    } else {
        // Shortest of a few fixed precisions that still shows the value.
        let text = format!("{v:.4}");
        let text = text.trim_end_matches('0').trim_end_matches('.');
        if text == "-0" {
            "0".to_string()
        } else {
            text.to_string()
        }
    }
}

/// The points of `series` that can be drawn on these axes.
fn drawable(series: &Series, x_log: bool, y_log: bool) -> Vec<(f64, f64)> {
    series
        .points
        .iter()
        .copied()
        .filter(|&(x, y)| x.is_finite() && y.is_finite() && (!x_log || x > 0.0) && (!y_log || y > 0.0))
        .collect()
}

/// Draw `chart` and write it to `path` (PNG) through a temporary name.
pub fn write_png(chart: &Chart, path: &Path) -> Result<(), PlotError> {
    let rgb = draw_rgb(chart)?;
    gonio::render::image::write_rgb8_png(path, chart.width as usize, chart.height as usize, rgb)?;
    Ok(())
}

/// Draw `chart` into an 8-bit RGB buffer (row 0 at the top).
pub fn draw_rgb(chart: &Chart) -> Result<Vec<u8>, PlotError> {
    register_font();
    let title = chart.title.clone();
    let draw_err = |e: &dyn std::fmt::Display| PlotError::Draw {
        title: title.clone(),
        message: e.to_string(),
    };
    let series: Vec<(&Series, Vec<(f64, f64)>)> = chart
        .series
        .iter()
        .map(|s| (s, drawable(s, chart.x_log, chart.y_log)))
        .collect();
    let all = || series.iter().flat_map(|(_, p)| p.iter().copied());
    if all().next().is_none() {
        let any_finite = chart
            .series
            .iter()
            .flat_map(|s| &s.points)
            .any(|(x, y)| x.is_finite() && y.is_finite());
        return Err(if any_finite && (chart.x_log || chart.y_log) {
            PlotError::NonPositiveLog(chart.title.clone())
        } else {
            PlotError::NoData(chart.title.clone())
        });
    }
    let mut x_range = chart.x_range.or_else(|| fit_range(all().map(|p| p.0), chart.x_log));
    let mut y_range = chart.y_range.or_else(|| fit_range(all().map(|p| p.1), chart.y_log));
    if chart.diagonal {
        // Predicted-against-true plots share one range on both axes, so y = x is the diagonal.
        if let (Some(x), Some(y)) = (x_range, y_range) {
            let both = (x.0.min(y.0), x.1.max(y.1));
            x_range = Some(both);
            y_range = Some(both);
        }
    }
    let (Some(x_range), Some(y_range)) = (x_range, y_range) else {
        return Err(PlotError::NoData(chart.title.clone()));
    };
    if chart.x_log && x_range.0 <= 0.0 || chart.y_log && y_range.0 <= 0.0 {
        return Err(PlotError::NonPositiveLog(chart.title.clone()));
    }

    let mut buffer = vec![255u8; chart.width as usize * chart.height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (chart.width, chart.height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw_err(&e))?;
        let mut builder = ChartBuilder::on(&root);
        builder
            .caption(&chart.title, (FONT_FAMILY, 22))
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(64);
        // plotters types a chart by its coordinate kind, so each axis combination is its own branch.
        macro_rules! draw_with {
            ($x:expr, $y:expr) => {{
                let mut ctx = builder.build_cartesian_2d($x, $y).map_err(|e| draw_err(&e))?;
                ctx.configure_mesh()
                    .x_desc(chart.x_label.as_str())
                    .y_desc(chart.y_label.as_str())
                    .label_style((FONT_FAMILY, 14))
                    .axis_desc_style((FONT_FAMILY, 16))
                    .light_line_style(RGBColor(242, 242, 242))
                    .x_label_formatter(if chart.x_log { &log_tick_label } else { &tick_label })
                    .y_label_formatter(if chart.y_log { &log_tick_label } else { &tick_label })
                    .draw()
                    .map_err(|e| draw_err(&e))?;
                if chart.diagonal {
                    let lo = x_range.0.max(y_range.0);
                    let hi = x_range.1.min(y_range.1);
                    ctx.draw_series(LineSeries::new(vec![(lo, lo), (hi, hi)], RGBColor(150, 150, 150)))
                        .map_err(|e| draw_err(&e))?
                        .label("y = x")
                        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RGBColor(150, 150, 150)));
                }
                for (k, (s, points)) in series.iter().enumerate() {
                    let colour = PALETTE[k % PALETTE.len()];
                    let style = ShapeStyle::from(&colour).stroke_width(2);
                    if matches!(s.mark, Mark::Line | Mark::LineAndPoints) {
                        ctx.draw_series(LineSeries::new(points.iter().copied(), style))
                            .map_err(|e| draw_err(&e))?;
                    }
                    if matches!(s.mark, Mark::Points | Mark::LineAndPoints) {
                        ctx.draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                            .map_err(|e| draw_err(&e))?;
                    }
                    // An invisible empty series carries the legend entry for both marks.
                    ctx.draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
                        .map_err(|e| draw_err(&e))?
                        .label(s.label.as_str())
                        .legend(move |(x, y)| {
                            EmptyElement::at((x, y))
                                + PathElement::new(vec![(0, 0), (18, 0)], style)
                                + Circle::new((9, 0), 3, colour.filled())
                        });
                }
                ctx.configure_series_labels()
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .label_font((FONT_FAMILY, 14))
                    .position(SeriesLabelPosition::UpperLeft)
                    .draw()
                    .map_err(|e| draw_err(&e))?;
            }};
        }
        let (x0, x1) = x_range;
        let (y0, y1) = y_range;
        match (chart.x_log, chart.y_log) {
            (false, false) => draw_with!(x0..x1, y0..y1),
            (true, false) => draw_with!((x0..x1).log_scale(), y0..y1),
            (false, true) => draw_with!(x0..x1, (y0..y1).log_scale()),
            (true, true) => draw_with!((x0..x1).log_scale(), (y0..y1).log_scale()),
        }
        root.present().map_err(|e| draw_err(&e))?;
    }
    Ok(buffer)
}

/// Panels side by side into one RGB image (`cols` per row, all panels the same size).
pub fn tile(panels: &[Vec<u8>], w: usize, h: usize, cols: usize) -> (usize, usize, Vec<u8>) {
    let rows = panels.len().div_ceil(cols.max(1));
    let (tw, th) = (w * cols, h * rows);
    let mut out = vec![255u8; tw * th * 3];
    for (p, panel) in panels.iter().enumerate() {
        let (px, py) = ((p % cols) * w, (p / cols) * h);
        for y in 0..h {
            let src = &panel[y * w * 3..(y + 1) * w * 3];
            let at = ((py + y) * tw + px) * 3;
            out[at..at + w * 3].copy_from_slice(src);
        }
    }
    (tw, th, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scatter() -> Chart {
        Chart {
            diagonal: true,
            ..Chart::new("alpha: predicted vs true", "true alpha", "predicted alpha")
        }
        .with_series(Series::new(
            "test set",
            (0..20).map(|k| (k as f64 / 20.0, k as f64 / 20.0 + 0.01)).collect(),
            Mark::Points,
        ))
    }

    /// Pixels far from white: something was drawn there.
    fn inked(rgb: &[u8]) -> usize {
        rgb.chunks(3)
            .filter(|p| p.iter().map(|&c| c as u32).sum::<u32>() < 600)
            .count()
    }

    #[test]
    fn draws_marks_text_and_writes_a_png_that_reads_back() {
        let chart = scatter();
        let rgb = draw_rgb(&chart).unwrap();
        assert_eq!(rgb.len(), 800 * 600 * 3);
        let blank = draw_rgb(&Chart {
            series: vec![Series::new("test set", vec![(0.0, 0.0), (1.0, 1.0)], Mark::Line)],
            ..chart.clone()
        })
        .unwrap();
        assert!(inked(&rgb) > 2000, "axes, labels and points are drawn");
        assert_ne!(rgb, blank, "the data changes the picture");
        // The title's glyphs come from the bundled font: a chart without a title has less ink.
        let untitled = draw_rgb(&Chart {
            title: String::new(),
            ..chart.clone()
        })
        .unwrap();
        assert!(inked(&rgb) > inked(&untitled) + 200, "title text is rendered");

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("scatter.png");
        write_png(&chart, &path).unwrap();
        let back = image::open(&path).unwrap().to_rgb8();
        assert_eq!((back.width(), back.height()), (800, 600));
        assert_eq!(back.into_raw(), rgb);
    }

    #[test]
    fn log_axes_and_degenerate_data() {
        let mut chart = Chart::new("time vs N", "N", "seconds").with_series(Series::new(
            "raster",
            vec![(2.0, 10.0), (4.0, 40.0), (8.0, 160.0), (16.0, f64::NAN)],
            Mark::LineAndPoints,
        ));
        chart.x_log = true;
        chart.y_log = true;
        assert!(draw_rgb(&chart).is_ok());
        // A single point and a flat series still get a drawable range.
        let flat = Chart::new("flat", "x", "y").with_series(Series::new("one", vec![(1.0, 3.0)], Mark::Points));
        assert!(draw_rgb(&flat).is_ok());
        let empty = Chart::new("empty", "x", "y").with_series(Series::new("none", vec![(f64::NAN, 1.0)], Mark::Line));
        assert!(matches!(draw_rgb(&empty), Err(PlotError::NoData(_))));
        let mut negative = Chart::new("neg", "x", "y").with_series(Series::new("s", vec![(1.0, -1.0)], Mark::Line));
        negative.y_log = true;
        assert!(matches!(draw_rgb(&negative), Err(PlotError::NonPositiveLog(_))));
    }

    #[test]
    fn tick_labels_are_compact_and_sparse_on_log_axes() {
        assert_eq!(tick_label(&10.0), "10");
        assert_eq!(tick_label(&0.25), "0.25");
        assert_eq!(tick_label(&-0.0), "0");
        assert_eq!(tick_label(&1e6), "1e6");
        assert_eq!(log_tick_label(&20.0), "20");
        assert_eq!(log_tick_label(&0.5), "0.5");
        assert_eq!(log_tick_label(&70.0), "");
        assert_eq!(log_tick_label(&100.0), "100");
    }

    #[test]
    fn a_failed_write_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("missing-folder").join("chart.png");
        assert!(write_png(&scatter(), &path).is_err());
        assert!(!path.exists());
    }
}
