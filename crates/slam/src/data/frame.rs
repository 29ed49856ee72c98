//! A frame as tracking sees it: undistorted keypoints with depth and a virtual right coordinate.

use stillpoint_geometry::{PinholeCamera, Se3, Vec2, Vec3};
use stillpoint_image::DepthMetres;

use super::map::MpId;
use crate::SlamSettings;

/// A 256-bit ORB descriptor.
pub use stillpoint_features::Descriptor;

/// One keypoint as extracted: level-0 pixel position (distorted, as in the image), octave and
/// orientation in degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Feature {
    /// Column of the level-0 pixel (distorted, as in the image).
    pub x: f32,
    /// Row of the level-0 pixel.
    pub y: f32,
    /// Pyramid level it was found at.
    pub octave: u8,
    /// Orientation in degrees, [0, 360).
    pub angle: f32,
}

#[cfg(test)]
impl Feature {
    /// A level-0 feature at a projected pixel, orientation 0: what the unit tests observe.
    pub(crate) fn at(px: nalgebra::Vector2<f64>) -> Self {
        Self {
            x: px.x as f32,
            y: px.y as f32,
            octave: 0,
            angle: 0.0,
        }
    }
}

impl From<&stillpoint_features::KeyPoint> for Feature {
    fn from(k: &stillpoint_features::KeyPoint) -> Self {
        Self {
            x: k.x,
            y: k.y,
            octave: k.octave,
            angle: k.angle,
        }
    }
}

/// Where a frame's keypoint depths come from: a depth image (RGB-D, sampled at each keypoint's
/// pixel) or one value per keypoint (stereo matching; 0 = none).
#[derive(Clone, Copy, Debug)]
pub enum KeypointDepth<'a> {
    /// No depth (monocular).
    None,
    /// A depth image registered to the colour image, metres.
    Map(&'a DepthMetres),
    /// One depth per keypoint, metres (stereo matching; 0 = none).
    PerKeypoint(&'a [f32]),
}

impl<'a> From<Option<&'a DepthMetres>> for KeypointDepth<'a> {
    fn from(d: Option<&'a DepthMetres>) -> Self {
        d.map_or(Self::None, Self::Map)
    }
}

/// Keypoints bucketed in cells so that projection searches only look nearby (ORB-SLAM's
/// 64 x 48 `FRAME_GRID`). The cells are one index list cut by offsets: a list per cell
/// (3,072 allocations) cost every keyframe ~100 KB more, which a long run's map keeps.
#[derive(Clone, Debug)]
pub struct KeypointGrid {
    cols: usize,
    rows: usize,
    cell_w: f64,
    cell_h: f64,
    /// Cell `c` holds `indices[starts[c]..starts[c + 1]]`, in keypoint order.
    starts: Vec<u32>,
    indices: Vec<u32>,
}

impl KeypointGrid {
    /// Bucket `points` over a `width` x `height` image; points outside are left out.
    pub fn new(points: &[Vec2], width: f64, height: f64) -> Self {
        let (cols, rows) = (64usize, 48usize);
        let cell_w = (width / cols as f64).max(1e-6);
        let cell_h = (height / rows as f64).max(1e-6);
        let cell_of = |p: &Vec2| {
            if !(p.x >= 0.0 && p.y >= 0.0) {
                return None;
            }
            let (cx, cy) = ((p.x / cell_w) as usize, (p.y / cell_h) as usize);
            // Lazily: a huge coordinate saturates the casts, and their product would overflow.
            (cx < cols && cy < rows).then(|| cy * cols + cx)
        };
        // Counting sort: sizes, then offsets, then the indices in keypoint order.
        let mut starts = vec![0u32; cols * rows + 1];
        for c in points.iter().filter_map(cell_of) {
            starts[c + 1] += 1;
        }
        for c in 0..cols * rows {
            starts[c + 1] += starts[c];
        }
        let mut next = starts.clone();
        let mut indices = vec![0u32; starts[cols * rows] as usize];
        for (i, p) in points.iter().enumerate() {
            if let Some(c) = cell_of(p) {
                indices[next[c] as usize] = i as u32;
                next[c] += 1;
            }
        }
        Self {
            cols,
            rows,
            cell_w,
            cell_h,
            starts,
            indices,
        }
    }

    /// Indices of points within `radius` (square window, as ORB-SLAM) of (x, y) whose octave is in
    /// `[min_octave, max_octave]`.
    pub fn candidates(
        &self,
        (points, octaves): (&[Vec2], &[u8]),
        x: f64,
        y: f64,
        radius: f64,
        (min_octave, max_octave): (i32, i32),
    ) -> Vec<usize> {
        let mut out = Vec::new();
        if !(x.is_finite() && y.is_finite() && radius.is_finite()) {
            return out;
        }
        let x0 = ((x - radius) / self.cell_w).floor().max(0.0) as usize;
        let y0 = ((y - radius) / self.cell_h).floor().max(0.0) as usize;
        let x1 = ((x + radius) / self.cell_w).floor();
        let y1 = ((y + radius) / self.cell_h).floor();
        if x1 < 0.0 || y1 < 0.0 {
            return out;
        }
        let x1 = (x1 as usize).min(self.cols - 1);
        let y1 = (y1 as usize).min(self.rows - 1);
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                let c = cy * self.cols + cx;
                let cell = &self.indices[self.starts[c] as usize..self.starts[c + 1] as usize];
                for &i in cell {
                    let i = i as usize;
                    let o = octaves[i] as i32;
                    if o < min_octave || o > max_octave {
                        continue;
                    }
                    let p = points[i];
                    if (p.x - x).abs() < radius && (p.y - y).abs() < radius {
                        out.push(i);
                    }
                }
            }
        }
        out
    }
}

/// A frame ready for tracking.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Position in the sequence.
    pub index: usize,
    /// Time of the frame, seconds.
    pub timestamp: f64,
    /// Undistorted keypoint positions (pixels of the ideal camera).
    pub points: Vec<Vec2>,
    /// Pyramid level of each keypoint.
    pub octaves: Vec<u8>,
    /// Orientation in degrees (for the rotation-consistency histogram).
    pub angles: Vec<f32>,
    /// ORB descriptor of each keypoint.
    pub descriptors: Vec<Descriptor>,
    /// Depth per keypoint in metres, 0 when unknown.
    pub depth: Vec<f32>,
    /// Virtual right coordinate u - bf / z, negative when no depth (ORB-SLAM's `mvuRight`).
    pub u_right: Vec<f32>,
    /// Map point matched to each keypoint.
    pub map_points: Vec<Option<MpId>>,
    /// Outlier flag from pose optimisation.
    pub outliers: Vec<bool>,
    /// Keypoints that may be matched to map points but must not create new ones (the dynamic
    /// front-end kept them only because a static box protects them, inside a moving object's
    /// box: possibly on the moving object).
    pub no_new_point: Vec<bool>,
    /// Keypoints that may be matched to a map point only as closely as keyframes match
    /// (`th_low`): those the front-end culled, offered to the map's static points only
    /// (empty: none).
    pub close_match_only: Vec<bool>,
    /// World-to-camera pose once tracked.
    pub pose_cw: Option<Se3>,
    /// Keypoints by image cell, for searches in a window.
    pub grid: KeypointGrid,
}

impl Frame {
    /// Build a frame from extracted features. Depth is read at the raw (distorted) keypoint pixel
    /// because depth images are registered to the raw image; keypoints with NaN positions are
    /// dropped.
    pub fn new(
        index: usize,
        timestamp: f64,
        features: &[Feature],
        descriptors: &[Descriptor],
        depth: Option<&DepthMetres>,
        settings: &SlamSettings,
    ) -> Result<Self, crate::SlamError> {
        Self::new_with_mask(
            index,
            timestamp,
            features,
            descriptors,
            depth,
            settings,
            &[],
        )
    }

    /// [`Frame::new`] with a per-keypoint flag (same length as `features`, or empty for none):
    /// `true` = this keypoint may be tracked but must not create a map point.
    pub fn new_with_mask<'d>(
        index: usize,
        timestamp: f64,
        features: &[Feature],
        descriptors: &[Descriptor],
        depth: impl Into<KeypointDepth<'d>>,
        settings: &SlamSettings,
        no_new_points: &[bool],
    ) -> Result<Self, crate::SlamError> {
        let depth = depth.into();
        if features.len() != descriptors.len() {
            return Err(crate::SlamError::BadInput {
                index,
                msg: format!(
                    "{} keypoints but {} descriptors",
                    features.len(),
                    descriptors.len()
                ),
            });
        }
        let cam = &settings.camera;
        let n_levels = settings.n_levels.max(1);
        let mut f = Frame {
            index,
            timestamp,
            points: Vec::with_capacity(features.len()),
            octaves: Vec::with_capacity(features.len()),
            angles: Vec::with_capacity(features.len()),
            descriptors: Vec::with_capacity(features.len()),
            depth: Vec::with_capacity(features.len()),
            u_right: Vec::with_capacity(features.len()),
            map_points: Vec::new(),
            outliers: Vec::new(),
            no_new_point: Vec::with_capacity(features.len()),
            close_match_only: Vec::new(),
            pose_cw: None,
            grid: KeypointGrid::new(&[], 1.0, 1.0),
        };
        for (j, (kp, d)) in features.iter().zip(descriptors).enumerate() {
            if !(kp.x.is_finite() && kp.y.is_finite()) {
                continue;
            }
            let raw = Vec2::new(kp.x as f64, kp.y as f64);
            let un = cam.undistort_pixel(&raw);
            if !(un.x.is_finite() && un.y.is_finite()) {
                continue;
            }
            let z = match depth {
                KeypointDepth::None => None,
                KeypointDepth::Map(dm) => {
                    let (x, y) = (kp.x.round() as isize, kp.y.round() as isize);
                    dm.get_checked(x, y)
                }
                KeypointDepth::PerKeypoint(d) => d.get(j).copied(),
            }
            .filter(|z| z.is_finite() && *z > 0.0)
            .unwrap_or(0.0);
            f.points.push(un);
            f.octaves.push(kp.octave.min((n_levels - 1).min(255) as u8));
            f.angles
                .push(if kp.angle.is_finite() { kp.angle } else { 0.0 });
            f.descriptors.push(*d);
            f.depth.push(z);
            f.no_new_point
                .push(no_new_points.get(j).copied().unwrap_or(false));
            f.u_right.push(if z > 0.0 {
                (un.x - settings.bf / z as f64) as f32
            } else {
                -1.0
            });
        }
        let n = f.points.len();
        f.map_points = vec![None; n];
        f.outliers = vec![false; n];
        f.grid = KeypointGrid::new(&f.points, cam.width as f64, cam.height as f64);
        Ok(f)
    }

    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// What matching the frame again to map points by projection needs (positions, levels,
    /// descriptors, the grid), kept for later at about half the memory; the matches, flags,
    /// angles and depths are left out. See [`Frame::ready_to_match`].
    pub fn kept_to_match_later(&self) -> Self {
        Self {
            index: self.index,
            timestamp: self.timestamp,
            points: self.points.clone(),
            octaves: self.octaves.clone(),
            angles: Vec::new(),
            descriptors: self.descriptors.clone(),
            depth: Vec::new(),
            u_right: self.u_right.clone(),
            map_points: Vec::new(),
            outliers: Vec::new(),
            no_new_point: Vec::new(),
            close_match_only: self.close_match_only.clone(),
            pose_cw: self.pose_cw,
            grid: self.grid.clone(),
        }
    }

    /// A frame from [`Frame::kept_to_match_later`], at `pose_cw`, with no matches yet.
    pub fn ready_to_match(&mut self, pose_cw: Se3) {
        self.pose_cw = Some(pose_cw);
        self.map_points = vec![None; self.points.len()];
        self.outliers = vec![false; self.points.len()];
    }

    /// No keypoints.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Number of keypoints with a depth measurement.
    pub fn with_depth(&self) -> usize {
        self.depth.iter().filter(|&&z| z > 0.0).count()
    }

    /// Camera-frame 3D point of keypoint `i` from its depth.
    pub fn unproject_camera(&self, i: usize, cam: &PinholeCamera) -> Option<Vec3> {
        let z = *self.depth.get(i)?;
        (z > 0.0).then(|| cam.unproject(&self.points[i], z as f64))
    }

    /// World point of keypoint `i` from its depth and the frame pose.
    pub fn unproject_world(&self, i: usize, cam: &PinholeCamera) -> Option<Vec3> {
        let pc = self.unproject_camera(i, cam)?;
        let t_wc = self.pose_cw?.inverse();
        Some(t_wc * nalgebra::Point3::from(pc)).map(|p| p.coords)
    }

    /// Camera centre in the world.
    pub fn camera_center(&self) -> Option<Vec3> {
        self.pose_cw.map(|p| p.inverse().translation.vector)
    }

    /// Keypoints inside a square window around (x, y) within an octave range.
    pub fn features_in_area(
        &self,
        x: f64,
        y: f64,
        radius: f64,
        min_octave: i32,
        max_octave: i32,
    ) -> Vec<usize> {
        self.grid.candidates(
            (&self.points, &self.octaves),
            x,
            y,
            radius,
            (min_octave, max_octave),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_reads_depth_and_virtual_right() {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        let mut depth = DepthMetres::new(640, 480, 0.0);
        depth.set(100, 50, 2.0);
        let feats = [
            Feature {
                x: 100.0,
                y: 50.0,
                octave: 0,
                angle: 0.0,
            },
            Feature {
                x: 200.0,
                y: 60.0,
                octave: 9,
                angle: f32::NAN,
            },
            Feature {
                x: f32::NAN,
                y: 60.0,
                octave: 1,
                angle: 0.0,
            },
        ];
        let f = Frame::new(0, 0.0, &feats, &[[0; 32]; 3], Some(&depth), &s).unwrap();
        assert_eq!(f.len(), 2);
        assert_eq!(f.depth, vec![2.0, 0.0]);
        assert!((f.u_right[0] - (100.0 - 20.0)).abs() < 1e-4);
        assert!(f.u_right[1] < 0.0);
        assert_eq!(f.octaves[1], 7);
        assert_eq!(f.features_in_area(101.0, 51.0, 3.0, 0, 7), vec![0]);
        assert!(f.features_in_area(101.0, 51.0, 3.0, 1, 7).is_empty());
        assert!(Frame::new(0, 0.0, &feats, &[[0; 32]; 2], None, &s).is_err());
        assert_eq!(f.no_new_point, vec![false, false]);
        // The flag follows its keypoint past the dropped NaN one.
        let mut feats4 = feats.to_vec();
        feats4.insert(0, feats[2]);
        let masked = Frame::new_with_mask(
            0,
            0.0,
            &feats4,
            &[[0; 32]; 4],
            Some(&depth),
            &s,
            &[false, false, true, false],
        )
        .unwrap();
        assert_eq!(masked.no_new_point, vec![false, true]);
    }
}
