//! A dense static cloud from keyframe depth: each keyframe's depth pixels, minus the pixels of
//! the objects judged moving in it, are put into the map's frame with the keyframe's final pose
//! and fused in a voxel grid. A voxel is kept when enough keyframes saw something in it, so a
//! person the detector missed for a moment, seen at that place by one keyframe only, leaves no
//! trace.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};
use stillpoint_geometry::{PinholeCamera, Se3, Vec2, Vec3};
use stillpoint_image::{DepthMetres, Gray8, Rgb8};

/// How the dense cloud is made (`[dense]` in the settings tree).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenseSettings {
    /// Voxel edge, metres.
    pub voxel_m: f64,
    /// Every `pixel_step`-th pixel of each row and column is taken.
    pub pixel_step: usize,
    /// Depth beyond this (metres) is left out (a depth camera's far range is noisy).
    pub max_depth_m: f32,
    /// A voxel is kept when at least this many keyframes saw it.
    pub min_keyframes: u32,
    /// The movers' pixels are grown by this many pixels before they are left out (their
    /// outline's depth is a blend of person and background, outside the person's depth band).
    pub skip_grow_px: usize,
    /// Leave out voxels that more keyframes saw through than saw (free-space carving).
    pub carve: bool,
    /// A keyframe sees through a voxel when its depth there (and at the neighbouring samples)
    /// lies beyond the voxel by more than this plus `carve_margin_per_m2` x depth², metres: a
    /// depth camera's noise grows with the square of the distance.
    pub carve_margin_m: f32,
    /// See `carve_margin_m`.
    pub carve_margin_per_m2: f32,
    /// A voxel is carved only when at least this many keyframes saw through it.
    pub carve_min_views: u32,
}

impl Default for DenseSettings {
    fn default() -> Self {
        Self {
            voxel_m: 0.01,
            pixel_step: 2,
            max_depth_m: 4.0,
            min_keyframes: 2,
            skip_grow_px: 10,
            carve: true,
            carve_margin_m: 0.05,
            carve_margin_per_m2: 0.01,
            carve_min_views: 2,
        }
    }
}

/// `mask` (over 127 = set) grown by `r` pixels in each direction (a square), as booleans.
fn grow(mask: &Gray8, r: usize) -> Vec<bool> {
    let (w, h) = (mask.width, mask.height);
    let set: Vec<bool> = mask.data.iter().map(|&v| v > 127).collect();
    if r == 0 {
        return set;
    }
    // Separable: along rows, then along columns.
    let mut rows = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = set[y * w + a..=y * w + b].iter().any(|&v| v);
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (a..=b).any(|yy| rows[yy * w + x]);
        }
    }
    out
}

/// One keyframe's samples, in its camera frame, and its depth at every `pixel_step`-th pixel
/// (0: none), for carving.
struct KeyframeSamples {
    timestamp: f64,
    points: Vec<(Vec3, [u8; 3], bool)>,
    depth: Vec<f32>,
}

/// A point of the fused cloud.
#[derive(Clone, Copy, Debug)]
pub struct DensePoint {
    /// Position in the map's frame, metres.
    pub position: Vec3,
    /// Mean colour.
    pub colour: [u8; 3],
    /// Most of its samples came from pixels a ground-truth mask marks as moving (only with
    /// [`DenseFusion::add_keyframe`]'s `truth_mask`).
    pub on_mover: bool,
}

/// The samples that fell in one voxel.
#[derive(Default)]
struct Voxel {
    sum: Vec3,
    colour: [u64; 3],
    samples: u64,
    on_mover: u64,
    keyframes: u32,
    last_keyframe: usize,
}

impl Voxel {
    fn centre(&self) -> Vec3 {
        self.sum / self.samples.max(1) as f64
    }
}

/// Keyframe depth gathered during a run, fused at the end.
pub struct DenseFusion {
    settings: DenseSettings,
    camera: PinholeCamera,
    keyframes: Vec<KeyframeSamples>,
}

impl DenseFusion {
    /// An empty fusion for images of `camera`.
    pub fn new(settings: DenseSettings, camera: PinholeCamera) -> Self {
        Self {
            settings,
            camera,
            keyframes: Vec::new(),
        }
    }

    /// Keep a keyframe's depth (and colour), leaving out the pixels `skip` marks (over 127: the
    /// movers). `truth_mask` (a synthetic sequence's moving mask) only labels the samples, to
    /// measure what got through.
    pub fn add_keyframe(
        &mut self,
        timestamp: f64,
        depth: &DepthMetres,
        rgb: Option<&Rgb8>,
        skip: Option<&Gray8>,
        truth_mask: Option<&Gray8>,
    ) {
        let step = self.settings.pixel_step.max(1);
        let marked = |m: Option<&Gray8>, x: usize, y: usize| {
            m.and_then(|m| m.get_checked(x as isize, y as isize))
                .is_some_and(|v| v > 127)
        };
        let skip = skip
            .filter(|m| m.width == depth.width && m.height == depth.height)
            .map(|m| grow(m, self.settings.skip_grow_px));
        let skipped = |x: usize, y: usize| skip.as_ref().is_some_and(|s| s[y * depth.width + x]);
        let mut points = Vec::new();
        let mut sampled =
            Vec::with_capacity(depth.width.div_ceil(step) * depth.height.div_ceil(step));
        for y in (0..depth.height).step_by(step) {
            for x in (0..depth.width).step_by(step) {
                let z = depth.get(x, y);
                sampled.push(if z.is_finite() && z > 0.0 { z } else { 0.0 });
                if !(z > 0.0 && z <= self.settings.max_depth_m) || skipped(x, y) {
                    continue;
                }
                let px = self.camera.undistort_pixel(&Vec2::new(x as f64, y as f64));
                let colour = rgb.map_or([200; 3], |c| c.get(x, y));
                points.push((
                    self.camera.unproject(&px, z as f64),
                    colour,
                    marked(truth_mask, x, y),
                ));
            }
        }
        self.keyframes.push(KeyframeSamples {
            timestamp,
            points,
            depth: sampled,
        });
    }

    /// Keyframes gathered so far.
    pub fn keyframes(&self) -> usize {
        self.keyframes.len()
    }

    /// Fuse the keyframes with their poses at the end (`pose_wc(timestamp)`, camera to world;
    /// a keyframe without one is left out): one point per voxel seen by enough keyframes.
    pub fn fuse(&self, pose_wc: impl Fn(f64) -> Option<Se3>) -> Vec<DensePoint> {
        let size = self.settings.voxel_m.max(1e-4);
        let mut grid: HashMap<[i64; 3], Voxel> = HashMap::new();
        for (k, kf) in self.keyframes.iter().enumerate() {
            let Some(wc) = pose_wc(kf.timestamp) else {
                continue;
            };
            for (p, colour, on_mover) in &kf.points {
                let w: Vec3 = wc.rotation * p + wc.translation.vector;
                let key = [
                    (w.x / size).floor() as i64,
                    (w.y / size).floor() as i64,
                    (w.z / size).floor() as i64,
                ];
                let v = grid.entry(key).or_default();
                v.sum += w;
                for (sum, c) in v.colour.iter_mut().zip(colour) {
                    *sum += *c as u64;
                }
                v.samples += 1;
                v.on_mover += u64::from(*on_mover);
                if v.keyframes == 0 || v.last_keyframe != k {
                    v.keyframes += 1;
                    v.last_keyframe = k;
                }
            }
        }
        let mut kept: Vec<Voxel> = grid
            .into_values()
            .filter(|v| v.keyframes >= self.settings.min_keyframes)
            .collect();
        if self.settings.carve {
            let seen_through = self.seen_through(&kept, &pose_wc);
            kept = kept
                .into_iter()
                .zip(seen_through)
                .filter(|(v, free)| {
                    *free < self.settings.carve_min_views.max(1) || *free <= v.keyframes
                })
                .map(|(v, _)| v)
                .collect();
        }
        let mut points: Vec<DensePoint> = kept
            .into_iter()
            .map(|v| DensePoint {
                position: v.centre(),
                colour: v.colour.map(|c| (c / v.samples) as u8),
                on_mover: 2 * v.on_mover > v.samples,
            })
            .collect();
        // A stable order for the file.
        points.sort_by(|a, b| {
            (a.position.x, a.position.y, a.position.z)
                .partial_cmp(&(b.position.x, b.position.y, b.position.z))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        points
    }

    /// For each voxel (its samples' mean), how many keyframes saw through it: its pixel and the
    /// samples around it all hold depth beyond it by more than the margin. Requiring the
    /// neighbours keeps a voxel on an object's outline, which a little pose error puts just
    /// outside the silhouette in another view, from being carved by the background there.
    fn seen_through(&self, voxels: &[Voxel], pose_wc: &impl Fn(f64) -> Option<Se3>) -> Vec<u32> {
        let step = self.settings.pixel_step.max(1);
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let (gw, gh) = (w.div_ceil(step), h.div_ceil(step));
        let mut free = vec![0u32; voxels.len()];
        for kf in &self.keyframes {
            let Some(wc) = pose_wc(kf.timestamp) else {
                continue;
            };
            if kf.depth.len() != gw * gh {
                continue;
            }
            let cw = wc.inverse();
            for (v, f) in voxels.iter().zip(free.iter_mut()) {
                let c: Vec3 = cw.rotation * v.centre() + cw.translation.vector;
                if c.z <= 0.05 {
                    continue;
                }
                let Some(px) = self.camera.project(&c) else {
                    continue;
                };
                let (gx, gy) = ((px.x / step as f64).round(), (px.y / step as f64).round());
                if gx < 1.0 || gy < 1.0 || gx >= (gw - 1) as f64 || gy >= (gh - 1) as f64 {
                    continue;
                }
                let (gx, gy) = (gx as usize, gy as usize);
                let z = c.z as f32;
                let beyond =
                    z + self.settings.carve_margin_m + self.settings.carve_margin_per_m2 * z * z;
                let through = (gy - 1..=gy + 1)
                    .all(|yy| (gx - 1..=gx + 1).all(|xx| kf.depth[yy * gw + xx] > beyond));
                *f += u32::from(through);
            }
        }
        free
    }
}

/// Write `points` as an ASCII PLY cloud with colours. Returns how many were written.
pub fn write_dense_ply(
    points: &[DensePoint],
    mut w: impl std::io::Write,
) -> std::io::Result<usize> {
    write!(
        w,
        "ply\nformat ascii 1.0\ncomment stillpoint dense static cloud\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    )?;
    for p in points {
        writeln!(
            w,
            "{} {} {} {} {} {}",
            p.position.x as f32,
            p.position.y as f32,
            p.position.z as f32,
            p.colour[0],
            p.colour[1],
            p.colour[2]
        )?;
    }
    w.flush()?;
    Ok(points.len())
}

/// The positions of a cloud [`write_dense_ply`] wrote (ASCII PLY, x y z first on each vertex
/// line). `None` when the text is not such a file.
pub fn read_dense_ply_positions(text: &str) -> Option<Vec<Vec3>> {
    let (header, body) = text.split_once("end_header\n")?;
    let count: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))?
        .trim()
        .parse()
        .ok()?;
    let points: Vec<Vec3> = body
        .lines()
        .take(count)
        .map(|l| {
            let mut xyz = l.split_whitespace().map(|v| v.parse::<f64>());
            match (xyz.next(), xyz.next(), xyz.next()) {
                (Some(Ok(x)), Some(Ok(y)), Some(Ok(z))) => Some(Vec3::new(x, y, z)),
                _ => None,
            }
        })
        .collect::<Option<_>>()?;
    (points.len() == count).then_some(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat_wall(z: f32) -> DepthMetres {
        DepthMetres::new(40, 30, z)
    }

    #[test]
    fn a_grown_mask_covers_its_neighbours_and_stays_in_the_image() {
        let mut m = Gray8::new(7, 5, 0);
        m.set(0, 0, 255);
        m.set(4, 2, 255);
        let g = grow(&m, 1);
        let at = |x: usize, y: usize| g[y * 7 + x];
        assert!(at(0, 0) && at(1, 1) && at(0, 1) && !at(2, 0));
        assert!(at(3, 1) && at(5, 3) && at(4, 3) && !at(6, 2) && !at(4, 4));
        assert_eq!(grow(&m, 0).iter().filter(|&&v| v).count(), 2);
    }

    #[test]
    fn a_mover_missed_in_two_keyframes_is_carved_by_those_that_see_the_wall_behind_it() {
        let cam = PinholeCamera::new(40.0, 40.0, 20.0, 15.0, 40, 30);
        let s = DenseSettings {
            voxel_m: 0.05,
            pixel_step: 1,
            skip_grow_px: 0,
            ..DenseSettings::default()
        };
        // A person 1 m away in the middle of the first two keyframes, the wall at 3 m behind.
        let mut person = flat_wall(3.0);
        for y in 10..20 {
            for x in 15..25 {
                person.set(x, y, 1.0);
            }
        }
        let fuse = |carve: bool| {
            let mut f = DenseFusion::new(DenseSettings { carve, ..s.clone() }, cam);
            f.add_keyframe(0.0, &person, None, None, None);
            f.add_keyframe(1.0, &person, None, None, None);
            for t in 2..5 {
                f.add_keyframe(t as f64, &flat_wall(3.0), None, None, None);
            }
            f.fuse(|_| Some(Se3::identity()))
        };
        let near = |pts: &[DensePoint]| pts.iter().filter(|p| p.position.z < 2.0).count();
        let all = fuse(false);
        assert!(near(&all) > 10, "{}", near(&all));
        let carved = fuse(true);
        assert_eq!(near(&carved), 0);
        // The wall is all there: the part behind the person was seen by three keyframes.
        assert_eq!(carved.len(), all.len() - near(&all));
    }

    #[test]
    fn a_wall_seen_by_two_keyframes_is_kept_and_skipped_pixels_and_single_views_are_not() {
        let cam = PinholeCamera::new(40.0, 40.0, 20.0, 15.0, 40, 30);
        let s = DenseSettings {
            voxel_m: 0.05,
            pixel_step: 1,
            max_depth_m: 4.0,
            min_keyframes: 2,
            skip_grow_px: 0,
            ..DenseSettings::default()
        };
        let mut f = DenseFusion::new(s, cam);
        // Left half skipped in the first keyframe (a mover), nothing skipped in the second.
        let mut skip = Gray8::new(40, 30, 0);
        for y in 0..30 {
            for x in 0..20 {
                skip.set(x, y, 255);
            }
        }
        f.add_keyframe(0.0, &flat_wall(2.0), None, Some(&skip), None);
        f.add_keyframe(1.0, &flat_wall(2.0), None, None, Some(&skip));
        // A third keyframe sees something at 1 m that nobody else saw: a passing person.
        f.add_keyframe(2.0, &flat_wall(1.0), None, None, None);
        let pts = f.fuse(|_| Some(Se3::identity()));
        assert!(!pts.is_empty());
        // Only the wall's right half (x >= 0) had two keyframes; the 1 m surface had one.
        assert!(
            pts.iter().all(|p| (p.position.z - 2.0).abs() < 0.05),
            "{:?}",
            pts[0]
        );
        assert!(pts.iter().all(|p| p.position.x > -0.05));
        assert!(pts.iter().all(|p| !p.on_mover));
        // A keyframe without a pose is left out: nothing has two keyframes any more.
        assert!(f.fuse(|t| (t != 0.0).then(Se3::identity)).is_empty());
        let mut out = Vec::new();
        assert_eq!(write_dense_ply(&pts, &mut out).unwrap(), pts.len());
        let text = String::from_utf8(out).unwrap();
        assert_eq!(text.lines().count(), 11 + pts.len());
        let back = read_dense_ply_positions(&text).unwrap();
        assert_eq!(back.len(), pts.len());
        assert!((back[0] - pts[0].position).norm() < 1e-5);
        // A file cut short (its last line gone) is not a cloud.
        let cut = &text[..text.trim_end().rfind('\n').unwrap() + 1];
        assert_eq!(read_dense_ply_positions(cut), None);
    }
}
