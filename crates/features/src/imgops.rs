//! Small image kernels the front-ends need: OpenCV-compatible bilinear resize, 7x7 Gaussian
//! blur, `pyrDown`, Scharr derivatives. Plain loops written so LLVM vectorises them; on x86-64
//! the hot ones are compiled a second time for AVX2 and picked at run time.

use stillpoint_image::Gray8;

/// Define `fn $name` that runs its body compiled for AVX2+FMA when the CPU has them, and the
/// baseline build otherwise (the same arithmetic: Rust fuses no multiply-add on its own, so both
/// give the same bits). The body must not capture generics. Exported for the crates above that
/// vectorise a per-pixel loop of their own (the front-end's mover mask).
#[macro_export]
macro_rules! simd_fn {
    ($(#[$m:meta])* $vis:vis fn $name:ident($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$m])* $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn inner($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2,fma")]
                unsafe fn avx2($($arg: $ty),*) $(-> $ret)? { inner($($arg),*) }
                if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
                    // SAFETY: the CPU supports the features enabled on `avx2`.
                    return unsafe { avx2($($arg),*) };
                }
            }
            inner($($arg),*)
        }
    };
}
pub(crate) use crate::simd_fn;

/// OpenCV's BORDER_REFLECT_101 index (`gfedcb|abcdefgh|gfedcba`), valid for any `i`.
#[inline]
pub(crate) fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let mut i = i;
    loop {
        if i < 0 {
            i = -i;
        } else if i >= n {
            i = 2 * n - 2 - i;
        } else {
            return i as usize;
        }
    }
}

/// Bilinear resize with OpenCV's `INTER_LINEAR` sampling (`src = (dst + 0.5) * scale - 0.5`,
/// 11-bit fixed-point weights), which ORB-SLAM3 uses to build its pyramid.
#[cfg(test)]
pub(crate) fn resize_linear(src: &Gray8, dw: usize, dh: usize) -> Gray8 {
    let mut dst = Gray8::new(0, 0, 0);
    resize_linear_into(src, dw, dh, &mut dst);
    dst
}

/// The horizontal taps of a bilinear resize: per destination column the left source column, the
/// right one (clamped) and the right one's weight (11 bits); and, per group of 8 destination
/// columns whose taps lie within 16 source bytes, the byte shuffle and weight pairs that compute
/// the group in one vector step.
struct XTaps {
    left: Vec<u32>,
    right: Vec<u32>,
    weight: Vec<i32>,
    /// Per group of 8 columns: first source byte of its 16-byte window, or `None` (scalar).
    group_base: Vec<Option<usize>>,
    /// Per group: (left, right) byte index within the window for each of the 8 columns.
    group_shuffle: Vec<[u8; 16]>,
    /// Per group: (2048 - w, w) as i16 pairs for each of the 8 columns.
    group_weights: Vec<[i16; 16]>,
}

impl XTaps {
    fn new(sw: usize, dw: usize) -> Self {
        let mut t = XTaps {
            left: Vec::with_capacity(dw),
            right: Vec::with_capacity(dw),
            weight: Vec::with_capacity(dw),
            group_base: Vec::with_capacity(dw / 8),
            group_shuffle: Vec::with_capacity(dw / 8),
            group_weights: Vec::with_capacity(dw / 8),
        };
        for x in 0..dw {
            let (sx, a) = linear_coef(x, sw as f64 / dw as f64, sw);
            t.left.push(sx as u32);
            t.right.push((sx + 1).min(sw - 1) as u32);
            t.weight.push(a);
        }
        for g in 0..dw / 8 {
            let cols = g * 8..g * 8 + 8;
            let base = t.left[cols.start] as usize;
            let fits = base + 16 <= sw && cols.clone().all(|x| (t.right[x] as usize) < base + 16);
            let mut shuffle = [0u8; 16];
            let mut weights = [0i16; 16];
            if fits {
                for (i, x) in cols.enumerate() {
                    shuffle[2 * i] = (t.left[x] as usize - base) as u8;
                    shuffle[2 * i + 1] = (t.right[x] as usize - base) as u8;
                    weights[2 * i] = (2048 - t.weight[x]) as i16;
                    weights[2 * i + 1] = t.weight[x] as i16;
                }
            }
            t.group_base.push(fits.then_some(base));
            t.group_shuffle.push(shuffle);
            t.group_weights.push(weights);
        }
        t
    }

    /// One source row resized along x, before the vertical weights: `p[l] (2048 - w) + p[r] w`
    /// (exact, at most 255 * 2048).
    fn apply(&self, row: &[u8], out: &mut [i32]) {
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is available.
            done = unsafe { self.groups_avx2(row, out) };
        }
        let taps = self.left.iter().zip(&self.right).zip(&self.weight);
        for (o, ((&l, &r), &a)) in out.iter_mut().zip(taps).skip(done) {
            *o = row[l as usize] as i32 * (2048 - a) + row[r as usize] as i32 * a;
        }
    }

    /// The whole groups of 8 columns (a byte shuffle of the group's 16-byte window, widened to
    /// i16 pairs, and one multiply-add of each pair with its two weights); groups without a
    /// window take the scalar formula. Returns the columns written (`8 * groups`).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn groups_avx2(&self, row: &[u8], out: &mut [i32]) -> usize {
        use std::arch::x86_64::*;
        for (g, base) in self.group_base.iter().enumerate() {
            let cols = g * 8..g * 8 + 8;
            match *base {
                Some(base) if base + 16 <= row.len() && cols.end <= out.len() => {
                    // SAFETY: `base + 16 <= row.len()` and `cols.end <= out.len()` bound the
                    // loads and the store; shuffle and weights are 16-entry arrays.
                    unsafe {
                        let v = _mm_loadu_si128(row.as_ptr().add(base).cast());
                        let m = _mm_loadu_si128(self.group_shuffle[g].as_ptr().cast());
                        let pairs = _mm256_cvtepu8_epi16(_mm_shuffle_epi8(v, m));
                        let w = _mm256_loadu_si256(self.group_weights[g].as_ptr().cast());
                        let sums = _mm256_madd_epi16(pairs, w);
                        _mm256_storeu_si256(out.as_mut_ptr().add(cols.start).cast(), sums);
                    }
                }
                _ => {
                    for x in cols {
                        let (l, r, a) = (self.left[x], self.right[x], self.weight[x]);
                        out[x] = row[l as usize] as i32 * (2048 - a) + row[r as usize] as i32 * a;
                    }
                }
            }
        }
        self.group_base.len() * 8
    }
}

/// OpenCV's INTER_LINEAR source position of destination index `d`: the first source index and
/// the second one's weight in 11 bits (clamped at the borders).
fn linear_coef(d: usize, scale: f64, n: usize) -> (usize, i32) {
    let f = (d as f64 + 0.5) * scale - 0.5;
    let mut s = f.floor() as isize;
    let mut a = f - s as f64;
    if s < 0 {
        s = 0;
        a = 0.0;
    }
    if s as usize >= n - 1 {
        s = n as isize - 1;
        a = 0.0;
    }
    (s as usize, (a * 2048.0).round() as i32)
}

/// [`resize_linear`] into `dst`, reusing its buffer (every pixel is written).
pub(crate) fn resize_linear_into(src: &Gray8, dw: usize, dh: usize, dst: &mut Gray8) {
    let (sw, sh) = (src.width, src.height);
    dst.width = dw;
    dst.height = dh;
    dst.data.resize(dw * dh, 0);
    if sw == 0 || sh == 0 || dw == 0 || dh == 0 {
        dst.data.fill(0);
        return;
    }
    let taps = XTaps::new(sw, dw);
    // each source row is resized along x once (a destination row needs two, its neighbour
    // shares one), then pairs of those rows are weighted along y; the integer sums are exact
    // (< 2^31), so doing x before y gives OpenCV's bits
    let mut upper = (usize::MAX, vec![0i32; dw]);
    let mut lower = (usize::MAX, vec![0i32; dw]);
    for dy in 0..dh {
        let (sy, b) = linear_coef(dy, sh as f64 / dh as f64, sh);
        let sy1 = (sy + 1).min(sh - 1);
        if upper.0 != sy {
            if lower.0 == sy {
                std::mem::swap(&mut upper, &mut lower);
            } else {
                taps.apply(src.row(sy), &mut upper.1);
                upper.0 = sy;
            }
        }
        if lower.0 != sy1 {
            taps.apply(src.row(sy1), &mut lower.1);
            lower.0 = sy1;
        }
        blend_rows(&upper.1, &lower.1, b, &mut dst.data[dy * dw..(dy + 1) * dw]);
    }
}

simd_fn! {
/// `(top (2048 - b) + bottom b + 2^21) >> 22` per column: the vertical step of the resize.
fn blend_rows(top: &[i32], bottom: &[i32], b: i32, out: &mut [u8]) {
    let b0 = 2048 - b;
    for ((o, &t), &u) in out.iter_mut().zip(top).zip(bottom) {
        *o = ((t * b0 + u * b + (1 << 21)) >> 22) as u8;
    }
}
}

/// 7-tap Gaussian, sigma 2, in 8-bit fixed point (sum 256), as ORB-SLAM3 blurs each level
/// (`GaussianBlur(7x7, 2, 2, BORDER_REFLECT_101)`) before computing descriptors.
const GAUSS7: [u32; 7] = [18, 33, 49, 56, 49, 33, 18];

/// Separable 7x7 Gaussian blur (sigma 2) with reflect-101 borders.
#[cfg(test)]
pub(crate) fn gaussian_blur7(src: &Gray8, dst: &mut Gray8) {
    gaussian_blur7_with(src, dst, &mut Vec::new());
}

simd_fn! {
/// [`gaussian_blur7`] with a scratch buffer for the horizontal pass, kept between calls: a
/// ring of 8 rows (the 7 a destination row reads lie within 7 consecutive source rows, so
/// `row % 8` never collides), so the pass's output stays in the first-level cache.
pub(crate) fn gaussian_blur7_with(src: &Gray8, dst: &mut Gray8, tmp: &mut Vec<u16>) {
    let (w, h) = (src.width, src.height);
    dst.width = w;
    dst.height = h;
    dst.data.resize(w * h, 0);
    if w == 0 || h == 0 {
        return;
    }
    tmp.resize(8 * w, 0);
    let mut held = [usize::MAX; 8];
    let mut padded = vec![0u8; w + 6];
    for y in 0..h {
        let rows: [usize; 7] = std::array::from_fn(|k| reflect101(y as isize + k as isize - 3, h));
        for &sy in &rows {
            if held[sy % 8] == sy {
                continue;
            }
            held[sy % 8] = sy;
            // horizontal pass into u16 (max 255 * 256)
            let row = src.row(sy);
            padded[3..w + 3].copy_from_slice(row);
            for i in (0..3).chain(w + 3..w + 6) {
                padded[i] = row[reflect101(i as isize - 3, w)];
            }
            let out = &mut tmp[(sy % 8) * w..][..w];
            for (x, o) in out.iter_mut().enumerate() {
                let s = &padded[x..x + 7];
                // in u16: every partial sum is at most 255 * 256 (16 lanes per vector, not 8)
                let g = GAUSS7.map(|v| v as u16);
                *o = g[0] * (s[0] as u16 + s[6] as u16)
                    + g[1] * (s[1] as u16 + s[5] as u16)
                    + g[2] * (s[2] as u16 + s[4] as u16)
                    + g[3] * s[3] as u16;
            }
        }
        // vertical pass
        let r: [&[u16]; 7] = std::array::from_fn(|k| &tmp[(rows[k] % 8) * w..][..w]);
        let out = &mut dst.data[y * w..(y + 1) * w];
        for x in 0..w {
            let v = GAUSS7[0] * (r[0][x] as u32 + r[6][x] as u32)
                + GAUSS7[1] * (r[1][x] as u32 + r[5][x] as u32)
                + GAUSS7[2] * (r[2][x] as u32 + r[4][x] as u32)
                + GAUSS7[3] * r[3][x] as u32;
            out[x] = ((v + (1 << 15)) >> 16) as u8;
        }
    }
}
}

/// OpenCV `pyrDown`: 5x5 Gaussian ([1 4 6 4 1]² / 256), reflect-101, size ((w+1)/2, (h+1)/2).
#[cfg(test)]
pub(crate) fn pyr_down(src: &Gray8) -> Gray8 {
    let mut dst = Gray8::new(0, 0, 0);
    pyr_down_into(src, &mut dst);
    dst
}

simd_fn! {
/// [`pyr_down`] into `dst`, reusing its buffer.
pub(crate) fn pyr_down_into(src: &Gray8, dst: &mut Gray8) {
    let (w, h) = (src.width, src.height);
    let (dw, dh) = (w.div_ceil(2), h.div_ceil(2));
    dst.width = dw;
    dst.height = dh;
    dst.data.resize(dw * dh, 0);
    if w == 0 || h == 0 {
        return;
    }
    let mut vsum = vec![0u16; w + 4];
    for dy in 0..dh {
        let r: [&[u8]; 5] =
            std::array::from_fn(|k| src.row(reflect101(2 * dy as isize + k as isize - 2, h)));
        {
            let inner = &mut vsum[2..w + 2];
            for x in 0..w {
                inner[x] = r[0][x] as u16
                    + r[4][x] as u16
                    + 4 * (r[1][x] as u16 + r[3][x] as u16)
                    + 6 * r[2][x] as u16;
            }
        }
        for k in 0..2 {
            vsum[k] = vsum[2 + reflect101(k as isize - 2, w)];
            vsum[w + 2 + k] = vsum[2 + reflect101((w + k) as isize, w)];
        }
        let out = &mut dst.data[dy * dw..(dy + 1) * dw];
        for (x, o) in out.iter_mut().enumerate() {
            let s = &vsum[2 * x..2 * x + 5];
            let v = s[0] as u32 + s[4] as u32 + 4 * (s[1] as u32 + s[3] as u32) + 6 * s[2] as u32;
            *o = ((v + 128) >> 8) as u8;
        }
    }
}
}

/// Scharr derivatives as OpenCV's LK computes them (`[3 10 3]` smoothing × `[-1 0 1]`,
/// reflect-101), unscaled, as i16 (|value| <= 16 x 255, as OpenCV's `CV_16S` derivatives):
/// returns (dx, dy), each `w*h`.
#[cfg(test)]
pub(crate) fn scharr(src: &Gray8) -> (Vec<i16>, Vec<i16>) {
    let (w, h) = (src.width, src.height);
    let mut dx = vec![0i16; w * h];
    let mut dy = vec![0i16; w * h];
    scharr_into(src, &mut dx, &mut dy, w, 0);
    (dx, dy)
}

simd_fn! {
/// Scharr derivatives (see [`scharr`]) written into `dx`, `dy` at row stride `stride`, pixel
/// (0, 0) at index `origin` (so the outputs can carry a border).
pub(crate) fn scharr_into(src: &Gray8, dx: &mut [i16], dy: &mut [i16], stride: usize, origin: usize) {
    let (w, h) = (src.width, src.height);
    if w == 0 || h == 0 {
        return;
    }
    let mut trow = vec![0i16; w + 2]; // 3*up + 10*mid + 3*down (for dx)
    let mut drow = vec![0i16; w + 2]; // down - up (for dy)
    for y in 0..h {
        let up = src.row(reflect101(y as isize - 1, h));
        let mid = src.row(y);
        let down = src.row(reflect101(y as isize + 1, h));
        {
            let t = &mut trow[1..w + 1];
            let d = &mut drow[1..w + 1];
            for x in 0..w {
                t[x] = 3 * (up[x] as i16 + down[x] as i16) + 10 * mid[x] as i16;
                d[x] = down[x] as i16 - up[x] as i16;
            }
        }
        let l = reflect101(-1, w) + 1;
        let r = reflect101(w as isize, w) + 1;
        trow[0] = trow[l];
        drow[0] = drow[l];
        trow[w + 1] = trow[r];
        drow[w + 1] = drow[r];
        let o = origin + y * stride;
        let ox = &mut dx[o..o + w];
        let oy = &mut dy[o..o + w];
        for x in 0..w {
            ox[x] = trow[x + 2] - trow[x];
            oy[x] = 3 * (drow[x] + drow[x + 2]) + 10 * drow[x + 1];
        }
    }
}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reflect101_matches_opencv() {
        let idx: Vec<usize> = (-3..8).map(|i| reflect101(i, 5)).collect();
        assert_eq!(idx, vec![3, 2, 1, 0, 1, 2, 3, 4, 3, 2, 1]);
        assert_eq!(reflect101(-5, 1), 0);
    }

    #[test]
    fn blur_and_pyr_keep_constant_images() {
        let img = Gray8::new(13, 9, 77);
        let mut out = Gray8::new(0, 0, 0);
        gaussian_blur7(&img, &mut out);
        assert!(out.data.iter().all(|&v| v == 77));
        let d = pyr_down(&img);
        assert_eq!((d.width, d.height), (7, 5));
        assert!(d.data.iter().all(|&v| v == 77));
        let r = resize_linear(&img, 10, 7);
        assert!(r.data.iter().all(|&v| v == 77));
        let (gx, gy) = scharr(&img);
        assert!(gx.iter().chain(&gy).all(|&v| v == 0));
    }

    /// The resize by its definition: per destination pixel the four source pixels and their
    /// 11-bit weights, rounded once.
    fn resize_by_definition(src: &Gray8, dw: usize, dh: usize) -> Gray8 {
        let (sw, sh) = (src.width, src.height);
        let mut out = Gray8::new(dw, dh, 0);
        for dy in 0..dh {
            let (sy, b) = linear_coef(dy, sh as f64 / dh as f64, sh);
            for dx in 0..dw {
                let (sx, a) = linear_coef(dx, sw as f64 / dw as f64, sw);
                let p = |x: usize, y: usize| src.get(x.min(sw - 1), y.min(sh - 1)) as i64;
                let v = p(sx, sy) * (2048 - a as i64) * (2048 - b as i64)
                    + p(sx + 1, sy) * a as i64 * (2048 - b as i64)
                    + p(sx, sy + 1) * (2048 - a as i64) * b as i64
                    + p(sx + 1, sy + 1) * a as i64 * b as i64;
                out.set(dx, dy, ((v + (1 << 21)) >> 22) as u8);
            }
        }
        out
    }

    #[test]
    fn the_resize_equals_its_definition_at_every_size() {
        // the pyramid's 1/1.2 steps (vector groups), odd sizes (scalar tails), a strong
        // shrink (windows wider than 16 bytes: scalar groups) and an enlargement
        let mut src = Gray8::new(131, 97, 0);
        let mut s = 12345u32;
        for v in src.data.iter_mut() {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            *v = (s >> 24) as u8;
        }
        for (dw, dh) in [
            (109, 81),
            (91, 67),
            (130, 96),
            (20, 15),
            (7, 3),
            (200, 150),
            (131, 97),
        ] {
            let mut out = Gray8::new(0, 0, 0);
            resize_linear_into(&src, dw, dh, &mut out);
            assert_eq!(out, resize_by_definition(&src, dw, dh), "{dw}x{dh}");
        }
    }

    #[test]
    fn scharr_of_a_ramp_is_32_per_step() {
        let mut img = Gray8::new(8, 6, 0);
        for y in 0..6 {
            for x in 0..8 {
                img.set(x, y, (x * 10) as u8);
            }
        }
        let (gx, gy) = scharr(&img);
        // (10 - (-10)) ... central difference of 2 steps * 10 * (3 + 10 + 3) = 320
        assert_eq!(gx[3 * 8 + 4], 320);
        assert_eq!(gy[3 * 8 + 4], 0);
    }
}
