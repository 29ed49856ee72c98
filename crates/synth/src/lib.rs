//! stillpoint-synth: synthetic dynamic RGB-D / stereo sequences with exact ground truth.
//!
//! A furnished room with procedural textures (or photos), walking and seated articulated people
//! and moving objects, rendered by a z-buffer rasteriser in pure Rust: depth is exact at every
//! pixel (noise off), boxes are the tight boxes of each object's visible pixels, and the
//! per-pixel dynamic mask says which pixels belong to a part that moved since the previous
//! frame. Everything is deterministic for a seed, and frames can be rendered in any order.
//!
//! ```no_run
//! use stillpoint_synth::{Preset, SynthConfig, generate};
//! let cfg = SynthConfig { preset: Preset::WalkingXyz, frames: 30, ..Default::default() };
//! for frame in generate(&cfg).unwrap() {
//!     println!("{} {} boxes", frame.timestamp, frame.boxes.len());
//! }
//! ```

#![deny(missing_docs)]

pub mod living;
pub mod mesh;
pub mod noise;
pub mod presets;
pub mod render;
pub mod scene;
pub mod street;
pub mod texture;
pub mod write;

pub use noise::KinectNoise;
pub use presets::{CameraPath, Preset};
pub use write::{WriteOptions, WriteSummary, contact_sheet, draw_boxes, write_sequence};

use nalgebra::Isometry3;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use render::{DrawItem, Target};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use stillpoint_datasets::{GtBox, OrbParams, Sensor, Settings};
use stillpoint_geometry::{BBox, PinholeCamera, Se3};
use stillpoint_image::{DepthMetres, Gray8, ImageBuf, Rgb8};

/// Errors of the generator.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// A preset name that is not one of `Preset::ALL`: (name, the known names).
    #[error("unknown preset {0:?} (known: {1})")]
    UnknownPreset(String, String),
    /// A configuration the renderer cannot use (distorted or tiny camera, bad rate, baseline).
    #[error("bad configuration: {0}")]
    Config(String),
    /// A file cannot be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// An image cannot be read or written.
    #[error(transparent)]
    Image(#[from] stillpoint_image::ImageError),
    #[error("{path}: {msg}")]
    /// A file of the sequence cannot be encoded or laid out (its message says why).
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        msg: String,
    },
}

/// Sensor noise applied to the rendered frames.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Noise {
    /// Exact depth and clean images.
    #[default]
    None,
    /// Kinect-like depth noise and dropouts, image noise.
    Kinect(KinectNoise),
}

/// Everything that defines a synthetic sequence. Two runs with the same config give the same
/// bytes.
#[derive(Clone, Debug)]
pub struct SynthConfig {
    /// The scene and the camera's motion.
    pub preset: Preset,
    /// Number of frames (TUM fr3 walking sequences hold 700-1000; 300 is 10 s).
    pub frames: usize,
    /// Seed of every random choice (textures, clothes, noise).
    pub seed: u64,
    /// Intrinsics and image size; default TUM fr3 (fx 535.4, fy 539.2, cx 320.1, cy 247.6, 640x480,
    /// from TUM3.yaml of ORB-SLAM). Distortion must be zero (the renderer is a pinhole).
    pub camera: PinholeCamera,
    /// Frame rate (TUM: 30 Hz).
    pub fps: f64,
    /// Timestamp of the first frame in seconds (non-zero, TUM-like Unix time).
    pub start_time: f64,
    /// Seconds into the scene's motion (camera path, people, objects) at which the first frame
    /// is taken: another stretch of the same camera path through the same room (0: from the
    /// start). The ground truth stays in the room's frame.
    pub path_offset: f64,
    /// Sensor noise on the rendered depth and colour (`Preset::default_noise` for the preset's own).
    pub noise: Noise,
    /// Folder of photos: used as posters, and person cut-outs (an RGB image with a
    /// `<stem>_person_mask*.png` beside it anywhere under the folder) replace the people.
    pub textures: Option<PathBuf>,
    /// Render a right image for a rectified stereo pair with this baseline (metres).
    pub stereo_baseline: Option<f64>,
    /// Objects with fewer visible pixels get no box (a detector would not see them either).
    pub min_box_pixels: usize,
    /// The moving mask marks a pixel of a moving part only where that material point moved more
    /// than this many pixels in the image since the previous frame (its own motion, seen from the
    /// previous camera); 0 = any motion at all (the default). A hand that moves 0.1 px is not a
    /// measurable mover for a keypoint; `bench dynamic` can then score against what can be seen.
    pub mask_min_motion_px: f64,
    /// Colour samples a pixel along each axis (made odd; 1 = point sampling, the default): the
    /// colour of a pixel is the mean of its samples, as a camera integrates over its pixels.
    /// Depth, part ids and masks stay those of the pixel centre. 3 makes sub-pixel motion
    /// visible as it is on a real sensor (point-sampled edges move in whole-pixel steps) at
    /// ~6.7x the render time; measured effect in `stillpoint_dynamic`'s seated-test docs.
    pub antialias: usize,
    /// Frames where the camera sees nothing it can track (a covered lens, a blank wall) while it
    /// goes on moving: tracking is lost and must find its way back (`None`: never).
    pub blind: Option<Blind>,
}

/// A span of frames the camera cannot track through; the ground truth goes on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blind {
    /// First frame of the span.
    pub start: usize,
    /// Frames in it.
    pub frames: usize,
    /// What the camera sees meanwhile.
    pub view: BlindView,
}

/// What a blind camera sees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlindView {
    /// A covered lens: black colour, no depth.
    Covered,
    /// A blank wall close before the lens: one grey, depth 0.4 m everywhere.
    Wall,
}

impl Blind {
    /// Parse `START+FRAMES` or `START+FRAMES:wall` (the `--blind` argument).
    pub fn parse(s: &str) -> Option<Blind> {
        let (span, view) = match s.split_once(':') {
            Some((span, "wall")) => (span, BlindView::Wall),
            Some((span, "covered")) => (span, BlindView::Covered),
            Some(_) => return None,
            None => (s, BlindView::Covered),
        };
        let (start, frames) = span.split_once('+')?;
        Some(Blind {
            start: start.trim().parse().ok()?,
            frames: frames.trim().parse().ok()?,
            view,
        })
    }

    /// Whether frame `index` is in the span.
    pub fn covers(&self, index: usize) -> bool {
        index >= self.start && index - self.start < self.frames
    }
}

impl std::str::FromStr for Blind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Blind::parse(s).ok_or_else(|| {
            format!("{s:?}: expected START+FRAMES or START+FRAMES:wall, e.g. 200+60")
        })
    }
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            preset: Preset::WalkingXyz,
            frames: 300,
            seed: 0,
            camera: tum_fr3_camera(),
            fps: 30.0,
            start_time: 1_341_846_313.5,
            path_offset: 0.0,
            noise: Noise::None,
            textures: None,
            stereo_baseline: None,
            min_box_pixels: 16,
            mask_min_motion_px: 0.0,
            antialias: 1,
            blind: None,
        }
    }
}

/// TUM fr3's camera (ORB-SLAM's TUM3.yaml), without distortion (fr3 images are undistorted).
pub fn tum_fr3_camera() -> PinholeCamera {
    PinholeCamera::new(535.4, 539.2, 320.1, 247.6, 640, 480)
}

/// [`tum_fr3_camera`] for an image of `width` x `height`: the same field of view, focal
/// lengths scaled per axis and the principal point moved with the pixel centres (`synth
/// --size`).
pub fn tum_fr3_camera_sized(width: u32, height: u32) -> PinholeCamera {
    let mut cam = tum_fr3_camera();
    let (sx, sy) = (
        width as f64 / cam.width as f64,
        height as f64 / cam.height as f64,
    );
    cam.fx *= sx;
    cam.fy *= sy;
    cam.cx = (cam.cx + 0.5) * sx - 0.5;
    cam.cy = (cam.cy + 0.5) * sy - 0.5;
    cam.width = width;
    cam.height = height;
    cam
}

/// One object's box in one frame, per part (written to `parts.jsonl`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PartBox {
    /// Index of the object in `Generator::objects`.
    pub object: u32,
    /// The part's name (`PERSON_PARTS` for people).
    pub part: String,
    /// Tight box of the part's visible pixels.
    pub bbox: BBox,
    /// The part moved since the previous frame.
    pub moving: bool,
    /// Visible pixels of the part.
    pub pixels: usize,
}

/// One rendered frame with its ground truth.
#[derive(Clone, Debug)]
pub struct SynthFrame {
    /// Position in the sequence.
    pub index: usize,
    /// Time of the frame, seconds (`SynthConfig::start_time` + index / fps).
    pub timestamp: f64,
    /// The colour image (with noise when the config has it).
    pub rgb: Rgb8,
    /// Depth along the optical axis in metres, 0 where there is none.
    pub depth: DepthMetres,
    /// Camera-to-world pose.
    pub pose_wc: Se3,
    /// Boxes of visible objects that have a COCO class.
    pub boxes: Vec<GtBox>,
    /// Boxes of visible parts of those objects.
    pub parts: Vec<PartBox>,
    /// 255 where the pixel shows a part that moved since the previous frame, else 0.
    pub dynamic_mask: Gray8,
    /// Object id + 1 at every pixel (0: nothing); object ids are indices into `Generator::objects`.
    pub object_ids: ImageBuf<u16>,
    /// Right image of the stereo pair when `stereo_baseline` is set.
    pub right: Option<Rgb8>,
}

/// Name and class of a scene object (`objects.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObjectInfo {
    /// Index of the object (the `object` of its boxes).
    pub object: u32,
    /// Its name in the scene (`walker`, `desk`, ...).
    pub name: String,
    /// COCO class, `None` for things that get no box (walls, shelves).
    pub class_id: Option<u16>,
    /// Names of its rigid parts, in id order.
    pub parts: Vec<String>,
}

/// A sequence being generated: random access with [`Generator::frame`], or iterate.
pub struct Generator {
    config: SynthConfig,
    scene: scene::Scene,
    camera_path: CameraPath,
    /// Global part id (1-based in the id buffer) -> (object, part index).
    part_table: Vec<(usize, usize)>,
    next: usize,
}

/// Start generating the sequence `config` describes.
pub fn generate(config: &SynthConfig) -> Result<Generator, SynthError> {
    Generator::new(config)
}

fn photos(dir: &std::path::Path) -> Result<presets::Photos, SynthError> {
    let files = texture::image_files(dir).map_err(|source| SynthError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut out = presets::Photos::default();
    let stem = |p: &PathBuf| {
        p.file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("")
            .to_string()
    };
    for f in &files {
        let s = stem(f);
        if s.contains("mask") {
            continue;
        }
        let rgb = stillpoint_image::read_rgb(f)?;
        let mask = files
            .iter()
            .find(|m| stem(m).starts_with(&format!("{s}_")) && stem(m).contains("person_mask"));
        if let Some(m) = mask {
            let mask = stillpoint_image::read_gray(m)?;
            match texture::person_cutout(&rgb, &mask) {
                Some(t) => out.people.push(t),
                None => tracing::warn!("{}: no whole person in the mask; not used", m.display()),
            }
        }
        out.posters.push(texture::photo_texture(&rgb));
    }
    tracing::info!(
        "{}: {} photos, {} person cut-outs",
        dir.display(),
        out.posters.len(),
        out.people.len()
    );
    Ok(out)
}

fn moved(a: &Se3, b: &Se3) -> bool {
    (a.translation.vector - b.translation.vector).norm() > 1e-9
        || a.rotation.angle_to(&b.rotation) > 1e-9
}

impl Generator {
    /// The sequence `config` describes: checks the camera and rates, loads the photos, builds the
    /// scene and the camera path (deterministic for the seed).
    pub fn new(config: &SynthConfig) -> Result<Generator, SynthError> {
        let c = &config.camera;
        if !c.distortion.is_zero() {
            return Err(SynthError::Config(
                "the camera must have no distortion".into(),
            ));
        }
        if c.width < 8 || c.height < 8 || !(c.fx > 0.0 && c.fy > 0.0) {
            return Err(SynthError::Config(format!(
                "camera {}x{} fx {} fy {} is not usable",
                c.width, c.height, c.fx, c.fy
            )));
        }
        if config.fps.is_nan()
            || config.fps <= 0.0
            || !config.start_time.is_finite()
            || !config.path_offset.is_finite()
        {
            return Err(SynthError::Config(format!(
                "fps {} / start time {} / path offset {} must be positive / finite / finite",
                config.fps, config.start_time, config.path_offset
            )));
        }
        if let Some(b) = config.stereo_baseline
            && !(b > 0.0 && b < 10.0)
        {
            return Err(SynthError::Config(format!(
                "stereo baseline {b} m must be in (0, 10)"
            )));
        }
        let photos = match &config.textures {
            Some(d) => photos(d)?,
            None => presets::Photos::default(),
        };
        let mut rng = Pcg64Mcg::seed_from_u64(config.seed);
        let (scene, camera_path) = presets::build(config.preset, &mut rng, &photos);
        let mut part_table = Vec::new();
        for (o, obj) in scene.objects.iter().enumerate() {
            for p in 0..obj.parts.len() {
                part_table.push((o, p));
            }
        }
        if part_table.len() >= u16::MAX as usize {
            return Err(SynthError::Config(
                "too many parts for the id buffer".into(),
            ));
        }
        Ok(Generator {
            config: config.clone(),
            scene,
            camera_path,
            part_table,
            next: 0,
        })
    }

    /// The configuration it was built from.
    pub fn config(&self) -> &SynthConfig {
        &self.config
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.config.frames
    }

    /// No frames to render.
    pub fn is_empty(&self) -> bool {
        self.config.frames == 0
    }

    /// Timestamp of frame `i`.
    pub fn timestamp(&self, i: usize) -> f64 {
        self.config.start_time + i as f64 / self.config.fps
    }

    /// Camera-to-world pose of frame `i`.
    pub fn pose(&self, i: usize) -> Se3 {
        self.camera_path
            .pose(self.config.path_offset + i as f64 / self.config.fps)
    }

    /// The scene's objects (index = object id).
    pub fn objects(&self) -> Vec<ObjectInfo> {
        self.scene
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| ObjectInfo {
                object: i as u32,
                name: o.name.clone(),
                class_id: o.class_id,
                parts: o.parts.iter().map(|p| p.name.to_string()).collect(),
            })
            .collect()
    }

    /// True when object `o` never moves (furniture, the room).
    pub fn object_is_static(&self, o: usize) -> bool {
        self.scene
            .objects
            .get(o)
            .is_some_and(|ob| matches!(ob.motion, scene::Motion::Static(_)))
    }

    /// The triangles of everything that never moves (the room and its furniture; not seated
    /// people, nor objects carried and then put down), in the world frame: the true static
    /// scene a map of it should match.
    pub fn static_triangles(&self) -> Vec<[stillpoint_geometry::Vec3; 3]> {
        let mut out = Vec::new();
        for ob in &self.scene.objects {
            let scene::Motion::Static(pose) = &ob.motion else {
                continue;
            };
            for part in &ob.parts {
                out.extend(part.mesh.tris.iter().map(|t| {
                    t.p.map(|p| pose * nalgebra::Point3::from(p))
                        .map(|p| p.coords)
                }));
            }
        }
        out
    }

    /// Settings for the dataset reader: RGB-D with TUM3's `bf` 40 and `ThDepth` 40 (ORB-SLAM's
    /// TUM3.yaml), or stereo with the configured baseline.
    pub fn settings(&self, sensor: Sensor) -> Settings {
        let bf = match (sensor, self.config.stereo_baseline) {
            (Sensor::Stereo, Some(b)) => self.config.camera.fx * b,
            _ => 40.0,
        };
        Settings {
            sensor,
            camera: self.config.camera,
            fps: self.config.fps,
            depth_factor: 5000.0,
            bf: Some(bf),
            th_depth: 40.0,
            rgb: true,
            orb: OrbParams::default(),
            rectification: None,
        }
    }

    /// World poses of every part at time `t` with the camera at `eye`.
    fn part_poses(&self, t: f64, eye: &nalgebra::Vector3<f64>) -> Vec<Vec<Se3>> {
        self.scene
            .objects
            .iter()
            .map(|o| {
                let mut v = Vec::with_capacity(o.parts.len());
                o.motion.part_poses(t, eye, o.parts.len(), &mut v);
                v
            })
            .collect()
    }

    /// How far (pixels) the material point seen at pixel (x, y) of part `id`, at `depth`, moved
    /// in the image since the previous frame by its own motion: both its previous and its current
    /// world position projected with the previous camera. Infinite when it cannot be told
    /// (no depth, behind the camera), so such a pixel of a moving part counts as moving.
    fn image_motion_px(
        &self,
        (x, y): (usize, usize),
        depth: f32,
        id: u16,
        (pose_wc, prev_wc): (&Se3, &Se3),
        poses: &[Vec<Se3>],
        prev: &[Vec<Se3>],
    ) -> f64 {
        if self.config.mask_min_motion_px <= 0.0 || !depth.is_finite() || depth <= 0.0 {
            return f64::INFINITY;
        }
        let cam = &self.config.camera;
        let (o, p) = self.part_table[id as usize - 1];
        let seen = cam.unproject(&nalgebra::Vector2::new(x as f64, y as f64), depth as f64);
        let now_w = pose_wc * nalgebra::Point3::from(seen);
        let before_w = prev[o][p] * (poses[o][p].inverse() * now_w);
        let prev_cw = prev_wc.inverse();
        match (
            cam.project(&(prev_cw * now_w).coords),
            cam.project(&(prev_cw * before_w).coords),
        ) {
            (Some(a), Some(b)) => (a - b).norm(),
            _ => f64::INFINITY,
        }
    }

    fn items<'a>(&'a self, poses: &[Vec<Se3>], t_cw: &Se3) -> Vec<DrawItem<'a>> {
        let mut items = Vec::with_capacity(self.part_table.len());
        for (g, &(o, p)) in self.part_table.iter().enumerate() {
            let t_wp = poses[o][p];
            items.push(DrawItem {
                mesh: &self.scene.objects[o].parts[p].mesh,
                t_cp: t_cw * t_wp,
                r_wp: t_wp.rotation,
                id: (g + 1) as u16,
            });
        }
        items
    }

    /// Render frame `index` (any order; the result does not depend on other frames).
    pub fn frame(&self, index: usize) -> SynthFrame {
        let cfg = &self.config;
        let cam = &cfg.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let t = cfg.path_offset + index as f64 / cfg.fps;
        let dt = 1.0 / cfg.fps;
        let pose_wc = self.camera_path.pose(t);
        let prev_wc = self.camera_path.pose(t - dt);
        let poses = self.part_poses(t, &pose_wc.translation.vector);
        let prev = self.part_poses(t - dt, &prev_wc.translation.vector);
        let part_moving: Vec<bool> = self
            .part_table
            .iter()
            .map(|&(o, p)| moved(&poses[o][p], &prev[o][p]))
            .collect();
        let t_cw: Isometry3<f64> = pose_wc.inverse();
        let items = self.items(&poses, &t_cw);
        let mut target = Target::new(w, h);
        render::draw_antialiased(
            &mut target,
            cam,
            &items,
            &self.scene.textures,
            cfg.antialias,
        );

        // per-part pixel counts and boxes from the id buffer
        let np = self.part_table.len();
        let mut count = vec![0usize; np + 1];
        let mut bb = vec![[usize::MAX, usize::MAX, 0usize, 0usize]; np + 1];
        for y in 0..h {
            for x in 0..w {
                let id = target.id[y * w + x] as usize;
                count[id] += 1;
                let b = &mut bb[id];
                *b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
            }
        }
        let to_box = |b: [usize; 4]| {
            BBox::new(
                b[0] as f32 - 0.5,
                b[1] as f32 - 0.5,
                b[2] as f32 + 0.5,
                b[3] as f32 + 0.5,
            )
        };
        let mut boxes = Vec::new();
        let mut parts = Vec::new();
        let mut scratch = vec![false; w * h];
        for (o, obj) in self.scene.objects.iter().enumerate() {
            let Some(class_id) = obj.class_id else {
                continue;
            };
            let ids: Vec<usize> = (0..np)
                .filter(|&g| self.part_table[g].0 == o)
                .map(|g| g + 1)
                .collect();
            let n: usize = ids.iter().map(|&g| count[g]).sum();
            if n < cfg.min_box_pixels {
                continue;
            }
            let mut ob = [usize::MAX, usize::MAX, 0, 0];
            for &g in &ids {
                if count[g] == 0 {
                    continue;
                }
                let b = bb[g];
                ob = [
                    ob[0].min(b[0]),
                    ob[1].min(b[1]),
                    ob[2].max(b[2]),
                    ob[3].max(b[3]),
                ];
                parts.push(PartBox {
                    object: o as u32,
                    part: obj.parts[self.part_table[g - 1].1].name.to_string(),
                    bbox: to_box(b),
                    moving: part_moving[g - 1],
                    pixels: count[g],
                });
            }
            let own: Vec<DrawItem> = ids
                .iter()
                .map(|&g| {
                    let it = &items[g - 1];
                    DrawItem {
                        mesh: it.mesh,
                        t_cp: it.t_cp,
                        r_wp: it.r_wp,
                        id: it.id,
                    }
                })
                .collect();
            let unoccluded = render::coverage(&mut scratch, w, h, cam, &own, &self.scene.textures);
            boxes.push(GtBox {
                object: o as u32,
                class_id,
                bbox: to_box(ob),
                moving: ids.iter().any(|&g| part_moving[g - 1]),
                visible_fraction: (n as f32 / unoccluded.max(n) as f32).min(1.0),
            });
        }

        let mut dynamic_mask = ImageBuf {
            width: w,
            height: h,
            data: target
                .id
                .iter()
                .enumerate()
                .map(|(i, &id)| {
                    let moving = id > 0
                        && part_moving[id as usize - 1]
                        && self.image_motion_px(
                            (i % w, i / w),
                            target.depth[i],
                            id,
                            (&pose_wc, &prev_wc),
                            &poses,
                            &prev,
                        ) > cfg.mask_min_motion_px;
                    if moving { 255 } else { 0 }
                })
                .collect(),
        };
        let mut object_ids = ImageBuf {
            width: w,
            height: h,
            data: target
                .id
                .iter()
                .map(|&id| {
                    if id == 0 {
                        0
                    } else {
                        self.part_table[id as usize - 1].0 as u16 + 1
                    }
                })
                .collect(),
        };
        let mut depth: Vec<f32> = target
            .depth
            .iter()
            .map(|&z| if z.is_finite() { z } else { 0.0 })
            .collect();
        let mut rgb = target.rgb;

        let right = cfg.stereo_baseline.map(|b| {
            let right_wc = pose_wc * Isometry3::translation(b, 0.0, 0.0);
            let items = self.items(&poses, &right_wc.inverse());
            let mut rt = Target::new(w, h);
            render::draw_antialiased(&mut rt, cam, &items, &self.scene.textures, cfg.antialias);
            rt.rgb
        });
        let mut right = right;
        if let Noise::Kinect(p) = cfg.noise {
            let mut rng = Pcg64Mcg::seed_from_u64(
                cfg.seed ^ (index as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            noise::apply_depth(&mut depth, w, h, &p, &mut rng);
            noise::apply_image(&mut rgb, p.image_sigma, &mut rng);
            if let Some(r) = right.as_mut() {
                noise::apply_image(r, p.image_sigma, &mut rng);
            }
        }
        if let Some(b) = cfg.blind.filter(|b| b.covers(index)) {
            let (grey, z) = match b.view {
                BlindView::Covered => (0, 0.0),
                BlindView::Wall => (128, 0.4),
            };
            rgb.fill([grey; 3]);
            depth.fill(z);
            if let Some(r) = right.as_mut() {
                r.fill([grey; 3]);
            }
            boxes.clear();
            parts.clear();
            dynamic_mask.data.fill(0);
            object_ids.data.fill(0);
        }
        SynthFrame {
            index,
            timestamp: self.timestamp(index),
            rgb: ImageBuf {
                width: w,
                height: h,
                data: rgb,
            },
            depth: ImageBuf {
                width: w,
                height: h,
                data: depth,
            },
            pose_wc,
            boxes,
            parts,
            dynamic_mask,
            object_ids,
            right: right.map(|data| ImageBuf {
                width: w,
                height: h,
                data,
            }),
        }
    }
}

impl Iterator for Generator {
    type Item = SynthFrame;
    fn next(&mut self) -> Option<SynthFrame> {
        if self.next >= self.config.frames {
            return None;
        }
        let f = self.frame(self.next);
        self.next += 1;
        Some(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_blind_span_hides_the_scene_and_keeps_the_ground_truth() {
        assert_eq!(
            Blind::parse("5+3"),
            Some(Blind {
                start: 5,
                frames: 3,
                view: BlindView::Covered
            })
        );
        assert_eq!(
            Blind::parse("5+3:wall").map(|b| b.view),
            Some(BlindView::Wall)
        );
        for bad in ["5", "5+", "+3", "5+3:sky", "-1+3"] {
            assert_eq!(Blind::parse(bad), None, "{bad}");
        }
        let cam = tum_fr3_camera_sized(160, 120);
        let config = |blind| SynthConfig {
            preset: Preset::WalkingXyz,
            frames: 4,
            camera: cam,
            blind,
            ..SynthConfig::default()
        };
        let seen = Generator::new(&config(None)).unwrap();
        for view in [BlindView::Covered, BlindView::Wall] {
            let g =
                Generator::new(&config(Blind::parse("1+2").map(|b| Blind { view, ..b }))).unwrap();
            assert_eq!(g.frame(0).rgb.data, seen.frame(0).rgb.data);
            assert_eq!(g.frame(3).rgb.data, seen.frame(3).rgb.data);
            let f = g.frame(2);
            assert_eq!(f.pose_wc, seen.frame(2).pose_wc);
            assert!(f.boxes.is_empty() && f.dynamic_mask.data.iter().all(|&m| m == 0));
            let (grey, z) = if view == BlindView::Wall {
                (128, 0.4)
            } else {
                (0, 0.0)
            };
            assert!(f.rgb.data.iter().all(|p| *p == [grey; 3]));
            assert!(f.depth.data.iter().all(|&d| d == z));
        }
    }

    #[test]
    fn a_resized_camera_keeps_the_field_of_view() {
        let full = tum_fr3_camera();
        assert_eq!(tum_fr3_camera_sized(640, 480), full);
        let half = tum_fr3_camera_sized(320, 240);
        assert_eq!((half.width, half.height), (320, 240));
        assert_eq!((half.fx, half.fy), (full.fx / 2.0, full.fy / 2.0));
        // pixel centres stay aligned: level-0 pixel x maps to (x + 0.5) / 2 - 0.5
        assert_eq!(half.cx, (full.cx + 0.5) / 2.0 - 0.5);
        assert_eq!(half.cy, (full.cy + 0.5) / 2.0 - 0.5);
    }

    fn small(preset: Preset) -> SynthConfig {
        let mut camera = tum_fr3_camera();
        camera.fx /= 2.0;
        camera.fy /= 2.0;
        camera.cx = (camera.cx + 0.5) / 2.0 - 0.5;
        camera.cy = (camera.cy + 0.5) / 2.0 - 0.5;
        camera.width = 320;
        camera.height = 240;
        SynthConfig {
            preset,
            frames: 60,
            camera,
            ..Default::default()
        }
    }

    /// Re-project every static pixel of frame `a` into frame `b` with the ground-truth poses
    /// and compare with `b`'s depth where `b` sees the same part on a locally planar patch
    /// (there, bilinear interpolation of 1/z is exact). Returns (checked, max error m,
    /// occluded).
    fn reproject(g: &Generator, fa: &SynthFrame, fb: &SynthFrame) -> (usize, f64, usize) {
        let cam = &g.config().camera;
        let (w, h) = (fa.depth.width, fa.depth.height);
        let t_ba = fb.pose_wc.inverse() * fa.pose_wc;
        let (mut checked, mut max_err, mut occluded) = (0usize, 0.0f64, 0usize);
        let iz = |x: usize, y: usize| 1.0 / fb.depth.get(x, y) as f64;
        for v in 0..h {
            for u in 0..w {
                let z = fa.depth.get(u, v) as f64;
                let id = fa.object_ids.get(u, v);
                if z <= 0.0 || id == 0 || !g.object_is_static(id as usize - 1) {
                    continue;
                }
                let p = t_ba
                    * nalgebra::Point3::from(
                        cam.unproject(&stillpoint_geometry::Vec2::new(u as f64, v as f64), z),
                    );
                let Some(q) = cam.project(&p.coords) else {
                    continue;
                };
                let (x0, y0) = (q.x.floor(), q.y.floor());
                if x0 < 1.0 || y0 < 1.0 || x0 + 2.0 >= w as f64 || y0 + 2.0 >= h as f64 {
                    continue;
                }
                let (x0, y0) = (x0 as usize, y0 as usize);
                // same object over the 4x4 patch, 1/z affine there
                let mut same = true;
                for yy in y0 - 1..=y0 + 2 {
                    for xx in x0 - 1..=x0 + 2 {
                        same &= fb.object_ids.get(xx, yy) == id && fb.depth.get(xx, yy) > 0.0;
                    }
                }
                if !same {
                    continue;
                }
                let mut affine = true;
                for yy in y0..=y0 + 1 {
                    for xx in x0..=x0 + 1 {
                        let cx = iz(xx - 1, yy) + iz(xx + 1, yy) - 2.0 * iz(xx, yy);
                        let cy = iz(xx, yy - 1) + iz(xx, yy + 1) - 2.0 * iz(xx, yy);
                        affine &= cx.abs() < 1e-6 && cy.abs() < 1e-6;
                    }
                }
                if !affine {
                    continue;
                }
                let (fx, fy) = (q.x - x0 as f64, q.y - y0 as f64);
                let top = iz(x0, y0) * (1.0 - fx) + iz(x0 + 1, y0) * fx;
                let bot = iz(x0, y0 + 1) * (1.0 - fx) + iz(x0 + 1, y0 + 1) * fx;
                let zb = 1.0 / (top * (1.0 - fy) + bot * fy);
                if zb < p.z - 0.01 {
                    occluded += 1; // something of the same object is in front (self-occlusion)
                    continue;
                }
                checked += 1;
                max_err = max_err.max((zb - p.z).abs());
            }
        }
        (checked, max_err, occluded)
    }

    #[test]
    fn the_static_triangles_are_where_the_static_pixels_depth_puts_them() {
        use stillpoint_eval::surface::{SurfaceGrid, cloud_to_surface};
        for preset in [Preset::WalkingXyz, Preset::SittingHalfsphere] {
            let g = Generator::new(&small(preset)).unwrap();
            let grid = SurfaceGrid::new(g.static_triangles(), 0.1, 0.05);
            let f = g.frame(30);
            let cam = &g.config().camera;
            let (mut on_static, mut elsewhere) = (Vec::new(), Vec::new());
            for v in (0..f.depth.height).step_by(3) {
                for u in (0..f.depth.width).step_by(3) {
                    let z = f.depth.get(u, v) as f64;
                    let id = f.object_ids.get(u, v);
                    if z <= 0.0 || id == 0 {
                        continue;
                    }
                    let px = stillpoint_geometry::Vec2::new(u as f64, v as f64);
                    let w = f.pose_wc * nalgebra::Point3::from(cam.unproject(&px, z));
                    if g.object_is_static(id as usize - 1) {
                        on_static.push(w.coords);
                    } else {
                        elsewhere.push(w.coords);
                    }
                }
            }
            let d = cloud_to_surface(&on_static, &grid);
            assert!(d.points > 5000, "{preset:?}: {d:?}");
            assert!(d.p95_m < 1e-4 && d.beyond_reach == 0.0, "{preset:?}: {d:?}");
            // The people are not part of it.
            let d = cloud_to_surface(&elsewhere, &grid);
            assert!(d.points > 100 && d.median_m > 0.02, "{preset:?}: {d:?}");
        }
    }

    #[test]
    fn depth_reprojects_exactly_between_frames_on_static_pixels() {
        for preset in [
            Preset::WalkingXyz,
            Preset::WalkingRpy,
            Preset::SittingHalfsphere,
        ] {
            let g = generate(&small(preset)).unwrap();
            let (fa, fb) = (g.frame(3), g.frame(40));
            let (checked, max_err, occluded) = reproject(&g, &fa, &fb);
            eprintln!(
                "{preset:?}: {checked} px checked, max error {max_err:.2e} m, {occluded} self-occluded"
            );
            assert!(
                checked > 20_000,
                "{preset:?}: only {checked} pixels checked"
            );
            assert!(occluded * 20 < checked, "{preset:?}: {occluded} occluded");
            assert!(max_err < 1e-3, "{preset:?}: max depth error {max_err} m");
        }
    }

    #[test]
    fn boxes_are_the_tight_boxes_of_object_pixels_and_masks_lie_in_moving_boxes() {
        for preset in [
            Preset::WalkingXyz,
            Preset::SittingStatic,
            Preset::PlacingBox,
            Preset::Crowd,
        ] {
            let g = generate(&small(preset)).unwrap();
            let objects = g.objects();
            for i in [0, 17, 59] {
                let f = g.frame(i);
                let (w, h) = (f.rgb.width, f.rgb.height);
                let mut tight =
                    vec![(usize::MAX, usize::MAX, 0usize, 0usize, 0usize); objects.len()];
                for y in 0..h {
                    for x in 0..w {
                        let id = f.object_ids.get(x, y);
                        if id > 0 {
                            let t = &mut tight[id as usize - 1];
                            *t = (t.0.min(x), t.1.min(y), t.2.max(x), t.3.max(y), t.4 + 1);
                        }
                    }
                }
                for (o, info) in objects.iter().enumerate() {
                    let t = tight[o];
                    let b = f.boxes.iter().find(|b| b.object == o as u32);
                    match (info.class_id, b) {
                        (Some(c), Some(b)) => {
                            assert_eq!(b.class_id, c);
                            let want = BBox::new(
                                t.0 as f32 - 0.5,
                                t.1 as f32 - 0.5,
                                t.2 as f32 + 0.5,
                                t.3 as f32 + 0.5,
                            );
                            assert_eq!(b.bbox, want, "{preset:?} frame {i} object {o}");
                            assert!(b.visible_fraction > 0.0 && b.visible_fraction <= 1.0);
                        }
                        (Some(_), None) => assert!(
                            t.4 < g.config().min_box_pixels,
                            "{preset:?} frame {i}: object {o} has {} px but no box",
                            t.4
                        ),
                        (None, b) => assert!(b.is_none()),
                    }
                }
                for y in 0..h {
                    for x in 0..w {
                        if f.dynamic_mask.get(x, y) == 0 {
                            continue;
                        }
                        let o = f.object_ids.get(x, y) as u32 - 1;
                        let b = f
                            .boxes
                            .iter()
                            .find(|b| b.object == o)
                            .expect("moving pixel without a box");
                        assert!(b.moving && b.bbox.contains_strict(x as f32, y as f32));
                    }
                }
            }
        }
    }

    #[test]
    fn a_motion_threshold_keeps_only_pixels_that_moved_that_far() {
        let masks = |min: f64| {
            let g = generate(&SynthConfig {
                mask_min_motion_px: min,
                ..small(Preset::SittingXyz)
            })
            .unwrap();
            g.frame(30).dynamic_mask
        };
        let any = masks(0.0);
        let half = masks(0.5);
        let far = masks(1e9);
        let count = |m: &Gray8| m.data.iter().filter(|&&v| v > 0).count();
        assert!(count(&any) > 0, "sitting_xyz frame 30 has moving pixels");
        assert_eq!(count(&far), 0);
        assert!(count(&half) <= count(&any));
        assert!(
            any.data.iter().zip(&half.data).all(|(&a, &h)| a >= h),
            "the thresholded mask is a subset"
        );
    }

    #[test]
    fn moving_flags_follow_the_story() {
        // walkers always move, furniture never
        let g = generate(&small(Preset::WalkingStatic)).unwrap();
        let f = g.frame(10);
        for b in &f.boxes {
            assert_eq!(b.moving, b.class_id == 0, "{b:?}");
        }
        assert!(f.dynamic_mask.data.contains(&255));
        // seated people: legs never in the mask; sometimes the person is still
        let g = generate(&small(Preset::SittingStatic)).unwrap();
        let (mut still, mut moving) = (0, 0);
        for i in (0..300).step_by(5) {
            let f = g.frame(i);
            for b in f.boxes.iter().filter(|b| b.class_id == 0) {
                if b.moving { moving += 1 } else { still += 1 }
            }
            for p in f
                .parts
                .iter()
                .filter(|p| p.part.contains("shin") || p.part.contains("thigh"))
            {
                assert!(!p.moving);
            }
        }
        assert!(still > 0 && moving > 0, "still {still} moving {moving}");
        // the carried box moves, then stays on the desk
        let mut cfg = small(Preset::PlacingBox);
        cfg.frames = 300;
        let g = generate(&cfg).unwrap();
        let bx = g.objects().iter().position(|o| o.name == "box").unwrap() as u32;
        let moving_at = |i: usize| {
            g.frame(i)
                .boxes
                .iter()
                .find(|b| b.object == bx)
                .map(|b| b.moving)
        };
        assert_eq!(moving_at(30), Some(true));
        assert_eq!(moving_at(280), Some(false));
    }

    #[test]
    fn deterministic_for_a_seed_and_noise_is_kinect_like() {
        let cfg = small(Preset::Crowd);
        let (a, b) = (generate(&cfg).unwrap(), generate(&cfg).unwrap());
        assert_eq!(a.frame(7).rgb, b.frame(7).rgb);
        let other = generate(&SynthConfig {
            seed: 9,
            ..cfg.clone()
        })
        .unwrap();
        assert_ne!(a.frame(7).rgb, other.frame(7).rgb);
        let noisy = generate(&SynthConfig {
            noise: Noise::Kinect(KinectNoise::default()),
            ..cfg.clone()
        })
        .unwrap();
        let (clean, n1, n2) = (a.frame(7), noisy.frame(7), noisy.frame(7));
        assert_eq!(n1.depth, n2.depth);
        let holes = n1.depth.data.iter().filter(|&&d| d == 0.0).count();
        assert!(holes > 100, "{holes} holes");
        let diff: Vec<f32> = clean
            .depth
            .data
            .iter()
            .zip(&n1.depth.data)
            .filter(|(c, n)| **c > 0.0 && **n > 0.0)
            .map(|(c, n)| (c - n).abs())
            .collect();
        let mean = diff.iter().sum::<f32>() / diff.len() as f32;
        assert!(mean > 0.0005 && mean < 0.05, "mean depth noise {mean}");
    }

    #[test]
    fn stereo_right_image_is_shifted_by_the_disparity() {
        let mut cfg = small(Preset::Static);
        cfg.stereo_baseline = Some(0.1);
        let g = generate(&cfg).unwrap();
        let f = g.frame(0);
        let right = f.right.as_ref().unwrap();
        // a left pixel at depth z appears in the right image at u - fx b / z
        let cam = cfg.camera;
        let mut agree = 0;
        let mut total = 0;
        for v in (20..220).step_by(7) {
            for u in (40..300).step_by(7) {
                let z = f.depth.get(u, v) as f64;
                let ur = u as f64 - cam.fx * 0.1 / z;
                if ur.fract().abs() > 1e-9 || ur < 0.0 {
                    // compare with the nearest pixel only where the shift is nearly integral
                    let r = ur.round();
                    if (ur - r).abs() > 0.05 || r < 0.0 {
                        continue;
                    }
                }
                total += 1;
                let (l, r) = (f.rgb.get(u, v), right.get(ur.round() as usize, v));
                if l.iter()
                    .zip(r.iter())
                    .all(|(a, b)| (*a as i32 - *b as i32).abs() < 40)
                {
                    agree += 1;
                }
            }
        }
        assert!(total > 20 && agree * 10 > total * 8, "{agree}/{total}");
    }

    #[test]
    fn settings_toml_roundtrips_and_bad_config_is_an_error() {
        let g = generate(&small(Preset::Static)).unwrap();
        let s = g.settings(Sensor::Rgbd);
        let back: Settings = toml::from_str(&toml::to_string(&s).unwrap()).unwrap();
        assert_eq!(back, s);
        let mut bad = small(Preset::Static);
        bad.camera.distortion.k1 = 0.1;
        assert!(generate(&bad).is_err());
        bad = small(Preset::Static);
        bad.fps = 0.0;
        assert!(generate(&bad).is_err());
        bad = small(Preset::Static);
        bad.textures = Some(PathBuf::from("/nonexistent/textures"));
        let e = generate(&bad).err().unwrap().to_string();
        assert!(e.contains("/nonexistent/textures"), "{e}");
    }
}
