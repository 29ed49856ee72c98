//! EuRoC MAV layout: `mav0/cam0/data.csv` (`#timestamp [ns],filename`), images in
//! `mav0/cam0/data/`, intrinsics in `mav0/cam0/sensor.yaml`, ground truth in
//! `mav0/state_groundtruth_estimate0/data.csv`.

use crate::error::{DatasetError, io_err, layout_err, parse_err};
use crate::lists::data_lines;
use crate::sequence::{
    GroundTruthFormat, Sequence, check_header, check_index, check_size, dir_name,
};
use crate::{Frame, Sensor, Settings};
use std::path::{Path, PathBuf};
use stillpoint_geometry::{PinholeCamera, RadTan};
use stillpoint_image::{Gray8, read_gray, remap_bilinear};

/// Read a camera's `data.csv`: (seconds, image path), stamps strictly increasing.
fn read_cam_csv(cam: &Path) -> Result<Vec<(f64, PathBuf)>, DatasetError> {
    let csv = cam.join("data.csv");
    let mut out: Vec<(f64, PathBuf)> = Vec::new();
    for (line, text) in data_lines(&csv)? {
        let Some((ns, file)) = text.split_once(',') else {
            return Err(parse_err(&csv, line, "expected \"timestamp_ns,filename\""));
        };
        let ns: u64 = ns
            .trim()
            .parse()
            .map_err(|_| parse_err(&csv, line, format!("{ns:?} is not a nanosecond timestamp")))?;
        let t = ns as f64 / 1e9;
        if let Some(prev) = out.last()
            && t <= prev.0
        {
            return Err(parse_err(&csv, line, "timestamps must increase strictly"));
        }
        out.push((t, cam.join("data").join(file.trim())));
    }
    if out.is_empty() {
        return Err(parse_err(&csv, 1, "no frames listed"));
    }
    Ok(out)
}

/// Intrinsics of an EuRoC `sensor.yaml` (`intrinsics: [fu, fv, cu, cv]`, `resolution`,
/// `distortion_coefficients: [k1, k2, p1, p2]`, `rate_hz`).
pub fn read_euroc_sensor_yaml(path: &Path) -> Result<Settings, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    let fixed: String = text
        .lines()
        .map(|l| {
            if l.trim_start().starts_with("%YAML") {
                ""
            } else {
                l
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let bad = |msg: String| DatasetError::Settings {
        path: path.display().to_string(),
        msg,
    };
    let docs = yaml_rust2::YamlLoader::load_from_str(&fixed)
        .map_err(|e| bad(format!("line {}: {}", e.marker().line(), e.info())))?;
    let root = docs.into_iter().next().unwrap_or(yaml_rust2::Yaml::Null);
    let nums = |k: &str, n: usize| -> Result<Vec<f64>, DatasetError> {
        let v: Option<Vec<f64>> = root[k]
            .as_vec()
            .map(|a| {
                a.iter()
                    .map(|y| y.as_f64().or_else(|| y.as_i64().map(|i| i as f64)))
                    .collect::<Option<Vec<f64>>>()
            })
            .unwrap_or(None);
        v.filter(|v| v.len() >= n && v.iter().all(|x| x.is_finite()))
            .ok_or_else(|| bad(format!("{k} must be a list of at least {n} numbers")))
    };
    let k = nums("intrinsics", 4)?;
    let res = nums("resolution", 2)?;
    let d = nums("distortion_coefficients", 4).unwrap_or_else(|_| vec![0.0; 4]);
    if !(res[0] >= 1.0 && res[1] >= 1.0 && k[0] > 0.0 && k[1] > 0.0) {
        return Err(bad("resolution and focal lengths must be positive".into()));
    }
    let mut camera = PinholeCamera::new(k[0], k[1], k[2], k[3], res[0] as u32, res[1] as u32);
    camera.distortion = RadTan {
        k1: d[0],
        k2: d[1],
        p1: d[2],
        p2: d[3],
        k3: 0.0,
    };
    let mut s = Settings::with_camera(Sensor::Mono, camera);
    s.bf = None;
    s.fps = root["rate_hz"]
        .as_f64()
        .or_else(|| root["rate_hz"].as_i64().map(|v| v as f64))
        .unwrap_or(20.0);
    s.th_depth = 35.0;
    s.orb.n_features = 1000;
    Ok(s)
}

/// For each pixel of a rectified image, the raw pixel it samples (row-major).
type RectifyMap = Vec<[f32; 2]>;

/// An EuRoC MAV sequence: cam0 (left); cam1 as the right image when the settings are stereo
/// (an ORB-SLAM EuRoC settings file). Both images are rectified when the settings carry
/// ORB-SLAM's `LEFT/RIGHT.K, D, R, P` ([`Settings::rectification`]), as ORB-SLAM's
/// `stereo_euroc` does before tracking.
pub struct EurocSequence {
    mav: PathBuf,
    settings: Settings,
    left: Vec<(f64, PathBuf)>,
    right: Option<Vec<PathBuf>>,
    /// Where each rectified pixel samples the raw left and right images.
    rectify_maps: Option<(RectifyMap, RectifyMap)>,
}

impl EurocSequence {
    /// Open `dir` (the sequence folder holding `mav0/`, or `mav0/` itself).
    pub fn open(dir: &Path, settings: Option<Settings>) -> Result<Self, DatasetError> {
        let mav = if dir.join("mav0").is_dir() {
            dir.join("mav0")
        } else {
            dir.to_path_buf()
        };
        let cam0 = mav.join("cam0");
        if !cam0.join("data.csv").is_file() {
            return Err(layout_err(&mav, "no cam0/data.csv: not a EuRoC sequence"));
        }
        let left = read_cam_csv(&cam0)?;
        let settings = match settings {
            Some(s) => s,
            None => read_euroc_sensor_yaml(&cam0.join("sensor.yaml"))?,
        };
        let right = if settings.sensor == Sensor::Stereo && mav.join("cam1/data.csv").is_file() {
            let r = read_cam_csv(&mav.join("cam1"))?;
            // Pair by equal stamp (EuRoC cameras are hardware-synchronised).
            let mut paths = Vec::with_capacity(left.len());
            for (t, p) in &left {
                let j = r.partition_point(|x| x.0 < *t);
                match r.get(j) {
                    Some(x) if (x.0 - t).abs() < 1e-6 => paths.push(x.1.clone()),
                    _ => {
                        return Err(layout_err(
                            &mav.join("cam1/data.csv"),
                            format!("no cam1 frame at the stamp of {}", p.display()),
                        ));
                    }
                }
            }
            if settings.rectification.is_none() {
                // Stereo matching searches along image rows, which needs rectified pairs.
                tracing::warn!(
                    "{}: EuRoC cam0/cam1 are used as given, not rectified: stereo depth will be \
                     sparse and biased (give ORB-SLAM's EuRoC stereo settings, with LEFT/RIGHT.K, \
                     D, R, P, to rectify them)",
                    mav.display()
                );
            }
            Some(paths)
        } else {
            if settings.sensor == Sensor::Stereo {
                tracing::warn!(
                    "{}: stereo settings but no cam1/data.csv: running monocular",
                    mav.display()
                );
            }
            None
        };
        let rectify_maps = settings
            .rectification
            .map(|r| (r.left.map(), r.right.map()));
        Ok(Self {
            mav,
            settings,
            left,
            right,
            rectify_maps,
        })
    }
}

/// `img` (read from `path`) resampled through a rectification map of its size.
fn rectified(img: Gray8, map: &[[f32; 2]], path: &Path) -> Result<Gray8, DatasetError> {
    remap_bilinear(&img, map, img.width, img.height).ok_or_else(|| {
        layout_err(
            path,
            format!(
                "{}x{} image, but the rectification (LEFT/RIGHT.width, height) is for {} pixels",
                img.width,
                img.height,
                map.len()
            ),
        )
    })
}

impl Sequence for EurocSequence {
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn len(&self) -> usize {
        self.left.len()
    }
    fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
        check_index(i, self.left.len())?;
        let (t, p) = &self.left[i];
        check_header(p, &self.settings)?;
        let gray = read_gray(p)?;
        check_size(p, gray.width, gray.height, &self.settings)?;
        let right = match &self.right {
            Some(r) => {
                check_header(&r[i], &self.settings)?;
                let img = read_gray(&r[i])?;
                check_size(&r[i], img.width, img.height, &self.settings)?;
                Some(img)
            }
            None => None,
        };
        let (gray, right) = match (&self.rectify_maps, &self.right) {
            (Some((l, r)), Some(paths)) => (
                rectified(gray, l, p)?,
                right.map(|img| rectified(img, r, &paths[i])).transpose()?,
            ),
            (Some((l, _)), None) => (rectified(gray, l, p)?, right),
            (None, _) => (gray, right),
        };
        Ok(Frame {
            index: i,
            timestamp: *t,
            gray,
            rgb: None,
            depth: None,
            right,
        })
    }
    fn ground_truth_format(&self) -> GroundTruthFormat {
        GroundTruthFormat::EurocCsv
    }
    fn ground_truth(&self) -> Option<PathBuf> {
        Some(self.mav.join("state_groundtruth_estimate0/data.csv")).filter(|p| p.is_file())
    }
    fn boxes(&self) -> Option<PathBuf> {
        None
    }
    fn name(&self) -> String {
        let n = dir_name(&self.mav);
        if n == "mav0" {
            self.mav.parent().map(dir_name).unwrap_or(n)
        } else {
            n
        }
    }
    fn timestamp(&self, i: usize) -> Option<f64> {
        self.left.get(i).map(|f| f.0)
    }
}
