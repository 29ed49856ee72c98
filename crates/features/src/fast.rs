//! FAST-9 (16-pixel circle) corners with OpenCV's score and 3x3 non-maximum suppression.
//!
//! The rejection test runs 32 pixels at a time (every corner has, for each of the 8 opposite
//! pairs on the circle, at least one pixel brighter than centre + t, or darker than centre - t,
//! the same pre-test OpenCV uses); the full arc test and the score run only on survivors.

use crate::imgops::simd_fn;
use stillpoint_image::Gray8;

/// Circle of radius 3 in OpenCV's order, as (dx, dy).
const CIRCLE: [(isize, isize); 16] = [
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

/// Full segment test and score of pixel at `idx` (score 0 = not a corner at `t`).
#[inline]
fn score_at(data: &[u8], idx: usize, offsets: &[isize; 16], t: u8) -> u8 {
    let c = data[idx] as i32;
    let mut d = [0i32; 16];
    let (mut bright, mut dark) = (0u32, 0u32);
    for k in 0..16 {
        let p = data[(idx as isize + offsets[k]) as usize] as i32;
        d[k] = p - c;
        bright |= ((d[k] > t as i32) as u32) << k;
        dark |= ((d[k] < -(t as i32)) as u32) << k;
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
    // score: best over the 16 arcs of 9 of the smallest margin, minus one (OpenCV's convention)
    let mut best = 0i32;
    for k in 0..16 {
        let (mut lo_b, mut lo_d) = (i32::MAX, i32::MAX);
        for i in 0..9 {
            let v = d[(k + i) & 15];
            lo_b = lo_b.min(v);
            lo_d = lo_d.min(-v);
        }
        best = best.max(lo_b).max(lo_d);
    }
    (best - 1).clamp(1, 255) as u8
}

simd_fn! {
/// Mark pixels of row `y`, columns `x0..x1`, that pass the opposite-pairs pre-test.
fn pretest_row(img: &Gray8, y: usize, x0: usize, x1: usize, t: u8, out: &mut Vec<u8>) {
    let w = img.width;
    let n = x1 - x0;
    out.clear();
    out.resize(n, 0);
    let base = y * w + x0;
    let center = &img.data[base..base + n];
    let circ: [&[u8]; 16] = std::array::from_fn(|k| {
        let (dx, dy) = CIRCLE[k];
        let start = (base as isize + dy * w as isize + dx) as usize;
        &img.data[start..start + n]
    });
    const L: usize = 32;
    let mut i = 0;
    while i + L <= n {
        let c: &[u8; L] = center[i..i + L].try_into().unwrap_or(&[0; L]);
        let p: [&[u8; L]; 16] =
            std::array::from_fn(|k| circ[k][i..i + L].try_into().unwrap_or(&[0; L]));
        let o: &mut [u8; L] = (&mut out[i..i + L]).try_into().unwrap_or_else(|_| unreachable!());
        for j in 0..L {
            let hi = c[j].saturating_add(t);
            let lo = c[j].saturating_sub(t);
            let mut b = 1u8;
            let mut d = 1u8;
            for k in 0..8 {
                let (a, q) = (p[k][j], p[k + 8][j]);
                b &= ((a > hi) | (q > hi)) as u8;
                d &= ((a < lo) | (q < lo)) as u8;
            }
            o[j] = b | d;
        }
        i += L;
    }
    for j in i..n {
        let hi = center[j].saturating_add(t);
        let lo = center[j].saturating_sub(t);
        let mut b = true;
        let mut d = true;
        for k in 0..8 {
            let (a, q) = (circ[k][j], circ[k + 8][j]);
            b &= (a > hi) | (q > hi);
            d &= (a < lo) | (q < lo);
        }
        out[j] = (b | d) as u8;
    }
}
}

/// FAST corners at threshold `t` inside `[x0, x1) x [y0, y1)` (clipped to 3 px from the image
/// border), with 3x3 non-maximum suppression among the corners of that rectangle (like OpenCV's
/// `FAST(roi, t, true)`).
pub(crate) fn detect(img: &Gray8, rect: [usize; 4], t: u8, out: &mut Vec<Corner>) {
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
    let offsets: [isize; 16] = std::array::from_fn(|k| CIRCLE[k].1 * w as isize + CIRCLE[k].0);
    let rw = x1 - x0;
    // three rolling score rows (previous, current, next) with a zero column on each side
    let mut rows = [vec![0u8; rw + 2], vec![0u8; rw + 2], vec![0u8; rw + 2]];
    let mut mask = Vec::with_capacity(rw);
    let mut fill = |y: usize, row: &mut Vec<u8>| {
        row.iter_mut().for_each(|v| *v = 0);
        if y < y0 || y >= y1 {
            return;
        }
        pretest_row(img, y, x0, x1, t, &mut mask);
        for (j, &m) in mask.iter().enumerate() {
            if m != 0 {
                row[j + 1] = score_at(&img.data, y * w + x0 + j, &offsets, t);
            }
        }
    };
    fill(y0, &mut rows[1]);
    for y in y0..y1 {
        let [prev, cur, next] = &mut rows;
        fill(y + 1, next);
        for j in 1..=rw {
            let s = cur[j];
            if s != 0
                && s > cur[j - 1]
                && s > cur[j + 1]
                && s > prev[j - 1]
                && s > prev[j]
                && s > prev[j + 1]
                && s > next[j - 1]
                && s > next[j]
                && s > next[j + 1]
            {
                out.push(Corner {
                    x: (x0 + j - 1) as u16,
                    y: y as u16,
                    score: s,
                });
            }
        }
        rows.rotate_left(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_force(img: &Gray8, t: u8) -> Vec<(usize, usize, u8)> {
        let w = img.width;
        let offsets: [isize; 16] = std::array::from_fn(|k| CIRCLE[k].1 * w as isize + CIRCLE[k].0);
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

    #[test]
    fn simd_pretest_finds_the_same_corners_as_brute_force() {
        let (w, h) = (97, 61);
        let mut img = Gray8::new(w, h, 0);
        let mut s = 12345u32;
        for v in img.data.iter_mut() {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            *v = (s >> 24) as u8;
        }
        for t in [7u8, 20, 60] {
            let mut got = vec![];
            detect(&img, [0, 0, w, h], t, &mut got);
            let got: Vec<_> = got
                .iter()
                .map(|c| (c.x as usize, c.y as usize, c.score))
                .collect();
            let want = brute_force(&img, t);
            assert!(!want.is_empty());
            assert_eq!(got, want, "threshold {t}");
        }
    }

    #[test]
    fn a_bright_dot_is_a_corner_with_its_contrast_as_score() {
        let mut img = Gray8::new(20, 20, 50);
        img.set(10, 10, 150);
        let mut got = vec![];
        detect(&img, [0, 0, 20, 20], 20, &mut got);
        assert_eq!(got.len(), 1);
        assert_eq!((got[0].x, got[0].y, got[0].score), (10, 10, 99));
        let mut none = vec![];
        detect(&Gray8::new(5, 5, 0), [0, 0, 5, 5], 20, &mut none);
        assert!(none.is_empty());
    }
}
