//! FAST-9 (16-pixel circle) corners with OpenCV's score and 3x3 non-maximum suppression.
//!
//! The full segment test runs 32 pixels at a time as bit masks (blocks where no pixel passes
//! the opposite-pairs pre-test are skipped); the score runs only on true corners.

use crate::imgops::simd_fn;
use stillpoint_image::Gray8;

/// FAST's 16-pixel Bresenham circle of radius 3 in OpenCV's order, as (dx, dy).
pub const FAST_CIRCLE: [(isize, isize); 16] = [
    (0, 3),
    (1, 3),
    (2, 2),
    (3, 1),
    (3, 0),
    (3, -1),
    (2, -2),
    (1, -3),
    (0, -3),
    (-1, -3),
    (-2, -2),
    (-3, -1),
    (-3, 0),
    (-3, 1),
    (-2, 2),
    (-1, 3),
];

/// A FAST corner: pixel position and score (the largest threshold at which it is still a corner).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Corner {
    pub x: u16,
    pub y: u16,
    pub score: u8,
}

/// Score of a pixel known to be a corner: the largest margin over the 16 arcs of 9 of the
/// smallest |difference| on the arc (bright or dark), minus one (OpenCV's convention). Sliding
/// minima over the arcs in vector registers.
#[inline]
fn corner_score(data: &[u8], idx: usize, offsets: &[isize; 16]) -> u8 {
    let c = data[idx] as i16;
    let mut d = [0i16; 32];
    for k in 0..16 {
        let v = data[(idx as isize + offsets[k]) as usize] as i16 - c;
        d[k] = v;
        d[k + 16] = v;
    }
    #[cfg(target_arch = "x86_64")]
    {
        window_score_sse2(&d)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        window_score(&d)
    }
}

/// The score from the 16 differences `d` (repeated once, 32 entries), 8 arcs at a time in
/// SSE2 registers (OpenCV's `cornerScore<16>` scheme: the min / max of the 8 inner points, then
/// the arc starting one before and the one ending one after). Equal to [`window_score`].
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn window_score_sse2(d: &[i16; 32]) -> u8 {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of x86-64; every unaligned 8-lane load starts at most at index 17
    // of the 32-entry array.
    unsafe {
        let p = d.as_ptr();
        let load = |i: usize| _mm_loadu_si128(p.add(i).cast::<__m128i>());
        let mut best_min = _mm_setzero_si128();
        let mut best_max = _mm_setzero_si128();
        for k in [0usize, 8] {
            let mut a = _mm_min_epi16(load(k + 1), load(k + 2));
            let mut b = _mm_max_epi16(load(k + 1), load(k + 2));
            for j in 3..=8 {
                a = _mm_min_epi16(a, load(k + j));
                b = _mm_max_epi16(b, load(k + j));
            }
            let (first, last) = (load(k), load(k + 9));
            best_min = _mm_max_epi16(best_min, _mm_min_epi16(a, first));
            best_min = _mm_max_epi16(best_min, _mm_min_epi16(a, last));
            best_max = _mm_min_epi16(best_max, _mm_max_epi16(b, first));
            best_max = _mm_min_epi16(best_max, _mm_max_epi16(b, last));
        }
        // best = max(0, max of minima, -(min of maxima)), as `window_score`
        let q = _mm_max_epi16(best_min, _mm_sub_epi16(_mm_setzero_si128(), best_max));
        let q = _mm_max_epi16(q, _mm_srli_si128::<8>(q));
        let q = _mm_max_epi16(q, _mm_srli_si128::<4>(q));
        let q = _mm_max_epi16(q, _mm_srli_si128::<2>(q));
        let best = _mm_cvtsi128_si32(q) as i16;
        (best - 1).clamp(1, 255) as u8
    }
}

/// The score from the 16 differences `d` (repeated once, 32 entries): min / max of
/// d[k..k + 9] for k < 16 by doubling windows (2, 4, 8, then + 1).
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
#[inline(always)]
fn window_score(d: &[i16; 32]) -> u8 {
    let lo2: [i16; 24] = std::array::from_fn(|i| d[i].min(d[i + 1]));
    let hi2: [i16; 24] = std::array::from_fn(|i| d[i].max(d[i + 1]));
    let lo4: [i16; 20] = std::array::from_fn(|i| lo2[i].min(lo2[i + 2]));
    let hi4: [i16; 20] = std::array::from_fn(|i| hi2[i].max(hi2[i + 2]));
    let mut best = 0i16;
    for k in 0..16 {
        let mn = lo4[k].min(lo4[k + 4]).min(d[k + 8]);
        let mx = hi4[k].max(hi4[k + 4]).max(d[k + 8]);
        best = best.max(mn).max(-mx);
    }
    (best - 1).clamp(1, 255) as u8
}

/// Full segment test and score of pixel at `idx` (score 0 = not a corner at `t`).
#[cfg(test)]
fn score_at(data: &[u8], idx: usize, offsets: &[isize; 16], t: u8) -> u8 {
    let c = data[idx] as i32;
    let (mut bright, mut dark) = (0u32, 0u32);
    for k in 0..16 {
        let d = data[(idx as isize + offsets[k]) as usize] as i32 - c;
        bright |= ((d > t as i32) as u32) << k;
        dark |= ((d < -(t as i32)) as u32) << k;
    }
    let has_arc = |m: u32| {
        let m = m | (m << 16);
        let mut r = m;
        for s in 1..9 {
            r &= m >> s;
        }
        r != 0
    };
    if !has_arc(bright) && !has_arc(dark) {
        return 0;
    }
    corner_score(data, idx, offsets)
}

/// Lanes processed together by the row test (one AVX2 register of bytes).
const L: usize = 32;

/// Bit j set where 9 contiguous of the 16 circle masks `m` (one bit per pixel) are set,
/// cyclically: runs of 2, 4, 8, then one more.
#[inline(always)]
fn arc9(m: &[u32; 16]) -> u32 {
    let a1: [u32; 16] = std::array::from_fn(|k| m[k] & m[(k + 1) & 15]);
    let a2: [u32; 16] = std::array::from_fn(|k| a1[k] & a1[(k + 2) & 15]);
    let mut out = 0;
    for k in 0..16 {
        out |= a2[k] & a2[(k + 4) & 15] & m[(k + 8) & 15];
    }
    out
}

/// Bit j = top bit of byte j (byte masks 0x00 / 0xFF to a bit mask).
#[inline(always)]
fn movemask32(m: &[u8; L]) -> u32 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{__m128i, _mm_loadu_si128, _mm_movemask_epi8};
        // SAFETY: SSE2 is part of x86-64; both unaligned 16-byte loads lie inside `m`.
        unsafe {
            let lo = _mm_loadu_si128(m.as_ptr().cast::<__m128i>());
            let hi = _mm_loadu_si128(m.as_ptr().add(16).cast::<__m128i>());
            (_mm_movemask_epi8(lo) as u32 & 0xFFFF) | ((_mm_movemask_epi8(hi) as u32) << 16)
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let mut b = 0u32;
        for (j, &v) in m.iter().enumerate() {
            b |= ((v >> 7) as u32) << j;
        }
        b
    }
}

/// The whole 32-pixel blocks of [`corner_row`] (`n / 32` of them from `data[base]`) with AVX2
/// compares and movemasks, written to `out`, and every pixel's score to `scores` (0 where it is
/// not a corner); returns how many pixels it covered. Same masks as the portable loop (unsigned
/// compares as signed ones after flipping the top bit), same scores as [`corner_score`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn corner_blocks_avx2(
    data: &[u8],
    base: usize,
    n: usize,
    t: u8,
    offsets: &[isize; 16],
    out: &mut [u32],
    scores: &mut [u8],
) -> usize {
    use std::arch::x86_64::*;
    let blocks = n / L;
    // bounds of every read, checked once: block b reads data[base + b L + off ..][..L] for
    // each circle offset (and the centre, offset 0)
    let lo_off = offsets.iter().copied().min().unwrap_or(0).min(0);
    let hi_off = offsets.iter().copied().max().unwrap_or(0).max(0);
    let first = base as isize + lo_off;
    let last = (base + blocks * L) as isize + hi_off; // one past the last byte read
    if blocks == 0
        || first < 0
        || last > data.len() as isize
        || out.len() < blocks
        || scores.len() < blocks * L
    {
        return 0;
    }
    let sign = _mm256_set1_epi8(i8::MIN);
    let tv = _mm256_set1_epi8(t as i8);
    let ptr = data.as_ptr();
    for (b, slot) in out[..blocks].iter_mut().enumerate() {
        let at = base + b * L;
        // SAFETY: `first..last` bounds every load; `scores` holds `blocks * L` bytes.
        unsafe {
            let c = _mm256_loadu_si256(ptr.add(at).cast::<__m256i>());
            let hi = _mm256_xor_si256(_mm256_adds_epu8(c, tv), sign);
            let lo = _mm256_xor_si256(_mm256_subs_epu8(c, tv), sign);
            let mut bright = [0u32; 16];
            let mut dark = [0u32; 16];
            let mut ring = [_mm256_setzero_si256(); 16];
            macro_rules! compare {
                ($k:expr) => {{
                    let k = $k;
                    let q = ptr.offset(at as isize + offsets[k]).cast::<__m256i>();
                    ring[k] = _mm256_loadu_si256(q);
                    let p = _mm256_xor_si256(ring[k], sign);
                    bright[k] = _mm256_movemask_epi8(_mm256_cmpgt_epi8(p, hi)) as u32;
                    dark[k] = _mm256_movemask_epi8(_mm256_cmpgt_epi8(lo, p)) as u32;
                }};
            }
            // Four circle pixels first: an arc of 9 holds one of 0 and 8 and one of 4 and 12,
            // so a block where no pixel passes that needs none of the other twelve loads.
            for k in [0, 4, 8, 12] {
                compare!(k);
            }
            let quick = |m: &[u32; 16]| (m[0] | m[8]) & (m[4] | m[12]);
            let dst = scores.as_mut_ptr().add(b * L).cast::<__m256i>();
            if quick(&bright) | quick(&dark) == 0 {
                *slot = 0;
                _mm256_storeu_si256(dst, _mm256_setzero_si256());
                continue;
            }
            for k in [1, 2, 3, 5, 6, 7, 9, 10, 11, 13, 14, 15] {
                compare!(k);
            }
            let (mut bm, mut dm) = (u32::MAX, u32::MAX);
            for k in 0..8 {
                bm &= bright[k] | bright[k + 8];
                dm &= dark[k] | dark[k + 8];
            }
            let corners = if bm | dm != 0 {
                arc9(&bright) | arc9(&dark)
            } else {
                0
            };
            *slot = corners;
            if corners == 0 {
                _mm256_storeu_si256(dst, _mm256_setzero_si256());
            } else {
                let score = block_scores_avx2(c, &ring);
                _mm256_storeu_si256(dst, _mm256_and_si256(score, byte_mask_avx2(corners)));
            }
        }
    }
    blocks * L
}

/// [`corner_score`] of 32 pixels at once from their circles (`ring[k]` = circle pixel k of
/// each): the best arc of 9 of the saturated differences `p - c` (bright) and `c - p` (dark),
/// doubling windows (2, 4, 8, then + 1); saturation only clips arcs that are no corner either
/// way, so the best of both directions is the same as with signed differences.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn block_scores_avx2(
    c: std::arch::x86_64::__m256i,
    ring: &[std::arch::x86_64::__m256i; 16],
) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    let best_arc = |d: [__m256i; 16]| {
        let m2: [__m256i; 16] = std::array::from_fn(|k| _mm256_min_epu8(d[k], d[(k + 1) & 15]));
        let m4: [__m256i; 16] = std::array::from_fn(|k| _mm256_min_epu8(m2[k], m2[(k + 2) & 15]));
        let mut best = _mm256_setzero_si256();
        for k in 0..16 {
            let m8 = _mm256_min_epu8(m4[k], m4[(k + 4) & 15]);
            best = _mm256_max_epu8(best, _mm256_min_epu8(m8, d[(k + 8) & 15]));
        }
        best
    };
    let bright = best_arc(std::array::from_fn(|k| _mm256_subs_epu8(ring[k], c)));
    let dark = best_arc(std::array::from_fn(|k| _mm256_subs_epu8(c, ring[k])));
    // OpenCV's score: the best margin minus one, at least 1
    let best = _mm256_max_epu8(bright, dark);
    _mm256_max_epu8(
        _mm256_subs_epu8(best, _mm256_set1_epi8(1)),
        _mm256_set1_epi8(1),
    )
}

/// Bit j of `bits` to byte j (0xFF / 0x00) of a 32-byte vector.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn byte_mask_avx2(bits: u32) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    let v = _mm256_set1_epi32(bits as i32);
    // byte j takes byte j / 8 of the mask, then tests its bit j % 8
    let pick = _mm256_setr_epi8(
        0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 2, 2, 2, 2, 2, 2, 2, 2, 3, 3, 3, 3, 3, 3,
        3, 3,
    );
    let bit = _mm256_set1_epi64x(0x8040_2010_0804_0201u64 as i64);
    _mm256_cmpeq_epi8(_mm256_and_si256(_mm256_shuffle_epi8(v, pick), bit), bit)
}

simd_fn! {
/// Mark pixels of row `y`, columns `x0..x1`, that are FAST corners at threshold `t` (full
/// segment test, 32 pixels at a time as bit masks, one `u32` per block in `out`; blocks where
/// no pixel passes the opposite-pairs pre-test are skipped), and write each pixel's score to
/// `scores` (`x1 - x0` bytes; 0 = not a corner).
fn corner_row(
    img: &Gray8,
    y: usize,
    x0: usize,
    x1: usize,
    t: u8,
    out: &mut Vec<u32>,
    scores: &mut [u8],
) {
    let w = img.width;
    let n = x1 - x0;
    out.clear();
    out.resize(n.div_ceil(L), 0);
    scores.fill(0);
    let base = y * w + x0;
    let offsets: [isize; 16] = std::array::from_fn(|k| FAST_CIRCLE[k].1 * w as isize + FAST_CIRCLE[k].0);
    let mut i = 0;
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // whole blocks in AVX2 registers; the row's tail block below
        // SAFETY: AVX2 is available; `detect` keeps rows and columns 3 px inside the image,
        // so every circle pixel of a whole block lies in `img.data`.
        i = unsafe { corner_blocks_avx2(&img.data, base, n, t, &offsets, out, scores) };
        // the tail (under 32 pixels): one more whole block that ends at the tail's end, or as
        // far right as the image allows, with its bits shifted into place; a pixel's test does
        // not depend on the block it is in
        let x = x0 + i;
        if i < n && w >= L + 6 {
            let start = x.min(w - 3 - L);
            let mut bits = [0u32; 1];
            let mut block_scores = [0u8; L];
            // SAFETY: as above; `3 <= start` and `start + L <= w - 3` keep the block's circle
            // pixels on row `y` (3 px inside the image) in `img.data`.
            let covered = unsafe {
                corner_blocks_avx2(
                    &img.data,
                    y * w + start,
                    L,
                    t,
                    &offsets,
                    &mut bits,
                    &mut block_scores,
                )
            };
            if covered == L {
                let valid = (1u32 << (n - i)) - 1;
                out[i / L] = (bits[0] >> (x - start)) & valid;
                let from = x - start;
                scores[i..n].copy_from_slice(&block_scores[from..from + (n - i)]);
                i = n;
            }
        }
    }
    while i < n {
        let lanes = L.min(n - i);
        let mut c = [0u8; L];
        let mut p = [[0u8; L]; 16];
        if lanes == L {
            c.copy_from_slice(&img.data[base + i..base + i + L]);
            for k in 0..16 {
                let s = (base as isize + i as isize + offsets[k]) as usize;
                p[k].copy_from_slice(&img.data[s..s + L]);
            }
        } else {
            // the row's tail: copy what is there, the rest of the lanes stay flat (no corner)
            c[..lanes].copy_from_slice(&img.data[base + i..base + i + lanes]);
            for k in 0..16 {
                let s = (base as isize + i as isize + offsets[k]) as usize;
                p[k][..lanes].copy_from_slice(&img.data[s..s + lanes]);
            }
        }
        let mut hi = [0u8; L];
        let mut lo = [0u8; L];
        for j in 0..L {
            hi[j] = c[j].saturating_add(t);
            lo[j] = c[j].saturating_sub(t);
        }
        let mut bright = [0u32; 16];
        let mut dark = [0u32; 16];
        for k in 0..16 {
            let mut b = [0u8; L];
            let mut d = [0u8; L];
            for j in 0..L {
                b[j] = ((p[k][j] > hi[j]) as u8).wrapping_neg();
                d[j] = ((p[k][j] < lo[j]) as u8).wrapping_neg();
            }
            bright[k] = movemask32(&b);
            dark[k] = movemask32(&d);
        }
        // a 9-arc holds one pixel of every opposite pair: cheap block rejection
        let (mut b, mut d) = (u32::MAX, u32::MAX);
        for k in 0..8 {
            b &= bright[k] | bright[k + 8];
            d &= dark[k] | dark[k + 8];
        }
        if b | d != 0 {
            let valid = if lanes == L { u32::MAX } else { (1u32 << lanes) - 1 };
            let mut bits = (arc9(&bright) | arc9(&dark)) & valid;
            out[i / L] = bits;
            while bits != 0 {
                let j = bits.trailing_zeros() as usize;
                scores[i + j] = corner_score(&img.data, base + i + j, &offsets);
                bits &= bits - 1;
            }
        }
        i += L;
    }
}
}

/// Call `f(i)` for every `i` with `v[i] != 0`, in increasing order; most of a row is zero, so
/// it skips 32 bytes at a time, then 8.
#[inline(always)]
fn for_each_nonzero(v: &[u8], mut f: impl FnMut(usize)) {
    let word = |c: &[u8]| u64::from_le_bytes(c.try_into().unwrap_or([0; 8]));
    let chunks = v.chunks_exact(32);
    let tail = chunks.remainder();
    for (c, chunk) in chunks.enumerate() {
        let words: [u64; 4] = std::array::from_fn(|k| word(&chunk[k * 8..k * 8 + 8]));
        if words.iter().fold(0, |a, w| a | w) == 0 {
            continue;
        }
        for (k, &w) in words.iter().enumerate() {
            let mut bits = w;
            while bits != 0 {
                let i = bits.trailing_zeros() as usize / 8;
                f(c * 32 + k * 8 + i);
                bits &= !(0xFFu64 << (i * 8));
            }
        }
    }
    let base = v.len() - tail.len();
    for (i, &x) in tail.iter().enumerate() {
        if x != 0 {
            f(base + i);
        }
    }
}

/// 3x3 non-maximum suppression of one row of scores: `kept[j]` = `rows[1][j + 1]` where it is
/// above all 8 neighbours (`rows` = previous, current and next row, each `kept.len() + 2` long
/// with a zero column at both ends), else 0. 32 columns at a time with AVX2.
fn suppress_row(rows: [&[u8]; 3], kept: &mut [u8]) {
    let n = kept.len();
    let [prev, cur, next] = rows;
    let mut start = 0;
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2")
        && prev.len() >= n + 2
        && cur.len() >= n + 2
        && next.len() >= n + 2
    {
        // SAFETY: AVX2 is available; the three rows hold `n + 2` bytes each (checked).
        start = unsafe { suppress_row_avx2(rows, kept) };
    }
    for j in start..n {
        let around = cur[j]
            .max(cur[j + 2])
            .max(prev[j])
            .max(prev[j + 1])
            .max(prev[j + 2])
            .max(next[j])
            .max(next[j + 1])
            .max(next[j + 2]);
        kept[j] = if cur[j + 1] > around { cur[j + 1] } else { 0 };
    }
}

/// The whole 32-column blocks of [`suppress_row`]; returns the columns done. The caller checks
/// that the rows hold `kept.len() + 2` bytes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn suppress_row_avx2(rows: [&[u8]; 3], kept: &mut [u8]) -> usize {
    use std::arch::x86_64::*;
    let n = kept.len();
    let block = |j: usize, kept: &mut [u8]| {
        // SAFETY: `j + L + 2 <= n + 2`: every load lies in its row, the store in `kept`.
        unsafe {
            let at =
                |r: &[u8], o: usize| _mm256_loadu_si256(r.as_ptr().add(j + o).cast::<__m256i>());
            let s = at(rows[1], 1);
            let mut around = _mm256_max_epu8(at(rows[1], 0), at(rows[1], 2));
            for r in [rows[0], rows[2]] {
                around = _mm256_max_epu8(around, at(r, 0));
                around = _mm256_max_epu8(around, at(r, 1));
                around = _mm256_max_epu8(around, at(r, 2));
            }
            // s > around  <=>  max(s, around) != around
            let not_above = _mm256_cmpeq_epi8(_mm256_max_epu8(s, around), around);
            let out = _mm256_andnot_si256(not_above, s);
            _mm256_storeu_si256(kept.as_mut_ptr().add(j).cast::<__m256i>(), out);
        }
    };
    let mut j = 0;
    while j + L <= n {
        block(j, kept);
        j += L;
    }
    // The last columns as one more block ending at the row's end, over some done already
    // (each column depends on the rows alone, so it is written the same again): ORB's cells
    // are a few columns over one block wide, and those columns one at a time cost more than
    // the block.
    if j < n && n >= L {
        block(n - L, kept);
        j = n;
    }
    j
}

/// [`detect`]'s buffers, kept between calls (a level's cells call it hundreds of times).
#[derive(Default)]
pub(crate) struct FastScratch {
    rows: [Vec<u8>; 3],
    mask: Vec<u32>,
    kept: Vec<u8>,
}

simd_fn! {
/// FAST corners at threshold `t` inside `[x0, x1) x [y0, y1)` (clipped to 3 px from the image
/// border), with 3x3 non-maximum suppression among the corners of that rectangle (like OpenCV's
/// `FAST(roi, t, true)`).
pub(crate) fn detect(
    img: &Gray8,
    rect: [usize; 4],
    t: u8,
    out: &mut Vec<Corner>,
    scratch: &mut FastScratch,
) {
    let [x0, y0, x1, y1] = rect;
    let (w, h) = (img.width, img.height);
    if w < 7 || h < 7 {
        return;
    }
    let (x0, y0) = (x0.max(3), y0.max(3));
    let (x1, y1) = (x1.min(w - 3), y1.min(h - 3));
    if x0 >= x1 || y0 >= y1 {
        return;
    }
    let t = t.max(1);
    let rw = x1 - x0;
    // three rolling score rows (previous, current, next) with a zero column on each side
    let FastScratch { rows, mask, kept } = scratch;
    for row in rows.iter_mut() {
        row.clear();
        row.resize(rw + 2, 0);
    }
    kept.clear();
    kept.resize(rw, 0);
    // the end columns stay zero; `corner_row` writes every score between them
    let mut fill = |y: usize, row: &mut Vec<u8>| {
        if y < y0 || y >= y1 {
            row.fill(0);
        } else {
            corner_row(img, y, x0, x1, t, mask, &mut row[1..=rw]);
        }
    };
    fill(y0, &mut rows[1]);
    for y in y0..y1 {
        let [prev, cur, next] = &mut *rows;
        fill(y + 1, next);
        // 3x3 suppression for the whole row in vector lanes: a score survives where it is
        // above all 8 neighbours' (0 = no corner), then the few survivors are collected
        suppress_row([prev, cur, next], kept);
        for_each_nonzero(kept, |j| {
            out.push(Corner {
                x: (x0 + j) as u16,
                y: y as u16,
                score: kept[j],
            });
        });
        // previous <- current <- next <- the old previous, to be filled (two swaps of three
        // vectors, not `rotate_left`'s copy through a buffer)
        rows.swap(0, 1);
        rows.swap(1, 2);
    }
}
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_force(img: &Gray8, t: u8) -> Vec<(usize, usize, u8)> {
        let w = img.width;
        let offsets: [isize; 16] =
            std::array::from_fn(|k| FAST_CIRCLE[k].1 * w as isize + FAST_CIRCLE[k].0);
        let mut s = vec![0u8; w * img.height];
        for y in 3..img.height - 3 {
            for x in 3..w - 3 {
                s[y * w + x] = score_at(&img.data, y * w + x, &offsets, t);
            }
        }
        let mut v = vec![];
        for y in 3..img.height - 3 {
            for x in 3..w - 3 {
                let c = s[y * w + x];
                let nb = [-1isize, 0, 1];
                let is_max = c > 0
                    && nb.iter().all(|&dy| {
                        nb.iter().all(|&dx| {
                            (dx == 0 && dy == 0) || {
                                let (xx, yy) = (x as isize + dx, y as isize + dy);
                                let inside = xx >= 3
                                    && yy >= 3
                                    && (xx as usize) < w - 3
                                    && (yy as usize) < img.height - 3;
                                !inside || c > s[yy as usize * w + xx as usize]
                            }
                        })
                    });
                if is_max {
                    v.push((x, y, c));
                }
            }
        }
        v
    }

    /// The score by its definition: best over the 16 arcs of 9 of the smallest margin, minus one.
    fn naive_score(data: &[u8], idx: usize, offsets: &[isize; 16]) -> u8 {
        let c = data[idx] as i32;
        let d: Vec<i32> = (0..16)
            .map(|k| data[(idx as isize + offsets[k]) as usize] as i32 - c)
            .collect();
        let mut best = 0i32;
        for k in 0..16 {
            let arc = (0..9).map(|i| d[(k + i) & 15]);
            best = best.max(arc.clone().min().unwrap_or(0));
            best = best.max(-arc.max().unwrap_or(0));
        }
        (best - 1).clamp(1, 255) as u8
    }

    #[test]
    fn corner_row_marks_exactly_the_segment_test_corners() {
        let (w, h) = (101usize, 12usize);
        let mut img = crate::test_rng::Lcg(5).noise_image(w, h);
        // a flat patch, so some blocks fail the pre-test
        for y in 0..h {
            for x in 40..80 {
                img.set(x, y, 128);
            }
        }
        // whole rows, and spans whose tail block has to start left of them (short spans,
        // spans ending at the image's right margin)
        for (x0, x1) in [(3, w - 3), (5, 20), (60, w - 3), (10, 50), (90, w - 3)] {
            for t in [1u8, 7, 20, 60, 250] {
                for y in 3..h - 3 {
                    let mut fast = Vec::new();
                    let mut scores = vec![7u8; x1 - x0];
                    corner_row(&img, y, x0, x1, t, &mut fast, &mut scores);
                    // the segment test, pixel by pixel
                    let offsets: [isize; 16] =
                        std::array::from_fn(|k| FAST_CIRCLE[k].1 * w as isize + FAST_CIRCLE[k].0);
                    let expect: Vec<usize> = (x0..x1)
                        .filter(|&x| score_at(&img.data, y * w + x, &offsets, t) > 0)
                        .map(|x| x - x0)
                        .collect();
                    let got: Vec<usize> = (0..x1 - x0)
                        .filter(|&j| fast[j / L] >> (j % L) & 1 == 1)
                        .collect();
                    assert_eq!(got, expect, "span {x0}..{x1} t {t} row {y}");
                    // every corner's score as the scalar score, 0 elsewhere
                    let want: Vec<u8> = (x0..x1)
                        .map(|x| score_at(&img.data, y * w + x, &offsets, t))
                        .collect();
                    assert_eq!(scores, want, "scores, span {x0}..{x1} t {t} row {y}");
                }
            }
        }
    }

    #[test]
    fn sliding_window_score_matches_its_definition() {
        let (w, h) = (40, 30);
        let img = crate::test_rng::Lcg(987).noise_image(w, h);
        let offsets: [isize; 16] =
            std::array::from_fn(|k| FAST_CIRCLE[k].1 * w as isize + FAST_CIRCLE[k].0);
        for y in 3..h - 3 {
            for x in 3..w - 3 {
                let i = y * w + x;
                let want = naive_score(&img.data, i, &offsets);
                assert_eq!(corner_score(&img.data, i, &offsets), want);
                // the portable path (used off x86-64) too
                let c = img.data[i] as i16;
                let d: [i16; 32] = std::array::from_fn(|k| {
                    img.data[(i as isize + offsets[k & 15]) as usize] as i16 - c
                });
                assert_eq!(window_score(&d), want);
            }
        }
    }

    #[test]
    fn simd_pretest_finds_the_same_corners_as_brute_force() {
        // Rows of 31 to 91 columns inside the border: under one vector block, exactly one,
        // one and a few more (ORB's cells), two, two and most of a third.
        for w in [37, 38, 39, 41, 70, 97] {
            let h = 61;
            let img = crate::test_rng::Lcg(12345 + w as u32).noise_image(w, h);
            for t in [7u8, 20, 60] {
                let mut got = vec![];
                detect(&img, [0, 0, w, h], t, &mut got, &mut FastScratch::default());
                let got: Vec<_> = got
                    .iter()
                    .map(|c| (c.x as usize, c.y as usize, c.score))
                    .collect();
                let want = brute_force(&img, t);
                assert!(!want.is_empty());
                assert_eq!(got, want, "width {w}, threshold {t}");
            }
        }
    }

    #[test]
    fn a_bright_dot_is_a_corner_with_its_contrast_as_score() {
        let mut img = Gray8::new(20, 20, 50);
        img.set(10, 10, 150);
        let mut got = vec![];
        detect(
            &img,
            [0, 0, 20, 20],
            20,
            &mut got,
            &mut FastScratch::default(),
        );
        assert_eq!(got.len(), 1);
        assert_eq!((got[0].x, got[0].y, got[0].score), (10, 10, 99));
        let mut none = vec![];
        detect(
            &Gray8::new(5, 5, 0),
            [0, 0, 5, 5],
            20,
            &mut none,
            &mut FastScratch::default(),
        );
        assert!(none.is_empty());
    }
}
