//! Pyramidal Lucas-Kanade tracking, following OpenCV's `calcOpticalFlowPyrLK` (Bouguet's
//! scheme): `pyrDown` pyramids, Scharr gradients of the previous image, per-level Newton steps
//! on a window, minimum-eigenvalue rejection, oscillation damping.

use crate::imgops::{pyr_down, scharr, simd_fn};
use crate::valid;
use stillpoint_image::Gray8;

/// LK settings. `Default` = the paper's geometry module (DS-SLAM's
/// `calcOpticalFlowPyrLK(.., Size(22, 22), 5, TermCriteria(COUNT + EPS, 20, 0.01))`).
#[derive(Clone, Debug, PartialEq)]
pub struct LkParams {
    /// Window side in pixels (paper: 22).
    pub window: usize,
    /// Coarsest pyramid level, 0 = no pyramid (paper: 5, OpenCV `maxLevel`). Like OpenCV, levels
    /// whose size would not exceed the window are not built.
    pub max_level: usize,
    /// Newton iterations per level (paper: 20).
    pub max_iterations: usize,
    /// Stop when the step is below this many pixels (paper: 0.01).
    pub epsilon: f32,
    /// Reject a point whose gradient matrix' smallest eigenvalue / window area is below this
    /// (OpenCV default `minEigThreshold` 1e-4, in OpenCV's units).
    pub min_eig_threshold: f32,
}

impl Default for LkParams {
    fn default() -> Self {
        Self {
            window: 22,
            max_level: 5,
            max_iterations: 20,
            epsilon: 0.01,
            min_eig_threshold: 1e-4,
        }
    }
}

/// One image prepared for LK: its pyramid as f32 (and Scharr gradients when it is the image
/// tracked *from*). Build once per frame and reuse it for both directions of a
/// forward-backward check.
#[derive(Clone, Debug)]
pub struct LkPyramid {
    sizes: Vec<(usize, usize)>,
    levels: Vec<Vec<f32>>,
    grads: Vec<(Vec<f32>, Vec<f32>)>,
}

impl LkPyramid {
    /// Build the pyramid of `img` (with gradients) for the settings `p`.
    pub fn new(img: &Gray8, p: &LkParams) -> Self {
        Self::build(img, p, true)
    }

    fn build(img: &Gray8, p: &LkParams, with_gradients: bool) -> Self {
        let mut out = Self {
            sizes: Vec::new(),
            levels: Vec::new(),
            grads: Vec::new(),
        };
        if !valid(img) {
            return out;
        }
        let win = p.window.max(3);
        let mut cur = img.clone();
        for level in 0..=p.max_level {
            out.sizes.push((cur.width, cur.height));
            out.levels
                .push(cur.data.iter().map(|&v| v as f32).collect());
            if with_gradients {
                out.grads.push(scharr(&cur));
            }
            // OpenCV stops when the next level would not exceed the window
            let (nw, nh) = (cur.width.div_ceil(2), cur.height.div_ceil(2));
            if level == p.max_level || nw <= win || nh <= win {
                break;
            }
            cur = pyr_down(&cur);
        }
        out
    }

    /// Number of levels built.
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// Size of level 0.
    pub fn size(&self) -> (usize, usize) {
        self.sizes.first().copied().unwrap_or((0, 0))
    }
}

/// Track `pts` from `prev` into `cur`; `None` where tracking failed (flat window, left the
/// image, NaN input). Same-size images required (else all `None`).
///
/// ```
/// use stillpoint_features::{track_lk, LkParams};
/// use stillpoint_image::Gray8;
/// let mut a = Gray8::new(64, 64, 0);
/// for y in 0..64 { for x in 0..64 {
///     let (fx, fy) = (x as f32, y as f32);
///     a.set(x, y, (128.0 + 60.0 * (fx * 0.3).sin() * (fy * 0.25).cos()) as u8);
/// }}
/// let r = track_lk(&a, &a, &[[32.0, 32.0]], &LkParams::default());
/// let p = r[0].unwrap();
/// assert!((p[0] - 32.0).abs() < 0.01 && (p[1] - 32.0).abs() < 0.01);
/// ```
pub fn track_lk(
    prev: &Gray8,
    cur: &Gray8,
    pts: &[[f32; 2]],
    p: &LkParams,
) -> Vec<Option<[f32; 2]>> {
    let a = LkPyramid::build(prev, p, true);
    let b = LkPyramid::build(cur, p, false);
    track_lk_pyramids(&a, &b, pts, p)
}

/// [`track_lk`] on prepared pyramids (`prev` must have been built with [`LkPyramid::new`]).
pub fn track_lk_pyramids(
    prev: &LkPyramid,
    cur: &LkPyramid,
    pts: &[[f32; 2]],
    p: &LkParams,
) -> Vec<Option<[f32; 2]>> {
    if prev.levels.is_empty()
        || prev.grads.len() != prev.levels.len()
        || prev.sizes.first() != cur.sizes.first()
    {
        return vec![None; pts.len()];
    }
    track_all(prev, cur, pts, p)
}

/// Forward-backward error of each tracked point: track `tracked` back from `cur` to `prev` and
/// measure the distance to where it started (`None` where either direction failed). Both
/// pyramids need gradients ([`LkPyramid::new`]).
pub fn forward_backward_errors(
    prev: &LkPyramid,
    cur: &LkPyramid,
    pts: &[[f32; 2]],
    tracked: &[Option<[f32; 2]>],
    p: &LkParams,
) -> Vec<Option<f32>> {
    let idx: Vec<usize> = (0..pts.len().min(tracked.len()))
        .filter(|&i| tracked[i].is_some())
        .collect();
    let fwd: Vec<[f32; 2]> = idx.iter().filter_map(|&i| tracked[i]).collect();
    let back = track_lk_pyramids(cur, prev, &fwd, p);
    let mut out = vec![None; pts.len()];
    for (k, &i) in idx.iter().enumerate() {
        if let Some(b) = back[k] {
            out[i] = Some(((b[0] - pts[i][0]).powi(2) + (b[1] - pts[i][1]).powi(2)).sqrt());
        }
    }
    out
}

/// Padded patch width: a multiple of 8 so the inner loops run on whole vectors.
#[inline(always)]
fn padded(win: usize) -> usize {
    win.div_ceil(8) * 8
}

/// Bilinear patch of `rows` x `pw` samples whose top-left is (ix + a, iy + b), into `out`
/// (stride `pw`); columns at or beyond `valid_cols` are zero. Clamps at the image border.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn sample_patch(
    src: &[f32],
    (w, h): (usize, usize),
    ix: isize,
    iy: isize,
    wts: [f32; 4],
    rows: usize,
    pw: usize,
    valid_cols: usize,
    out: &mut [f32],
) {
    let [w00, w01, w10, w11] = wts;
    let inside = ix >= 0 && iy >= 0 && ix as usize + pw < w && iy as usize + rows < h;
    for r in 0..rows {
        let o = &mut out[r * pw..(r + 1) * pw];
        if inside {
            let base = (iy as usize + r) * w + ix as usize;
            let r0 = &src[base..base + pw + 1];
            let r1 = &src[base + w..base + w + pw + 1];
            for (c, v) in o.iter_mut().enumerate() {
                *v = w00 * r0[c] + w01 * r0[c + 1] + w10 * r1[c] + w11 * r1[c + 1];
            }
        } else {
            let y0 = (iy + r as isize).clamp(0, h as isize - 1) as usize;
            let y1 = (iy + r as isize + 1).clamp(0, h as isize - 1) as usize;
            for (c, v) in o.iter_mut().enumerate() {
                let x0 = (ix + c as isize).clamp(0, w as isize - 1) as usize;
                let x1 = (ix + c as isize + 1).clamp(0, w as isize - 1) as usize;
                *v = w00 * src[y0 * w + x0]
                    + w01 * src[y0 * w + x1]
                    + w10 * src[y1 * w + x0]
                    + w11 * src[y1 * w + x1];
            }
        }
        for v in o.iter_mut().skip(valid_cols) {
            *v = 0.0;
        }
    }
}

/// Σ (J - I) Gx and Σ (J - I) Gy over the window, J sampled bilinearly at (ix + a, iy + b),
/// accumulated in 8 lanes.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn mismatch(
    src: &[f32],
    (w, h): (usize, usize),
    ix: isize,
    iy: isize,
    wts: [f32; 4],
    win: usize,
    pw: usize,
    ip: &[f32],
    gx: &[f32],
    gy: &[f32],
    scratch: &mut [f32],
) -> (f32, f32) {
    let [w00, w01, w10, w11] = wts;
    let inside = ix >= 0 && iy >= 0 && ix as usize + pw < w && iy as usize + win < h;
    let mut acc1 = [0f32; 8];
    let mut acc2 = [0f32; 8];
    for r in 0..win {
        let jrow: &[f32] = if inside {
            let base = (iy as usize + r) * w + ix as usize;
            let r0 = &src[base..base + pw + 1];
            let r1 = &src[base + w..base + w + pw + 1];
            let s = &mut scratch[..pw];
            for c in 0..pw {
                s[c] = w00 * r0[c] + w01 * r0[c + 1] + w10 * r1[c] + w11 * r1[c + 1];
            }
            s
        } else {
            sample_patch(src, (w, h), ix, iy + r as isize, wts, 1, pw, pw, scratch);
            &scratch[..pw]
        };
        let (ir, xr, yr) = (
            &ip[r * pw..(r + 1) * pw],
            &gx[r * pw..(r + 1) * pw],
            &gy[r * pw..(r + 1) * pw],
        );
        for (((j8, i8), x8), y8) in jrow
            .chunks_exact(8)
            .zip(ir.chunks_exact(8))
            .zip(xr.chunks_exact(8))
            .zip(yr.chunks_exact(8))
        {
            for l in 0..8 {
                let d = j8[l] - i8[l];
                acc1[l] += d * x8[l];
                acc2[l] += d * y8[l];
            }
        }
    }
    (acc1.iter().sum(), acc2.iter().sum())
}

#[inline(always)]
fn weights(a: f32, b: f32) -> [f32; 4] {
    [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b]
}

simd_fn! {
fn track_all(
    prev: &LkPyramid,
    cur: &LkPyramid,
    pts: &[[f32; 2]],
    p: &LkParams,
) -> Vec<Option<[f32; 2]>> {
    let win = p.window.max(3);
    let pw = padded(win);
    let half = (win as f32 - 1.0) * 0.5;
    let n_levels = prev.levels.len().min(cur.levels.len());
    let eps2 = p.epsilon * p.epsilon;
    // OpenCV's units: gradients are raw Scharr, products scaled by 2^-20, intensities x 32
    let flt_scale = 1.0 / (1u32 << 20) as f32;
    let mut ip = vec![0f32; win * pw];
    let mut gx = vec![0f32; win * pw];
    let mut gy = vec![0f32; win * pw];
    let mut scratch = vec![0f32; pw];
    let mut out = Vec::with_capacity(pts.len());
    for pt in pts {
        if !(pt[0].is_finite() && pt[1].is_finite()) {
            out.push(None);
            continue;
        }
        let mut next = [0f32; 2];
        let mut ok = true;
        for level in (0..n_levels).rev() {
            let (w, h) = prev.sizes[level];
            let s = 1.0 / (1u32 << level) as f32;
            let pp = [pt[0] * s - half, pt[1] * s - half];
            // `next` is the centre estimate, carried from the coarser level
            next = if level == n_levels - 1 {
                [pt[0] * s, pt[1] * s]
            } else {
                [next[0] * 2.0, next[1] * 2.0]
            };
            let (fx, fy) = (pp[0].floor(), pp[1].floor());
            let (ix, iy) = (fx as isize, fy as isize);
            if ix < -(win as isize) || ix >= w as isize || iy < -(win as isize) || iy >= h as isize {
                if level == 0 {
                    ok = false;
                }
                continue;
            }
            let wts = weights(pp[0] - fx, pp[1] - fy);
            let (dx, dy) = &prev.grads[level];
            sample_patch(&prev.levels[level], (w, h), ix, iy, wts, win, pw, win, &mut ip);
            sample_patch(dx, (w, h), ix, iy, wts, win, pw, win, &mut gx);
            sample_patch(dy, (w, h), ix, iy, wts, win, pw, win, &mut gy);
            let (mut a11, mut a12, mut a22) = ([0f32; 8], [0f32; 8], [0f32; 8]);
            for (x8, y8) in gx.chunks_exact(8).zip(gy.chunks_exact(8)) {
                for l in 0..8 {
                    let (x, y) = (x8[l], y8[l]);
                    a11[l] += x * x;
                    a12[l] += x * y;
                    a22[l] += y * y;
                }
            }
            let a11: f32 = a11.iter().sum::<f32>() * flt_scale;
            let a12: f32 = a12.iter().sum::<f32>() * flt_scale;
            let a22: f32 = a22.iter().sum::<f32>() * flt_scale;
            let det = a11 * a22 - a12 * a12;
            let min_eig = (a22 + a11 - ((a11 - a22) * (a11 - a22) + 4.0 * a12 * a12).sqrt())
                / (2.0 * (win * win) as f32);
            if min_eig.is_nan() || min_eig < p.min_eig_threshold || det < f32::EPSILON {
                if level == 0 {
                    ok = false;
                }
                continue;
            }
            let inv_det = 1.0 / det;
            // next is in window-corner coordinates from here on
            next = [next[0] - half, next[1] - half];
            let mut prev_delta = [0f32; 2];
            let jl = &cur.levels[level];
            for it in 0..p.max_iterations.max(1) {
                let (fx, fy) = (next[0].floor(), next[1].floor());
                let (jx, jy) = (fx as isize, fy as isize);
                if !(next[0].is_finite() && next[1].is_finite())
                    || jx < -(win as isize)
                    || jx >= w as isize
                    || jy < -(win as isize)
                    || jy >= h as isize
                {
                    if level == 0 {
                        ok = false;
                    }
                    break;
                }
                let jw = weights(next[0] - fx, next[1] - fy);
                let (b1, b2) =
                    mismatch(jl, (w, h), jx, jy, jw, win, pw, &ip, &gx, &gy, &mut scratch);
                // OpenCV scales intensities by 32 and products by 2^-20
                let (b1, b2) = (b1 * 32.0 * flt_scale, b2 * 32.0 * flt_scale);
                let delta = [
                    (a12 * b2 - a22 * b1) * inv_det,
                    (a12 * b1 - a11 * b2) * inv_det,
                ];
                next = [next[0] + delta[0], next[1] + delta[1]];
                if delta[0] * delta[0] + delta[1] * delta[1] <= eps2 {
                    break;
                }
                if it > 0
                    && (delta[0] + prev_delta[0]).abs() < 0.01
                    && (delta[1] + prev_delta[1]).abs() < 0.01
                {
                    next = [next[0] - delta[0] * 0.5, next[1] - delta[1] * 0.5];
                    break;
                }
                prev_delta = delta;
            }
            next = [next[0] + half, next[1] + half];
            if !ok {
                break;
            }
        }
        let (w0, h0) = prev.sizes[0];
        let inside = next[0] > -1.0 && next[1] > -1.0 && next[0] < w0 as f32 && next[1] < h0 as f32;
        out.push(if ok && inside && next[0].is_finite() && next[1].is_finite() {
            Some(next)
        } else {
            None
        });
    }
    out
}
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth random texture defined everywhere, sampled at an offset (exact sub-pixel shift).
    fn field(w: usize, h: usize, dx: f32, dy: f32) -> Gray8 {
        let mut img = Gray8::new(w, h, 0);
        let waves: Vec<(f32, f32, f32, f32)> = (0..24)
            .map(|i| {
                let t = i as f32 * 2.399;
                let f = 0.05 + 0.25 * ((i * 7 % 24) as f32 / 24.0);
                (
                    f * t.cos(),
                    f * t.sin(),
                    (i * 13 % 7) as f32,
                    22.0 / (1.0 + i as f32 * 0.1),
                )
            })
            .collect();
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f32 - dx, y as f32 - dy);
                let v: f32 = waves
                    .iter()
                    .map(|&(kx, ky, ph, a)| a * (kx * fx + ky * fy + ph).sin())
                    .sum();
                img.set(x, y, (128.0 + v).round().clamp(0.0, 255.0) as u8);
            }
        }
        img
    }

    #[test]
    fn recovers_a_sub_pixel_shift_to_a_hundredth_of_a_pixel() {
        let (dx, dy) = (1.37f32, -0.62f32);
        let a = field(320, 240, 0.0, 0.0);
        let b = field(320, 240, dx, dy);
        let pts: Vec<[f32; 2]> = (0..200)
            .map(|i| [30.0 + (i % 20) as f32 * 13.0, 30.0 + (i / 20) as f32 * 18.0])
            .collect();
        let r = track_lk(&a, &b, &pts, &LkParams::default());
        let mut errs: Vec<f32> = pts
            .iter()
            .zip(&r)
            .filter_map(|(p, q)| {
                q.map(|q| ((q[0] - p[0] - dx).powi(2) + (q[1] - p[1] - dy).powi(2)).sqrt())
            })
            .collect();
        assert!(errs.len() >= 190, "{}", errs.len());
        errs.sort_by(f32::total_cmp);
        let median = errs[errs.len() / 2];
        eprintln!("median {median} p90 {}", errs[errs.len() * 9 / 10]);
        assert!(median < 0.01, "median error {median}");
    }

    #[test]
    fn large_motion_is_found_through_the_pyramid_and_fb_check_is_small() {
        let (dx, dy) = (17.3f32, 9.8f32);
        let a = field(320, 240, 0.0, 0.0);
        let b = field(320, 240, dx, dy);
        let p = LkParams::default();
        let (pa, pb) = (LkPyramid::new(&a, &p), LkPyramid::new(&b, &p));
        assert_eq!(pa.levels(), 4); // 320 → 160 → 80 → 40; 20 would not exceed the window
        let pts: Vec<[f32; 2]> = (0..50)
            .map(|i| [60.0 + (i % 10) as f32 * 20.0, 60.0 + (i / 10) as f32 * 25.0])
            .collect();
        let r = track_lk_pyramids(&pa, &pb, &pts, &p);
        let good = pts
            .iter()
            .zip(&r)
            .filter(|(p, q)| {
                q.is_some_and(|q| {
                    (q[0] - p[0] - dx).abs() < 0.05 && (q[1] - p[1] - dy).abs() < 0.05
                })
            })
            .count();
        assert!(good >= 45, "{good}");
        let fb = forward_backward_errors(&pa, &pb, &pts, &r, &p);
        let small = fb.iter().flatten().filter(|&&e| e < 0.1).count();
        assert!(small >= 45, "{small}");
    }

    #[test]
    fn flat_outside_and_bad_input_fail_cleanly() {
        let flat = Gray8::new(100, 80, 50);
        let p = LkParams::default();
        let r = track_lk(
            &flat,
            &flat,
            &[[50.0, 40.0], [f32::NAN, 1.0], [-500.0, 3.0]],
            &p,
        );
        assert_eq!(r, vec![None, None, None]);
        let tex = field(100, 80, 0.0, 0.0);
        // different sizes, empty images, tiny images
        assert_eq!(
            track_lk(&tex, &field(90, 80, 0.0, 0.0), &[[5.0, 5.0]], &p),
            vec![None]
        );
        assert_eq!(
            track_lk(
                &Gray8::new(0, 0, 0),
                &Gray8::new(0, 0, 0),
                &[[1.0, 1.0]],
                &p
            ),
            vec![None]
        );
        let tiny = field(8, 6, 0.0, 0.0);
        let r = track_lk(&tiny, &tiny, &[[4.0, 3.0]], &p);
        assert_eq!(r.len(), 1);
        // points at the very border are handled (clamped sampling), not a panic
        let r = track_lk(&tex, &tex, &[[0.0, 0.0], [99.9, 79.9]], &p);
        assert_eq!(r.len(), 2);
    }
}
