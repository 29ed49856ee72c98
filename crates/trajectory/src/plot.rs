//! A top-view plot of an estimate against its ground truth, the estimate coloured by its error.
//! PNG or SVG, chosen by the file extension.

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

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    gt: &[Vec3],
    est: &[Vec3],
    errors: &[f64],
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
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(cx - half..cx + half, cy - half..cy + half)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc(format!("{} [m]", names[a]))
        .y_desc(format!("{} [m]", names[b]))
        .draw()
        .map_err(e)?;
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
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
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
    let is_svg = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    let size = (900, 900);
    if is_svg {
        draw(
            SVGBackend::new(path, size).into_drawing_area(),
            title,
            gt,
            est,
            errors,
        )
        .map_err(fail)
    } else {
        draw(
            BitMapBackend::new(path, size).into_drawing_area(),
            title,
            gt,
            est,
            errors,
        )
        .map_err(fail)
    }
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
}
