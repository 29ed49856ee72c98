//! Dense depth from a rectified stereo pair, for the parts of the system that read a depth
//! image (the dynamic front-end's depth bands and world-motion check, map hygiene): census
//! block matching along the rows at reduced resolution, winner takes all, with a uniqueness,
//! texture and left-right check, and a parabola for the sub-pixel disparity.
//!
//! Census costs are immune to a gain or offset between the two cameras; matching at half
//! resolution keeps the cost a few milliseconds a frame (the front-end needs metres to a few
//! per cent, not per-pixel edges). Pixels without a trusted match are 0, as in an RGB-D hole.
//!
//! ```
//! use stillpoint_image::{Gray8, stereo_depth::{DenseStereo, DenseStereoParams}};
//! // A random texture seen 8 pixels apart: bf / 8 metres everywhere it can be matched.
//! let (w, h) = (96, 48);
//! let mut seed = 7u32;
//! let tex: Vec<u8> = (0..w * h).map(|_| { seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223); (seed >> 24) as u8 }).collect();
//! let left = Gray8::from_vec(w, h, tex.clone()).unwrap();
//! let right = Gray8::from_vec(w, h, (0..w * h).map(|i| if i % w + 8 < w { tex[i + 8] } else { 0 }).collect()).unwrap();
//! let depth = DenseStereo::default().depth(&left, &right, 40.0, &DenseStereoParams::default());
//! assert!((depth.get(60, 24) - 5.0).abs() < 0.1);
//! ```

use crate::{DepthMetres, Gray8};

/// How the dense stereo depth is matched (`stereo.dense_depth` in the settings tree).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenseStereoParams {
    /// Match the pair densely: every frame of a run with a dynamic front-end (its depth bands,
    /// world-motion check and map hygiene), else each keyframe (the dense cloud).
    pub enabled: bool,
    /// Match at 1/`downsample` of the image size (2: a quarter of the pixels).
    pub downsample: usize,
    /// Largest disparity searched, in full-size pixels (128: 0.42 m at a 0.1 m baseline and
    /// fx 535; 3 m on KITTI).
    pub max_disparity_px: f32,
    /// Half side of the census window, at the matching size (2: 5x5).
    pub census_radius: usize,
    /// Half side of the window the census costs are summed over (3: 7x7).
    pub window_radius: usize,
    /// The best cost must be below this share of the best cost more than one disparity away.
    pub uniqueness: f32,
    /// Mean absolute horizontal gradient (grey levels) a window needs to be matched at all.
    pub min_texture: f32,
    /// Largest disagreement of the left and right images' disparities, at the matching size.
    pub left_right_px: u16,
}

impl Default for DenseStereoParams {
    fn default() -> Self {
        Self {
            enabled: true,
            downsample: 2,
            max_disparity_px: 128.0,
            census_radius: 2,
            window_radius: 3,
            uniqueness: 0.9,
            min_texture: 2.0,
            left_right_px: 1,
        }
    }
}

/// The matcher's buffers, kept between frames so a frame allocates nothing.
#[derive(Default)]
pub struct DenseStereo {
    left: Vec<u8>,
    right: Vec<u8>,
    census_left: Vec<u32>,
    census_right: Vec<u32>,
    texture: Vec<u16>,
    /// One row's census costs, `[x][d]`.
    raw: Vec<u16>,
    /// One row of the right census, reversed.
    reversed: Vec<u32>,
    /// The last `2r+1` rows' costs summed along x, `[row % (2r+1)][x][d]`.
    ring: Vec<u16>,
    /// Those summed down the window's rows: the window costs of the current row, `[x][d]`.
    column: Vec<u16>,
    /// The window costs of every row, kept for the left-right check, `[y][x][d]`.
    volume: Vec<u16>,
}

/// The sizes of one frame's matching.
#[derive(Clone, Copy)]
struct Grid {
    w: usize,
    h: usize,
    /// Disparities searched: 0..d.
    d: usize,
    census_radius: usize,
    window_radius: usize,
}

impl DenseStereo {
    /// Depth in metres for every pixel of `left` (0 where no trusted match), from a rectified
    /// pair of the same size; `bf` is the baseline times fx (full-size pixels x metres).
    pub fn depth(
        &mut self,
        left: &Gray8,
        right: &Gray8,
        bf: f32,
        p: &DenseStereoParams,
    ) -> DepthMetres {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt") {
            // SAFETY: the features are available; the body is the portable one.
            return unsafe { self.depth_avx2(left, right, bf, p) };
        }
        self.depth_portable(left, right, bf, p)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,popcnt")]
    unsafe fn depth_avx2(
        &mut self,
        left: &Gray8,
        right: &Gray8,
        bf: f32,
        p: &DenseStereoParams,
    ) -> DepthMetres {
        self.depth_portable(left, right, bf, p)
    }

    #[inline(always)]
    fn depth_portable(
        &mut self,
        left: &Gray8,
        right: &Gray8,
        bf: f32,
        p: &DenseStereoParams,
    ) -> DepthMetres {
        let (w, h) = (left.width, left.height);
        let mut out = DepthMetres::new(w, h, 0.0);
        let ds = p.downsample.max(1);
        let (sw, sh) = (w / ds, h / ds);
        let reach = p.census_radius + p.window_radius;
        if right.width != w || right.height != h || sw <= 2 * reach + 2 || sh <= 2 * reach + 1 {
            return out;
        }
        shrink(left, ds, &mut self.left);
        shrink(right, ds, &mut self.right);
        census(&self.left, sw, sh, p.census_radius, &mut self.census_left);
        census(&self.right, sw, sh, p.census_radius, &mut self.census_right);
        texture(&self.left, sw, sh, p.window_radius, &mut self.texture);
        let grid = Grid {
            w: sw,
            h: sh,
            d: ((p.max_disparity_px / ds as f32) as usize).clamp(1, sw - 2 * reach - 1) + 1,
            census_radius: p.census_radius,
            window_radius: p.window_radius,
        };
        self.cost_volume(grid);
        let (dn, side) = (grid.d, 2 * p.window_radius + 1);
        let min_texture = (p.min_texture * (side * side) as f32) as u16;
        for y in reach..sh - reach {
            for x in reach..sw - reach - 1 {
                let i = y * sw + x;
                if self.texture[i] < min_texture {
                    continue;
                }
                // Disparities that keep the right window inside the image.
                let reachable = dn.min(x - reach + 1);
                let costs = &self.volume[i * dn..i * dn + reachable];
                let Some(best) = lowest(costs) else { continue };
                let below = costs[..best.saturating_sub(1)].iter().copied().min();
                let above = costs.get(best + 2..).and_then(|c| c.iter().copied().min());
                let second = below.into_iter().chain(above).min().unwrap_or(u16::MAX);
                if best == 0 || f32::from(costs[best]) >= p.uniqueness * f32::from(second) {
                    continue;
                }
                // The right pixel's own best match must lead back here.
                let xr = x - best;
                let right_best = (0..dn.min(sw - reach - 1 - xr))
                    .min_by_key(|&d| self.volume[(i - best + d) * dn + d])
                    .unwrap_or(0);
                if right_best.abs_diff(best) > usize::from(p.left_right_px) {
                    continue;
                }
                let mut disparity = best as f32;
                if best + 1 < reachable {
                    let (c0, c1, c2) = (
                        f32::from(costs[best - 1]),
                        f32::from(costs[best]),
                        f32::from(costs[best + 1]),
                    );
                    let curvature = c0 - 2.0 * c1 + c2;
                    if curvature > 0.0 {
                        disparity += ((c0 - c2) / (2.0 * curvature)).clamp(-0.5, 0.5);
                    }
                }
                let z = bf / (disparity * ds as f32);
                for fy in y * ds..(y + 1) * ds {
                    out.data[fy * w + x * ds..fy * w + (x + 1) * ds].fill(z);
                }
            }
        }
        out
    }

    /// `volume[y][x][d]`: census Hamming distances between left (x, y) and right (x - d, y),
    /// summed over the window, for the rows and columns whose window lies inside the image.
    #[inline(always)]
    fn cost_volume(&mut self, g: Grid) {
        let (w, dn, r) = (g.w, g.d, g.window_radius);
        let side = 2 * r + 1;
        self.raw.clear();
        self.raw.resize(w * dn, 0);
        self.ring.clear();
        self.ring.resize(side * w * dn, 0);
        self.column.clear();
        self.column.resize(w * dn, 0);
        self.volume.clear();
        self.volume.resize(g.h * w * dn, u16::MAX);
        let top = g.census_radius;
        for y in top..g.h - top {
            let slot = (y % side) * w * dn;
            // Leaving the window: the row `side` rows up, still in its ring slot.
            if y >= top + side {
                let old = &self.ring[slot..slot + w * dn];
                for (c, o) in self.column.iter_mut().zip(old) {
                    *c -= o;
                }
            }
            let row = y * w;
            self.reversed.clear();
            self.reversed
                .extend(self.census_right[row..row + w].iter().rev());
            row_costs_portable(
                &self.census_left[row..row + w],
                &self.reversed,
                dn,
                &mut self.raw,
            );
            let sums = &mut self.ring[slot..slot + w * dn];
            box_along_x(&self.raw, w, dn, r, sums);
            for (c, s) in self.column.iter_mut().zip(sums.iter()) {
                *c += s;
            }
            if y + 1 >= top + side {
                let centre = y - r;
                self.volume[centre * w * dn..(centre + 1) * w * dn].copy_from_slice(&self.column);
            }
        }
    }
}

/// The lowest entry's index (the first of equals).
#[inline(always)]
fn lowest(costs: &[u16]) -> Option<usize> {
    let min = costs.iter().copied().min()?;
    costs.iter().position(|&c| c == min)
}

/// `raw[x][d]` = Hamming distance of left x and right x - d (24, the most, where x < d);
/// the right row comes reversed, so that x - d for d = 0, 1, ... reads forwards (vectorised).
#[inline(always)]
fn row_costs_portable(left: &[u32], reversed: &[u32], dn: usize, raw: &mut [u16]) {
    let w = reversed.len();
    for (x, (&l, out)) in left.iter().zip(raw.chunks_exact_mut(dn)).enumerate() {
        let reachable = dn.min(x + 1);
        let from = &reversed[w - 1 - x..w - 1 - x + reachable];
        for (o, &r) in out[..reachable].iter_mut().zip(from) {
            *o = (l ^ r).count_ones() as u16;
        }
        out[reachable..].fill(24);
    }
}

/// `sums[x][d]` = sum of `raw[x-r..=x+r][d]` for x in r..w-r (0 elsewhere).
#[inline(always)]
fn box_along_x(raw: &[u16], w: usize, dn: usize, r: usize, sums: &mut [u16]) {
    let side = 2 * r + 1;
    sums.fill(0);
    let (first, rest) = sums.split_at_mut((r + 1) * dn);
    let acc = &mut first[r * dn..];
    for x in 0..side {
        for (a, v) in acc.iter_mut().zip(&raw[x * dn..(x + 1) * dn]) {
            *a += v;
        }
    }
    let mut previous: &[u16] = acc;
    for (k, out) in rest.chunks_exact_mut(dn).take(w - side).enumerate() {
        // Centre x = r + 1 + k: in raw[x + r], out raw[x - r - 1].
        let x = r + 1 + k;
        let (add, sub) = (
            &raw[(x + r) * dn..(x + r + 1) * dn],
            &raw[(x - r - 1) * dn..(x - r) * dn],
        );
        for (((o, p), a), s) in out.iter_mut().zip(previous).zip(add).zip(sub) {
            *o = p + a - s;
        }
        previous = out;
    }
}

/// Mean of each `ds` x `ds` block.
#[inline(always)]
fn shrink(img: &Gray8, ds: usize, out: &mut Vec<u8>) {
    let (sw, sh) = (img.width / ds, img.height / ds);
    out.clear();
    out.reserve(sw * sh);
    let n = (ds * ds) as u32;
    for y in 0..sh {
        for x in 0..sw {
            let mut s = 0u32;
            for dy in 0..ds {
                let row = (y * ds + dy) * img.width + x * ds;
                s += img.data[row..row + ds]
                    .iter()
                    .map(|&v| v as u32)
                    .sum::<u32>();
            }
            out.push(((s + n / 2) / n) as u8);
        }
    }
}

/// One bit per neighbour in the (2r+1)^2 window: darker than the centre. 0 near the border.
#[inline(always)]
fn census(img: &[u8], w: usize, h: usize, r: usize, out: &mut Vec<u32>) {
    out.clear();
    out.resize(w * h, 0);
    if w <= 2 * r || h <= 2 * r {
        return;
    }
    for y in r..h - r {
        let centre = &img[y * w + r..(y + 1) * w - r];
        let bits = &mut out[y * w + r..(y + 1) * w - r];
        // Neighbour by neighbour over the whole row: each pass is one vector compare.
        for yy in y - r..=y + r {
            for dx in 0..=2 * r {
                if (yy, dx) == (y, r) {
                    continue;
                }
                let start = yy * w + dx;
                let near = &img[start..start + centre.len()];
                for ((b, &n), &c) in bits.iter_mut().zip(near).zip(centre) {
                    *b = (*b << 1) | u32::from(n < c);
                }
            }
        }
    }
}

/// Sum of absolute horizontal gradients over the window around each pixel (0 near the border).
#[inline(always)]
fn texture(img: &[u8], w: usize, h: usize, r: usize, out: &mut Vec<u16>) {
    out.clear();
    out.resize(w * h, 0);
    let side = 2 * r + 1;
    if w <= side + 1 || h < side {
        return;
    }
    // Window sums of |I(x+1) - I(x)| along each row, then down the columns.
    let mut rows = vec![0u16; w * h];
    for y in 0..h {
        let row = &img[y * w..(y + 1) * w];
        let g: Vec<u16> = row
            .windows(2)
            .map(|p| u16::from(p[1].abs_diff(p[0])))
            .collect();
        let sums = &mut rows[y * w..(y + 1) * w];
        let mut acc: u16 = g[..side].iter().sum();
        sums[r] = acc;
        for x in r + 1..w - r - 1 {
            acc = acc + g[x + r] - g[x - r - 1];
            sums[x] = acc;
        }
    }
    let mut column = vec![0u16; w];
    for y in 0..side {
        for (c, s) in column.iter_mut().zip(&rows[y * w..(y + 1) * w]) {
            *c = c.saturating_add(*s);
        }
    }
    for y in r..h - r {
        out[y * w..(y + 1) * w].copy_from_slice(&column);
        if y + r + 1 < h {
            let (add, sub) = (
                &rows[(y + r + 1) * w..(y + r + 2) * w],
                &rows[(y - r) * w..(y - r + 1) * w],
            );
            for ((c, a), s) in column.iter_mut().zip(add).zip(sub) {
                *c = c.wrapping_add(*a).wrapping_sub(*s);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(w: usize, h: usize, mut seed: u32) -> Vec<u8> {
        (0..w * h)
            .map(|_| {
                seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (seed >> 24) as u8
            })
            .collect()
    }

    /// A far wall (disparity 12) with a near square (disparity 40) in front of it, both randomly
    /// textured; the right image sees each shifted by its disparity, with a gain and offset.
    fn two_planes(w: usize, h: usize) -> (Gray8, Gray8, Vec<f32>) {
        let wall = noise(w + 64, h, 1);
        let near = noise(w + 64, h, 2);
        let (x0, x1, y0, y1) = (w / 3, 2 * w / 3, h / 4, 3 * h / 4);
        let sample = |x: usize, y: usize, d: usize, right: bool| -> (u8, usize) {
            // Where (x, y) of the given image sees: the square, or the wall behind it.
            let xs = if right { x + 40 } else { x };
            if (x0..x1).contains(&xs) && (y0..y1).contains(&y) {
                return (near[y * (w + 64) + xs], 40);
            }
            let xw = if right { x + d } else { x };
            (wall[y * (w + 64) + xw], 12)
        };
        let mut l = Gray8::new(w, h, 0);
        let mut r = Gray8::new(w, h, 0);
        let mut truth = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let (v, d) = sample(x, y, 12, false);
                l.set(x, y, v);
                truth[y * w + x] = d as f32;
                let (v, _) = sample(x, y, 12, true);
                r.set(x, y, (v as f32 * 0.8 + 20.0) as u8);
            }
        }
        (l, r, truth)
    }

    #[test]
    fn two_planes_come_back_at_their_depths() {
        let (w, h) = (320, 160);
        let (l, r, truth) = two_planes(w, h);
        let bf = 50.0;
        let depth = DenseStereo::default().depth(&l, &r, bf, &DenseStereoParams::default());
        let (mut valid, mut good) = (0, 0);
        for (z, d) in depth.data.iter().zip(&truth) {
            if *z > 0.0 {
                valid += 1;
                let expected = bf / d;
                good += usize::from((z - expected).abs() < 0.05 * expected);
            }
        }
        // Borders, the occluded strip beside the square and the search's left edge are holes.
        assert!(valid > w * h / 2, "{valid} of {} matched", w * h);
        assert!(
            good as f64 > 0.97 * valid as f64,
            "{good} of {valid} within 5 %"
        );
    }

    #[test]
    fn a_blank_pair_gives_no_depth() {
        let flat = Gray8::new(200, 100, 128);
        let depth = DenseStereo::default().depth(&flat, &flat, 50.0, &DenseStereoParams::default());
        assert!(depth.data.iter().all(|&z| z == 0.0));
    }

    #[test]
    fn pairs_of_different_sizes_give_no_depth() {
        let depth = DenseStereo::default().depth(
            &Gray8::new(200, 100, 0),
            &Gray8::new(100, 100, 0),
            50.0,
            &DenseStereoParams::default(),
        );
        assert_eq!((depth.width, depth.height), (200, 100));
        assert!(depth.data.iter().all(|&z| z == 0.0));
    }
}
