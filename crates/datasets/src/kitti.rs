//! KITTI odometry layout: `image_0/` + `image_1/` (gray stereo) or `image_2/` + `image_3/`
//! (colour), `calib.txt` (`P0:` .. `P3:`, 3x4 row-major), `times.txt`, and a poses file.

use crate::error::{DatasetError, io_err, layout_err, parse_err};
use crate::lists::{data_lines, read_times};
use crate::sequence::{
    GroundTruthFormat, Sequence, check_header, check_index, check_size, dir_name, header_size,
    is_image,
};
use crate::settings_file::{Field, check_values};
use crate::{Frame, Sensor, Settings};
use std::path::{Path, PathBuf};
use stillpoint_geometry::PinholeCamera;
use stillpoint_image::{read_gray, read_rgb, rgb_to_gray};

/// The projection matrices of a KITTI `calib.txt`, by name (`P0`, `P1`, ...).
pub fn read_kitti_calib(path: &Path) -> Result<Vec<(String, [f64; 12])>, DatasetError> {
    let mut out = Vec::new();
    for (line, text) in data_lines(path)? {
        let Some((key, rest)) = text.split_once(':') else {
            return Err(parse_err(path, line, "expected \"NAME: 12 numbers\""));
        };
        let v: Vec<f64> = rest
            .split_whitespace()
            .map(|f| f.parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<_>>()
            .ok_or_else(|| {
                parse_err(
                    path,
                    line,
                    format!("{key}: not all values are finite numbers"),
                )
            })?;
        // Tr / Tr_imu lines have 12 values too; other lengths are skipped only if not P*.
        match <[f64; 12]>::try_from(v.as_slice()) {
            Ok(m) => out.push((key.trim().to_string(), m)),
            Err(_) if key.trim().starts_with('P') => {
                return Err(parse_err(
                    path,
                    line,
                    format!("{key}: expected 12 numbers, found {}", v.len()),
                ));
            }
            Err(_) => {}
        }
    }
    Ok(out)
}

/// A KITTI odometry sequence.
pub struct KittiSequence {
    dir: PathBuf,
    settings: Settings,
    left: Vec<PathBuf>,
    right: Option<Vec<PathBuf>>,
    colour: bool,
    stamps: Vec<f64>,
}

fn sorted_images(dir: &Path) -> Result<Vec<PathBuf>, DatasetError> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io_err(dir))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| is_image(p))
        .collect();
    v.sort();
    Ok(v)
}

impl KittiSequence {
    /// Open `dir`. Camera from `settings`, else `settings*.toml` in `dir`, else `calib.txt`
    /// (or the first `calib*.txt`): fx, fy, cx, cy from P0 (P2 for colour), bf = `-P1[3]`
    /// (P3 - P2 for colour) and the image size from the first image. Stamps from `times.txt`,
    /// else frame index / fps.
    pub fn open(dir: &Path, settings: Option<Settings>) -> Result<Self, DatasetError> {
        let colour = !dir.join("image_0").is_dir() && dir.join("image_2").is_dir();
        let (l, r) = if colour {
            ("image_2", "image_3")
        } else {
            ("image_0", "image_1")
        };
        let left = sorted_images(&dir.join(l))?;
        if left.is_empty() {
            return Err(layout_err(&dir.join(l), "no images"));
        }
        let right = if dir.join(r).is_dir() {
            let right = sorted_images(&dir.join(r))?;
            if right.len() != left.len() {
                return Err(layout_err(
                    &dir.join(r),
                    format!(
                        "{} right images for {} left images",
                        right.len(),
                        left.len()
                    ),
                ));
            }
            Some(right)
        } else {
            tracing::warn!(
                "{}: no {r}/ folder: running monocular (scale from the first two views only)",
                dir.display()
            );
            None
        };
        // `stillpoint synth --stereo` writes both: the stereo one when there is a right image.
        let names = if right.is_some() {
            ["settings_stereo.toml", "settings.toml"]
        } else {
            ["settings.toml", "settings_stereo.toml"]
        };
        let local_toml = names.iter().map(|f| dir.join(f)).find(|p| p.is_file());
        let settings = match (settings, local_toml) {
            (Some(s), _) => s,
            (None, Some(p)) => crate::read_settings_toml(&p)?,
            (None, None) => settings_from_calib(dir, &left[0], colour, right.is_some())?,
        };
        let stamps = if dir.join("times.txt").is_file() {
            let t = read_times(&dir.join("times.txt"))?;
            if t.len() < left.len() {
                return Err(layout_err(
                    &dir.join("times.txt"),
                    format!("{} stamps for {} images", t.len(), left.len()),
                ));
            }
            t[..left.len()].to_vec()
        } else {
            (0..left.len()).map(|i| i as f64 / settings.fps).collect()
        };
        let right = right.filter(|_| settings.sensor == Sensor::Stereo);
        Ok(Self {
            dir: dir.to_path_buf(),
            settings,
            left,
            right,
            colour,
            stamps,
        })
    }
}

fn find_calib(dir: &Path) -> Result<PathBuf, DatasetError> {
    if dir.join("calib.txt").is_file() {
        return Ok(dir.join("calib.txt"));
    }
    let mut c: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io_err(dir))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("calib") && n.ends_with(".txt"))
        })
        .collect();
    c.sort();
    c.into_iter()
        .next()
        .ok_or_else(|| layout_err(dir, "no calib.txt and no settings file"))
}

fn settings_from_calib(
    dir: &Path,
    first: &Path,
    colour: bool,
    stereo: bool,
) -> Result<Settings, DatasetError> {
    let calib_path = find_calib(dir)?;
    let calib = read_kitti_calib(&calib_path)?;
    let get = |k: &str| calib.iter().find(|(n, _)| n == k).map(|(_, m)| *m);
    let (kl, kr) = if colour { ("P2", "P3") } else { ("P0", "P1") };
    let p = get(kl).ok_or_else(|| layout_err(&calib_path, format!("no {kl} line")))?;
    let (width, height) = match header_size(first) {
        Some(size) => size,
        None => {
            let img = read_gray(first)?;
            (img.width, img.height)
        }
    };
    let camera = PinholeCamera::new(p[0], p[5], p[2], p[6], width as u32, height as u32);
    let mut s = Settings::with_camera(if stereo { Sensor::Stereo } else { Sensor::Mono }, camera);
    // P_r[3] = -fx * baseline (relative to P_l[3] for the colour pair).
    s.bf = get(kr).map(|pr| -(pr[3] - p[3]));
    if stereo && s.bf.is_none() {
        tracing::warn!("{}: no {kr} line: running monocular", calib_path.display());
        s.sensor = Sensor::Mono;
    }
    // ORB-SLAM's KITTI settings: 10 fps, ThDepth 35, 2000 features, FAST 20/7.
    s.fps = 10.0;
    s.th_depth = 35.0;
    s.orb.n_features = 2000;
    let key = |field: Field| match field {
        Field::Fx => format!("{kl}[0] (fx)"),
        Field::Fy => format!("{kl}[5] (fy)"),
        Field::Cx => format!("{kl}[2] (cx)"),
        Field::Cy => format!("{kl}[6] (cy)"),
        Field::Bf => format!("{kr}[3] (-fx x baseline)"),
        Field::Size => format!("{}: image size", first.display()),
        other => format!("{other:?}"),
    };
    check_values(&s, key).map_err(|m| layout_err(&calib_path, m))?;
    Ok(s)
}

impl Sequence for KittiSequence {
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn len(&self) -> usize {
        self.left.len()
    }
    fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
        check_index(i, self.left.len())?;
        let (gray, rgb) = if self.colour {
            check_header(&self.left[i], &self.settings)?;
            let rgb = read_rgb(&self.left[i])?;
            (rgb_to_gray(&rgb), Some(rgb))
        } else {
            check_header(&self.left[i], &self.settings)?;
            (read_gray(&self.left[i])?, None)
        };
        check_size(&self.left[i], gray.width, gray.height, &self.settings)?;
        let right = match &self.right {
            Some(r) => {
                check_header(&r[i], &self.settings)?;
                let img = read_gray(&r[i])?;
                check_size(&r[i], img.width, img.height, &self.settings)?;
                Some(img)
            }
            None => None,
        };
        Ok(Frame {
            index: i,
            timestamp: self.stamps[i],
            gray,
            rgb,
            depth: None,
            right,
        })
    }
    fn ground_truth_format(&self) -> GroundTruthFormat {
        GroundTruthFormat::KittiPoses
    }
    /// `poses.txt`, else the first `poses*.txt` in the directory, else `../../poses/<name>.txt`
    /// (the official layout `sequences/NN/` beside `poses/NN.txt`).
    fn ground_truth(&self) -> Option<PathBuf> {
        let direct = self.dir.join("poses.txt");
        if direct.is_file() {
            return Some(direct);
        }
        let mut c: Vec<PathBuf> = std::fs::read_dir(&self.dir)
            .ok()?
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("poses") && n.ends_with(".txt"))
            })
            .collect();
        c.sort();
        c.into_iter().next().or_else(|| {
            Some(
                self.dir
                    .join("../../poses")
                    .join(format!("{}.txt", self.name())),
            )
            .filter(|p| p.is_file())
        })
    }
    fn boxes(&self) -> Option<PathBuf> {
        Some(self.dir.join("boxes.jsonl")).filter(|p| p.is_file())
    }
    fn name(&self) -> String {
        dir_name(&self.dir)
    }
    fn timestamp(&self, i: usize) -> Option<f64> {
        self.stamps.get(i).copied()
    }
}
