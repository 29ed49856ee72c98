//! A top-view plot of an estimate against its ground truth, the estimate coloured by its error,
//! and the error over time with the periods a moving object was in view shaded. PNG or SVG,
//! chosen by the file extension.
//!
//! Text (captions, axis labels, legends) needs a TrueType font file from the system's font
//! folders, read at run time and drawn by plotters' pure-Rust `ab_glyph` feature, so the binary
//! links no fontconfig or freetype and starts on a machine without them; where no font is
//! installed the plots are drawn without text rather than not at all ([`text_renders`]).

use crate::TrajectoryError;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;
use stillpoint_geometry::Vec3;

/// Map an error in [lo, hi] to a blue → green → red colour.
fn error_colour(e: f64, lo: f64, hi: f64) -> RGBColor {
    let t = if hi > lo {
        ((e - lo) / (hi - lo)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let (r, g, b) = if t < 0.5 {
        let u = t * 2.0;
        (0.0, u, 1.0 - u)
    } else {
        let u = (t - 0.5) * 2.0;
        (u, 1.0 - u, 0.0)
    };
    RGBColor((r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8)
}

/// The two axes along which the ground truth spreads most: the "top" view for any convention
/// (x-y for TUM's motion capture, x-z for KITTI's camera frame).
fn top_axes(points: &[Vec3]) -> (usize, usize) {
    let mut spread: Vec<(usize, f64)> = (0..3)
        .map(|a| {
            let (lo, hi) = points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p[a]), hi.max(p[a]))
                });
            (a, hi - lo)
        })
        .collect();
    spread.sort_by(|x, y| y.1.total_cmp(&x.1));
    let (a, b) = (spread[0].0.min(spread[1].0), spread[0].0.max(spread[1].0));
    (a, b)
}

/// Whether text can be drawn: a font was found and registered as "sans-serif" (checked once).
pub fn text_renders() -> bool {
    static FOUND: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *FOUND.get_or_init(|| {
        if let Some(bytes) = system_font() {
            // plotters keeps fonts for the program's life: the bytes are leaked once.
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes);
        }
        let found = ("sans-serif", 12).into_font().box_size("0.5 m").is_ok();
        if !found {
            tracing_free_warning();
        }
        found
    })
}

/// A sans-serif TrueType font from the usual font folders (Linux, macOS, Windows): a
/// well-known one first, else the first `.ttf` found.
fn system_font() -> Option<Vec<u8>> {
    const PREFERRED: [&str; 5] = [
        "DejaVuSans.ttf",
        "LiberationSans-Regular.ttf",
        "NotoSans-Regular.ttf",
        "FreeSans.ttf",
        "Arial.ttf",
    ];
    let mut roots = vec![
        std::path::PathBuf::from("/usr/share/fonts"),
        std::path::PathBuf::from("/usr/local/share/fonts"),
        std::path::PathBuf::from("/Library/Fonts"),
        std::path::PathBuf::from("/System/Library/Fonts"),
        std::path::PathBuf::from("C:\\Windows\\Fonts"),
    ];
    if let Some(home) = std::env::var_os("HOME") {
        roots.push(Path::new(&home).join(".fonts"));
        roots.push(Path::new(&home).join(".local/share/fonts"));
    }
    let mut found = Vec::new();
    for root in &roots {
        collect_ttf(root, 4, &mut found);
    }
    let name = |p: &std::path::PathBuf| p.file_name().and_then(|n| n.to_str()).map(str::to_owned);
    let best = PREFERRED
        .iter()
        .find_map(|want| found.iter().find(|p| name(p).as_deref() == Some(*want)))
        .or_else(|| found.first())?;
    std::fs::read(best).ok()
}

/// The `.ttf` files under `dir`, at most `depth` folders down, in name order.
fn collect_ttf(dir: &Path, depth: usize, out: &mut Vec<std::path::PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut paths: Vec<_> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for p in paths {
        if p.is_dir() {
            if depth > 0 {
                collect_ttf(&p, depth - 1, out);
            }
        } else if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("ttf")) {
            out.push(p);
        }
    }
}

/// Said once on stderr: this crate logs nothing else.
fn tracing_free_warning() {
    eprintln!(
        "warning: no TrueType font found in the system's font folders: plots are drawn without text"
    );
}

/// Both plots' frame: a margin and, when text renders, the caption and room for the axis
/// labels (`y_labels` px wide).
fn chart_builder<'a, 'b, DB: DrawingBackend>(
    root: &'a DrawingArea<DB, Shift>,
    caption: &str,
    text: bool,
    y_labels: u32,
) -> ChartBuilder<'a, 'b, DB> {
    let mut builder = ChartBuilder::on(root);
    builder.margin(12);
    if text {
        builder
            .caption(caption, ("sans-serif", 18))
            .x_label_area_size(36)
            .y_label_area_size(y_labels);
    }
    builder
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    gt: &[Vec3],
    est: &[Vec3],
    errors: &[f64],
    text: bool,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let (a, b) = top_axes(gt);
    let all = gt.iter().chain(est);
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for p in all {
        x0 = x0.min(p[a]);
        x1 = x1.max(p[a]);
        y0 = y0.min(p[b]);
        y1 = y1.max(p[b]);
    }
    // Equal scale on both axes, with a margin.
    let half = 0.55 * (x1 - x0).max(y1 - y0).max(1e-6);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (lo, hi) = errors
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let names = ["x", "y", "z"];
    let caption = format!("{title}  (error {lo:.4} blue .. {hi:.4} m red)");
    let mut chart = chart_builder(&root, &caption, text, 56)
        .build_cartesian_2d(cx - half..cx + half, cy - half..cy + half)
        .map_err(e)?;
    if text {
        chart
            .configure_mesh()
            .x_desc(format!("{} [m]", names[a]))
            .y_desc(format!("{} [m]", names[b]))
            .draw()
            .map_err(e)?;
    } else {
        frame_plot(&mut chart).map_err(e)?;
    }
    chart
        .draw_series(LineSeries::new(
            gt.iter().map(|p| (p[a], p[b])),
            BLACK.stroke_width(1),
        ))
        .map_err(e)?
        .label("ground truth")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK));
    chart
        .draw_series(
            est.iter()
                .zip(errors)
                .map(|(p, &err)| Circle::new((p[a], p[b]), 2, error_colour(err, lo, hi).filled())),
        )
        .map_err(e)?
        .label("estimate (aligned)")
        .legend(|(x, y)| Circle::new((x + 8, y), 3, RED.filled()));
    if text {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
    }
    root.present().map_err(e)?;
    Ok(())
}

/// The plotting area's border, for plots drawn without text (no mesh, whose labels need a font).
fn frame_plot<DB: DrawingBackend>(
    chart: &mut ChartContext<
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (x, y) = (chart.x_range(), chart.y_range());
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(x.start, y.start), (x.end, y.end)],
            BLACK.stroke_width(1),
        )))
        .map(|_| ())
}

/// Plot the ground-truth path (black line) and the aligned estimate (dots coloured by error) seen
/// from the top, to `path` (`.svg` → SVG, anything else → PNG). `gt` may be the full ground truth;
/// `est` and `errors` must have equal length.
pub fn plot_top_view(
    path: &Path,
    title: &str,
    gt: &[Vec3],
    est: &[Vec3],
    errors: &[f64],
) -> Result<(), TrajectoryError> {
    let fail = |msg: String| TrajectoryError::Plot {
        path: path.display().to_string(),
        msg,
    };
    if gt.is_empty() || est.len() != errors.len() {
        return Err(fail(format!(
            "need ground truth and one error per estimated pose ({} gt, {} est, {} errors)",
            gt.len(),
            est.len(),
            errors.len()
        )));
    }
    let size = (900, 900);
    let text = text_renders();
    if is_svg(path) {
        draw(
            SVGBackend::new(path, size).into_drawing_area(),
            title,
            gt,
            est,
            errors,
            text,
        )
        .map_err(fail)
    } else {
        draw_png(path, size, |root| draw(root, title, gt, est, errors, text)).map_err(fail)
    }
}

fn is_svg(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"))
}

/// One curve of [`plot_error_over_time`]: a name for the legend and (stamp s, error m) points.
pub struct ErrorSeries<'a> {
    /// Legend text.
    pub label: &'a str,
    /// (stamp in seconds, error in metres), in time order.
    pub points: &'a [(f64, f64)],
}

/// Size of [`plot_error_over_time`]'s picture, pixels.
pub const ERROR_PLOT_SIZE: (u32, u32) = (1200, 500);

/// Shading of the moving periods.
const SHADE: RGBColor = RGBColor(255, 200, 140);
/// Colours of the curves, in order.
const CURVES: [RGBColor; 4] = [
    RGBColor(90, 90, 90),
    RGBColor(0, 90, 220),
    RGBColor(220, 30, 30),
    RGBColor(0, 150, 60),
];

/// Plot each series' error over time (seconds from the earliest stamp, metres), the intervals
/// in `shaded` (stamps on the same clock: when a moving object was in view) shaded orange,
/// to `path` (`.svg` -> SVG, anything else -> PNG, [`ERROR_PLOT_SIZE`]).
pub fn plot_error_over_time(
    path: &Path,
    title: &str,
    series: &[ErrorSeries],
    shaded: &[(f64, f64)],
) -> Result<(), TrajectoryError> {
    let fail = |msg: String| TrajectoryError::Plot {
        path: path.display().to_string(),
        msg,
    };
    let all = || series.iter().flat_map(|s| s.points.iter());
    if all().next().is_none() {
        return Err(fail("no errors to plot".into()));
    }
    let text = text_renders();
    if is_svg(path) {
        let root = SVGBackend::new(path, ERROR_PLOT_SIZE).into_drawing_area();
        draw_error_over_time(root, title, series, shaded, text).map_err(fail)
    } else {
        draw_png(path, ERROR_PLOT_SIZE, |root| {
            draw_error_over_time(root, title, series, shaded, text)
        })
        .map_err(fail)
    }
}

/// Draw into an RGB buffer with `draw`, then write it to `path` as a PNG with the `png` crate
/// (plotters' own PNG encoder would bring a second version of `image` into the build).
fn draw_png(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), String>,
) -> Result<(), String> {
    let mut rgb = vec![0u8; width as usize * height as usize * 3];
    draw(BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area())?;
    let file = std::fs::File::create(path).map_err(|e| e.to_string())?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
    writer.write_image_data(&rgb).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())
}

fn draw_error_over_time<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    series: &[ErrorSeries],
    shaded: &[(f64, f64)],
    text: bool,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let points = || series.iter().flat_map(|s| s.points.iter());
    let t0 = points().map(|p| p.0).fold(f64::INFINITY, f64::min);
    let t1 = points().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
    let top = points().map(|p| p.1).fold(0.0, f64::max).max(1e-6) * 1.1;
    let end = (t1 - t0).max(1e-6);
    let mut chart = chart_builder(&root, title, text, 64)
        .build_cartesian_2d(0.0..end, 0.0..top)
        .map_err(e)?;
    // The mesh, then the shading over it, then the curves; the shading clipped to the
    // plotted time.
    if text {
        chart
            .configure_mesh()
            .light_line_style(TRANSPARENT)
            .x_desc("time [s]")
            .y_desc("translation error after alignment [m]")
            .draw()
            .map_err(e)?;
    } else {
        frame_plot(&mut chart).map_err(e)?;
    }
    let spans: Vec<(f64, f64)> = shaded
        .iter()
        .map(|&(a, b)| ((a - t0).max(0.0), (b - t0).min(end)))
        .filter(|(a, b)| a < b)
        .collect();
    chart
        .draw_series(
            spans
                .iter()
                .map(|&(a, b)| Rectangle::new([(a, 0.0), (b, top)], SHADE.mix(0.5).filled())),
        )
        .map_err(e)?
        .label("moving object in view")
        .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], SHADE.filled()));
    for (i, s) in series.iter().enumerate() {
        let colour = CURVES[i % CURVES.len()];
        chart
            .draw_series(LineSeries::new(
                s.points.iter().map(|&(t, v)| (t - t0, v)),
                colour.stroke_width(2),
            ))
            .map_err(e)?
            .label(s.label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
            });
    }
    if text {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
    }
    root.present().map_err(e)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_png_and_svg_and_rejects_mismatched_input() {
        let dir = tempfile::tempdir().unwrap();
        let gt: Vec<Vec3> = (0..100)
            .map(|i| {
                let a = i as f64 * 0.06;
                Vec3::new(a.cos(), a.sin(), 0.01 * a)
            })
            .collect();
        let est: Vec<Vec3> = gt.iter().map(|p| p * 1.02).collect();
        let errors: Vec<f64> = gt.iter().zip(&est).map(|(g, e)| (g - e).norm()).collect();
        for name in ["top.png", "top.svg"] {
            let path = dir.path().join(name);
            plot_top_view(&path, "test", &gt, &est, &errors).unwrap();
            assert!(std::fs::metadata(&path).unwrap().len() > 1000);
        }
        let bad = plot_top_view(&dir.path().join("x.png"), "t", &gt, &est, &errors[1..]);
        assert!(bad.unwrap_err().to_string().contains("x.png"));
        assert_eq!(top_axes(&gt), (0, 1));
    }

    /// A PNG's size, and the share of the pixels in x0..x1 by y0..y1 that are the shading's
    /// orange (red well over blue).
    fn png_orange(path: &Path, (x0, x1): (u32, u32), (y0, y1): (u32, u32)) -> ((u32, u32), f64) {
        let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        let mut reader = png::Decoder::new(file).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgb);
        let mut orange = 0;
        for y in y0..y1 {
            for x in x0..x1 {
                let i = ((y * info.width + x) * 3) as usize;
                orange += usize::from(buf[i] > 200 && buf[i] as i32 - buf[i + 2] as i32 > 40);
            }
        }
        let n = ((x1 - x0) * (y1 - y0)) as f64;
        ((info.width, info.height), orange as f64 / n)
    }

    #[test]
    fn error_over_time_shades_the_moving_periods_with_and_without_text() {
        let dir = tempfile::tempdir().unwrap();
        // Two flat curves, one near the bottom and one near the top: the middle rows are free.
        let a: Vec<(f64, f64)> = (0..100).map(|i| (100.0 + i as f64 * 0.1, 0.001)).collect();
        let b: Vec<(f64, f64)> = a.iter().map(|&(t, _)| (t, 0.02)).collect();
        let series = [
            ErrorSeries {
                label: "off",
                points: &a,
            },
            ErrorSeries {
                label: "on",
                points: &b,
            },
        ];
        // From half the time on.
        let shaded = [(104.95, 120.0)];
        let path = dir.path().join("t.png");
        plot_error_over_time(&path, "test", &series, &shaded).unwrap();
        let (w, h) = ERROR_PLOT_SIZE;
        let rows = (h * 2 / 5, h * 3 / 5);
        let (size, right) = png_orange(&path, (w * 3 / 5, w * 9 / 10), rows);
        assert_eq!(size, ERROR_PLOT_SIZE);
        assert!(right > 0.8, "{right}");
        for text in [true, false] {
            let path = dir.path().join(format!("t{text}.png"));
            draw_png(&path, ERROR_PLOT_SIZE, |root| {
                draw_error_over_time(root, "test", &series, &shaded, text)
            })
            .unwrap();
            let (_, right) = png_orange(&path, (w * 3 / 5, w * 9 / 10), rows);
            let (_, left) = png_orange(&path, (w / 8, w * 2 / 5), rows);
            assert!(right > 0.8 && left == 0.0, "text {text}: {left} {right}");
        }
        plot_error_over_time(&dir.path().join("t.svg"), "test", &series, &[]).unwrap();
        let empty = plot_error_over_time(&dir.path().join("e.png"), "t", &[], &shaded);
        assert!(empty.unwrap_err().to_string().contains("e.png"));
    }
}
