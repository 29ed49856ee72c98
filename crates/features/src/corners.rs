//! Harris / Shi-Tomasi corners with sub-pixel refinement, as OpenCV's `goodFeaturesToTrack` and
//! `cornerSubPix` compute them (DS-SLAM's and the paper's geometry module call those two).

use crate::imgops::{reflect101, simd_fn};
use crate::valid;
use stillpoint_image::Gray8;

/// Corner detection settings. `Default` = the paper's geometry module (DS-SLAM's
/// `goodFeaturesToTrack(.., 1000, 0.01, 8, Mat(), 3, true, 0.04)` and
/// `cornerSubPix(.., Size(10, 10), Size(-1, -1), TermCriteria(EPS + COUNT, 20, 0.03))`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct CornerParams {
    /// Most corners returned, strongest first (paper: 1000).
    pub max_corners: usize,
    /// Corners weaker than this fraction of the strongest response are dropped (paper: 0.01).
    pub quality_level: f32,
    /// Smallest distance between returned corners in pixels (paper: 8).
    pub min_distance: f32,
    /// Side of the window summing the gradient products (paper: 3).
    pub block_size: usize,
    /// Harris response (true, paper) or Shi-Tomasi minimum eigenvalue (false).
    pub use_harris: bool,
    /// Harris `k` (paper: 0.04).
    pub harris_k: f32,
    /// Half-size of the sub-pixel window (OpenCV `winSize` 10 → 21 x 21 px; paper: 10x10);
    /// 0 switches refinement off.
    pub subpix_half_window: usize,
    /// Sub-pixel iterations (paper: 20).
    pub subpix_max_iterations: usize,
    /// Sub-pixel stop when the update is below this many pixels (paper: 0.03).
    pub subpix_epsilon: f32,
}

impl Default for CornerParams {
    fn default() -> Self {
        Self {
            max_corners: 1000,
            quality_level: 0.01,
            min_distance: 8.0,
            block_size: 3,
            use_harris: true,
            harris_k: 0.04,
            subpix_half_window: 10,
            subpix_max_iterations: 20,
            subpix_epsilon: 0.03,
        }
    }
}

/// Buffers of [`corner_response`], kept per thread by [`good_features_to_track`]: the response
/// (one f32 image, 1.2 MB at 640x480, whose fresh pages cost about as much as the arithmetic)
/// and `block` rows of each gradient product's horizontal box sums. Every buffer is written
/// before it is read, so reuse changes no result.
#[derive(Default)]
struct ResponseScratch {
    resp: Vec<f32>,
    /// Horizontal box sums of xx, xy, yy for `block` rows, row `r` in slot `r % block`.
    rings: [Vec<f32>; 3],
    /// The image row each ring slot holds (`usize::MAX`: none yet).
    ring_rows: Vec<usize>,
}

/// `v` with `n` elements, reusing its buffer (new ones come zeroed from the allocator).
fn sized(v: &mut Vec<f32>, n: usize) -> &mut [f32] {
    if v.len() != n {
        *v = vec![0.0; n];
    }
    v
}

/// One image row's Sobel products, each box-summed along the row: the buffers of
/// [`corner_response`]'s row step.
struct SobelRows {
    /// [1 2 1] vertical smoothing, for dx (one sample of border each side).
    sm: Vec<i16>,
    /// Vertical difference, for dy (the same border).
    df: Vec<i16>,
    /// gx², gx gy, gy² of the row.
    products: [Vec<f32>; 3],
    /// A product row with `block` samples of reflect-101 border around it.
    pad: Vec<f32>,
}

impl SobelRows {
    /// Row `y`'s Sobel products (gradients times `scale`), each box-summed along the row over
    /// the block (as many samples as `pad` is wider than the row; reflect-101) into `out`. Inlined
    /// into its caller, so that it runs with the caller's vector extensions (a closure there
    /// was compiled without them).
    #[inline(always)]
    fn fill(&mut self, img: &Gray8, y: usize, scale: f32, out: [&mut [f32]; 3]) {
        let (w, h) = (img.width, img.height);
        let block = self.pad.len() - w;
        let half = (block / 2) as isize;
        let (sm, df) = (&mut self.sm, &mut self.df);
        let up = img.row(reflect101(y as isize - 1, h));
        let mid = img.row(y);
        let down = img.row(reflect101(y as isize + 1, h));
        {
            let (s, d) = (&mut sm[1..w + 1], &mut df[1..w + 1]);
            for x in 0..w {
                s[x] = up[x] as i16 + 2 * mid[x] as i16 + down[x] as i16;
                d[x] = down[x] as i16 - up[x] as i16;
            }
        }
        let (l, r) = (reflect101(-1, w) + 1, reflect101(w as isize, w) + 1);
        sm[0] = sm[l];
        df[0] = df[l];
        sm[w + 1] = sm[r];
        df[w + 1] = df[r];
        let [pxx, pxy, pyy] = &mut self.products;
        for x in 0..w {
            let gx = (sm[x + 2] - sm[x]) as f32 * scale;
            let gy = (df[x] + 2 * df[x + 1] + df[x + 2]) as f32 * scale;
            pxx[x] = gx * gx;
            pxy[x] = gx * gy;
            pyy[x] = gy * gy;
        }
        let pad = &mut self.pad;
        for (row, out) in self.products.iter().zip(out) {
            // reflect-101 only on the `half` border samples; the middle is a copy
            let hb = half as usize;
            pad[hb..hb + w].copy_from_slice(row);
            for i in (0..hb).chain(hb + w..w + block) {
                pad[i] = row[reflect101(i as isize - half, w)];
            }
            out.copy_from_slice(&pad[..w]);
            // shifted whole-row adds (vectorised), not a small sum per pixel
            for d in 1..block {
                for (o, &v) in out.iter_mut().zip(&pad[d..d + w]) {
                    *o += v;
                }
            }
        }
    }
}

simd_fn! {
/// Corner response of every pixel into `s.resp`: Sobel 3x3 gradients (scaled like OpenCV's
/// `cornerHarris` on 8-bit input), products summed over `block` x `block` (reflect-101), then
/// Harris or min-eig.
fn corner_response(img: &Gray8, block: usize, harris: bool, k: f32, s: &mut ResponseScratch) {
    let (w, h) = (img.width, img.height);
    let scale = 1.0 / (4.0 * block as f32 * 255.0);
    let half = (block / 2) as isize;
    let ResponseScratch {
        resp,
        rings,
        ring_rows,
    } = s;
    let resp = sized(resp, w * h);
    let [rxx, rxy, ryy] = rings;
    let (rxx, rxy, ryy) = (sized(rxx, block * w), sized(rxy, block * w), sized(ryy, block * w));
    ring_rows.clear();
    ring_rows.resize(block, usize::MAX);
    let mut sobel = SobelRows {
        sm: vec![0i16; w + 2],
        df: vec![0i16; w + 2],
        products: [vec![0f32; w], vec![0f32; w], vec![0f32; w]],
        pad: vec![0f32; w + block],
    };
    let mut sums = [vec![0f32; w], vec![0f32; w], vec![0f32; w]];
    // Unnormalised box sums over block x block, a row at a time: the rows output row `y` adds
    // (reflect-101) lie within `block` consecutive rows, so `r % block` never collides.
    for y in 0..h {
        let rows = |dy: isize| reflect101(y as isize + dy - half, h);
        for dy in 0..block as isize {
            let r = rows(dy);
            let slot = r % block;
            if ring_rows[slot] != r {
                sobel.fill(
                    img,
                    r,
                    scale,
                    [
                        &mut rxx[slot * w..][..w],
                        &mut rxy[slot * w..][..w],
                        &mut ryy[slot * w..][..w],
                    ],
                );
                ring_rows[slot] = r;
            }
        }
        for (sum, ring) in sums.iter_mut().zip([&*rxx, &*rxy, &*ryy]) {
            sum.copy_from_slice(&ring[(rows(0) % block) * w..][..w]);
            for dy in 1..block as isize {
                let r = &ring[(rows(dy) % block) * w..][..w];
                for (o, v) in sum.iter_mut().zip(r) {
                    *o += v;
                }
            }
        }
        let [sa, sb, sc] = &sums;
        let out = &mut resp[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b, c) = (sa[x], sb[x], sc[x]);
            out[x] = if harris {
                a * c - b * b - k * (a + c) * (a + c)
            } else {
                let (a, c) = (a * 0.5, c * 0.5);
                (a + c) - ((a - c) * (a - c) + b * b).sqrt()
            };
        }
    }
}
}

/// Strongest corners of `img` (OpenCV `goodFeaturesToTrack`: response above
/// `quality_level` x max, 3x3 local maxima, strongest first, `min_distance` apart, at most
/// `max_corners`), refined to sub-pixel accuracy with [`corner_sub_pix`]. Blank, tiny or
/// malformed images give no corners. The response buffer (4 bytes per pixel) is kept per
/// thread and reused by the next call.
pub fn good_features_to_track(img: &Gray8, p: &CornerParams) -> Vec<[f32; 2]> {
    if !valid(img) || img.width < 3 || img.height < 3 || p.max_corners == 0 {
        return Vec::new();
    }
    thread_local! {
        static SCRATCH: std::cell::RefCell<ResponseScratch> = Default::default();
    }
    SCRATCH.with(|s| match s.try_borrow_mut() {
        Ok(mut s) => corners_with(img, p, &mut s),
        // not reachable (nothing here calls back in), but never panic
        Err(_) => corners_with(img, p, &mut ResponseScratch::default()),
    })
}

fn corners_with(img: &Gray8, p: &CornerParams, scratch: &mut ResponseScratch) -> Vec<[f32; 2]> {
    let (w, h) = (img.width, img.height);
    corner_response(img, p.block_size.max(1), p.use_harris, p.harris_k, scratch);
    let resp = &scratch.resp;
    let max = resp.iter().copied().fold(0f32, f32::max);
    if max.is_nan() || max <= 0.0 {
        return Vec::new();
    }
    let thr = max * p.quality_level.max(0.0);
    // local maxima of the thresholded response (OpenCV compares with its 3x3 dilation)
    let mut cands: Vec<(f32, u32)> = Vec::new();
    for y in 1..h - 1 {
        let (up, mid, down) = (
            &resp[(y - 1) * w..y * w],
            &resp[y * w..(y + 1) * w],
            &resp[(y + 1) * w..(y + 2) * w],
        );
        for x in 1..w - 1 {
            let v = mid[x];
            if v > thr
                && v >= mid[x - 1]
                && v >= mid[x + 1]
                && v >= up[x - 1]
                && v >= up[x]
                && v >= up[x + 1]
                && v >= down[x - 1]
                && v >= down[x]
                && v >= down[x + 1]
            {
                cands.push((v, (y * w + x) as u32));
            }
        }
    }
    // strongest first; ties: larger address first (OpenCV's greaterThanPtr)
    cands.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(b.1.cmp(&a.1)));
    let mut corners: Vec<[f32; 2]> = Vec::new();
    if p.min_distance >= 1.0 {
        let cell = p.min_distance.round().max(1.0) as usize;
        let (gw, gh) = (w.div_ceil(cell), h.div_ceil(cell));
        let mut grid: Vec<Vec<[f32; 2]>> = vec![Vec::new(); gw * gh];
        let md2 = p.min_distance * p.min_distance;
        for &(_, idx) in &cands {
            let (x, y) = (idx as usize % w, idx as usize / w);
            let (cx, cy) = (x / cell, y / cell);
            let pt = [x as f32, y as f32];
            let mut good = true;
            'search: for yy in cy.saturating_sub(1)..=(cy + 1).min(gh - 1) {
                for xx in cx.saturating_sub(1)..=(cx + 1).min(gw - 1) {
                    for q in &grid[yy * gw + xx] {
                        let (dx, dy) = (q[0] - pt[0], q[1] - pt[1]);
                        if dx * dx + dy * dy < md2 {
                            good = false;
                            break 'search;
                        }
                    }
                }
            }
            if good {
                grid[cy * gw + cx].push(pt);
                corners.push(pt);
                if corners.len() >= p.max_corners {
                    break;
                }
            }
        }
    } else {
        corners.extend(
            cands
                .iter()
                .take(p.max_corners)
                .map(|&(_, i)| [(i as usize % w) as f32, (i as usize / w) as f32]),
        );
    }
    if p.subpix_half_window > 0 {
        corner_sub_pix(
            img,
            &mut corners,
            p.subpix_half_window,
            p.subpix_max_iterations,
            p.subpix_epsilon,
        );
    }
    corners
}

/// The two taps (clamped to `0..n`) and the weight of the second for a bilinear sample at `v`,
/// as [`sample_clamped`] computes them.
#[inline(always)]
fn clamped_taps(v: f32, n: usize) -> (usize, usize, f32) {
    let v0 = v.floor();
    let a = v - v0;
    let i = v0 as isize;
    let last = n as isize - 1;
    (
        i.clamp(0, last) as usize,
        (i + 1).clamp(0, last) as usize,
        a,
    )
}

/// Bilinear sample with replicated borders (OpenCV `getRectSubPix` behaviour at the edge).
#[cfg(test)]
#[inline(always)]
fn sample_clamped(img: &Gray8, x: f32, y: f32) -> f32 {
    let (w, h) = (img.width as isize, img.height as isize);
    let (x0, y0) = (x.floor(), y.floor());
    let (a, b) = (x - x0, y - y0);
    let (x0, y0) = (x0 as isize, y0 as isize);
    let px = |xx: isize, yy: isize| {
        img.data[(yy.clamp(0, h - 1) * w + xx.clamp(0, w - 1)) as usize] as f32
    };
    (1.0 - b) * ((1.0 - a) * px(x0, y0) + a * px(x0 + 1, y0))
        + b * ((1.0 - a) * px(x0, y0 + 1) + a * px(x0 + 1, y0 + 1))
}

simd_fn! {
/// Refine corner positions in place (OpenCV `cornerSubPix` with no dead zone): iterate the
/// point that makes image gradients in a Gaussian-weighted `(2 half_window + 1)²` window
/// orthogonal to the offsets, until the step is below `epsilon` px or `max_iterations`.
/// A point that drifts more than `half_window` away keeps its original position.
pub fn corner_sub_pix(
    img: &Gray8,
    pts: &mut [[f32; 2]],
    half_window: usize,
    max_iterations: usize,
    epsilon: f32,
) {
    if !valid(img) || half_window == 0 {
        return;
    }
    let win = half_window as isize;
    let side = 2 * half_window + 1;
    // gradient lanes per row (side, padded to whole vectors) and the patch row stride: the
    // patch has side + 2 rows and every gradient lane j reads patch columns j..=j + 2
    let gw = side.div_ceil(8) * 8;
    let pst = gw + 8;
    let ps = side + 2;
    let coeff = 1.0 / (half_window * half_window) as f32;
    let mask_1d: Vec<f32> = (-win..=win).map(|i| (-(i * i) as f32 * coeff).exp()).collect();
    // Gaussian weights per lane (zero on the padding lanes) and the lane's x offset
    let mut weight = vec![0f32; side * gw];
    for i in 0..side {
        for j in 0..side {
            weight[i * gw + j] = mask_1d[i] * mask_1d[j];
        }
    }
    let px: Vec<f32> = (0..gw).map(|j| j as f32 - win as f32).collect();
    let mut patch = vec![0f32; ps * pst];
    let mut border_cols = vec![(0usize, 0usize, 0f32); pst];
    let eps2 = (epsilon * epsilon) as f64;
    let (w, h) = (img.width as f32, img.height as f32);
    for pt in pts.iter_mut() {
        let start = *pt;
        let mut c = *pt;
        for _ in 0..max_iterations.max(1) {
            // sample the patch centred on c (1-pixel margin for the gradients)
            let (ox, oy) = (c[0] - (half_window + 1) as f32, c[1] - (half_window + 1) as f32);
            let (fx, fy) = (ox.floor(), oy.floor());
            let (ix, iy) = (fx as isize, fy as isize);
            let (a, b) = (ox - fx, oy - fy);
            let inside = ix >= 0
                && iy >= 0
                && ix + (pst as isize) < img.width as isize
                && iy + (ps as isize) < img.height as isize;
            if inside {
                let wts = [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b];
                for r in 0..ps {
                    let base = (iy as usize + r) * img.width + ix as usize;
                    let r0 = &img.data[base..base + pst + 1];
                    let r1 = &img.data[base + img.width..base + img.width + pst + 1];
                    let out = &mut patch[r * pst..(r + 1) * pst];
                    for k in 0..pst / 8 {
                        let v = bilinear8_u8(r0, r1, k * 8, wts);
                        out[k * 8..k * 8 + 8].copy_from_slice(&v);
                    }
                }
            } else {
                // near the border: `sample_clamped` with its floors and clamps hoisted out of
                // the pixel loop (per column and per row; the same arithmetic)
                for (x, c) in border_cols.iter_mut().enumerate() {
                    *c = clamped_taps(ox + x as f32, img.width);
                }
                for r in 0..ps {
                    let (y0, y1, b) = clamped_taps(oy + r as f32, img.height);
                    let (r0, r1) = (img.row(y0), img.row(y1));
                    for (o, &(x0, x1, a)) in patch[r * pst..(r + 1) * pst].iter_mut().zip(&border_cols) {
                        *o = (1.0 - b) * ((1.0 - a) * r0[x0] as f32 + a * r0[x1] as f32)
                            + b * ((1.0 - a) * r1[x0] as f32 + a * r1[x1] as f32);
                    }
                }
            }
            let sums = SubpixWindow {
                patch: &patch,
                stride: pst,
                side,
                lanes: gw,
                weight: &weight,
                px: &px,
            };
            let [sa, sb, sc, bb1, bb2] = subpix_sums(&sums);
            let det = sa * sc - sb * sb;
            if det.abs() <= f64::EPSILON * f64::EPSILON {
                break;
            }
            let s = 1.0 / det;
            let nx = c[0] as f64 + sc * s * bb1 - sb * s * bb2;
            let ny = c[1] as f64 - sb * s * bb1 + sa * s * bb2;
            let err = (nx - c[0] as f64).powi(2) + (ny - c[1] as f64).powi(2);
            c = [nx as f32, ny as f32];
            if !(c[0] >= 0.0 && c[0] < w && c[1] >= 0.0 && c[1] < h) || err <= eps2 {
                break;
            }
        }
        let far = (c[0] - start[0]).abs() > half_window as f32
            || (c[1] - start[1]).abs() > half_window as f32;
        *pt = if far || !c[0].is_finite() || !c[1].is_finite() { start } else { c };
    }
}
}

/// The sampled window of one [`corner_sub_pix`] iteration: `side + 2` rows of `stride`
/// samples (`patch`), gradient lanes per row `lanes` (a multiple of 8, at least `side`),
/// Gaussian weights per lane (`weight`, `side * lanes`, zero on padding lanes) and the x
/// offset of each lane (`px`).
struct SubpixWindow<'a> {
    patch: &'a [f32],
    stride: usize,
    side: usize,
    lanes: usize,
    weight: &'a [f32],
    px: &'a [f32],
}

impl SubpixWindow<'_> {
    fn fits(&self) -> bool {
        self.lanes.is_multiple_of(8)
            && self.lanes + 2 <= self.stride
            && self.patch.len() >= (self.side + 2) * self.stride
            && self.weight.len() >= self.side * self.lanes
            && self.px.len() >= self.lanes
    }
}

/// Sums over the window of `gxx, gxy, gyy, gxx px + gxy py, gxy px + gyy py` (gradients by
/// central differences, Gaussian-weighted), in f64 at the end. The lanes are summed in f32 in
/// registers and added up in a fixed order; the x86-64 AVX2 path is bit-identical to the
/// portable one (same operations, same order, no fused multiply-add).
fn subpix_sums(win: &SubpixWindow) -> [f64; 5] {
    if !win.fits() {
        return [0.0; 5];
    }
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 is available; `fits` bounds every read.
        return unsafe { subpix_sums_avx2(win) };
    }
    subpix_sums_portable(win)
}

fn lanes_total(acc: &[[f32; 8]; 5]) -> [f64; 5] {
    acc.map(|a| a.iter().map(|&v| v as f64).sum())
}

// lanes indexed as in the AVX2 path, on purpose
#[allow(clippy::needless_range_loop)]
fn subpix_sums_portable(win: &SubpixWindow) -> [f64; 5] {
    let mut acc = [[0f32; 8]; 5];
    let half = (win.side / 2) as f32;
    for i in 0..win.side {
        let py = i as f32 - half;
        let up = &win.patch[i * win.stride..];
        let mid = &win.patch[(i + 1) * win.stride..];
        let down = &win.patch[(i + 2) * win.stride..];
        for j in (0..win.lanes).step_by(8) {
            for q in 0..8 {
                let c = j + q;
                let m = win.weight[i * win.lanes + c];
                let (tgx, tgy) = (mid[c + 2] - mid[c], down[c + 1] - up[c + 1]);
                let (gxx, gxy, gyy) = (tgx * tgx * m, tgx * tgy * m, tgy * tgy * m);
                let x = win.px[c];
                acc[0][q] += gxx;
                acc[1][q] += gxy;
                acc[2][q] += gyy;
                acc[3][q] += gxx * x + gxy * py;
                acc[4][q] += gxy * x + gyy * py;
            }
        }
    }
    lanes_total(&acc)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn subpix_sums_avx2(win: &SubpixWindow) -> [f64; 5] {
    use std::arch::x86_64::*;
    let half = (win.side / 2) as f32;
    let (patch, weight, pxs) = (win.patch.as_ptr(), win.weight.as_ptr(), win.px.as_ptr());
    let z = _mm256_setzero_ps();
    let (mut a0, mut a1, mut a2, mut a3, mut a4) = (z, z, z, z, z);
    for i in 0..win.side {
        let py = _mm256_set1_ps(i as f32 - half);
        // SAFETY (all reads): the caller checked `SubpixWindow::fits`.
        unsafe {
            let up = patch.add(i * win.stride);
            let mid = patch.add((i + 1) * win.stride);
            let down = patch.add((i + 2) * win.stride);
            let mut j = 0;
            while j < win.lanes {
                let m = _mm256_loadu_ps(weight.add(i * win.lanes + j));
                let tgx =
                    _mm256_sub_ps(_mm256_loadu_ps(mid.add(j + 2)), _mm256_loadu_ps(mid.add(j)));
                let tgy = _mm256_sub_ps(
                    _mm256_loadu_ps(down.add(j + 1)),
                    _mm256_loadu_ps(up.add(j + 1)),
                );
                let gxx = _mm256_mul_ps(_mm256_mul_ps(tgx, tgx), m);
                let gxy = _mm256_mul_ps(_mm256_mul_ps(tgx, tgy), m);
                let gyy = _mm256_mul_ps(_mm256_mul_ps(tgy, tgy), m);
                let x = _mm256_loadu_ps(pxs.add(j));
                a0 = _mm256_add_ps(a0, gxx);
                a1 = _mm256_add_ps(a1, gxy);
                a2 = _mm256_add_ps(a2, gyy);
                let t3 = _mm256_add_ps(_mm256_mul_ps(gxx, x), _mm256_mul_ps(gxy, py));
                let t4 = _mm256_add_ps(_mm256_mul_ps(gxy, x), _mm256_mul_ps(gyy, py));
                a3 = _mm256_add_ps(a3, t3);
                a4 = _mm256_add_ps(a4, t4);
                j += 8;
            }
        }
    }
    let acc = [a0, a1, a2, a3, a4].map(|v| {
        let mut out = [0f32; 8];
        // SAFETY: `out` holds 8 floats.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        out
    });
    lanes_total(&acc)
}

/// Bilinear sample of 8 lanes at columns `c..c + 8` between the 8-bit rows `r0`, `r1`.
#[inline(always)]
fn bilinear8_u8(r0: &[u8], r1: &[u8], c: usize, wts: [f32; 4]) -> [f32; 8] {
    let [w00, w01, w10, w11] = wts;
    let (a, b) = (&r0[c..c + 9], &r1[c..c + 9]);
    let (mut fa, mut fb) = ([0f32; 9], [0f32; 9]);
    for q in 0..9 {
        fa[q] = a[q] as f32;
        fb[q] = b[q] as f32;
    }
    let mut o = [0f32; 8];
    for q in 0..8 {
        o[q] = w00 * fa[q] + w01 * fa[q + 1] + w10 * fb[q] + w11 * fb[q + 1];
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The response the row-at-a-time box sums must reproduce bit for bit: whole product images,
    /// summed along each row and then down each column in the same order.
    fn response_by_whole_images(img: &Gray8, block: usize, harris: bool, k: f32) -> Vec<f32> {
        let (w, h) = (img.width, img.height);
        let scale = 1.0 / (4.0 * block as f32 * 255.0);
        let px = |x: isize, y: isize| img.data[reflect101(y, h) * w + reflect101(x, w)] as i16;
        let half = (block / 2) as isize;
        let mut prods = vec![[0f32; 3]; w * h];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let sm = |x| px(x, y - 1) + 2 * px(x, y) + px(x, y + 1);
                let df = |x| px(x, y + 1) - px(x, y - 1);
                let gx = (sm(x + 1) - sm(x - 1)) as f32 * scale;
                let gy = (df(x - 1) + 2 * df(x) + df(x + 1)) as f32 * scale;
                prods[y as usize * w + x as usize] = [gx * gx, gx * gy, gy * gy];
            }
        }
        let mut rows = vec![[0f32; 3]; w * h];
        for y in 0..h {
            for x in 0..w as isize {
                let mut acc = prods[y * w + reflect101(x - half, w)];
                for d in 1..block as isize {
                    let p = prods[y * w + reflect101(x + d - half, w)];
                    (0..3).for_each(|c| acc[c] += p[c]);
                }
                rows[y * w + x as usize] = acc;
            }
        }
        (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, (i / w) as isize);
                let mut acc = rows[reflect101(y - half, h) * w + x];
                for d in 1..block as isize {
                    let p = rows[reflect101(y + d - half, h) * w + x];
                    (0..3).for_each(|c| acc[c] += p[c]);
                }
                let [a, b, c] = acc;
                if harris {
                    a * c - b * b - k * (a + c) * (a + c)
                } else {
                    let (a, c) = (a * 0.5, c * 0.5);
                    (a + c) - ((a - c) * (a - c) + b * b).sqrt()
                }
            })
            .collect()
    }

    #[test]
    fn row_at_a_time_box_sums_equal_whole_image_ones_bit_for_bit() {
        for (w, h) in [(37, 29), (5, 3), (3, 7)] {
            let mut img = Gray8::new(w, h, 0);
            for y in 0..h {
                for x in 0..w {
                    img.set(x, y, ((x * 73 + y * 151 + x * y * 7) % 251) as u8);
                }
            }
            for block in 1..=6 {
                for harris in [true, false] {
                    let mut s = ResponseScratch::default();
                    corner_response(&img, block, harris, 0.04, &mut s);
                    let want = response_by_whole_images(&img, block, harris, 0.04);
                    let same = s
                        .resp
                        .iter()
                        .zip(&want)
                        .all(|(a, b)| a.to_bits() == b.to_bits());
                    assert!(same, "{w}x{h} block {block} harris {harris}");
                }
            }
        }
    }

    #[test]
    fn hoisted_border_taps_match_sample_clamped() {
        let mut img = Gray8::new(37, 23, 0);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = (i * 97 % 251) as u8;
        }
        for &(x, y) in &[
            (-3.7f32, -1.2f32),
            (35.6, 21.9),
            (0.25, 10.5),
            (40.1, 30.3),
            (17.0, 5.0),
        ] {
            let (x0, x1, a) = clamped_taps(x, img.width);
            let (y0, y1, b) = clamped_taps(y, img.height);
            let (r0, r1) = (img.row(y0), img.row(y1));
            let v = (1.0 - b) * ((1.0 - a) * r0[x0] as f32 + a * r0[x1] as f32)
                + b * ((1.0 - a) * r1[x0] as f32 + a * r1[x1] as f32);
            assert_eq!(v, sample_clamped(&img, x, y), "at ({x}, {y})");
        }
    }

    #[test]
    fn subpix_sums_are_the_same_on_every_code_path() {
        let (side, lanes, stride) = (21usize, 24usize, 32usize);
        let mut rng = crate::test_rng::Lcg(11);
        let mut rnd = || rng.unit() * 255.0;
        let patch: Vec<f32> = (0..(side + 2) * stride).map(|_| rnd()).collect();
        let weight: Vec<f32> = (0..side * lanes)
            .map(|i| if i % lanes < side { rnd() / 255.0 } else { 0.0 })
            .collect();
        let px: Vec<f32> = (0..lanes).map(|j| j as f32 - 10.0).collect();
        let win = SubpixWindow {
            patch: &patch,
            stride,
            side,
            lanes,
            weight: &weight,
            px: &px,
        };
        let portable = subpix_sums_portable(&win);
        assert_eq!(subpix_sums(&win), portable);
        assert!(portable[0] > 0.0 && portable[2] > 0.0);
        let short = SubpixWindow {
            patch: &patch[..stride * side],
            ..win
        };
        assert_eq!(subpix_sums(&short), [0.0; 5]);
    }

    /// A blurred checkerboard whose inner corners sit at (x0 + i*sq, y0 + j*sq) exactly.
    fn checker(w: usize, h: usize, sq: f32, x0: f32, y0: f32) -> Gray8 {
        let mut img = Gray8::new(w, h, 0);
        // supersample 8x8 for an anti-aliased edge at sub-pixel positions
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for sy in 0..8 {
                    for sx in 0..8 {
                        let px = x as f32 + (sx as f32 + 0.5) / 8.0 - 0.5 - x0;
                        let py = y as f32 + (sy as f32 + 0.5) / 8.0 - 0.5 - y0;
                        let cx = (px / sq).floor() as i32;
                        let cy = (py / sq).floor() as i32;
                        s += if (cx + cy).rem_euclid(2) == 0 {
                            200.0
                        } else {
                            40.0
                        };
                    }
                }
                img.set(x, y, (s / 64.0f32).round() as u8);
            }
        }
        img
    }

    #[test]
    fn checkerboard_corners_are_found_to_sub_pixel_accuracy() {
        let (x0, y0, sq) = (20.3, 17.6, 20.0);
        let img = checker(160, 120, sq, x0, y0);
        let pts = good_features_to_track(&img, &CornerParams::default());
        assert!(pts.len() >= 20, "{}", pts.len());
        let mut errs: Vec<f32> = pts
            .iter()
            .filter(|p| p[0] > 12.0 && p[0] < 148.0 && p[1] > 12.0 && p[1] < 108.0)
            .map(|p| {
                let gx = ((p[0] - x0) / sq).round() * sq + x0;
                let gy = ((p[1] - y0) / sq).round() * sq + y0;
                ((p[0] - gx).powi(2) + (p[1] - gy).powi(2)).sqrt()
            })
            .collect();
        errs.sort_by(f32::total_cmp);
        assert!(errs.len() >= 15, "{}", errs.len());
        assert!(
            errs[errs.len() / 2] < 0.1,
            "median {}",
            errs[errs.len() / 2]
        );
    }

    #[test]
    fn min_distance_and_max_corners_hold_before_refinement() {
        let img = checker(200, 200, 9.0, 3.0, 3.0);
        let p = CornerParams {
            max_corners: 30,
            min_distance: 15.0,
            subpix_half_window: 0,
            ..CornerParams::default()
        };
        let pts = good_features_to_track(&img, &p);
        assert_eq!(pts.len(), 30);
        for (i, a) in pts.iter().enumerate() {
            for b in &pts[i + 1..] {
                assert!((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) >= 225.0);
            }
        }
        let st = good_features_to_track(
            &img,
            &CornerParams {
                use_harris: false,
                ..p
            },
        );
        assert_eq!(st.len(), 30);
    }

    #[test]
    fn blank_and_tiny_images_give_no_corners() {
        let p = CornerParams::default();
        assert!(good_features_to_track(&Gray8::new(64, 48, 9), &p).is_empty());
        assert!(good_features_to_track(&Gray8::new(2, 2, 9), &p).is_empty());
        assert!(good_features_to_track(&Gray8::new(0, 0, 9), &p).is_empty());
        // corners near the border of a small image are refined without panicking
        let img = checker(12, 12, 4.0, 1.5, 1.5);
        let pts = good_features_to_track(&img, &p);
        assert!(pts.iter().all(|p| p[0].is_finite() && p[1].is_finite()));
    }
}
