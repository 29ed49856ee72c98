//! Settings trees layered from files and overrides: any serde tree ([`layered`]) read from
//! stillpoint TOML files over its defaults and overridden with `section.key=value` on the
//! command line, each value remembering where it came from (so `stillpoint settings` can show
//! it); unknown, removed and moved keys refused by name with the file and line. The run's tree
//! (`stillpoint_run::SettingsTree`) is built with it.
//!
//! ```
//! use stillpoint_pipeline::settings::layered;
//! #[derive(Default, serde::Serialize, serde::Deserialize)]
//! #[serde(default)]
//! struct Tree {
//!     orb: Orb,
//! }
//! #[derive(Default, serde::Serialize, serde::Deserialize)]
//! struct Orb {
//!     n_features: usize,
//! }
//! let l = layered(&Tree::default(), [], &["orb.n_features=1500".into()], &[], &[]).unwrap();
//! assert_eq!(l.tree.orb.n_features, 1500);
//! assert!(l.describe().contains("orb.n_features = 1500  # --set"));
//! assert!(layered(&Tree::default(), [], &["orb.n_feature=1".into()], &[], &[]).is_err());
//! ```

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;
use serde::de::DeserializeOwned;

/// Where a value of the tree came from.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    /// A default (the crates' own, or the dataset's settings).
    Default,
    /// A settings file, at this line.
    File {
        /// The file.
        path: PathBuf,
        /// 1-based line of the key.
        line: usize,
    },
    /// `--set key=value`.
    CommandLine,
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Source::Default => write!(f, "default"),
            Source::File { path, line } => write!(f, "{}:{line}", path.display()),
            Source::CommandLine => write!(f, "--set"),
        }
    }
}

/// What can be wrong with a settings file or an override; each names the file and line, or the
/// override, and the key.
#[derive(Debug, thiserror::Error)]
pub enum SettingsError {
    /// The file cannot be read.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// The file is not TOML.
    #[error("{path}: not TOML: {msg}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        msg: String,
    },
    /// A key that was a setting and moved.
    #[error("{origin}: `{key}` is no longer a setting of its own: set `{now}`")]
    MovedKey {
        /// `FILE:LINE` or `--set ...`.
        origin: String,
        /// The dotted key.
        key: String,
        /// The key that holds the value now.
        now: &'static str,
    },
    /// A key that was a setting and was removed.
    #[error("{origin}: `{key}` was removed: {why}")]
    RemovedKey {
        /// `FILE:LINE` or `--set ...`.
        origin: String,
        /// The dotted key.
        key: String,
        /// Why, and what does its work now.
        why: &'static str,
    },
    /// A key that no setting has.
    #[error("{origin}: unknown key `{key}`")]
    UnknownKey {
        /// `FILE:LINE` or `--set ...`.
        origin: String,
        /// The dotted key.
        key: String,
    },
    /// A value of the wrong kind.
    #[error("{origin}: `{key}`: {msg}")]
    BadValue {
        /// `FILE:LINE` or `--set ...`.
        origin: String,
        /// The dotted key.
        key: String,
        /// What was expected.
        msg: String,
    },
    /// A value of the right kind out of its range; the message names where it came from and
    /// the key.
    #[error("{0}")]
    OutOfRange(String),
    /// An override that is not `section.key=value`.
    #[error("--set {arg}: expected section.key=value")]
    BadOverride {
        /// The argument as given.
        arg: String,
    },
}

/// Keys that were settings and now live elsewhere: refused by name, with where they went.
const MOVED_KEYS: [(&str, &str); 2] = [
    ("slam.scale_factor", "orb.scale_factor"),
    ("slam.n_levels", "orb.n_levels"),
];

/// Settings that were removed, and why: switches measured worse than the default and off by
/// default (their measurements are in docs/).
const REMOVED_KEYS: [(&str, &str); 7] = [
    (
        "front_end.seated_track_only",
        "seated people's still parts are judged by `front_end.seated_motion` (measured worse with YOLOX)",
    ),
    (
        "front_end.seated_still_max_outlier_share",
        "it served `front_end.seated_track_only`, removed",
    ),
    (
        "front_end.dynamic.depth.seated_parts_local",
        "a seated person's part is culled at its depth band (local only: recall 0.96 -> 0.45)",
    ),
    (
        "front_end.dynamic.keypoint_motion.keep_in_seated_parts",
        "a seated person's hand moves under half a pixel: its keypoints stay culled",
    ),
    (
        "front_end.dynamic.keypoint_motion.keep_with_fundamental",
        "the epipolar test is blind along the epipolar line: it keeps no keypoint",
    ),
    (
        "slam.no_points_from_pose_outliers",
        "`slam.point_max_rejections` and the front-end's outlier guard do its work",
    ),
    (
        "slam.kf_count_blocked_close",
        "keypoints that may not make map points never ask for a keyframe",
    ),
];

/// A tree and where each of its values came from.
#[derive(Clone, Debug)]
pub struct Layered<T> {
    /// The effective settings.
    pub tree: T,
    /// Dotted key -> source, for the keys a file or an override set (the rest are defaults).
    pub sources: BTreeMap<String, Source>,
}

/// `defaults` with the tables of `files` (in order), then the `key=value` overrides, laid over
/// them, and where each value came from. A file flagged as also the dataset's settings file (a
/// synthetic sequence's `settings.toml` with `[camera]`, `[orb]`, `[detect]`) gives only its
/// `dataset_tables` (the rest of it reached the tree through the dataset already); any other
/// key the tree lacks is an error naming the file and line (or the override), as is a key
/// removed or moved ([`SettingsError::RemovedKey`], [`SettingsError::MovedKey`]), and so is a
/// number no setting takes ([`number_problem`]; keys under a prefix in `signed` may be
/// negative).
pub fn layered<'a, T: Serialize + DeserializeOwned>(
    defaults: &T,
    files: impl IntoIterator<Item = (&'a Path, bool)>,
    overrides: &[String],
    dataset_tables: &[&str],
    signed: &[&str],
) -> Result<Layered<T>, SettingsError> {
    let mut base = match toml::Value::try_from(defaults) {
        Ok(toml::Value::Table(t)) => t,
        _ => unreachable!("a struct serialises to a table"),
    };
    let mut sources = BTreeMap::new();
    let mut origins: BTreeMap<String, String> = BTreeMap::new();
    for (path, dataset_file) in files {
        let text = std::fs::read_to_string(path).map_err(|error| SettingsError::Io {
            path: path.to_path_buf(),
            error,
        })?;
        let text = text.strip_prefix('\u{feff}').unwrap_or(&text).to_string();
        let mut user: toml::Table =
            text.parse()
                .map_err(|e: toml::de::Error| SettingsError::Syntax {
                    path: path.to_path_buf(),
                    msg: e.message().to_string(),
                })?;
        if dataset_file {
            user.retain(|k, _| dataset_tables.contains(&k));
        }
        let mut set = Vec::new();
        merge(&mut base, &user, "", &mut set);
        for key in set {
            let line = line_of(&text, &key);
            origins.insert(key.clone(), format!("{}:{line}", path.display()));
            sources.insert(
                key,
                Source::File {
                    path: path.to_path_buf(),
                    line,
                },
            );
        }
    }
    for arg in overrides {
        let (key, value) = arg
            .split_once('=')
            .map(|(k, v)| (k.trim(), v.trim()))
            .filter(|(k, v)| !k.is_empty() && !v.is_empty())
            .ok_or_else(|| SettingsError::BadOverride { arg: arg.clone() })?;
        let value = parse_value(value);
        let mut table = toml::Table::new();
        insert_dotted(&mut table, key, value);
        let mut set = Vec::new();
        merge(&mut base, &table, "", &mut set);
        origins.insert(key.to_string(), format!("--set {arg}"));
        sources.insert(key.to_string(), Source::CommandLine);
    }
    let origin_of = |key: &str| {
        origins
            .iter()
            .filter(|(k, _)| key == k.as_str() || key.starts_with(&format!("{k}.")))
            .map(|(_, o)| o.clone())
            .next_back()
            .unwrap_or_else(|| "settings".into())
    };
    // Unknown keys: those serde ignores while building the tree.
    let mut unknown = Vec::new();
    // A number no setting takes, found before the tree is built (merging made an integer given
    // for a float a float) and reported after the unknown keys and wrong kinds.
    let number_error = sources.keys().find_map(|key| {
        let mut path = key.split('.');
        let first = base.get(path.next()?);
        let x = path.try_fold(first?, |v, k| v.get(k))?.as_float()?;
        number_problem(key, x, signed).map(|msg| (key.clone(), msg))
    });
    let value = toml::Value::Table(base);
    let tree: Result<T, _> =
        serde_ignored::deserialize(value, |path| unknown.push(path.to_string()));
    if let Some(key) = unknown.into_iter().next() {
        if let Some(&(_, why)) = REMOVED_KEYS.iter().find(|(old, _)| *old == key) {
            return Err(SettingsError::RemovedKey {
                origin: origin_of(&key),
                key,
                why,
            });
        }
        if let Some(&(_, now)) = MOVED_KEYS.iter().find(|(old, _)| *old == key) {
            return Err(SettingsError::MovedKey {
                origin: origin_of(&key),
                key,
                now,
            });
        }
        return Err(SettingsError::UnknownKey {
            origin: origin_of(&key),
            key,
        });
    }
    let tree = tree.map_err(|e| {
        // toml names the key on a line of its own ("in `orb.n_features`").
        let full = e.to_string();
        let msg = full.lines().next().unwrap_or_default().to_string();
        let key = full
            .rsplit_once("in `")
            .and_then(|(_, k)| k.split_once('`'))
            .map(|(k, _)| k.to_string())
            .or_else(|| {
                sources
                    .keys()
                    .find(|k| full.contains(k.rsplit('.').next().unwrap_or(k)))
                    .cloned()
            })
            .unwrap_or_default();
        // A table that denies unknown fields names the field in the message.
        let field = msg
            .split_once("unknown field `")
            .and_then(|(_, f)| f.split_once('`'))
            .map(|(f, _)| f.to_string());
        if let Some(field) = field {
            let key = if key.is_empty() {
                field
            } else {
                format!("{key}.{field}")
            };
            SettingsError::UnknownKey {
                origin: origin_of(&key),
                key,
            }
        } else {
            SettingsError::BadValue {
                origin: origin_of(&key),
                key,
                msg,
            }
        }
    })?;
    if let Some((key, msg)) = number_error {
        return Err(SettingsError::BadValue {
            origin: origin_of(&key),
            key,
            msg,
        });
    }
    Ok(Layered { tree, sources })
}

/// What is wrong with `value` for the setting `key`, if anything: not a number; negative (the
/// settings are sizes, counts, times and thresholds, except those under a prefix in `signed`);
/// or, for a share, fraction, ratio or confidence (keys so named), outside 0 to 1. A value
/// that parses but no setting takes ran silently before (`--set slam.fps=nan`).
pub fn number_problem(key: &str, value: f64, signed: &[&str]) -> Option<String> {
    let name = key.rsplit('.').next().unwrap_or(key);
    let unit = ["ratio", "share", "fraction", "confidence"]
        .iter()
        .any(|s| name.ends_with(s))
        || matches!(name, "conf_threshold" | "nms_threshold");
    if value.is_nan() {
        Some("not a number".into())
    } else if value < 0.0 && !signed.iter().any(|p| key.starts_with(p)) {
        Some(format!("{value} is negative; this setting is 0 or more"))
    } else if unit && value > 1.0 {
        Some(format!("{value} is over 1; this setting is 0 to 1"))
    } else {
        None
    }
}

impl<T: Serialize> Layered<T> {
    /// Every setting as (dotted key, value as TOML, where it came from), sections in order.
    pub fn entries(&self) -> Vec<(String, String, String)> {
        let mut lines = Vec::new();
        if let Ok(toml::Value::Table(t)) = toml::Value::try_from(&self.tree) {
            flatten(&t, "", &mut lines);
        }
        lines
            .into_iter()
            .map(|(key, value)| {
                let source = self
                    .sources
                    .iter()
                    .filter(|(k, _)| key == **k || key.starts_with(&format!("{k}.")))
                    .map(|(_, s)| s.to_string())
                    .next_back()
                    .unwrap_or_else(|| Source::Default.to_string());
                (key, value, source)
            })
            .collect()
    }

    /// The effective tree, a `key = value  # source` line per setting (TOML, the sources as
    /// comments).
    pub fn describe(&self) -> String {
        let mut out = String::new();
        for (key, value, source) in self.entries() {
            let _ = writeln!(out, "{key} = {value}  # {source}");
        }
        out
    }
}

/// Lay `user` over `base`, recording the dotted keys it sets. Keys `base` lacks are added (serde
/// decides whether they exist: optional settings are absent from a serialised tree). An integer
/// where `base` holds a float becomes a float.
fn merge(base: &mut toml::Table, user: &toml::Table, prefix: &str, set: &mut Vec<String>) {
    for (k, v) in user {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match (base.get_mut(k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(u)) => merge(b, u, &key, set),
            (Some(toml::Value::Float(_)), toml::Value::Integer(i)) => {
                base.insert(k.clone(), toml::Value::Float(*i as f64));
                set.push(key);
            }
            _ => {
                base.insert(k.clone(), v.clone());
                set.push(key);
            }
        }
    }
}

/// A command-line value: TOML when it parses as one (`0.5`, `true`, `[1, 2]`, `"x"`), else a
/// string (`--set detect.model=yolox.onnx`).
fn parse_value(text: &str) -> toml::Value {
    format!("v = {text}")
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(text.to_string()))
}

fn insert_dotted(table: &mut toml::Table, key: &str, value: toml::Value) {
    match key.split_once('.') {
        None => {
            table.insert(key.to_string(), value);
        }
        Some((head, rest)) => {
            let entry = table
                .entry(head.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            if let toml::Value::Table(t) = entry {
                insert_dotted(t, rest, value);
            }
        }
    }
}

fn flatten(t: &toml::Table, prefix: &str, out: &mut Vec<(String, String)>) {
    for (k, v) in t {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            toml::Value::Table(t) => flatten(t, &key, out),
            v => out.push((key, show(v))),
        }
    }
}

/// A value as TOML, f32 settings as written (0.4, not 0.4000000059604645).
fn show(v: &toml::Value) -> String {
    match v {
        toml::Value::Float(f) if (*f as f32) as f64 == *f => {
            let s = format!("{}", *f as f32);
            if s.contains(['.', 'e', 'i', 'N']) {
                s
            } else {
                format!("{s}.0")
            }
        }
        toml::Value::Array(a) => {
            let items: Vec<String> = a.iter().map(show).collect();
            format!("[{}]", items.join(", "))
        }
        v => v.to_string(),
    }
}

/// The 1-based line where a dotted key is set in a TOML text: the key's line under its table
/// header (`[a.b]` then `c = ...`), or a dotted `b.c = ...` line; 1 when not found.
fn line_of(text: &str, key: &str) -> usize {
    let parts: Vec<&str> = key.split('.').collect();
    let mut section: Vec<String> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let l = line.trim();
        if let Some(h) = l.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
            section = h
                .trim_matches(['[', ']'])
                .split('.')
                .map(|s| s.trim().to_string())
                .collect();
            continue;
        }
        let Some((lhs, _)) = l.split_once('=') else {
            continue;
        };
        let full: Vec<String> = section
            .iter()
            .cloned()
            .chain(
                lhs.split('.')
                    .map(|s| s.trim().trim_matches('"').to_string()),
            )
            .collect();
        if full.len() <= parts.len() && full.iter().zip(&parts).all(|(a, b)| a == b) {
            return n + 1;
        }
    }
    1
}

#[cfg(test)]
mod tests {
    use super::number_problem;

    #[test]
    fn numbers_no_setting_takes_are_named() {
        assert_eq!(
            number_problem("a.b_px", f64::NAN, &[]).as_deref(),
            Some("not a number")
        );
        assert!(number_problem("a.b_px", -1.0, &[]).is_some());
        assert!(number_problem("cam.distortion.k1", -1.0, &["cam.distortion."]).is_none());
        assert!(number_problem("a.b_px", f64::INFINITY, &[]).is_none());
        for key in [
            "a.ratio",
            "a.kf_ref_ratio",
            "a.min_share",
            "a.side_fraction",
            "d.conf_threshold",
        ] {
            assert!(number_problem(key, 1.5, &[]).is_some(), "{key}");
            assert!(number_problem(key, 1.0, &[]).is_none(), "{key}");
        }
        assert!(number_problem("a.max_aspect", 3.0, &[]).is_none());
    }
}
