//! Pyramidal Lucas-Kanade tracking, following OpenCV's `calcOpticalFlowPyrLK` (Bouguet's
//! scheme): `pyrDown` pyramids, Scharr gradients of the previous image, per-level Newton steps
//! on a window, minimum-eigenvalue rejection, oscillation damping.

use crate::imgops::{pyr_down_into, reflect101, scharr_into, simd_fn};
use crate::valid;
use stillpoint_image::Gray8;

/// LK settings. `Default` = the paper's geometry module (DS-SLAM's
/// `calcOpticalFlowPyrLK(.., Size(22, 22), 5, TermCriteria(COUNT + EPS, 20, 0.01))`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
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

/// One image prepared for LK: its pyramid as f32 with a border (reflect-101 for the image,
/// zero for the gradients, as OpenCV's `buildOpticalFlowPyramid`), and the Scharr gradients when
/// it is the image tracked *from*. Build once per frame and reuse it for both directions of a
/// forward-backward check, or keep the current frame's pyramid as the next frame's previous one
/// (see [`LkPyramid::rebuild`], which reuses the buffers).
#[derive(Clone, Debug, Default)]
pub struct LkPyramid {
    sizes: Vec<(usize, usize)>,
    /// Border on each side of every level, in pixels.
    border: usize,
    levels: Vec<Vec<f32>>,
    /// Scharr derivatives as i16 (exact; half the memory of f32), zero on the border.
    grads: Vec<(Vec<i16>, Vec<i16>)>,
    /// The 8-bit levels (scratch for `pyrDown`, kept to reuse the allocations).
    gray: Vec<Gray8>,
}

/// Border needed for a window of `win` pixels: a window corner may sit `win` px left of the
/// image (OpenCV's bound), and a padded row reads `padded(win) + 1` samples from its corner.
fn border_for(win: usize) -> usize {
    padded(win) + 2
}

impl LkPyramid {
    /// Build the pyramid of `img` (with gradients) for the settings `p`.
    pub fn new(img: &Gray8, p: &LkParams) -> Self {
        let mut out = Self::default();
        out.build(img, p, true);
        out
    }

    /// Rebuild in place for a new image (same result as [`LkPyramid::new`]), reusing the
    /// buffers: a tracker that keeps one pyramid per frame allocates nothing after the first.
    pub fn rebuild(&mut self, img: &Gray8, p: &LkParams) {
        self.build(img, p, true);
    }

    fn build(&mut self, img: &Gray8, p: &LkParams, with_gradients: bool) {
        self.sizes.clear();
        if !valid(img) {
            self.levels.clear();
            self.grads.clear();
            return;
        }
        let win = p.window.max(3);
        let bd = border_for(win);
        self.border = bd;
        let mut n = 0;
        for level in 0..=p.max_level {
            let (w, h) = if level == 0 {
                (img.width, img.height)
            } else {
                (
                    self.sizes[level - 1].0.div_ceil(2),
                    self.sizes[level - 1].1.div_ceil(2),
                )
            };
            if level > 0 {
                // OpenCV stops when the next level would not exceed the window
                if w <= win || h <= win {
                    break;
                }
                if self.gray.len() < level {
                    self.gray.push(Gray8::new(0, 0, 0));
                }
                let (done, rest) = self.gray.split_at_mut(level - 1);
                let src = if level == 1 { img } else { &done[level - 2] };
                pyr_down_into(src, &mut rest[0]);
            }
            let cur = if level == 0 {
                img
            } else {
                &self.gray[level - 1]
            };
            self.sizes.push((w, h));
            let (sw, sh) = (w + 2 * bd, h + 2 * bd);
            if self.levels.len() <= level {
                self.levels.push(Vec::new());
            }
            fill_padded(cur, bd, &mut self.levels[level]);
            if with_gradients {
                if self.grads.len() <= level {
                    self.grads.push((Vec::new(), Vec::new()));
                }
                let (dx, dy) = &mut self.grads[level];
                // the border stays zero: only the interior is ever written, so a buffer of
                // the right size is reused as it is and a new one comes zeroed from the
                // allocator (no memset pass over the whole level)
                for d in [&mut *dx, &mut *dy] {
                    if d.len() != sw * sh {
                        *d = vec![0; sw * sh];
                    }
                }
                scharr_into(cur, dx, dy, sw, bd * sw + bd);
            }
            n += 1;
        }
        self.levels.truncate(n);
        self.grads.truncate(if with_gradients { n } else { 0 });
    }

    /// Number of levels built.
    pub fn levels(&self) -> usize {
        self.sizes.len()
    }

    /// Size of level 0.
    pub fn size(&self) -> (usize, usize) {
        self.sizes.first().copied().unwrap_or((0, 0))
    }

    /// Zero-mean normalised cross-correlation of the `2 half + 1` square patches around `a` in
    /// this image and around `b` in `other` (level 0, bilinear samples): 1 for the same
    /// texture, whatever its brightness and contrast. `None` where a patch leaves its image or
    /// either patch is flat (standard deviation under 1 grey level).
    ///
    /// ```
    /// use stillpoint_features::{LkParams, LkPyramid};
    /// use stillpoint_image::Gray8;
    /// let mut a = Gray8::new(64, 64, 0);
    /// let mut b = Gray8::new(64, 64, 0);
    /// for y in 0..64 { for x in 0..64 {
    ///     let v = |x: usize, y: usize| ((x * 37 + y * 91) % 97) as u8;
    ///     a.set(x, y, v(x, y));
    ///     b.set(x, y, v(x + 2, y).saturating_add(40)); // moved 2 px left, brighter
    /// }}
    /// let p = LkParams::default();
    /// let (pa, pb) = (LkPyramid::new(&a, &p), LkPyramid::new(&b, &p));
    /// assert!(pa.patch_ncc([30.0, 30.0], &pb, [28.0, 30.0], 3).unwrap() > 0.99);
    /// assert!(pa.patch_ncc([30.0, 30.0], &pb, [30.0, 30.0], 3).unwrap() < 0.5);
    /// assert_eq!(pa.patch_ncc([1.0, 30.0], &pb, [30.0, 30.0], 3), None); // off the image
    /// ```
    pub fn patch_ncc(
        &self,
        a: [f32; 2],
        other: &LkPyramid,
        b: [f32; 2],
        half: usize,
    ) -> Option<f32> {
        let pa = self.patch(a, half)?;
        let pb = other.patch(b, half)?;
        let n = pa.len() as f32;
        let (ma, mb) = (pa.iter().sum::<f32>() / n, pb.iter().sum::<f32>() / n);
        let (mut sab, mut saa, mut sbb) = (0.0f32, 0.0f32, 0.0f32);
        for (x, y) in pa.iter().zip(&pb) {
            let (da, db) = (x - ma, y - mb);
            sab += da * db;
            saa += da * da;
            sbb += db * db;
        }
        (saa >= n && sbb >= n).then(|| sab / (saa * sbb).sqrt())
    }

    /// The level-0 samples of the `2 half + 1` square patch around `c` (bilinear), or `None`
    /// where it leaves the image.
    fn patch(&self, c: [f32; 2], half: usize) -> Option<Vec<f32>> {
        let (w, h) = self.size();
        let level = self.levels.first()?;
        let r = half as f32;
        let inside = |v: f32, n: usize| v.is_finite() && v - r >= 0.0 && v + r <= (n - 1) as f32;
        if !(inside(c[0], w) && inside(c[1], h)) {
            return None;
        }
        let sw = w + 2 * self.border;
        let (x0, y0) = (c[0] - r, c[1] - r);
        let (ix, iy) = (x0.floor(), y0.floor());
        let (fx, fy) = (x0 - ix, y0 - iy);
        let (ix, iy) = (ix as usize + self.border, iy as usize + self.border);
        let side = 2 * half + 1;
        let mut out = Vec::with_capacity(side * side);
        for dy in 0..side {
            let row = (iy + dy) * sw + ix;
            for dx in 0..side {
                let i = row + dx;
                let top = level[i] + fx * (level[i + 1] - level[i]);
                let bottom = level[i + sw] + fx * (level[i + sw + 1] - level[i + sw]);
                out.push(top + fy * (bottom - top));
            }
        }
        Some(out)
    }
}

/// `img` as f32 with a reflect-101 border of `bd` pixels on each side, into `out`.
fn fill_padded(img: &Gray8, bd: usize, out: &mut Vec<f32>) {
    let (w, h) = (img.width, img.height);
    let sw = w + 2 * bd;
    // every sample is written below, so only a new size needs a (zeroed, not memset) buffer
    if out.len() != sw * (h + 2 * bd) {
        *out = vec![0.0; sw * (h + 2 * bd)];
    }
    let cols: Vec<usize> = (0..sw)
        .map(|i| reflect101(i as isize - bd as isize, w))
        .collect();
    for (r, row) in out.chunks_exact_mut(sw).enumerate() {
        let src = img.row(reflect101(r as isize - bd as isize, h));
        let (left, rest) = row.split_at_mut(bd);
        let (mid, right) = rest.split_at_mut(w);
        for (o, &v) in mid.iter_mut().zip(src) {
            *o = v as f32;
        }
        for (o, &c) in left.iter_mut().zip(&cols[..bd]) {
            *o = src[c] as f32;
        }
        for (o, &c) in right.iter_mut().zip(&cols[bd + w..]) {
            *o = src[c] as f32;
        }
    }
}

/// Track `pts` from `prev` into `cur`; `None` where tracking failed (flat window, left the
/// image, NaN input). Same-size images required (else all `None`). Builds both pyramids into
/// buffers kept per thread (about 16 bytes per pixel over all levels, reused by the next call),
/// so only the first call allocates.
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
    thread_local! {
        /// The two pyramids of the last call on this thread, kept so that their buffers
        /// (about 12 bytes per pixel) are reused: fresh pages cost more than the tracking
        /// itself on a 640x480 frame. Only the allocations are reused, never the content.
        static SCRATCH: std::cell::RefCell<(LkPyramid, LkPyramid)> = Default::default();
    }
    SCRATCH.with(|s| match s.try_borrow_mut() {
        Ok(mut s) => {
            let (a, b) = &mut *s;
            a.build(prev, p, true);
            b.build(cur, p, false);
            track_lk_pyramids(a, b, pts, p)
        }
        // not reachable (tracking does not call back into track_lk), but never panic
        Err(_) => {
            let (mut a, mut b) = (LkPyramid::default(), LkPyramid::default());
            a.build(prev, p, true);
            b.build(cur, p, false);
            track_lk_pyramids(&a, &b, pts, p)
        }
    })
}

/// [`track_lk`] on prepared pyramids (`prev` must have been built with [`LkPyramid::new`] or
/// [`LkPyramid::rebuild`], both with a window at least `p.window`).
pub fn track_lk_pyramids(
    prev: &LkPyramid,
    cur: &LkPyramid,
    pts: &[[f32; 2]],
    p: &LkParams,
) -> Vec<Option<[f32; 2]>> {
    let win = p.window.max(3);
    if prev.levels.is_empty()
        || prev.grads.len() != prev.levels.len()
        || prev.sizes.first() != cur.sizes.first()
        || prev.border < border_for(win)
        || cur.border < border_for(win)
        || prev.border != cur.border
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

#[inline(always)]
fn weights(a: f32, b: f32) -> [f32; 4] {
    [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b]
}

/// A `rows` x `width` window of a bordered level (`width` a multiple of 8): sample (r, c) is
/// `src[base + r * stride + c]`; bilinear sampling reads one more row and column.
struct Window<'a> {
    src: &'a [f32],
    base: usize,
    stride: usize,
    rows: usize,
    width: usize,
}

impl Window<'_> {
    /// The window and its extra row and column lie inside `src`, and `rows * width` samples
    /// fit the patch buffers of length `patch_len`.
    fn fits(&self, patch_len: usize) -> bool {
        self.rows > 0
            && self.width.is_multiple_of(8)
            && self.rows * self.width <= patch_len
            && self.base + self.rows * self.stride + self.width < self.src.len()
    }
}

/// Lanes of an 8-lane sum, added in a fixed order (the same in every code path).
#[inline(always)]
fn lane_sum(v: &[f32; 8]) -> f32 {
    ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]))
}

/// The right-hand side of the LK step: sums over the window of `(J - I) Ix` and `(J - I) Iy`,
/// `J` sampled bilinearly (weights `jw`) from `j`, `I`, `Ix`, `Iy` the prepared patches (row
/// stride `j.width`). Even and odd rows go to separate 8-lane sums so consecutive adds do not
/// wait for each other; the x86-64 AVX2 path is bit-identical to the portable one (same
/// operations in the same order, no fused multiply-add).
fn mismatch_sums(j: &Window, jw: [f32; 4], ip: &[f32], gx: &[f32], gy: &[f32]) -> [f32; 2] {
    let patch = ip.len().min(gx.len()).min(gy.len());
    if !j.fits(patch) {
        return [0.0; 2];
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is available; `fits` bounds every read.
        return unsafe { mismatch_sums_avx2(j, jw, ip, gx, gy) };
    }
    mismatch_sums_portable(j, jw, ip, gx, gy)
}

// lanes indexed as in the AVX2 path, on purpose
#[allow(clippy::needless_range_loop)]
fn mismatch_sums_portable(
    j: &Window,
    jw: [f32; 4],
    ip: &[f32],
    gx: &[f32],
    gy: &[f32],
) -> [f32; 2] {
    // [x even rows, y even rows, x odd rows, y odd rows]
    let mut acc = [[0f32; 8]; 4];
    for r in 0..j.rows {
        let o = j.base + r * j.stride;
        let (r0, r1) = (&j.src[o..], &j.src[o + j.stride..]);
        let k = r * j.width;
        let a = (r % 2) * 2;
        for c in (0..j.width).step_by(8) {
            for l in 0..8 {
                let x = c + l;
                let v = jw[0] * r0[x] + jw[1] * r0[x + 1] + jw[2] * r1[x] + jw[3] * r1[x + 1];
                let d = v - ip[k + x];
                acc[a][l] += d * gx[k + x];
                acc[a + 1][l] += d * gy[k + x];
            }
        }
    }
    [
        lane_sum(&acc[0]) + lane_sum(&acc[2]),
        lane_sum(&acc[1]) + lane_sum(&acc[3]),
    ]
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn mismatch_sums_avx2(
    j: &Window,
    jw: [f32; 4],
    ip: &[f32],
    gx: &[f32],
    gy: &[f32],
) -> [f32; 2] {
    use std::arch::x86_64::*;
    let w = jw.map(|v| _mm256_set1_ps(v));
    let mut acc = [_mm256_setzero_ps(); 4];
    let (src, ip, gx, gy) = (j.src.as_ptr(), ip.as_ptr(), gx.as_ptr(), gy.as_ptr());
    // SAFETY (all reads): the caller checked `Window::fits`.
    macro_rules! row {
        ($r:expr, $x:expr, $y:expr) => {{
            let p0 = src.add(j.base + $r * j.stride);
            let p1 = p0.add(j.stride);
            let k = $r * j.width;
            let mut c = 0;
            while c < j.width {
                let mut v = _mm256_mul_ps(w[0], _mm256_loadu_ps(p0.add(c)));
                v = _mm256_add_ps(v, _mm256_mul_ps(w[1], _mm256_loadu_ps(p0.add(c + 1))));
                v = _mm256_add_ps(v, _mm256_mul_ps(w[2], _mm256_loadu_ps(p1.add(c))));
                v = _mm256_add_ps(v, _mm256_mul_ps(w[3], _mm256_loadu_ps(p1.add(c + 1))));
                let d = _mm256_sub_ps(v, _mm256_loadu_ps(ip.add(k + c)));
                $x = _mm256_add_ps($x, _mm256_mul_ps(d, _mm256_loadu_ps(gx.add(k + c))));
                $y = _mm256_add_ps($y, _mm256_mul_ps(d, _mm256_loadu_ps(gy.add(k + c))));
                c += 8;
            }
        }};
    }
    let [mut xe, mut ye, mut xo, mut yo] = acc;
    let mut r = 0;
    while r + 1 < j.rows {
        unsafe {
            row!(r, xe, ye);
            row!(r + 1, xo, yo);
        }
        r += 2;
    }
    if r < j.rows {
        unsafe { row!(r, xe, ye) };
    }
    acc = [xe, ye, xo, yo];
    let lanes = acc.map(|v| {
        let mut out = [0f32; 8];
        // SAFETY: `out` holds 8 floats.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        out
    });
    [
        lane_sum(&lanes[0]) + lane_sum(&lanes[2]),
        lane_sum(&lanes[1]) + lane_sum(&lanes[3]),
    ]
}

/// The patches of the image tracked from, sampled once per level: intensities and the two
/// gradients (`rows * width` each, gradients zero past the window).
struct Patches<'a> {
    ip: &'a mut [f32],
    gx: &'a mut [f32],
    gy: &'a mut [f32],
}

/// Sample the window of the previous level (`i`) and of its gradients (`dx`, `dy`, laid out
/// like `i.src`) bilinearly with weights `wts` into `out`, gradients multiplied by `lane_mask`
/// (1 inside the window, 0 in the padding lanes), and return the gradient matrix sums
/// `[Σ Ix², Σ Ix Iy, Σ Iy²]`. Same scheme and guarantees as [`mismatch_sums`].
fn prepare_patch(
    i: &Window,
    dx: &[i16],
    dy: &[i16],
    wts: [f32; 4],
    lane_mask: &[f32],
    out: Patches,
) -> [f32; 3] {
    let patch = out.ip.len().min(out.gx.len()).min(out.gy.len());
    if !i.fits(patch)
        || dx.len() < i.src.len()
        || dy.len() < i.src.len()
        || lane_mask.len() < i.width
    {
        return [0.0; 3];
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is available; the checks above bound every read and write.
        return unsafe { prepare_patch_avx2(i, dx, dy, wts, lane_mask, out) };
    }
    prepare_patch_portable(i, dx, dy, wts, lane_mask, out)
}

// lanes indexed as in the AVX2 path, on purpose
#[allow(clippy::needless_range_loop)]
fn prepare_patch_portable(
    i: &Window,
    dx: &[i16],
    dy: &[i16],
    wts: [f32; 4],
    lane_mask: &[f32],
    out: Patches,
) -> [f32; 3] {
    let w = wts;
    // [xx, xy, yy] of even rows, then of odd rows
    let mut acc = [[0f32; 8]; 6];
    for r in 0..i.rows {
        let o = i.base + r * i.stride;
        let s = i.stride;
        let k = r * i.width;
        let a = (r % 2) * 3;
        for c in (0..i.width).step_by(8) {
            for l in 0..8 {
                let x = c + l;
                let taps = [o + x, o + x + 1, o + s + x, o + s + x + 1];
                let at = |v: [f32; 4]| w[0] * v[0] + w[1] * v[1] + w[2] * v[2] + w[3] * v[3];
                let xs = at(taps.map(|j| dx[j] as f32)) * lane_mask[x];
                let ys = at(taps.map(|j| dy[j] as f32)) * lane_mask[x];
                out.ip[k + x] = at(taps.map(|j| i.src[j]));
                out.gx[k + x] = xs;
                out.gy[k + x] = ys;
                acc[a][l] += xs * xs;
                acc[a + 1][l] += xs * ys;
                acc[a + 2][l] += ys * ys;
            }
        }
    }
    [
        lane_sum(&acc[0]) + lane_sum(&acc[3]),
        lane_sum(&acc[1]) + lane_sum(&acc[4]),
        lane_sum(&acc[2]) + lane_sum(&acc[5]),
    ]
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn prepare_patch_avx2(
    i: &Window,
    dx: &[i16],
    dy: &[i16],
    wts: [f32; 4],
    lane_mask: &[f32],
    out: Patches,
) -> [f32; 3] {
    use std::arch::x86_64::*;
    let w = wts.map(|v| _mm256_set1_ps(v));
    let (src, dx, dy, mask) = (i.src.as_ptr(), dx.as_ptr(), dy.as_ptr(), lane_mask.as_ptr());
    let (ip, gx, gy) = (
        out.ip.as_mut_ptr(),
        out.gx.as_mut_ptr(),
        out.gy.as_mut_ptr(),
    );
    // SAFETY (all reads and writes): the caller checked the window and the buffers.
    // eight i16 as f32 (exact)
    macro_rules! ld16 {
        ($p:expr) => {
            _mm256_cvtepi32_ps(_mm256_cvtepi16_epi32(_mm_loadu_si128($p.cast::<__m128i>())))
        };
    }
    macro_rules! bilinear {
        ($p:expr, $o:expr, $ld:ident) => {{
            let p0 = $p.add($o);
            let p1 = p0.add(i.stride);
            let mut v = _mm256_mul_ps(w[0], $ld!(p0));
            v = _mm256_add_ps(v, _mm256_mul_ps(w[1], $ld!(p0.add(1))));
            v = _mm256_add_ps(v, _mm256_mul_ps(w[2], $ld!(p1)));
            _mm256_add_ps(v, _mm256_mul_ps(w[3], $ld!(p1.add(1))))
        }};
    }
    macro_rules! ld32 {
        ($p:expr) => {
            _mm256_loadu_ps($p)
        };
    }
    macro_rules! row {
        ($r:expr, $xx:expr, $xy:expr, $yy:expr) => {{
            let o = i.base + $r * i.stride;
            let k = $r * i.width;
            let mut c = 0;
            while c < i.width {
                let m = _mm256_loadu_ps(mask.add(c));
                let xs = _mm256_mul_ps(bilinear!(dx, o + c, ld16), m);
                let ys = _mm256_mul_ps(bilinear!(dy, o + c, ld16), m);
                _mm256_storeu_ps(ip.add(k + c), bilinear!(src, o + c, ld32));
                _mm256_storeu_ps(gx.add(k + c), xs);
                _mm256_storeu_ps(gy.add(k + c), ys);
                $xx = _mm256_add_ps($xx, _mm256_mul_ps(xs, xs));
                $xy = _mm256_add_ps($xy, _mm256_mul_ps(xs, ys));
                $yy = _mm256_add_ps($yy, _mm256_mul_ps(ys, ys));
                c += 8;
            }
        }};
    }
    let z = _mm256_setzero_ps();
    let (mut xxe, mut xye, mut yye, mut xxo, mut xyo, mut yyo) = (z, z, z, z, z, z);
    let mut r = 0;
    while r + 1 < i.rows {
        unsafe {
            row!(r, xxe, xye, yye);
            row!(r + 1, xxo, xyo, yyo);
        }
        r += 2;
    }
    if r < i.rows {
        unsafe { row!(r, xxe, xye, yye) };
    }
    let lanes = [xxe, xye, yye, xxo, xyo, yyo].map(|v| {
        let mut out = [0f32; 8];
        // SAFETY: `out` holds 8 floats.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        out
    });
    [
        lane_sum(&lanes[0]) + lane_sum(&lanes[3]),
        lane_sum(&lanes[1]) + lane_sum(&lanes[4]),
        lane_sum(&lanes[2]) + lane_sum(&lanes[5]),
    ]
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
    let bd = prev.border as isize;
    let half = (win as f32 - 1.0) * 0.5;
    let n_levels = prev.levels.len().min(cur.levels.len());
    let eps2 = p.epsilon * p.epsilon;
    // OpenCV's units: gradients are raw Scharr, products scaled by 2^-20, intensities x 32
    let flt_scale = 1.0 / (1u32 << 20) as f32;
    // lanes past the window carry zero gradients, so they add nothing to any sum
    let lane_mask: Vec<f32> = (0..pw).map(|c| if c < win { 1.0 } else { 0.0 }).collect();
    let mut ip = vec![0f32; win * pw];
    let mut gx = vec![0f32; win * pw];
    let mut gy = vec![0f32; win * pw];
    // per-lane sums (float sums are not reassociated, so each column keeps its own)
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
            let stride = w + 2 * bd as usize;
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
            let (dxl, dyl) = &prev.grads[level];
            let il = &prev.levels[level];
            let base = (iy + bd) as usize * stride + (ix + bd) as usize;
            let win_i = Window {
                src: il,
                base,
                stride,
                rows: win,
                width: pw,
            };
            let patches = Patches {
                ip: &mut ip,
                gx: &mut gx,
                gy: &mut gy,
            };
            let [a11, a12, a22] = prepare_patch(&win_i, dxl, dyl, wts, &lane_mask, patches);
            let (a11, a12, a22) = (a11 * flt_scale, a12 * flt_scale, a22 * flt_scale);
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
                let jbase = (jy + bd) as usize * stride + (jx + bd) as usize;
                let win_j = Window {
                    src: jl,
                    base: jbase,
                    stride,
                    rows: win,
                    width: pw,
                };
                let [b1, b2] = mismatch_sums(&win_j, jw, &ip, &gx, &gy);
                // OpenCV scales intensities by 32 and products by 2^-20
                let b1 = b1 * 32.0 * flt_scale;
                let b2 = b2 * 32.0 * flt_scale;
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
    fn mismatch_sums_are_the_same_on_every_code_path() {
        let (stride, rows, width) = (40usize, 22usize, 24usize);
        let mut rng = crate::test_rng::Lcg(7);
        let mut rnd = || rng.unit() * 255.0;
        let src: Vec<f32> = (0..stride * 30).map(|_| rnd()).collect();
        let ip: Vec<f32> = (0..rows * width).map(|_| rnd()).collect();
        let gx: Vec<f32> = (0..rows * width).map(|_| rnd() - 128.0).collect();
        let gy: Vec<f32> = (0..rows * width).map(|_| rnd() - 128.0).collect();
        let win = Window {
            src: &src,
            base: 3 * stride + 5,
            stride,
            rows,
            width,
        };
        let jw = weights(0.3, 0.71);
        let portable = mismatch_sums_portable(&win, jw, &ip, &gx, &gy);
        assert_eq!(mismatch_sums(&win, jw, &ip, &gx, &gy), portable);
        assert!(portable.iter().all(|v| v.is_finite() && *v != 0.0));
        let (mut pi, mut px, mut py) = (ip.clone(), gx.clone(), gy.clone());
        let (mut qi, mut qx, mut qy) = (ip.clone(), gx.clone(), gy.clone());
        let mask: Vec<f32> = (0..width).map(|c| if c < 22 { 1.0 } else { 0.0 }).collect();
        // gradients laid out like the level
        let dx: Vec<i16> = src.iter().map(|v| (v * 16.0) as i16 - 2000).collect();
        let dy: Vec<i16> = src.iter().rev().map(|v| 1000 - (v * 12.0) as i16).collect();
        let a = prepare_patch_portable(
            &win,
            &dx,
            &dy,
            jw,
            &mask,
            Patches {
                ip: &mut pi,
                gx: &mut px,
                gy: &mut py,
            },
        );
        let b = prepare_patch(
            &win,
            &dx,
            &dy,
            jw,
            &mask,
            Patches {
                ip: &mut qi,
                gx: &mut qx,
                gy: &mut qy,
            },
        );
        assert_eq!(a, b);
        assert!(a[0] > 0.0 && a[2] > 0.0 && a[1].is_finite());
        // padding lanes carry no gradient
        assert!((0..rows).all(|r| px[r * width + 22] == 0.0 && py[r * width + 23] == 0.0));
        assert_eq!((&pi, &px, &py), (&qi, &qx, &qy));
        // a window reaching past the buffer is refused, not read
        let outside = Window {
            base: src.len() - 10,
            ..win
        };
        assert_eq!(mismatch_sums(&outside, jw, &ip, &gx, &gy), [0.0, 0.0]);
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
