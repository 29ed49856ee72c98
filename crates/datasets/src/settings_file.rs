//! Settings files: ORB-SLAM's OpenCV `%YAML:1.0` files as they are (ORB-SLAM2 keys `Camera.fx`,
//! ORB-SLAM3 keys `Camera1.fx`, `Stereo.b`, `RGBD.DepthMapFactor`), and stillpoint's TOML form
//! of [`Settings`] (its serde form).
//!
//! OpenCV's YAML is not quite YAML: a `%YAML:1.0` directive, `!!opencv-matrix` tags, and
//! `key:value` without a space (`data:[`). Those are fixed in the text (keeping line numbers)
//! before `yaml-rust2` parses it.

use crate::error::{DatasetError, io_err};
use crate::{Sensor, Settings};
use std::path::Path;
use stillpoint_core::OrbParams;
use stillpoint_geometry::{PinholeCamera, RadTan, RectifyingView, StereoRectification};
use yaml_rust2::parser::{Event, Parser};
use yaml_rust2::{Yaml, YamlLoader};

fn settings_err(path: &Path, msg: impl Into<String>) -> DatasetError {
    DatasetError::Settings {
        path: path.display().to_string(),
        msg: msg.into(),
    }
}

/// Make OpenCV's YAML dialect parseable, line for line.
fn opencv_to_yaml(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 64);
    for line in text.lines() {
        let trimmed = line.trim_start();
        if trimmed.starts_with("%YAML") {
            out.push('\n');
            continue;
        }
        let mut l = line.replace("!!opencv-matrix", "");
        if !trimmed.starts_with('#')
            && let Some(colon) = l.find(':')
        {
            let key = l[..colon].trim();
            let next = l[colon + 1..].chars().next();
            let is_key = !key.is_empty()
                && key
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '.' || c == '-');
            if is_key && next.is_some_and(|c| !c.is_whitespace()) {
                l.insert(colon + 1, ' ');
            }
        }
        out.push_str(&l);
        out.push('\n');
    }
    out
}

/// A parsed YAML document with the file it came from, for messages.
struct Doc<'a> {
    path: &'a Path,
    text: &'a str,
    root: Yaml,
}

impl Doc<'_> {
    /// Line of `key:` in the file, for messages.
    fn line_of(&self, key: &str) -> usize {
        self.text
            .lines()
            .position(|l| l.trim_start().starts_with(&format!("{key}:")))
            .map_or(0, |i| i + 1)
    }

    fn number(&self, key: &str) -> Result<Option<f64>, DatasetError> {
        let v = &self.root[key];
        let n = match v {
            Yaml::BadValue | Yaml::Null => return Ok(None),
            Yaml::Integer(i) => *i as f64,
            Yaml::Real(_) => v.as_f64().unwrap_or(f64::NAN),
            _ => f64::NAN,
        };
        if n.is_finite() {
            Ok(Some(n))
        } else {
            Err(settings_err(
                self.path,
                format!("line {}: {key} must be a finite number", self.line_of(key)),
            ))
        }
    }

    /// The first of `keys` that is present.
    fn any(&self, keys: &[&str]) -> Result<Option<f64>, DatasetError> {
        for k in keys {
            if let Some(v) = self.number(k)? {
                return Ok(Some(v));
            }
        }
        Ok(None)
    }

    /// An OpenCV matrix (`data: [...]`) of `rows` x one of `cols` finite numbers, row-major
    /// (distortion vectors come with 4 or 5 columns). `None` when absent.
    fn matrix(
        &self,
        key: &str,
        rows: usize,
        cols: &[usize],
    ) -> Result<Option<Vec<f64>>, DatasetError> {
        let m = &self.root[key];
        if matches!(m, Yaml::BadValue | Yaml::Null) {
            return Ok(None);
        }
        let data: Option<Vec<f64>> = m["data"].as_vec().and_then(|v| {
            v.iter()
                .map(|y| y.as_f64().or_else(|| y.as_i64().map(|i| i as f64)))
                .collect()
        });
        match data {
            Some(d)
                if cols.iter().any(|&c| d.len() == rows * c) && d.iter().all(|v| v.is_finite()) =>
            {
                Ok(Some(d))
            }
            _ => Err(settings_err(
                self.path,
                format!(
                    "line {}: {key} must be a {rows}x{} matrix of finite numbers (data: [...])",
                    self.line_of(key),
                    cols.iter()
                        .map(|c| c.to_string())
                        .collect::<Vec<_>>()
                        .join(" or ")
                ),
            )),
        }
    }

    /// One camera's `K`, `D`, `R`, `P` (`side` = `LEFT` or `RIGHT`), `None` when none of them
    /// is there; some but not all is an error.
    fn rectifying_view(
        &self,
        side: &str,
        size: (u32, u32),
    ) -> Result<Option<RectifyingView>, DatasetError> {
        let key = |k: &str| format!("{side}.{k}");
        let k = self.matrix(&key("K"), 3, &[3])?;
        let d = self.matrix(&key("D"), 1, &[4, 5])?;
        let r = self.matrix(&key("R"), 3, &[3])?;
        let p = self.matrix(&key("P"), 3, &[4])?;
        let (k, d, r, p) = match (k, d, r, p) {
            (None, None, None, None) => return Ok(None),
            (Some(k), Some(d), Some(r), Some(p)) => (k, d, r, p),
            _ => {
                return Err(settings_err(
                    self.path,
                    format!(
                        "{side}.K, {side}.D, {side}.R and {side}.P go together: some are missing"
                    ),
                ));
            }
        };
        let dim = |k: &str, dflt: u32| -> Result<u32, DatasetError> {
            Ok(self.number(&key(k))?.map_or(dflt, |v| v as u32))
        };
        let mut raw = PinholeCamera::new(
            k[0],
            k[4],
            k[2],
            k[5],
            dim("width", size.0)?,
            dim("height", size.1)?,
        );
        raw.distortion = RadTan {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d.get(4).copied().unwrap_or(0.0),
        };
        if !(raw.fx > 0.0 && raw.fy > 0.0 && p[0] > 0.0 && p[5] > 0.0) {
            return Err(settings_err(
                self.path,
                format!("{side}.K and {side}.P need positive focal lengths"),
            ));
        }
        Ok(Some(RectifyingView {
            raw,
            r: [[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]],
            p: [
                [p[0], p[1], p[2], p[3]],
                [p[4], p[5], p[6], p[7]],
                [p[8], p[9], p[10], p[11]],
            ],
        }))
    }

    fn required(&self, keys: &[&str]) -> Result<f64, DatasetError> {
        self.any(keys)?
            .ok_or_else(|| settings_err(self.path, format!("missing key {}", keys.join(" or "))))
    }
}

/// Read an ORB-SLAM settings file (`%YAML:1.0`).
///
/// The sensor is not in the file: a `DepthMapFactor` means RGB-D, else a `Camera.bf` (or
/// `Stereo.b`) means stereo, else monocular.
pub fn read_orbslam_yaml(path: &Path) -> Result<Settings, DatasetError> {
    read_orbslam_yaml_sized(path, None)
}

fn read_orbslam_yaml_sized(
    path: &Path,
    image_size: Option<(u32, u32)>,
) -> Result<Settings, DatasetError> {
    let raw = std::fs::read(path).map_err(io_err(path))?;
    let text = String::from_utf8(raw).map_err(|_| settings_err(path, "file is not valid UTF-8"))?;
    // A byte-order mark (Windows editors) is not part of the first key.
    parse_orbslam_yaml_sized(
        text.strip_prefix('\u{feff}').unwrap_or(&text),
        path,
        image_size,
    )
}

/// [`read_settings`] for a source that knows its images' size before the settings are read (a
/// video, a camera): an ORB-SLAM file without `Camera.width` / `Camera.height` (ORB-SLAM2's
/// own files have none) takes that size; a size the file gives must be the images' (checked
/// where each frame is read).
pub fn read_settings_for_images(
    path: &Path,
    image_size: (u32, u32),
) -> Result<Settings, DatasetError> {
    read_settings_sized(path, Some(image_size))
}

/// YAML aliases (`*name`) are refused: the loader copies the anchored node at each one, so a
/// few lines of nested aliases made 10^9 nodes and the process was killed for its memory.
/// Settings files have no use for them (ORB-SLAM's files have none).
fn refuse_aliases(text: &str, path: &Path) -> Result<(), DatasetError> {
    let mut parser = Parser::new_from_str(text);
    // Syntax errors are left to the loader, which names them.
    while let Ok((event, mark)) = parser.next_token() {
        match event {
            Event::StreamEnd => break,
            Event::Alias(_) => {
                return Err(settings_err(
                    path,
                    format!(
                        "line {}: YAML aliases (*name) are not read in settings files; write the value out",
                        mark.line()
                    ),
                ));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Parse the text of an ORB-SLAM settings file; `path` names it in messages.
pub fn parse_orbslam_yaml(text: &str, path: &Path) -> Result<Settings, DatasetError> {
    parse_orbslam_yaml_sized(text, path, None)
}

/// [`parse_orbslam_yaml`]; a missing `Camera.width` / `Camera.height` takes `image_size` when
/// it is given.
fn parse_orbslam_yaml_sized(
    text: &str,
    path: &Path,
    image_size: Option<(u32, u32)>,
) -> Result<Settings, DatasetError> {
    let fixed = opencv_to_yaml(text);
    refuse_aliases(&fixed, path)?;
    let docs = YamlLoader::load_from_str(&fixed)
        .map_err(|e| settings_err(path, format!("line {}: {}", e.marker().line(), e.info())))?;
    let root = docs.into_iter().next().unwrap_or(Yaml::Null);
    if root.as_hash().is_none() {
        return Err(settings_err(
            path,
            "not a settings file (no key: value pairs)",
        ));
    }
    let d = Doc { path, text, root };
    let fx = d.required(&["Camera.fx", "Camera1.fx"])?;
    let fy = d.required(&["Camera.fy", "Camera1.fy"])?;
    let cx = d.required(&["Camera.cx", "Camera1.cx"])?;
    let cy = d.required(&["Camera.cy", "Camera1.cy"])?;
    let dim = |keys: &[&str], from_images: Option<u32>| -> Result<u32, DatasetError> {
        let v = match (d.any(keys)?, from_images) {
            (Some(v), _) => v,
            (None, Some(n)) => return Ok(n),
            (None, None) => d.required(keys)?,
        };
        if (1.0..=100_000.0).contains(&v) && v.fract() == 0.0 {
            Ok(v as u32)
        } else {
            Err(settings_err(
                path,
                format!("{} must be a positive whole number", keys[0]),
            ))
        }
    };
    let width = dim(&["Camera.width", "Camera1.width"], image_size.map(|s| s.0))?;
    let height = dim(
        &["Camera.height", "Camera1.height"],
        image_size.map(|s| s.1),
    )?;
    let coef = |k: &str| -> Result<f64, DatasetError> {
        Ok(d.any(&[&format!("Camera.{k}"), &format!("Camera1.{k}")])?
            .unwrap_or(0.0))
    };
    let mut camera = PinholeCamera::new(fx, fy, cx, cy, width, height);
    camera.distortion = RadTan {
        k1: coef("k1")?,
        k2: coef("k2")?,
        p1: coef("p1")?,
        p2: coef("p2")?,
        k3: coef("k3")?,
    };
    let depth_factor = d.any(&["DepthMapFactor", "RGBD.DepthMapFactor"])?;
    let bf = match d.number("Camera.bf")? {
        Some(bf) => Some(bf),
        None => d.number("Stereo.b")?.map(|b| b * fx),
    };
    let sensor = if depth_factor.is_some() {
        Sensor::Rgbd
    } else if bf.is_some() {
        Sensor::Stereo
    } else {
        Sensor::Mono
    };
    let defaults = OrbParams::default();
    let int = |k: &str, dflt: f64| -> Result<f64, DatasetError> {
        let v = d.number(k)?.unwrap_or(dflt);
        if v >= 0.0 && v.fract() == 0.0 {
            Ok(v)
        } else {
            Err(settings_err(
                path,
                format!("line {}: {k} must be a whole number >= 0", d.line_of(k)),
            ))
        }
    };
    let orb = OrbParams {
        n_features: int("ORBextractor.nFeatures", defaults.n_features as f64)? as usize,
        scale_factor: d
            .number("ORBextractor.scaleFactor")?
            .map_or(defaults.scale_factor, |v| v as f32),
        // 0 is refused by `check_values` (it ran as one level without a word).
        n_levels: int("ORBextractor.nLevels", defaults.n_levels as f64)? as usize,
        ini_th_fast: int("ORBextractor.iniThFAST", defaults.ini_th_fast as f64)?.min(255.0) as u8,
        min_th_fast: int("ORBextractor.minThFAST", defaults.min_th_fast as f64)?.min(255.0) as u8,
        ..defaults
    };
    let rectification = match (
        d.rectifying_view("LEFT", (width, height))?,
        d.rectifying_view("RIGHT", (width, height))?,
    ) {
        (None, None) => None,
        (Some(left), Some(right)) => {
            // ORB-SLAM: "Camera.fx, .fy, etc must be the same as in LEFT.P" (the tracked
            // camera is the rectified one), and Camera.bf the rectified baseline.
            let rect = left.rectified_camera();
            let off = (rect.fx - fx).abs()
                + (rect.fy - fy).abs()
                + (rect.cx - cx).abs()
                + (rect.cy - cy).abs();
            if off > 0.01 || !camera.distortion.is_zero() {
                return Err(settings_err(
                    path,
                    format!(
                        "with LEFT/RIGHT rectification, Camera.fx/fy/cx/cy must be LEFT.P's \
                         ({:.4} {:.4} {:.4} {:.4}) and Camera.k1.. zero: the images are tracked \
                         rectified",
                        rect.fx, rect.fy, rect.cx, rect.cy
                    ),
                ));
            }
            for (side, v) in [("LEFT", &left), ("RIGHT", &right)] {
                if (v.raw.width, v.raw.height) != (width, height) {
                    return Err(settings_err(
                        path,
                        format!(
                            "{side}.width x height {}x{} differs from Camera.width x height \
                             {width}x{height} (rectified images keep the raw size)",
                            v.raw.width, v.raw.height
                        ),
                    ));
                }
            }
            let s = StereoRectification { left, right };
            if let Some(bf) = bf
                && (bf - s.bf()).abs() > 1e-3 * s.bf().abs()
            {
                return Err(settings_err(
                    path,
                    format!("Camera.bf {bf} differs from -RIGHT.P[0][3] = {}", s.bf()),
                ));
            }
            Some(s)
        }
        _ => {
            return Err(settings_err(
                path,
                "stereo rectification needs both LEFT.* and RIGHT.*",
            ));
        }
    };
    let settings = Settings {
        rectification,
        sensor,
        camera,
        fps: d.number("Camera.fps")?.unwrap_or(30.0),
        depth_factor: depth_factor.unwrap_or(5000.0),
        bf,
        th_depth: d.any(&["ThDepth", "Stereo.ThDepth"])?.unwrap_or(40.0),
        rgb: d.number("Camera.RGB")?.is_none_or(|v| v != 0.0),
        orb,
    };
    // The file's own key (ORB-SLAM2 or 3 spelling, whichever it has) and its line.
    let key = |field: Field| -> String {
        let keys: &[&str] = match field {
            Field::Fx => &["Camera.fx", "Camera1.fx"],
            Field::Fy => &["Camera.fy", "Camera1.fy"],
            Field::Cx => &["Camera.cx", "Camera1.cx"],
            Field::Cy => &["Camera.cy", "Camera1.cy"],
            Field::Fps => &["Camera.fps"],
            Field::DepthFactor => &["DepthMapFactor", "RGBD.DepthMapFactor"],
            Field::Bf => &["Camera.bf", "Stereo.b"],
            Field::ThDepth => &["ThDepth", "Stereo.ThDepth"],
            Field::ScaleFactor => &["ORBextractor.scaleFactor"],
            Field::NFeatures => &["ORBextractor.nFeatures"],
            Field::NLevels => &["ORBextractor.nLevels"],
            // not an ORB-SLAM key: only stillpoint's own settings set it
            Field::NoiseThFactor => &["orb.noise_th_factor"],
            Field::Size => &["Camera.width", "Camera1.width"],
        };
        let found = keys.iter().find(|k| d.line_of(k) > 0).unwrap_or(&keys[0]);
        match d.line_of(found) {
            0 => found.to_string(),
            line => format!("line {line}: {found}"),
        }
    };
    check_values(&settings, key).map_err(|m| settings_err(path, m))?;
    Ok(settings)
}

/// A settings value [`check_values`] can complain about.
#[derive(Clone, Copy, Debug)]
#[allow(missing_docs)] // the fields of `Settings` they name
pub enum Field {
    Fx,
    Fy,
    Cx,
    Cy,
    Fps,
    DepthFactor,
    Bf,
    ThDepth,
    ScaleFactor,
    NFeatures,
    NLevels,
    NoiseThFactor,
    /// The image size (width x height).
    Size,
}

/// Largest image side the settings may give, pixels.
pub(crate) const MAX_CAMERA_SIDE: u64 = 16384;
/// Most pixels an image may have: a frame costs ~80 bytes a pixel (pyramid, features, depth),
/// so 40 million is ~3 GB; 8K video has 33 million.
pub(crate) const MAX_CAMERA_PIXELS: u64 = 40_000_000;

/// A number for a message: 1e-300 as `1e-300`, not 300 digits.
fn shown<T: std::fmt::Display + std::fmt::LowerExp + Copy + Into<f64>>(v: T) -> String {
    let m = v.into().abs();
    if m == 0.0 || !m.is_finite() || (1e-4..1e15).contains(&m) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Value ranges that parse but make nonsense (a focal length of 1e-300 px gave identity poses
/// and exit code 0), for every way settings are read (ORB-SLAM YAML, TOML, KITTI `calib.txt`);
/// `key` names a field as the source spells it. The run's settings tree checks its values
/// with it again once files and `--set` are laid over them.
pub fn check_values(s: &Settings, key: impl Fn(Field) -> String) -> Result<(), String> {
    let c = &s.camera;
    let bad = |field: Field, why: &str| Err(format!("{} {why}", key(field)));
    for (field, f) in [(Field::Fx, c.fx), (Field::Fy, c.fy)] {
        if !(f.is_finite() && (1.0..=1e6).contains(&f)) {
            return bad(
                field,
                &format!("= {}: a focal length is 1 to 10^6 pixels", shown(f)),
            );
        }
    }
    for (field, v) in [(Field::Cx, c.cx), (Field::Cy, c.cy)] {
        if !v.is_finite() {
            return bad(field, &format!("= {v}: must be a finite number"));
        }
    }
    let (w, h) = (c.width as u64, c.height as u64);
    if w == 0 || h == 0 || w.max(h) > MAX_CAMERA_SIDE || w * h > MAX_CAMERA_PIXELS {
        return bad(
            Field::Size,
            &format!(
                "= {w}x{h}: images of 1 to {MAX_CAMERA_SIDE} pixels a side and at most {} \
                 million pixels (each pixel costs ~80 bytes of memory)",
                MAX_CAMERA_PIXELS / 1_000_000
            ),
        );
    }
    if !(s.fps.is_finite() && s.fps > 0.0) {
        return bad(
            Field::Fps,
            &format!("= {}: frames per second must be positive", shown(s.fps)),
        );
    }
    if s.sensor == Sensor::Rgbd && !(s.depth_factor.is_finite() && s.depth_factor > 0.0) {
        return bad(
            Field::DepthFactor,
            &format!(
                "= {}: depth units per metre must be positive (TUM: 5000)",
                shown(s.depth_factor)
            ),
        );
    }
    // RGB-D uses it too: its close-point depth is `th_depth * bf / fx`.
    if let Some(bf) = s.bf
        && !(bf.is_finite() && bf > 0.0)
    {
        return bad(
            Field::Bf,
            &format!("= {}: baseline x focal length must be positive", shown(bf)),
        );
    }
    if !(s.th_depth.is_finite() && s.th_depth > 0.0) {
        return bad(
            Field::ThDepth,
            &format!("= {}: must be positive", shown(s.th_depth)),
        );
    }
    let o = &s.orb;
    if !(o.scale_factor.is_finite() && o.scale_factor > 1.0 && o.scale_factor <= 4.0) {
        return bad(
            Field::ScaleFactor,
            &format!(
                "= {}: the pyramid's scale must be over 1 (ORB-SLAM: 1.2)",
                shown(o.scale_factor)
            ),
        );
    }
    if o.n_features == 0 {
        return bad(
            Field::NFeatures,
            "= 0: at least one feature (ORB-SLAM: 1000)",
        );
    }
    if !(1..=32).contains(&o.n_levels) {
        return bad(
            Field::NLevels,
            &format!("= {}: 1 to 32 levels (ORB-SLAM: 8)", o.n_levels),
        );
    }
    if !(o.noise_th_factor.is_finite() && o.noise_th_factor >= 0.0) {
        return bad(
            Field::NoiseThFactor,
            &format!(
                "= {}: a factor of the image noise, 0 or more (default 2)",
                shown(o.noise_th_factor)
            ),
        );
    }
    Ok(())
}

/// Read stillpoint's TOML settings (the serde form of [`Settings`]).
///
/// ```
/// use stillpoint_datasets::{Settings, Sensor};
/// let text = r#"
/// sensor = "rgbd"
/// [camera]
/// fx = 535.4
/// fy = 539.2
/// cx = 320.1
/// cy = 247.6
/// width = 640
/// height = 480
/// "#;
/// let s = stillpoint_datasets::parse_settings_toml(text, "s.toml".as_ref()).unwrap();
/// assert_eq!((s.sensor, s.depth_factor, s.orb.n_features), (Sensor::Rgbd, 5000.0, 1000));
/// ```
pub fn read_settings_toml(path: &Path) -> Result<Settings, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    parse_settings_toml(text.strip_prefix('\u{feff}').unwrap_or(&text), path)
}

/// Parse the TOML settings text; `path` names it in messages.
pub fn parse_settings_toml(text: &str, path: &Path) -> Result<Settings, DatasetError> {
    let s: Settings = toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|r| text[..r.start.min(text.len())].matches('\n').count() + 1);
        let msg = e.message().to_string();
        match line {
            Some(l) => settings_err(path, format!("line {l}: {msg}")),
            None => settings_err(path, msg),
        }
    })?;
    // TOML keys as `stillpoint settings` prints them, with the line where the file sets them.
    let key = |field: Field| -> String {
        let (table, name) = match field {
            Field::Fx => ("camera", "fx"),
            Field::Fy => ("camera", "fy"),
            Field::Cx => ("camera", "cx"),
            Field::Cy => ("camera", "cy"),
            Field::Fps => ("", "fps"),
            Field::DepthFactor => ("", "depth_factor"),
            Field::Bf => ("", "bf"),
            Field::ThDepth => ("", "th_depth"),
            Field::ScaleFactor => ("orb", "scale_factor"),
            Field::NFeatures => ("orb", "n_features"),
            Field::NLevels => ("orb", "n_levels"),
            Field::NoiseThFactor => ("orb", "noise_th_factor"),
            Field::Size => ("camera", "width"),
        };
        let dotted = if table.is_empty() {
            name.to_string()
        } else {
            format!("{table}.{name}")
        };
        let line = text.lines().position(|l| {
            l.trim_start()
                .strip_prefix(name)
                .is_some_and(|r| r.trim_start().starts_with('='))
        });
        match line {
            Some(i) => format!("line {}: {dotted}", i + 1),
            None => dotted,
        }
    };
    check_values(&s, key).map_err(|m| settings_err(path, m))?;
    Ok(s)
}

/// Write settings as TOML.
pub fn write_settings_toml(path: &Path, s: &Settings) -> Result<(), DatasetError> {
    let text = toml::to_string(s).map_err(|e| settings_err(path, e.to_string()))?;
    std::fs::write(path, text).map_err(io_err(path))
}

/// Read a settings file by extension: `.toml` is ours, anything else ORB-SLAM YAML.
pub fn read_settings(path: &Path) -> Result<Settings, DatasetError> {
    read_settings_sized(path, None)
}

fn read_settings_sized(
    path: &Path,
    image_size: Option<(u32, u32)>,
) -> Result<Settings, DatasetError> {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
    {
        read_settings_toml(path)
    } else {
        read_orbslam_yaml_sized(path, image_size)
    }
}
