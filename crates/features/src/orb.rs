//! ORB extraction as ORB-SLAM3's `ORBextractor` does it (file `ORBextractor.cc` of ORB-SLAM3
//! v1.0): image pyramid, FAST on a grid of cells with a fallback threshold, quadtree ("octree")
//! distribution, intensity-centroid angle, steered BRIEF on a blurred level.

use std::sync::Arc;
use std::time::Instant;

use stillpoint_core::ms_since;

use crate::fast::{self, Corner, FastScratch};
use crate::imgops::{gaussian_blur7_with, resize_linear_into};
use crate::pattern::BIT_PATTERN_31;
use crate::{Descriptor, valid};
use stillpoint_image::Gray8;

/// Side of the BRIEF patch (ORB-SLAM3 `PATCH_SIZE`).
const PATCH_SIZE: f32 = 31.0;
/// Radius of the orientation patch (ORB-SLAM3 `HALF_PATCH_SIZE`).
const HALF_PATCH_SIZE: usize = 15;
/// Keypoints stay this far from a level's border (ORB-SLAM3 `EDGE_THRESHOLD`).
const EDGE_THRESHOLD: usize = 19;
/// Side of the FAST grid cells (ORB-SLAM3 `W` in `ComputeKeyPointsOctTree`).
const CELL: f32 = 35.0;

/// A keypoint in level-0 pixel coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeyPoint {
    /// Column, level-0 pixels.
    pub x: f32,
    /// Row, level-0 pixels.
    pub y: f32,
    /// Pyramid level it was found on (0 = full resolution).
    pub octave: u8,
    /// Orientation in degrees, [0, 360), by intensity centroid.
    pub angle: f32,
    /// FAST score (larger = stronger corner).
    pub response: f32,
    /// Diameter of the described patch in level-0 pixels (31 x scale of its level).
    pub size: f32,
}

pub use stillpoint_core::OrbParams;

/// Keypoints and their descriptors (same length, same order; grouped by octave).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OrbFeatures {
    /// The keypoints, level-0 pixels.
    pub keypoints: Vec<KeyPoint>,
    /// One descriptor per keypoint.
    pub descriptors: Vec<Descriptor>,
}

/// Time of each stage of the last [`OrbExtractor::extract`] call, in milliseconds, summed over
/// the levels (with [`OrbExtractor::extract_on`] on two threads, more than the call took).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OrbTimings {
    /// Building the scale pyramid.
    pub pyramid_ms: f64,
    /// FAST corners and their Harris scores.
    pub fast_ms: f64,
    /// Spreading corners over the image (quadtree).
    pub distribute_ms: f64,
    /// Orientation, blur and descriptors.
    pub describe_ms: f64,
}

/// ORB-SLAM3-style ORB extractor; keeps its buffers between frames (build it once).
pub struct OrbExtractor {
    params: OrbParams,
    scale_factors: Vec<f32>,
    level_sigma2: Vec<f32>,
    features_per_level: Vec<usize>,
    /// The orientation patch as per-row column weights (built from `umax`).
    angle_patch: AnglePatch,
    /// Levels 1.. (level 0 is the input itself); buffers kept between frames, the first
    /// `pyramid_len` hold the current frame.
    pyramid: Vec<Gray8>,
    pyramid_len: usize,
    /// Buffers of the calling thread and of the helper of [`Self::extract_on`].
    scratch: [LevelScratch; 2],
    timings: OrbTimings,
    score: OrbScore,
    /// Rectangles `[x1, y1, x2, y2]` (level-0 pixels) where no corner is kept, so the budget
    /// goes to the rest of the image.
    exclude: Vec<[f32; 4]>,
    /// Level-0 mask (non-zero = keep no corner there), beside the rectangles; shared with
    /// whoever set it, who may report it.
    exclude_mask: Option<Arc<Gray8>>,
    /// Per level, the corners of the last extraction that the mask kept out, in FAST's order
    /// (for [`Self::extract_masked`]).
    masked_corners: Vec<Vec<Corner>>,
}

/// Which corner score picks the keypoint kept in each quadtree node.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OrbScore {
    /// FAST score, as ORB-SLAM3.
    #[default]
    Fast,
    /// Harris response of the 7x7 block, as OpenCV's ORB ranks keypoints.
    Harris,
}

impl OrbExtractor {
    /// Build an extractor; out-of-range parameters are clamped (at least 1 level, scale > 1).
    pub fn new(params: OrbParams) -> Self {
        let mut params = params;
        params.n_levels = params.n_levels.clamp(1, 32);
        if !(params.scale_factor.is_finite() && params.scale_factor > 1.0) {
            params.scale_factor = 1.2;
        }
        params.min_th_fast = params.min_th_fast.max(1);
        params.ini_th_fast = params.ini_th_fast.max(params.min_th_fast);
        let n = params.n_levels;
        let scale_factors: Vec<f32> = (0..n)
            .scan(1.0f32, |s, i| {
                if i > 0 {
                    *s *= params.scale_factor;
                }
                Some(*s)
            })
            .collect();
        let level_sigma2 = scale_factors.iter().map(|s| s * s).collect();
        let features_per_level = features_per_level(params.n_features, params.scale_factor, n);
        let angle_patch = AnglePatch::new(&orientation_umax());
        Self {
            params,
            scale_factors,
            level_sigma2,
            features_per_level,
            angle_patch,
            pyramid: Vec::new(),
            pyramid_len: 0,
            scratch: Default::default(),
            timings: OrbTimings::default(),
            score: OrbScore::default(),
            exclude: Vec::new(),
            exclude_mask: None,
            masked_corners: Vec::new(),
        }
    }

    /// Keep no corner inside these rectangles (`[x1, y1, x2, y2]`, level-0 pixels) in the next
    /// extractions, so that the feature budget is spent on the rest of the image (the boxes of
    /// objects seen moving, whose keypoints would be culled anyway). Empty = the whole image.
    ///
    /// ```
    /// use stillpoint_features::{OrbExtractor, OrbParams};
    /// use stillpoint_image::Gray8;
    /// let mut img = Gray8::new(320, 240, 0);
    /// for y in 0..240 { for x in 0..320 { img.set(x, y, ((x / 6 * 37 + y / 6 * 91) % 200 + 20) as u8); } }
    /// let mut orb = OrbExtractor::new(OrbParams { n_features: 300, ..Default::default() });
    /// orb.set_exclusion(vec![[0.0, 0.0, 160.0, 240.0]]);
    /// let f = orb.extract(&img);
    /// assert!(f.keypoints.len() > 150 && f.keypoints.iter().all(|k| k.x >= 160.0));
    /// ```
    pub fn set_exclusion(&mut self, rects: Vec<[f32; 4]>) {
        self.exclude = rects;
    }

    /// Keep no corner where `mask` (level-0 pixels) is non-zero in the next extractions: a
    /// mover's own pixels rather than its whole box (`None` = no mask).
    pub fn set_exclusion_mask(&mut self, mask: Option<Arc<Gray8>>) {
        self.exclude_mask = mask;
    }

    /// Choose the score that picks the keypoint of each quadtree node (and is reported as
    /// `KeyPoint::response`).
    pub fn with_score(mut self, score: OrbScore) -> Self {
        self.score = score;
        self
    }

    /// The third FAST threshold for this frame: `low_texture_th_fast` raised to the image's
    /// noise times `noise_th_factor`; none when that is not under `min_th_fast`.
    fn low_texture_threshold(&self, img: &Gray8) -> Option<u8> {
        let p = &self.params;
        if p.low_texture_th_fast == 0 || p.low_texture_th_fast >= p.min_th_fast {
            return None;
        }
        let noise_floor = (p.noise_th_factor.max(0.0) * noise_sigma(img)).round();
        let th = (p.low_texture_th_fast as f32).max(noise_floor);
        (th < p.min_th_fast as f32).then_some(th as u8)
    }

    /// The settings in use.
    pub fn params(&self) -> &OrbParams {
        &self.params
    }

    /// Scale of each level relative to level 0 (1, 1.2, 1.44, ...).
    pub fn scale_factors(&self) -> &[f32] {
        &self.scale_factors
    }

    /// Squared scale of each level (ORB-SLAM's `mvLevelSigma2`, the measurement variance factor).
    pub fn level_sigma2(&self) -> &[f32] {
        &self.level_sigma2
    }

    /// Target number of features of each level.
    pub fn features_per_level(&self) -> &[usize] {
        &self.features_per_level
    }

    /// Stage timings of the last `extract`.
    pub fn timings(&self) -> OrbTimings {
        self.timings
    }

    /// Extract keypoints (level-0 pixels) and descriptors. A blank, tiny or malformed image
    /// gives empty features.
    pub fn extract(&mut self, img: &Gray8) -> OrbFeatures {
        self.extract_on(img, 1)
    }

    /// [`Self::extract`] with the pyramid's levels shared between `threads` threads (the
    /// calling one and at most one more): the same features in the same order, sooner when a
    /// core is free. Each level is independent once the pyramid is built; the two groups are
    /// balanced by pixel count (level 0 is a third of the pyramid).
    pub fn extract_on(&mut self, img: &Gray8, threads: usize) -> OrbFeatures {
        let mut out = OrbFeatures::default();
        self.timings = OrbTimings::default();
        if !valid(img) {
            return out;
        }
        let t0 = Instant::now();
        self.build_pyramid(img);
        self.timings.pyramid_ms = ms_since(t0);
        let low_th = self.low_texture_threshold(img);
        let mut levels: Vec<(usize, &Gray8)> = Vec::with_capacity(self.params.n_levels);
        for level in 0..self.params.n_levels {
            let level_img = if level == 0 {
                img
            } else {
                match self.pyramid[..self.pyramid_len].get(level - 1) {
                    Some(l) => l,
                    None => break,
                }
            };
            if level_img.width <= 2 * EDGE_THRESHOLD + 1
                || level_img.height <= 2 * EDGE_THRESHOLD + 1
            {
                break;
            }
            levels.push((level, level_img));
        }
        let ctx = LevelContext {
            image: img,
            params: &self.params,
            low_th,
            score: self.score,
            exclude: &self.exclude,
            exclude_mask: self.exclude_mask.as_deref(),
            features_per_level: &self.features_per_level,
            scale_factors: &self.scale_factors,
            angle_patch: &self.angle_patch,
        };
        let [mine, helper] = &mut self.scratch;
        let mut done: Vec<LevelFeatures> = if threads > 1 && levels.len() > 1 {
            // Largest first, each to the group with fewer pixels so far.
            let (mut a, mut b) = (Vec::new(), Vec::new());
            let (mut pa, mut pb) = (0usize, 0usize);
            for &(level, l) in &levels {
                let px = l.width * l.height;
                if pa <= pb {
                    a.push((level, l));
                    pa += px;
                } else {
                    b.push((level, l));
                    pb += px;
                }
            }
            let ctx = &ctx;
            std::thread::scope(|sc| {
                let other = sc.spawn(move || {
                    b.iter()
                        .map(|&(level, l)| extract_level(ctx, level, l, helper))
                        .collect::<Vec<_>>()
                });
                let mut done: Vec<LevelFeatures> = a
                    .iter()
                    .map(|&(level, l)| extract_level(ctx, level, l, mine))
                    .collect();
                match other.join() {
                    Ok(theirs) => done.extend(theirs),
                    Err(payload) => std::panic::resume_unwind(payload),
                }
                done
            })
        } else {
            levels
                .iter()
                .map(|&(level, l)| extract_level(&ctx, level, l, mine))
                .collect()
        };
        done.sort_by_key(|d| d.level);
        self.masked_corners.resize_with(done.len(), Vec::new);
        for d in done {
            self.masked_corners[d.level] = d.masked;
            self.timings.fast_ms += d.fast_ms;
            self.timings.distribute_ms += d.distribute_ms;
            self.timings.describe_ms += d.describe_ms;
            out.keypoints.extend(d.keypoints);
            out.descriptors.extend(d.descriptors);
        }
        out
    }

    /// The keypoints the last extraction's mask ([`Self::set_exclusion_mask`]) kept out, up to
    /// `n_features` spread over the levels as an extraction with that budget spreads them; `img`
    /// must be the image last given. The same keypoints, in the same order, as a fresh
    /// extraction of `img` with that budget and the mask inverted (a mask of 0 and 255), without
    /// building the pyramid or running FAST again: the last extraction's are kept.
    pub fn extract_masked(&mut self, img: &Gray8, n_features: usize) -> OrbFeatures {
        let mut out = OrbFeatures::default();
        if !valid(img) {
            return out;
        }
        let per_level =
            features_per_level(n_features, self.params.scale_factor, self.params.n_levels);
        let ctx = LevelContext {
            image: img,
            params: &self.params,
            low_th: None,
            score: self.score,
            exclude: &[],
            exclude_mask: None,
            features_per_level: &per_level,
            scale_factors: &self.scale_factors,
            angle_patch: &self.angle_patch,
        };
        for (level, corners) in self.masked_corners.iter().enumerate() {
            let level_img = match level {
                0 => img,
                _ => match self.pyramid[..self.pyramid_len].get(level - 1) {
                    Some(l) => l,
                    None => break,
                },
            };
            let mut d = LevelFeatures::new(level);
            describe_level(&ctx, level_img, corners, &mut self.scratch[0], &mut d);
            out.keypoints.extend(d.keypoints);
            out.descriptors.extend(d.descriptors);
        }
        out
    }

    /// The pyramid of the image last given to [`Self::extract`], which must be `img`: level 0 is
    /// `img` itself, the others are kept from that call. Stereo matching refines disparities on
    /// these levels, as ORB-SLAM does.
    pub fn pyramid<'a>(&'a self, img: &'a Gray8) -> Vec<&'a Gray8> {
        std::iter::once(img)
            .chain(self.pyramid[..self.pyramid_len].iter())
            .collect()
    }

    fn build_pyramid(&mut self, img: &Gray8) {
        self.pyramid_len = 0;
        for level in 1..self.params.n_levels {
            let inv = 1.0 / self.scale_factors[level];
            let (w, h) = (
                (img.width as f32 * inv).round() as usize,
                (img.height as f32 * inv).round() as usize,
            );
            if w <= 2 * EDGE_THRESHOLD + 1 || h <= 2 * EDGE_THRESHOLD + 1 {
                break;
            }
            // ORB-SLAM resizes each level from the previous one
            if self.pyramid.len() < level {
                self.pyramid.push(Gray8::new(0, 0, 0));
            }
            let (done, rest) = self.pyramid.split_at_mut(level - 1);
            let prev = if level == 1 { img } else { &done[level - 2] };
            resize_linear_into(prev, w, h, &mut rest[0]);
            self.pyramid_len = level;
        }
    }
}

/// What every level's extraction reads.
struct LevelContext<'a> {
    image: &'a Gray8,
    params: &'a OrbParams,
    low_th: Option<u8>,
    score: OrbScore,
    exclude: &'a [[f32; 4]],
    exclude_mask: Option<&'a Gray8>,
    features_per_level: &'a [usize],
    scale_factors: &'a [f32],
    angle_patch: &'a AnglePatch,
}

/// One thread's buffers, kept between frames.
struct LevelScratch {
    corners: Vec<Corner>,
    fast: FastScratch,
    blurred: Gray8,
    blur_tmp: Vec<u16>,
}

impl Default for LevelScratch {
    fn default() -> Self {
        Self {
            corners: Vec::new(),
            fast: FastScratch::default(),
            blurred: Gray8::new(0, 0, 0),
            blur_tmp: Vec::new(),
        }
    }
}

/// One level's features (level-0 pixels) and its stage times.
struct LevelFeatures {
    level: usize,
    keypoints: Vec<KeyPoint>,
    descriptors: Vec<Descriptor>,
    /// The corners the exclusion mask kept out, in FAST's order.
    masked: Vec<Corner>,
    fast_ms: f64,
    distribute_ms: f64,
    describe_ms: f64,
}

impl LevelFeatures {
    fn new(level: usize) -> Self {
        Self {
            level,
            keypoints: Vec::new(),
            descriptors: Vec::new(),
            masked: Vec::new(),
            fast_ms: 0.0,
            distribute_ms: 0.0,
            describe_ms: 0.0,
        }
    }
}

/// Features per level for a budget of `n_features`: a geometric series with ratio 1/scale
/// (ORB-SLAM3's extractor constructor), the last level taking what is left.
fn features_per_level(n_features: usize, scale_factor: f32, n_levels: usize) -> Vec<usize> {
    let factor = 1.0 / scale_factor;
    let mut desired = n_features as f32 * (1.0 - factor) / (1.0 - factor.powi(n_levels as i32));
    let mut per_level = vec![0usize; n_levels];
    let mut sum = 0;
    for f in per_level.iter_mut().take(n_levels - 1) {
        *f = desired.round() as usize;
        sum += *f;
        desired *= factor;
    }
    per_level[n_levels - 1] = n_features.saturating_sub(sum);
    per_level
}

/// FAST corners of one level, spread by the quadtree, oriented and described.
fn extract_level(
    ctx: &LevelContext,
    level: usize,
    level_img: &Gray8,
    scratch: &mut LevelScratch,
) -> LevelFeatures {
    let t1 = Instant::now();
    let mut out = LevelFeatures::new(level);
    let mut corners = std::mem::take(&mut scratch.corners);
    corners.clear();
    detect_in_cells(
        level_img,
        ctx.params,
        ctx.low_th,
        &mut corners,
        &mut scratch.fast,
    );
    let to_image = LevelToImage::new(ctx.image, level_img);
    if let Some(mask) = ctx.exclude_mask {
        let masked = &mut out.masked;
        corners.retain(|c| {
            let (x, y) = to_image.map(c.x as f32, c.y as f32);
            let free = mask
                .get_checked(x as isize, y as isize)
                .is_none_or(|m| m == 0);
            if !free {
                masked.push(*c);
            }
            free
        });
    }
    if !ctx.exclude.is_empty() {
        corners.retain(|c| {
            let (x, y) = to_image.map(c.x as f32, c.y as f32);
            !ctx.exclude
                .iter()
                .any(|r| x >= r[0] && x <= r[2] && y >= r[1] && y <= r[3])
        });
    }
    out.fast_ms = ms_since(t1);
    describe_level(ctx, level_img, &corners, scratch, &mut out);
    scratch.corners = corners;
    out
}

/// The corners of one level scored, spread by the quadtree to the level's budget, oriented and
/// described into `out`.
fn describe_level(
    ctx: &LevelContext,
    level_img: &Gray8,
    corners: &[Corner],
    scratch: &mut LevelScratch,
    out: &mut LevelFeatures,
) {
    let t1 = Instant::now();
    let (level, (w, h)) = (out.level, (level_img.width, level_img.height));
    let to_image = LevelToImage::new(ctx.image, level_img);
    // The Harris score is part of detection, so it counts in `fast_ms`.
    let scores: Vec<f32> = match ctx.score {
        OrbScore::Harris => corners
            .iter()
            .map(|c| harris_at(level_img, c.x as usize, c.y as usize))
            .collect(),
        OrbScore::Fast => corners.iter().map(|c| c.score as f32).collect(),
    };
    let t2 = Instant::now();
    out.fast_ms += (t2 - t1).as_secs_f64() * 1e3;
    let keep = distribute_quadtree(
        corners,
        &scores,
        [
            EDGE_THRESHOLD - 3,
            w - EDGE_THRESHOLD + 3,
            EDGE_THRESHOLD - 3,
            h - EDGE_THRESHOLD + 3,
        ],
        ctx.features_per_level[level],
    );
    let t3 = Instant::now();
    out.distribute_ms = (t3 - t2).as_secs_f64() * 1e3;
    if keep.is_empty() {
        return;
    }
    gaussian_blur7_with(level_img, &mut scratch.blurred, &mut scratch.blur_tmp);
    let scale = ctx.scale_factors[level];
    let size = PATCH_SIZE * scale;
    out.keypoints.reserve(keep.len());
    out.descriptors.reserve(keep.len());
    for &i in &keep {
        let c = corners[i];
        let (x, y) = (c.x as usize, c.y as usize);
        let angle = ic_angle(level_img, x, y, ctx.angle_patch);
        out.descriptors
            .push(steered_brief(&scratch.blurred, x, y, angle));
        let (dx, dy) = if ctx.params.subpixel {
            corner_offset(level_img, x, y)
        } else {
            (0.0, 0.0)
        };
        let (x0, y0) = to_image.map(x as f32 + dx, y as f32 + dy);
        out.keypoints.push(KeyPoint {
            x: x0,
            y: y0,
            octave: level as u8,
            angle,
            response: scores[i],
            size,
        });
    }
    out.describe_ms = ms_since(t3);
}

/// Level pixel -> level-0 pixel. Each level is resized from the one above with pixel centres
/// aligned (`resize_linear_into`), so the map is `(x + 0.5) * ratio - 0.5` with the levels' true
/// size ratio. ORB-SLAM's `x * scale` is off by `(scale - 1) / 2` (1.3 px on level 7) and its
/// nominal scale by up to 0.3 % (the sizes are rounded): a keypoint found on one level and
/// matched on another then carries a pixel of error that no pose can explain.
#[derive(Clone, Copy, Debug)]
struct LevelToImage {
    ratio_x: f32,
    ratio_y: f32,
}

impl LevelToImage {
    fn new(image: &Gray8, level: &Gray8) -> Self {
        Self {
            ratio_x: image.width as f32 / level.width.max(1) as f32,
            ratio_y: image.height as f32 / level.height.max(1) as f32,
        }
    }

    fn map(&self, x: f32, y: f32) -> (f32, f32) {
        (
            (x + 0.5) * self.ratio_x - 0.5,
            (y + 0.5) * self.ratio_y - 0.5,
        )
    }
}

/// The standard deviation of an image's noise in grey levels (Immerkaer 1996, "Fast noise
/// variance estimation": the mean absolute response to a mask that cancels planes and lines,
/// here on every second row). Texture adds to it, so it errs high.
///
/// ```
/// use stillpoint_image::Gray8;
/// let flat = Gray8::new(64, 48, 90);
/// assert_eq!(stillpoint_features::noise_sigma(&flat), 0.0);
/// ```
pub fn noise_sigma(img: &Gray8) -> f32 {
    let (w, h) = (img.width, img.height);
    if w < 3 || h < 3 || img.data.len() != w * h {
        return 0.0;
    }
    let (sum, n) = laplacian_abs_sum(img);
    (std::f64::consts::FRAC_PI_2.sqrt() * sum as f64 / (6.0 * n as f64)) as f32
}

crate::imgops::simd_fn! {
/// Sum of |[1 -2 1]ᵀ[1 -2 1] * img| over every other row (1, 3, ...) and the inner columns, and
/// how many pixels that is. Exact integers (|r| <= 16 * 255 fits an i16), so the order of the
/// sums (vectorised) does not change the result.
fn laplacian_abs_sum(img: &Gray8) -> (u64, u64) {
    let (w, h) = (img.width, img.height);
    let n = w - 2;
    let (mut sum, mut count) = (0u64, 0u64);
    for y in (1..h - 1).step_by(2) {
        let (a, b, c) = (img.row(y - 1), img.row(y), img.row(y + 1));
        let second = |r: &[u8], x: usize| r[x] as i16 - 2 * r[x + 1] as i16 + r[x + 2] as i16;
        let mut row_sum = 0u32;
        for x in 0..n {
            let r = second(a, x) - 2 * second(b, x) + second(c, x);
            row_sum += r.unsigned_abs() as u32;
        }
        sum += row_sum as u64;
        count += n as u64;
    }
    (sum, count)
}
}

/// FAST on ORB-SLAM3's grid: cells of ~35 px between borders of 16 px, threshold
/// `ini_th_fast`, `min_th_fast` in the cells where that found nothing, and `low_th` (when
/// under `min_th_fast`) in the cells still empty.
fn detect_in_cells(
    img: &Gray8,
    p: &OrbParams,
    low_th: Option<u8>,
    out: &mut Vec<Corner>,
    scratch: &mut FastScratch,
) {
    let (min_x, min_y) = (EDGE_THRESHOLD - 3, EDGE_THRESHOLD - 3);
    let (max_x, max_y) = (
        img.width - EDGE_THRESHOLD + 3,
        img.height - EDGE_THRESHOLD + 3,
    );
    let (width, height) = ((max_x - min_x) as f32, (max_y - min_y) as f32);
    let n_cols = ((width / CELL) as usize).max(1);
    let n_rows = ((height / CELL) as usize).max(1);
    let w_cell = (width / n_cols as f32).ceil() as usize;
    let h_cell = (height / n_rows as f32).ceil() as usize;
    // the strong threshold over the whole detection area at once (a corner's score does not
    // depend on the threshold, so this equals running it cell by cell), then the fallback
    let area = [min_x + 3, min_y + 3, max_x - 3, max_y - 3];
    let first = out.len();
    fast::detect(img, area, p.ini_th_fast, out, scratch);
    let mut per_cell = vec![0u32; n_cols * n_rows];
    let cell_of = |c: &Corner| {
        let j = ((c.x as usize - area[0]) / w_cell).min(n_cols - 1);
        let i = ((c.y as usize - area[1]) / h_cell).min(n_rows - 1);
        i * n_cols + j
    };
    for c in &out[first..] {
        per_cell[cell_of(c)] += 1;
    }
    if p.min_th_fast >= p.ini_th_fast {
        return;
    }
    for i in 0..n_rows {
        for j in 0..n_cols {
            if per_cell[i * n_cols + j] > 0 {
                continue;
            }
            let x0 = area[0] + j * w_cell;
            let y0 = area[1] + i * h_cell;
            let x1 = if j + 1 == n_cols {
                area[2]
            } else {
                (x0 + w_cell).min(area[2])
            };
            let y1 = if i + 1 == n_rows {
                area[3]
            } else {
                (y0 + h_cell).min(area[3])
            };
            if x0 < x1 && y0 < y1 {
                let before = out.len();
                fast::detect(img, [x0, y0, x1, y1], p.min_th_fast, out, scratch);
                if let Some(th) = low_th.filter(|_| out.len() == before) {
                    fast::detect(img, [x0, y0, x1, y1], th, out, scratch);
                }
            }
        }
    }
}

struct Node {
    ul: (i32, i32),
    br: (i32, i32),
    keys: Vec<u32>,
    no_more: bool,
    dead: bool,
}

impl Node {
    /// ORB-SLAM3 `ExtractorNode::DivideNode`: four children split at the ceiling of half.
    fn divide(&self, pts: &[(i32, i32)]) -> [Node; 4] {
        let half_x = ((self.br.0 - self.ul.0) as f32 / 2.0).ceil() as i32;
        let half_y = ((self.br.1 - self.ul.1) as f32 / 2.0).ceil() as i32;
        let (mx, my) = (self.ul.0 + half_x, self.ul.1 + half_y);
        let mk = |ul, br| Node {
            ul,
            br,
            keys: Vec::new(),
            no_more: false,
            dead: false,
        };
        let mut n = [
            mk(self.ul, (mx, my)),
            mk((mx, self.ul.1), (self.br.0, my)),
            mk((self.ul.0, my), (mx, self.br.1)),
            mk((mx, my), self.br),
        ];
        for &k in &self.keys {
            let (x, y) = pts[k as usize];
            let q = match (x < mx, y < my) {
                (true, true) => 0,
                (false, true) => 1,
                (true, false) => 2,
                (false, false) => 3,
            };
            n[q].keys.push(k);
        }
        for c in n.iter_mut() {
            c.no_more = c.keys.len() == 1;
        }
        n
    }
}

/// ORB-SLAM3 `DistributeOctTree`: split the area into quadrants until there are `n` non-empty
/// nodes (largest nodes first in the last round), then keep the strongest corner of each node.
/// `bounds` = [min_x, max_x, min_y, max_y]. Returns indices into `corners`.
fn distribute_quadtree(
    corners: &[Corner],
    scores: &[f32],
    bounds: [usize; 4],
    n: usize,
) -> Vec<usize> {
    let [min_x, max_x, min_y, max_y] = bounds.map(|v| v as i32);
    if corners.is_empty() || n == 0 {
        return Vec::new();
    }
    let pts: Vec<(i32, i32)> = corners
        .iter()
        .map(|c| (c.x as i32 - min_x, c.y as i32 - min_y))
        .collect();
    let (w, h) = ((max_x - min_x) as f32, (max_y - min_y) as f32);
    let n_ini = ((w / h).round() as usize).max(1);
    let hx = w / n_ini as f32;
    let mut nodes: Vec<Node> = (0..n_ini)
        .map(|i| Node {
            ul: ((hx * i as f32) as i32, 0),
            br: ((hx * (i + 1) as f32) as i32, h as i32),
            keys: Vec::new(),
            no_more: false,
            dead: false,
        })
        .collect();
    for (k, &(x, _)) in pts.iter().enumerate() {
        let i = ((x as f32 / hx) as usize).min(n_ini - 1);
        nodes[i].keys.push(k as u32);
    }
    nodes.retain(|nd| !nd.keys.is_empty());
    for nd in nodes.iter_mut() {
        nd.no_more = nd.keys.len() == 1;
    }
    loop {
        let prev_size = nodes.len();
        let mut next = Vec::with_capacity(nodes.len() * 4);
        let mut to_expand: Vec<usize> = Vec::new();
        for nd in nodes.drain(..) {
            if nd.no_more {
                next.push(nd);
                continue;
            }
            for c in nd.divide(&pts) {
                if !c.keys.is_empty() {
                    if c.keys.len() > 1 {
                        to_expand.push(next.len());
                    }
                    next.push(c);
                }
            }
        }
        nodes = next;
        if nodes.len() >= n || nodes.len() == prev_size {
            break;
        }
        if nodes.len() + to_expand.len() * 3 > n {
            // last rounds: split the biggest nodes first, stop as soon as there are enough
            let mut live = nodes.len();
            loop {
                let prev_live = live;
                let mut prev_expand = std::mem::take(&mut to_expand);
                prev_expand.sort_by_key(|&i| nodes[i].keys.len());
                let mut done = false;
                for &i in prev_expand.iter().rev() {
                    let children = nodes[i].divide(&pts);
                    nodes[i].dead = true;
                    nodes[i].keys.clear();
                    live -= 1;
                    for c in children {
                        if !c.keys.is_empty() {
                            if c.keys.len() > 1 {
                                to_expand.push(nodes.len());
                            }
                            nodes.push(c);
                            live += 1;
                        }
                    }
                    if live >= n {
                        done = true;
                        break;
                    }
                }
                if done || live >= n || live == prev_live || to_expand.is_empty() {
                    break;
                }
            }
            nodes.retain(|nd| !nd.dead);
            break;
        }
    }
    nodes
        .iter()
        .filter_map(|nd| {
            let mut best = *nd.keys.first()? as usize;
            for &k in &nd.keys[1..] {
                if scores[k as usize] > scores[best] {
                    best = k as usize;
                }
            }
            Some(best)
        })
        .collect()
}

/// Harris response of the 7x7 block around (x, y) with OpenCV ORB's `HarrisResponses` gradients
/// (k = 0.04). The caller keeps (x, y) 4 px inside the image.
fn harris_at(img: &Gray8, x: usize, y: usize) -> f32 {
    let w = img.width;
    let d = &img.data;
    let (mut a, mut b, mut c) = (0i64, 0i64, 0i64);
    for yy in y - 3..=y + 3 {
        for xx in x - 3..=x + 3 {
            let i = yy * w + xx;
            let p = |o: isize| d[(i as isize + o) as usize] as i32;
            let s = w as isize;
            let ix = (p(1) - p(-1)) * 2 + (p(-s + 1) - p(-s - 1)) + (p(s + 1) - p(s - 1));
            let iy = (p(s) - p(-s)) * 2 + (p(s - 1) - p(-s - 1)) + (p(s + 1) - p(-s + 1));
            a += (ix * ix) as i64;
            b += (iy * iy) as i64;
            c += (ix * iy) as i64;
        }
    }
    let (a, b, c) = (a as f64, b as f64, c as f64);
    // OpenCV's scale: 1 / (4 * block * 255)^4
    let scale = 1.0 / (4.0 * 7.0 * 255.0f64);
    ((a * b - c * c - 0.04 * (a + b) * (a + b)) * scale.powi(4)) as f32
}

/// Where the corner at pixel `(x, y)` lies below the pixel: the point `q` that the 7x7
/// window's gradients best point away from, `sum(g g^T) q = sum(g g^T p)` (Förstner 1987;
/// OpenCV's `cornerSubPix`, one step from the pixel), weighted towards the centre. An edge or
/// a flat patch (an ill-conditioned system) or a point beyond the next pixel keeps the pixel.
/// `(x, y)` must lie 4 pixels inside the image.
fn corner_offset(img: &Gray8, x: usize, y: usize) -> (f32, f32) {
    let w = img.width;
    let d = &img.data;
    let s = w as isize;
    let (mut a, mut b, mut c, mut bx, mut by) = (0f32, 0f32, 0f32, 0f32, 0f32);
    for (j, yy) in (y - 3..=y + 3).enumerate() {
        for (i, xx) in (x - 3..=x + 3).enumerate() {
            let k = (yy * w + xx) as isize;
            let p = |o: isize| d[(k + o) as usize] as f32;
            let ix = (p(1) - p(-1)) * 2.0 + (p(-s + 1) - p(-s - 1)) + (p(s + 1) - p(s - 1));
            let iy = (p(s) - p(-s)) * 2.0 + (p(s - 1) - p(-s - 1)) + (p(s + 1) - p(-s + 1));
            let (px, py) = (i as f32 - 3.0, j as f32 - 3.0);
            let wt = CORNER_WEIGHTS[j] * CORNER_WEIGHTS[i];
            let (gxx, gyy, gxy) = (wt * ix * ix, wt * iy * iy, wt * ix * iy);
            a += gxx;
            b += gyy;
            c += gxy;
            bx += gxx * px + gxy * py;
            by += gxy * px + gyy * py;
        }
    }
    let det = a * b - c * c;
    let half_trace = 0.5 * (a + b);
    // Both eigenvalues clear of zero, the smaller over a tenth of their mean: not an edge.
    let smaller = half_trace - (0.25 * (a - b) * (a - b) + c * c).sqrt();
    if half_trace <= 0.0 || smaller <= 0.1 * half_trace {
        return (0.0, 0.0);
    }
    let qx = (b * bx - c * by) / det;
    let qy = (a * by - c * bx) / det;
    if qx.abs() > 1.0 || qy.abs() > 1.0 || !qx.is_finite() || !qy.is_finite() {
        return (0.0, 0.0);
    }
    (qx, qy)
}

/// Gaussian weights (sigma 2 px) along one axis of [`corner_offset`]'s window.
const CORNER_WEIGHTS: [f32; 7] = [0.3247, 0.6065, 0.8825, 1.0, 0.8825, 0.6065, 0.3247];

/// Half-width of each row of the circular orientation patch of radius 15, made symmetric
/// (ORB-SLAM3's `umax`).
fn orientation_umax() -> Vec<usize> {
    let hp = HALF_PATCH_SIZE;
    let mut umax = vec![0usize; hp + 1];
    let vmax = (hp as f64 * 2f64.sqrt() / 2.0 + 1.0).floor() as usize;
    let vmin = (hp as f64 * 2f64.sqrt() / 2.0).ceil() as usize;
    for (v, u) in umax.iter_mut().enumerate().take(vmax + 1) {
        *u = ((hp * hp - v * v) as f64).sqrt().round() as usize;
    }
    let mut v0 = 0;
    for v in (vmin..=hp).rev() {
        while umax[v0] == umax[v0 + 1] {
            v0 += 1;
        }
        umax[v] = v0;
        v0 += 1;
    }
    umax
}

/// The circular orientation patch of radius 15 as weights over 32 columns (`-16..16`, the first
/// always 0) for each row `v` of `0..=15`: the column's `u` inside the circle (`|u| <= umax[v]`),
/// else 0; and 1 / 0 for inside / outside. Fixed-width rows let the sums run in vector lanes.
#[derive(Clone, Debug)]
struct AnglePatch {
    u: [[i16; 32]; HALF_PATCH_SIZE + 1],
    inside: [[i16; 32]; HALF_PATCH_SIZE + 1],
}

impl AnglePatch {
    fn new(umax: &[usize]) -> Self {
        let mut p = AnglePatch {
            u: [[0; 32]; HALF_PATCH_SIZE + 1],
            inside: [[0; 32]; HALF_PATCH_SIZE + 1],
        };
        for (v, (u_row, inside_row)) in p.u.iter_mut().zip(&mut p.inside).enumerate() {
            let r = if v == 0 { HALF_PATCH_SIZE } else { umax[v] } as i16;
            for (i, (u_col, in_col)) in u_row.iter_mut().zip(inside_row.iter_mut()).enumerate() {
                let u = i as i16 - 16;
                if u.abs() <= r {
                    *u_col = u;
                    *in_col = 1;
                }
            }
        }
        p
    }
}

/// Orientation (degrees, [0, 360)) of the intensity centroid of the circular patch of radius 15
/// around (x, y) (ORB-SLAM3 `IC_Angle`). The caller keeps (x, y) 16 px inside the image.
fn ic_angle(img: &Gray8, x: usize, y: usize, patch: &AnglePatch) -> f32 {
    let (m01, m10) = angle_moments(&img.data, y * img.width + x, img.width, patch);
    let a = (m01 as f32).atan2(m10 as f32).to_degrees();
    if a < 0.0 { a + 360.0 } else { a }
}

crate::imgops::simd_fn! {
/// The patch's moments `(m01, m10)` around `data[c]` (rows `width` apart): every row pair
/// `±v` over 32 columns with the patch's weights. Exact integers, as ORB-SLAM's loops.
fn angle_moments(data: &[u8], c: usize, width: usize, patch: &AnglePatch) -> (i32, i32) {
    let row = |start: usize| -> &[u8; 32] {
        data[start - 16..start + 16].try_into().expect("32 bytes")
    };
    let centre = row(c);
    let mut m10: i32 = centre
        .iter()
        .zip(&patch.u[0])
        .map(|(&p, &u)| (u * p as i16) as i32)
        .sum();
    let mut m01 = 0i32;
    for v in 1..=HALF_PATCH_SIZE {
        let (up, down) = (row(c + v * width), row(c - v * width));
        let (mut s10, mut s01) = (0i32, 0i32);
        for i in 0..32 {
            let (p, m) = (up[i] as i16, down[i] as i16);
            s10 += (patch.u[v][i] * (p + m)) as i32;
            s01 += (patch.inside[v][i] * (p - m)) as i32;
        }
        m10 += s10;
        m01 += v as i32 * s01;
    }
    (m01, m10)
}
}

/// The pattern's points as f32, first points of all pairs then second points, so the rotation
/// runs over plain arrays (vectorised) before the 512 lookups.
const PATTERN_X: [f32; 512] = pattern_coords(0);
const PATTERN_Y: [f32; 512] = pattern_coords(1);

const fn pattern_coords(axis: usize) -> [f32; 512] {
    let mut out = [0f32; 512];
    let mut i = 0;
    while i < 256 {
        out[i] = BIT_PATTERN_31[i][axis] as f32;
        out[256 + i] = BIT_PATTERN_31[i][2 + axis] as f32;
        i += 1;
    }
    out
}

/// 256-bit BRIEF with ORB's pattern rotated by `angle_deg` (ORB-SLAM3
/// `computeOrbDescriptor`; offsets rounded to nearest like `cvRound`).
fn steered_brief(img: &Gray8, x: usize, y: usize, angle_deg: f32) -> Descriptor {
    let (b, a) = angle_deg.to_radians().sin_cos();
    let mut offsets = [0i32; 512];
    rotated_offsets(a, b, img.width as i32, &mut offsets);
    let c = (y * img.width + x) as isize;
    let d = &img.data;
    let at = |o: i32| d[(c + o as isize) as usize];
    let (first, second) = offsets.split_at(256);
    let mut desc = [0u8; 32];
    for (byte, (p0, p1)) in desc
        .iter_mut()
        .zip(first.chunks_exact(8).zip(second.chunks_exact(8)))
    {
        let mut v = 0u8;
        for bit in 0..8 {
            v |= ((at(p0[bit]) < at(p1[bit])) as u8) << bit;
        }
        *byte = v;
    }
    desc
}

crate::imgops::simd_fn! {
/// Pixel offsets (`dy * width + dx`) of the pattern's points rotated by (cos `a`, sin `b`).
/// Same f32 operations in the same order as a point-by-point loop, so the same rounding.
fn rotated_offsets(a: f32, b: f32, width: i32, out: &mut [i32; 512]) {
    // round half away from zero with a truncating cast: `round_ties_even` is a libm call on
    // baseline x86-64 and differs only on exact .5 ties, which irrational cos/sin never hit
    // (pattern coordinates are within ±13, so |v| < 20 and the unchecked cast, which LLVM
    // vectorises unlike the saturating `as`, truncates exactly like it)
    let round = |v: f32| {
        let r = v + 0.5f32.copysign(v);
        debug_assert!(r.abs() < 64.0);
        // SAFETY: |r| < 20: finite and representable in i32
        unsafe { r.to_int_unchecked::<i32>() }
    };
    for ((o, &px), &py) in out.iter_mut().zip(&PATTERN_X).zip(&PATTERN_Y) {
        let dy = round(px * b + py * a);
        let dx = round(px * a - py * b);
        *o = dy * width + dx;
    }
}
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dark square whose corner lies between pixels, each pixel its covered share (a camera
    /// integrating over the pixel): one step from the nearest whole pixel finds the corner within
    /// 0.15 px, on either side; along a straight edge the pixel is kept.
    #[test]
    fn a_corner_between_pixels_is_found_below_the_pixel() {
        let covered = |lo: f32, p: usize| (p as f32 + 0.5 - lo).clamp(0.0, 1.0);
        for &(cx, cy) in &[(20.3f32, 24.6f32), (20.8, 23.2), (21.5, 24.5), (20.0, 24.0)] {
            // Pixel p spans [p - 0.5, p + 0.5]; the bright area is x >= cx, y >= cy.
            let data = (0..48 * 48)
                .map(|i| {
                    let (x, y) = (i % 48, i / 48);
                    (40.0 + 160.0 * covered(cx, x) * covered(cy, y)).round() as u8
                })
                .collect();
            let img = Gray8::from_vec(48, 48, data).unwrap();
            let (px, py) = (cx.round() as usize, cy.round() as usize);
            let (dx, dy) = corner_offset(&img, px, py);
            let (ex, ey) = (px as f32 + dx - cx, py as f32 + dy - cy);
            assert!(
                ex.abs() < 0.15 && ey.abs() < 0.15,
                "corner ({cx}, {cy}): off by ({ex}, {ey})"
            );
        }
        let edge = Gray8::from_vec(
            48,
            48,
            (0..48 * 48)
                .map(|i| if i % 48 < 24 { 40 } else { 200 })
                .collect(),
        )
        .unwrap();
        assert_eq!(corner_offset(&edge, 24, 24), (0.0, 0.0));
    }

    /// Smooth random texture (sum of blobs) so FAST finds corners everywhere.
    pub(crate) fn texture(w: usize, h: usize, seed: u32) -> Gray8 {
        let mut img = Gray8::new(w, h, 0);
        let mut rng = crate::test_rng::Lcg(seed);
        let mut rnd = || rng.unit();
        let mut f = vec![0f32; w * h];
        for _ in 0..(w * h / 60) {
            let (cx, cy, r, a) = (rnd() * w as f32, rnd() * h as f32, 2.0 + rnd() * 6.0, rnd());
            let (x0, x1) = ((cx - r) as usize, ((cx + r) as usize).min(w - 1));
            let (y0, y1) = ((cy - r) as usize, ((cy + r) as usize).min(h - 1));
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let (dx, dy) = (x as f32 - cx, y as f32 - cy);
                    if dx * dx + dy * dy < r * r {
                        f[y * w + x] += a * 90.0 - 45.0;
                    }
                }
            }
        }
        for (o, v) in img.data.iter_mut().zip(&f) {
            *o = (128.0 + v).clamp(0.0, 255.0) as u8;
        }
        img
    }

    /// A flat grey image with Gaussian noise of `sigma` grey levels.
    fn noisy_flat(w: usize, h: usize, sigma: f32, seed: u32) -> Gray8 {
        let mut rng = crate::test_rng::Lcg(seed);
        let mut img = Gray8::new(w, h, 0);
        for o in img.data.iter_mut() {
            let (u1, u2) = (rng.unit().max(1e-7), rng.unit());
            let g = (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos();
            *o = (128.0 + sigma * g).round().clamp(0.0, 255.0) as u8;
        }
        img
    }

    #[test]
    fn noise_sigma_measures_gaussian_noise() {
        for sigma in [1.0f32, 3.0, 6.0] {
            let est = noise_sigma(&noisy_flat(320, 240, sigma, 7));
            assert!((est - sigma).abs() < 0.15 * sigma + 0.15, "{sigma}: {est}");
        }
    }

    /// A plain, low-contrast surface (blobs of a few grey levels): ORB-SLAM's thresholds (20, 7)
    /// find little there, the third pass fills its cells.
    #[test]
    fn plain_surfaces_get_corners_from_the_low_texture_pass() {
        let mut img = texture(640, 480, 3);
        for v in img.data.iter_mut() {
            *v = (128.0 + (*v as f32 - 128.0) * 0.1).round() as u8;
        }
        let count = |low| {
            OrbExtractor::new(OrbParams {
                low_texture_th_fast: low,
                ..OrbParams::default()
            })
            .extract(&img)
            .keypoints
            .len()
        };
        let (without, with) = (count(0), count(3));
        assert!(with > 2 * without && with > 300, "{without} -> {with}");
    }

    /// On a noisy sensor the third threshold rises with the noise; over `min_th_fast` there is
    /// no third pass at all, and the output is ORB-SLAM's.
    #[test]
    fn noisy_images_skip_the_low_texture_pass() {
        let img = noisy_flat(320, 240, 4.0, 11);
        let run = |low| {
            OrbExtractor::new(OrbParams {
                low_texture_th_fast: low,
                ..OrbParams::default()
            })
            .extract(&img)
        };
        assert_eq!(run(0), run(3));
    }

    /// A wide blob's centroid on every level, mapped back, lands where the blob is: the levels
    /// are resized with pixel centres aligned, so `x * scale` (ORB-SLAM's map) would be off by
    /// `(scale - 1) / 2`, 1.3 px on level 7.
    #[test]
    fn level_pixels_map_back_to_the_image_without_bias() {
        let (w, h) = (640usize, 480usize);
        let (bx, by, sigma) = (301.3f32, 207.8f32, 12.0f32);
        let mut img = Gray8::new(w, h, 0);
        for y in 0..h {
            for x in 0..w {
                let d2 = (x as f32 - bx).powi(2) + (y as f32 - by).powi(2);
                img.data[y * w + x] = (220.0 * (-d2 / (2.0 * sigma * sigma)).exp()).round() as u8;
            }
        }
        let mut orb = OrbExtractor::new(OrbParams::default());
        orb.build_pyramid(&img);
        assert_eq!(orb.pyramid_len, 7);
        for level in &orb.pyramid[..orb.pyramid_len] {
            let (mut sx, mut sy, mut sw) = (0f64, 0f64, 0f64);
            for y in 0..level.height {
                for x in 0..level.width {
                    let v = level.data[y * level.width + x] as f64;
                    sx += v * x as f64;
                    sy += v * y as f64;
                    sw += v;
                }
            }
            let (cx, cy) = ((sx / sw) as f32, (sy / sw) as f32);
            let (x, y) = LevelToImage::new(&img, level).map(cx, cy);
            assert!(
                (x - bx).abs() < 0.2 && (y - by).abs() < 0.2,
                "level {}x{}: ({x}, {y}) for ({bx}, {by})",
                level.width,
                level.height
            );
        }
    }

    #[test]
    fn features_per_level_follow_the_geometric_series() {
        let orb = OrbExtractor::new(OrbParams::default());
        let f = orb.features_per_level();
        assert_eq!(f.iter().sum::<usize>(), 1000);
        assert_eq!(f[0], 217); // ORB-SLAM3 with 1000 features, 1.2, 8 levels
        assert!(f.windows(2).all(|p| p[0] >= p[1]));
        assert!((orb.scale_factors()[7] - 1.2f32.powi(7)).abs() < 1e-4);
        assert!((orb.level_sigma2()[1] - 1.44).abs() < 1e-6);
    }

    #[test]
    fn umax_is_symmetric_circle() {
        let umax = orientation_umax();
        assert_eq!(
            umax,
            vec![15, 15, 15, 15, 14, 14, 14, 13, 13, 12, 11, 10, 9, 8, 6, 3]
        );
        // the vector patch holds the same rows
        let patch = AnglePatch::new(&umax);
        for (v, &r) in umax.iter().enumerate().skip(1) {
            let n: i16 = patch.inside[v].iter().sum();
            assert_eq!(n as usize, 2 * r + 1);
        }
    }

    #[test]
    fn levels_shared_between_two_threads_give_the_same_features() {
        let img = texture(640, 480, 7);
        let mut one = OrbExtractor::new(OrbParams::default());
        let mut two = OrbExtractor::new(OrbParams::default());
        let serial = one.extract(&img);
        assert!(serial.keypoints.len() > 500);
        assert_eq!(two.extract_on(&img, 2), serial);
        // And again, on the buffers the first call left.
        assert_eq!(two.extract_on(&img, 2), serial);
    }

    #[test]
    fn the_masked_corners_kept_are_a_fresh_extraction_under_the_inverted_mask() {
        let img = texture(640, 480, 9);
        let mut mask = Gray8::new(640, 480, 0);
        for y in 60..420 {
            for x in 200..520 {
                mask.set(x, y, 255);
            }
        }
        let mut inverted = mask.clone();
        inverted.data.iter_mut().for_each(|v| *v = 255 - *v);
        let mut orb = OrbExtractor::new(OrbParams::default());
        orb.set_exclusion_mask(Some(Arc::new(mask)));
        for (threads, budget) in [(1, 400), (2, 400), (2, 1000)] {
            orb.extract_on(&img, threads);
            let mut fresh = OrbExtractor::new(OrbParams {
                n_features: budget,
                ..OrbParams::default()
            });
            fresh.set_exclusion_mask(Some(Arc::new(inverted.clone())));
            let expected = fresh.extract(&img);
            assert!(expected.keypoints.len() > budget / 2);
            assert_eq!(
                orb.extract_masked(&img, budget),
                expected,
                "{threads} threads"
            );
        }
    }

    #[test]
    fn keypoints_are_spread_over_a_textured_image() {
        let img = texture(640, 480, 7);
        let mut orb = OrbExtractor::new(OrbParams::default());
        let f = orb.extract(&img);
        assert!(f.keypoints.len() >= 900, "{}", f.keypoints.len());
        assert!(f.keypoints.len() <= 1100);
        let mut cells = [0usize; 100];
        for k in &f.keypoints {
            assert!(k.x >= 0.0 && k.x < 640.0 && k.y >= 0.0 && k.y < 480.0);
            assert!(k.angle >= 0.0 && k.angle < 360.0);
            let (cx, cy) = ((k.x / 64.0) as usize, (k.y / 48.0) as usize);
            cells[cy.min(9) * 10 + cx.min(9)] += 1;
        }
        let max = *cells.iter().max().unwrap_or(&0);
        assert!(
            (max as f32) <= 0.05 * f.keypoints.len() as f32,
            "max cell {max} of {}",
            f.keypoints.len()
        );
        // all 8 octaves are used
        let octaves: std::collections::BTreeSet<u8> =
            f.keypoints.iter().map(|k| k.octave).collect();
        assert_eq!(octaves.len(), 8);
    }

    #[test]
    fn rotation_is_measured_by_the_intensity_centroid() {
        // bright right half → centroid to the right → angle 0; bright bottom → 90 degrees
        let mut img = Gray8::new(40, 40, 0);
        let orb = OrbExtractor::new(OrbParams::default());
        for y in 0..40 {
            for x in 20..40 {
                img.set(x, y, 200);
            }
        }
        let a = ic_angle(&img, 20, 20, &orb.angle_patch);
        assert!(!(1.0..=359.0).contains(&a), "{a}");
        let mut img = Gray8::new(40, 40, 0);
        for y in 21..40 {
            for x in 0..40 {
                img.set(x, y, 200);
            }
        }
        let a = ic_angle(&img, 20, 20, &orb.angle_patch);
        assert!((a - 90.0).abs() < 1.0, "{a}");
    }

    #[test]
    fn descriptors_follow_a_rotated_image() {
        // a 90-degree rotation of the image maps keypoints and keeps descriptors close
        let img = texture(300, 300, 3);
        let mut rot = Gray8::new(300, 300, 0);
        for y in 0..300 {
            for x in 0..300 {
                rot.set(299 - y, x, img.get(x, y));
            }
        }
        let mut orb = OrbExtractor::new(OrbParams {
            n_features: 300,
            ..OrbParams::default()
        });
        let a = orb.extract(&img);
        let b = orb.extract(&rot);
        let mut close = 0;
        let mut total = 0;
        for (ka, da) in a.keypoints.iter().zip(&a.descriptors) {
            if ka.octave != 0 {
                continue;
            }
            let (ex, ey) = (299.0 - ka.y, ka.x);
            if let Some((_, db)) = b
                .keypoints
                .iter()
                .zip(&b.descriptors)
                .find(|(kb, _)| kb.octave == 0 && kb.x == ex && kb.y == ey)
            {
                total += 1;
                if crate::hamming(da, db) < 50 {
                    close += 1;
                }
            }
        }
        assert!(total > 20, "{total}");
        assert!(close * 10 >= total * 8, "{close}/{total}");
    }

    #[test]
    fn blank_tiny_and_malformed_images_give_no_features() {
        let mut orb = OrbExtractor::new(OrbParams::default());
        assert!(orb.extract(&Gray8::new(640, 480, 128)).keypoints.is_empty());
        assert!(orb.extract(&texture(30, 20, 1)).keypoints.is_empty());
        assert!(orb.extract(&Gray8::new(0, 0, 0)).keypoints.is_empty());
        let bad = Gray8 {
            width: 100,
            height: 100,
            data: vec![0; 10],
        };
        assert!(orb.extract(&bad).keypoints.is_empty());
        // a thin strip still works
        let f = orb.extract(&texture(640, 45, 2));
        assert_eq!(f.keypoints.len(), f.descriptors.len());
        // weird parameters are clamped, not a panic
        let mut odd = OrbExtractor::new(OrbParams {
            n_features: 0,
            scale_factor: f32::NAN,
            n_levels: 0,
            ini_th_fast: 0,
            min_th_fast: 0,
            low_texture_th_fast: 0,
            noise_th_factor: f32::NAN,
            subpixel: true,
        });
        assert!(odd.extract(&texture(100, 100, 1)).keypoints.is_empty());
    }
}
