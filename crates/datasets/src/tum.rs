//! TUM RGB-D / Bonn RGB-D Dynamic layout, and stillpoint's synthetic sequences (same layout plus
//! `boxes.jsonl` and `settings.toml`).

use crate::error::{DatasetError, layout_err};
use crate::lists::{RgbdEntry, associate_nearest, read_associations, read_stamped_list};
use crate::sequence::{Sequence, check_header, check_index, check_size, dir_name};
use crate::{Frame, Sensor, Settings};
use std::path::{Path, PathBuf};
use stillpoint_geometry::{PinholeCamera, RadTan};
use stillpoint_image::{read_depth_metres, read_rgb, rgb_to_gray};

/// Largest rgb/depth stamp difference TUM's `associate.py` accepts, seconds.
pub const TUM_ASSOCIATION_MAX_DIFF: f64 = 0.02;

/// Association files looked for beside the lists, in order.
const ASSOCIATION_FILES: [&str; 3] = ["associations.txt", "associate.txt", "association.txt"];

/// ORB-SLAM's camera for a TUM / Bonn sequence, chosen by its directory name (freiburg1/2/3,
/// bonn); TUM3's (no distortion) when the name tells nothing.
pub fn default_tum_settings(name: &str) -> Settings {
    let n = name.to_ascii_lowercase();
    let (fx, fy, cx, cy, d, factor) = if n.contains("freiburg1") || n.contains("fr1") {
        (
            517.306408,
            516.469215,
            318.643040,
            255.313989,
            [0.262383, -0.953104, -0.005358, 0.002628, 1.163314],
            5000.0,
        )
    } else if n.contains("freiburg2") || n.contains("fr2") {
        (
            520.908620,
            521.007327,
            325.141442,
            249.701764,
            [0.231222, -0.784899, -0.003257, -0.000105, 0.917205],
            5208.0,
        )
    } else if n.contains("bonn") {
        (
            542.822841,
            542.576870,
            315.593520,
            237.756098,
            [0.039903, -0.099343, -0.000730, -0.000144, 0.0],
            5000.0,
        )
    } else {
        (535.4, 539.2, 320.1, 247.6, [0.0; 5], 5000.0)
    };
    let mut camera = PinholeCamera::new(fx, fy, cx, cy, 640, 480);
    camera.distortion = RadTan {
        k1: d[0],
        k2: d[1],
        p1: d[2],
        p2: d[3],
        k3: d[4],
    };
    let mut s = Settings::with_camera(Sensor::Rgbd, camera);
    s.depth_factor = factor;
    s
}

/// A TUM-layout sequence.
pub struct TumSequence {
    dir: PathBuf,
    settings: Settings,
    /// RGB stamp and file, and the associated depth file when RGB-D.
    frames: Vec<(f64, PathBuf, Option<PathBuf>)>,
}

impl TumSequence {
    /// Open `dir`. Frames come from an association file when one is there, else from `rgb.txt`
    /// and `depth.txt` associated by TUM's rule (nearest within 0.02 s, one-to-one); without
    /// `depth.txt` the sequence is monocular. Settings: `settings` if given, else
    /// `settings.toml` in `dir`, else ORB-SLAM's TUM1/2/3 or Bonn camera chosen by the name.
    pub fn open(dir: &Path, settings: Option<Settings>) -> Result<Self, DatasetError> {
        let name = dir_name(dir);
        let mut settings = match settings {
            Some(s) => s,
            None if dir.join("settings.toml").is_file() => {
                crate::read_settings_toml(&dir.join("settings.toml"))?
            }
            None => {
                tracing::info!(
                    "{}: no settings given, using ORB-SLAM's camera for {name:?}",
                    dir.display()
                );
                default_tum_settings(&name)
            }
        };
        let frames: Vec<(f64, PathBuf, Option<PathBuf>)> = if let Some(assoc) = ASSOCIATION_FILES
            .iter()
            .map(|f| dir.join(f))
            .find(|p| p.is_file())
        {
            read_associations(&assoc, dir)?
                .into_iter()
                .map(|e: RgbdEntry| (e.rgb_stamp, e.rgb, Some(e.depth)))
                .collect()
        } else {
            let rgb_txt = dir.join("rgb.txt");
            if !rgb_txt.is_file() {
                return Err(layout_err(
                    dir,
                    "no rgb.txt (nor an associations file): not a TUM-layout sequence",
                ));
            }
            let rgb = read_stamped_list(&rgb_txt, dir)?;
            let depth_txt = dir.join("depth.txt");
            if depth_txt.is_file() && settings.sensor != Sensor::Mono {
                let depth = read_stamped_list(&depth_txt, dir)?;
                let a: Vec<f64> = rgb.iter().map(|r| r.0).collect();
                let b: Vec<f64> = depth.iter().map(|d| d.0).collect();
                let pairs = associate_nearest(&a, &b, TUM_ASSOCIATION_MAX_DIFF);
                if pairs.len() < rgb.len() {
                    tracing::info!(
                        "{}: {} of {} rgb frames have a depth frame within {TUM_ASSOCIATION_MAX_DIFF} s",
                        dir.display(),
                        pairs.len(),
                        rgb.len()
                    );
                }
                pairs
                    .into_iter()
                    .map(|(i, j)| (rgb[i].0, rgb[i].1.clone(), Some(depth[j].1.clone())))
                    .collect()
            } else {
                if settings.sensor == Sensor::Rgbd {
                    tracing::warn!(
                        "{}: no depth.txt; reading the sequence as monocular",
                        dir.display()
                    );
                    settings.sensor = Sensor::Mono;
                }
                rgb.into_iter().map(|(t, p)| (t, p, None)).collect()
            }
        };
        if frames.is_empty() {
            return Err(layout_err(
                dir,
                "no rgb frame has a depth frame within 0.02 s",
            ));
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            settings,
            frames,
        })
    }
}

impl Sequence for TumSequence {
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn len(&self) -> usize {
        self.frames.len()
    }
    fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
        check_index(i, self.frames.len())?;
        let (t, rgb_path, depth_path) = &self.frames[i];
        check_header(rgb_path, &self.settings)?;
        let rgb = read_rgb(rgb_path)?;
        check_size(rgb_path, rgb.width, rgb.height, &self.settings)?;
        let depth = match depth_path {
            Some(p) => {
                check_header(p, &self.settings)?;
                let d = read_depth_metres(p, self.settings.depth_factor as f32)?;
                check_size(p, d.width, d.height, &self.settings)?;
                Some(d)
            }
            None => None,
        };
        Ok(Frame {
            index: i,
            timestamp: *t,
            gray: rgb_to_gray(&rgb),
            rgb: Some(rgb),
            depth,
            right: None,
        })
    }
    fn ground_truth(&self) -> Option<PathBuf> {
        Some(self.dir.join("groundtruth.txt")).filter(|p| p.is_file())
    }
    fn boxes(&self) -> Option<PathBuf> {
        Some(self.dir.join("boxes.jsonl")).filter(|p| p.is_file())
    }
    fn name(&self) -> String {
        dir_name(&self.dir)
    }
    fn timestamp(&self, i: usize) -> Option<f64> {
        self.frames.get(i).map(|f| f.0)
    }
}
