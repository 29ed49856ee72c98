//! Map files: the whole map saved at the end of a run and loaded at the start of another
//! (`stillpoint run --save-map / --load-map`).
//!
//! Layout, little-endian: a 32-byte header, then the payload.
//!
//! | bytes  | what                                                        |
//! |--------|-------------------------------------------------------------|
//! | 0..8   | magic `STILLMAP`                                            |
//! | 8..12  | format version ([`FORMAT_VERSION`])                          |
//! | 12..16 | reserved, 0                                                  |
//! | 16..24 | payload length in bytes                                      |
//! | 24..32 | FNV-1a 64 checksum of the payload ([`crate::fnv1a64`])       |
//!
//! The payload is a serde structure in postcard's wire format (stable since postcard 1.0):
//! what the map was made with (camera, sensor, ORB pyramid), the keyframes (pose, keypoints,
//! descriptors, depth and virtual right coordinates, their map points, covisibility weights,
//! spanning-tree parent and children), the map points (position, descriptor, normal, distance
//! range, observations, counters), the loop edges of the essential graph, and the place
//! recognition vocabulary with its fingerprint. Bags of words and the keypoint grids are
//! recomputed on load.
//!
//! Reading checks magic, version, length and checksum before decoding, and the decoded map's
//! consistency after (vector lengths, indices, ids referred to): a truncated, corrupted or
//! crafted file gives an error, never a panic.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::Path;

use serde::{Deserialize, Serialize};
use stillpoint_geometry::{PinholeCamera, RadTan, Se3, Vec2, Vec3};

use crate::SlamSettings;
use crate::data::frame::KeypointGrid;
use crate::data::{KeyFrame, KfId, Map, MapPoint, MpId};
use crate::fnv1a64;
use crate::place::Vocabulary;

/// First bytes of every map file.
pub const MAGIC: [u8; 8] = *b"STILLMAP";
/// The format this build writes, and the newest it reads.
pub const FORMAT_VERSION: u32 = 1;
/// Bytes before the payload.
pub const HEADER_LEN: usize = 32;

/// What a map was made with: a map is used only by a run with the same.
#[derive(Clone, Debug, PartialEq)]
pub struct MapSensor {
    /// Camera intrinsics, image size and distortion.
    pub camera: PinholeCamera,
    /// Monocular map (arbitrary scale) rather than RGB-D / stereo.
    pub monocular: bool,
    /// Baseline times fx (RGB-D: ORB-SLAM's virtual stereo), which the virtual right
    /// coordinates were made with.
    pub bf: f64,
    /// ORB pyramid scale factor the keypoint octaves refer to.
    pub scale_factor: f64,
    /// ORB pyramid levels.
    pub n_levels: usize,
}

impl MapSensor {
    /// What a run with these settings makes maps with.
    pub fn of(s: &SlamSettings) -> Self {
        Self {
            camera: s.camera,
            monocular: s.monocular,
            bf: s.bf,
            scale_factor: s.scale_factor,
            n_levels: s.n_levels,
        }
    }

    /// `None` when a map made with `self` can be used with `run`; else what differs, as
    /// `map: ...; this run: ...`.
    pub fn difference(&self, run: &MapSensor) -> Option<String> {
        let (a, b) = (&self.camera, &run.camera);
        let cam = |c: &PinholeCamera| {
            let d = c.distortion;
            let mut s = format!(
                "{}x{} fx {} fy {} cx {} cy {}",
                c.width, c.height, c.fx, c.fy, c.cx, c.cy
            );
            if !d.is_zero() {
                s += &format!(" distortion {} {} {} {} {}", d.k1, d.k2, d.p1, d.p2, d.k3);
            }
            s
        };
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1.0);
        let same_camera = a.width == b.width
            && a.height == b.height
            && close(a.fx, b.fx)
            && close(a.fy, b.fy)
            && close(a.cx, b.cx)
            && close(a.cy, b.cy)
            && a.distortion == b.distortion;
        if !same_camera {
            return Some(format!("camera: map {}; this run {}", cam(a), cam(b)));
        }
        let sensor = |m: bool| if m { "monocular" } else { "RGB-D / stereo" };
        if self.monocular != run.monocular {
            return Some(format!(
                "sensor: map {}; this run {}",
                sensor(self.monocular),
                sensor(run.monocular)
            ));
        }
        if !self.monocular && !close(self.bf, run.bf) {
            return Some(format!("bf: map {}; this run {}", self.bf, run.bf));
        }
        if !close(self.scale_factor, run.scale_factor) || self.n_levels != run.n_levels {
            return Some(format!(
                "ORB pyramid: map {} levels x{}; this run {} levels x{}",
                self.n_levels, self.scale_factor, run.n_levels, run.scale_factor
            ));
        }
        None
    }
}

/// Everything a map file holds.
#[derive(Clone, Debug)]
pub struct MapFile {
    /// What the map was made with.
    pub sensor: MapSensor,
    /// Keyframes, map points, covisibility graph and spanning tree.
    pub map: Map,
    /// The place-recognition vocabulary (`None` when loop closing never trained one).
    pub vocabulary: Option<Vocabulary>,
    /// Loop edges of the essential graph (keyframe that closed the loop, loop keyframe).
    pub loop_edges: BTreeSet<(KfId, KfId)>,
}

/// Why a map file cannot be read or used. The caller names the file.
#[derive(Debug, thiserror::Error)]
pub enum MapFileError {
    /// The file cannot be read or written.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The file does not start with [`MAGIC`].
    #[error("not a stillpoint map file (it does not start with \"STILLMAP\")")]
    NotAMap,
    /// Written by a newer build.
    #[error(
        "map format version {found}, newer than this build reads (up to {supported}): use a newer stillpoint"
    )]
    NewerVersion {
        /// The file's version.
        found: u32,
        /// The newest this build reads.
        supported: u32,
    },
    /// Shorter (or longer) than its header says.
    #[error("truncated: the header announces {expected} payload bytes, the file holds {found}")]
    Truncated {
        /// Payload bytes the header announces.
        expected: u64,
        /// Payload bytes present.
        found: u64,
    },
    /// The payload's checksum differs from the header's.
    #[error("corrupted: payload checksum {computed:016x}, the header says {stored:016x}")]
    Checksum {
        /// The header's checksum.
        stored: u64,
        /// The payload's.
        computed: u64,
    },
    /// The payload does not decode, or decodes to an inconsistent map.
    #[error("corrupted: {0}")]
    Invalid(String),
    /// Made with another camera, sensor or ORB pyramid than the run's.
    #[error("made with another {0}")]
    Sensor(String),
    /// Made with another place-recognition vocabulary than the one given.
    #[error(
        "made with vocabulary {map}, the run's is {run:016x} ({run_words} words): leave --vocabulary out to use the map's"
    )]
    Vocabulary {
        /// The map's vocabulary fingerprint and word count.
        map: String,
        /// The run's vocabulary fingerprint.
        run: u64,
        /// Words in the run's vocabulary.
        run_words: usize,
    },
}

impl MapFile {
    /// Refuse a map made with another camera, sensor or ORB pyramid than `settings`.
    pub fn check_settings(&self, settings: &SlamSettings) -> Result<(), MapFileError> {
        match self.sensor.difference(&MapSensor::of(settings)) {
            Some(d) => Err(MapFileError::Sensor(d)),
            None => Ok(()),
        }
    }

    /// Refuse a vocabulary other than the map's (the map was made, and its loops found, with
    /// its own). A map without one takes any.
    pub fn check_vocabulary(&self, v: &Vocabulary) -> Result<(), MapFileError> {
        let run = v.fingerprint();
        match &self.vocabulary {
            Some(m) if m.fingerprint() != run => Err(MapFileError::Vocabulary {
                map: format!("{:016x} ({} words)", m.fingerprint(), m.words()),
                run,
                run_words: v.words(),
            }),
            _ => Ok(()),
        }
    }
}

/// A pose as translation and quaternion (x, y, z, w).
type PoseRecord = [f64; 7];

#[derive(Serialize, Deserialize)]
struct SensorRecord {
    width: u32,
    height: u32,
    /// fx, fy, cx, cy.
    intrinsics: [f64; 4],
    /// k1, k2, p1, p2, k3.
    distortion: [f64; 5],
    monocular: bool,
    bf: f64,
    scale_factor: f64,
    n_levels: u32,
}

#[derive(Serialize, Deserialize)]
struct KeyFrameRecord {
    id: u64,
    map_epoch: u32,
    frame_index: u64,
    timestamp: f64,
    pose_cw: PoseRecord,
    points: Vec<[f64; 2]>,
    octaves: Vec<u8>,
    angles: Vec<f32>,
    descriptors: Vec<[u8; 32]>,
    depth: Vec<f32>,
    u_right: Vec<f32>,
    map_points: Vec<Option<u64>>,
    no_new_point: Vec<bool>,
    connections: Vec<(u64, u64)>,
    parent: Option<u64>,
    children: Vec<u64>,
    bad: bool,
    pose_to_parent: Option<PoseRecord>,
}

#[derive(Serialize, Deserialize)]
struct MapPointRecord {
    id: u64,
    map_epoch: u32,
    position: [f64; 3],
    descriptor: [u8; 32],
    normal: [f64; 3],
    min_distance: f64,
    max_distance: f64,
    observations: Vec<(u64, u64)>,
    reference_kf: u64,
    first_kf: u64,
    visible: u32,
    found: u32,
    rejected: u32,
    seen_through: u32,
    bad: bool,
}

#[derive(Serialize, Deserialize)]
struct Payload {
    sensor: SensorRecord,
    epoch: u32,
    origin_kf: Option<u64>,
    next_kf: u64,
    next_mp: u64,
    keyframes: Vec<KeyFrameRecord>,
    points: Vec<MapPointRecord>,
    loop_edges: Vec<(u64, u64)>,
    vocabulary_fingerprint: Option<u64>,
    vocabulary: Option<Vocabulary>,
}

fn pose_record(p: &Se3) -> PoseRecord {
    let t = p.translation.vector;
    let q = p.rotation.coords;
    [t.x, t.y, t.z, q.x, q.y, q.z, q.w]
}

fn pose_from(r: &PoseRecord, what: &str) -> Result<Se3, String> {
    if r.iter().any(|v| !v.is_finite()) {
        return Err(format!("{what}: pose not finite"));
    }
    let q = nalgebra::Quaternion::new(r[6], r[3], r[4], r[5]);
    if (q.norm() - 1.0).abs() > 1e-6 {
        return Err(format!("{what}: rotation not a unit quaternion"));
    }
    // Unchecked: the saved quaternion is restored bit for bit.
    Ok(Se3::from_parts(
        nalgebra::Translation3::new(r[0], r[1], r[2]),
        nalgebra::UnitQuaternion::new_unchecked(q),
    ))
}

/// The file's bytes: header and payload.
pub fn encode(f: &MapFile) -> Vec<u8> {
    let c = &f.sensor.camera;
    let d = c.distortion;
    let payload = Payload {
        sensor: SensorRecord {
            width: c.width,
            height: c.height,
            intrinsics: [c.fx, c.fy, c.cx, c.cy],
            distortion: [d.k1, d.k2, d.p1, d.p2, d.k3],
            monocular: f.sensor.monocular,
            bf: f.sensor.bf,
            scale_factor: f.sensor.scale_factor,
            n_levels: f.sensor.n_levels as u32,
        },
        epoch: f.map.epoch,
        origin_kf: f.map.origin_kf,
        next_kf: f.map.next_kf,
        next_mp: f.map.next_mp,
        keyframes: f.map.keyframes.values().map(keyframe_record).collect(),
        points: f.map.points.values().map(point_record).collect(),
        loop_edges: f.loop_edges.iter().copied().collect(),
        vocabulary_fingerprint: f.vocabulary.as_ref().map(|v| v.fingerprint()),
        vocabulary: f.vocabulary.clone(),
    };
    // Serialising plain data into a Vec cannot fail.
    let body = postcard::to_stdvec(&payload).unwrap_or_default();
    let mut out = Vec::with_capacity(HEADER_LEN + body.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(body.len() as u64).to_le_bytes());
    out.extend_from_slice(&fnv1a64::hash(&body).to_le_bytes());
    out.extend_from_slice(&body);
    out
}

fn keyframe_record(k: &KeyFrame) -> KeyFrameRecord {
    KeyFrameRecord {
        id: k.id,
        map_epoch: k.map_epoch,
        frame_index: k.frame_index as u64,
        timestamp: k.timestamp,
        pose_cw: pose_record(&k.pose_cw),
        points: k.points.iter().map(|p| [p.x, p.y]).collect(),
        octaves: k.octaves.clone(),
        angles: k.angles.clone(),
        descriptors: k.descriptors.clone(),
        depth: k.depth.clone(),
        u_right: k.u_right.clone(),
        map_points: k.map_points.clone(),
        no_new_point: k.no_new_point.clone(),
        connections: k.connections.iter().map(|(&o, &w)| (o, w as u64)).collect(),
        parent: k.parent,
        children: k.children.iter().copied().collect(),
        bad: k.bad,
        pose_to_parent: k.pose_to_parent.as_ref().map(pose_record),
    }
}

fn point_record(p: &MapPoint) -> MapPointRecord {
    MapPointRecord {
        id: p.id,
        map_epoch: p.map_epoch,
        position: p.position.into(),
        descriptor: p.descriptor,
        normal: p.normal.into(),
        min_distance: p.min_distance,
        max_distance: p.max_distance,
        observations: p
            .observations
            .iter()
            .map(|(&k, &i)| (k, i as u64))
            .collect(),
        reference_kf: p.reference_kf,
        first_kf: p.first_kf,
        visible: p.visible,
        found: p.found,
        rejected: p.rejected,
        seen_through: p.seen_through,
        bad: p.bad,
    }
}

/// Read a map file's bytes: header, checksum, payload, consistency.
pub fn decode(bytes: &[u8]) -> Result<MapFile, MapFileError> {
    if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
        return Err(MapFileError::NotAMap);
    }
    let word = |at: usize, n: usize| -> Option<u64> {
        let b = bytes.get(at..at + n)?;
        let mut v = [0u8; 8];
        v[..n].copy_from_slice(b);
        Some(u64::from_le_bytes(v))
    };
    let (Some(version), Some(len), Some(stored)) = (word(8, 4), word(16, 8), word(24, 8)) else {
        return Err(MapFileError::Truncated {
            expected: 0,
            found: 0,
        });
    };
    let version = version as u32;
    if version == 0 {
        return Err(MapFileError::Invalid("format version 0".into()));
    }
    if version > FORMAT_VERSION {
        return Err(MapFileError::NewerVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    // Checked after the version: a newer format may use them.
    if word(12, 4) != Some(0) {
        return Err(MapFileError::Invalid(
            "reserved header bytes are not zero".into(),
        ));
    }
    let body = bytes.get(HEADER_LEN..).unwrap_or_default();
    if body.len() as u64 != len {
        return Err(MapFileError::Truncated {
            expected: len,
            found: body.len() as u64,
        });
    }
    let computed = fnv1a64::hash(body);
    if computed != stored {
        return Err(MapFileError::Checksum { stored, computed });
    }
    let (payload, rest): (Payload, &[u8]) = postcard::take_from_bytes(body)
        .map_err(|e| MapFileError::Invalid(format!("payload does not decode ({e})")))?;
    if !rest.is_empty() {
        return Err(MapFileError::Invalid(format!(
            "{} bytes after the payload",
            rest.len()
        )));
    }
    from_payload(payload).map_err(MapFileError::Invalid)
}

fn from_payload(p: Payload) -> Result<MapFile, String> {
    let s = &p.sensor;
    let [fx, fy, cx, cy] = s.intrinsics;
    let [k1, k2, p1, p2, k3] = s.distortion;
    let mut camera = PinholeCamera::new(fx, fy, cx, cy, s.width, s.height);
    camera.distortion = RadTan { k1, k2, p1, p2, k3 };
    let finite = s
        .intrinsics
        .iter()
        .chain(&s.distortion)
        .all(|v| v.is_finite());
    if !finite || fx <= 0.0 || fy <= 0.0 || s.width == 0 || s.height == 0 {
        return Err("camera unusable".into());
    }
    let pyramid_ok =
        (1..=32).contains(&s.n_levels) && s.scale_factor.is_finite() && s.scale_factor >= 1.0;
    if !pyramid_ok {
        return Err("ORB pyramid unusable".into());
    }
    if !s.bf.is_finite() {
        return Err("bf not finite".into());
    }
    let sensor = MapSensor {
        camera,
        monocular: s.monocular,
        bf: s.bf,
        scale_factor: s.scale_factor,
        n_levels: s.n_levels as usize,
    };
    if let Some(v) = &p.vocabulary {
        v.check()?;
        if p.vocabulary_fingerprint != Some(v.fingerprint()) {
            return Err("vocabulary fingerprint does not match the vocabulary".into());
        }
    }
    let mut map = Map::new();
    map.epoch = p.epoch;
    map.next_kf = p.next_kf;
    map.next_mp = p.next_mp;
    let n_levels = sensor.n_levels;
    for r in p.keyframes {
        let kf = keyframe_from(r, &camera, n_levels, p.next_kf)?;
        if map.keyframes.insert(kf.id, kf).is_some() {
            return Err("two keyframes with the same id".into());
        }
    }
    for r in p.points {
        let mp = point_from(r, p.next_mp)?;
        if map.points.insert(mp.id, mp).is_some() {
            return Err("two map points with the same id".into());
        }
    }
    check_references(&map)?;
    map.origin_kf = p.origin_kf;
    if map
        .origin_kf
        .is_some_and(|k| !map.keyframes.contains_key(&k))
    {
        return Err("origin keyframe missing".into());
    }
    let loop_edges: BTreeSet<(KfId, KfId)> = p.loop_edges.into_iter().collect();
    if loop_edges
        .iter()
        .any(|(a, b)| !map.keyframes.contains_key(a) || !map.keyframes.contains_key(b))
    {
        return Err("loop edge to a missing keyframe".into());
    }
    Ok(MapFile {
        sensor,
        map,
        vocabulary: p.vocabulary,
        loop_edges,
    })
}

fn keyframe_from(
    r: KeyFrameRecord,
    camera: &PinholeCamera,
    n_levels: usize,
    next_kf: KfId,
) -> Result<KeyFrame, String> {
    let what = format!("keyframe {}", r.id);
    let n = r.points.len();
    let lengths = [
        r.octaves.len(),
        r.angles.len(),
        r.descriptors.len(),
        r.depth.len(),
        r.u_right.len(),
        r.map_points.len(),
        r.no_new_point.len(),
    ];
    if lengths.iter().any(|&l| l != n) {
        return Err(format!("{what}: per-keypoint lists of different lengths"));
    }
    if r.id >= next_kf {
        return Err(format!("{what}: id beyond the next id"));
    }
    if r.octaves.iter().any(|&o| o as usize >= n_levels) {
        return Err(format!("{what}: keypoint octave beyond the pyramid"));
    }
    let finite = r.points.iter().flatten().all(|v| v.is_finite())
        && r.angles
            .iter()
            .chain(&r.depth)
            .chain(&r.u_right)
            .all(|v| v.is_finite())
        && r.timestamp.is_finite();
    if !finite {
        return Err(format!("{what}: values not finite"));
    }
    let points: Vec<Vec2> = r.points.iter().map(|p| Vec2::new(p[0], p[1])).collect();
    let grid = KeypointGrid::new(&points, camera.width as f64, camera.height as f64);
    Ok(KeyFrame {
        id: r.id,
        map_epoch: r.map_epoch,
        frame_index: usize::try_from(r.frame_index).map_err(|_| format!("{what}: frame index"))?,
        timestamp: r.timestamp,
        pose_cw: pose_from(&r.pose_cw, &what)?,
        points,
        octaves: r.octaves,
        angles: r.angles,
        descriptors: r.descriptors,
        depth: r.depth,
        u_right: r.u_right,
        map_points: r.map_points,
        no_new_point: r.no_new_point,
        grid,
        connections: r
            .connections
            .into_iter()
            .map(|(k, w)| (k, w as usize))
            .collect(),
        parent: r.parent,
        children: r.children.into_iter().collect(),
        bad: r.bad,
        pose_to_parent: r
            .pose_to_parent
            .as_ref()
            .map(|p| pose_from(p, &what))
            .transpose()?,
    })
}

fn point_from(r: MapPointRecord, next_mp: MpId) -> Result<MapPoint, String> {
    let what = format!("map point {}", r.id);
    if r.id >= next_mp {
        return Err(format!("{what}: id beyond the next id"));
    }
    let finite = r
        .position
        .iter()
        .chain(&r.normal)
        .chain(&[r.min_distance, r.max_distance])
        .all(|v| v.is_finite());
    if !finite {
        return Err(format!("{what}: values not finite"));
    }
    let mut observations = BTreeMap::new();
    for (k, i) in r.observations {
        let i = usize::try_from(i).map_err(|_| format!("{what}: keypoint index"))?;
        observations.insert(k, i);
    }
    Ok(MapPoint {
        id: r.id,
        map_epoch: r.map_epoch,
        position: Vec3::from(r.position),
        descriptor: r.descriptor,
        descriptor_of: 0,
        normal: Vec3::from(r.normal),
        min_distance: r.min_distance,
        max_distance: r.max_distance,
        observations,
        reference_kf: r.reference_kf,
        first_kf: r.first_kf,
        visible: r.visible,
        found: r.found,
        rejected: r.rejected,
        seen_through: r.seen_through,
        bad: r.bad,
    })
}

/// Every id a keyframe or point refers to exists, and every observation's keypoint index lies
/// in its keyframe (the SLAM code indexes by them).
fn check_references(map: &Map) -> Result<(), String> {
    let has_kf = |k: &KfId| map.keyframes.contains_key(k);
    for k in map.keyframes.values() {
        let what = format!("keyframe {}", k.id);
        if !k.connections.keys().all(has_kf)
            || !k.children.iter().all(has_kf)
            || !k.parent.iter().all(has_kf)
        {
            return Err(format!("{what}: refers to a missing keyframe"));
        }
        if !k
            .map_points
            .iter()
            .flatten()
            .all(|m| map.points.contains_key(m))
        {
            return Err(format!("{what}: refers to a missing map point"));
        }
    }
    for p in map.points.values() {
        let what = format!("map point {}", p.id);
        for (k, &i) in &p.observations {
            match map.keyframes.get(k) {
                Some(kf) if i < kf.points.len() => {}
                _ => {
                    return Err(format!(
                        "{what}: observation by a missing keyframe or keypoint"
                    ));
                }
            }
        }
        if !has_kf(&p.reference_kf) || !has_kf(&p.first_kf) {
            return Err(format!("{what}: refers to a missing keyframe"));
        }
    }
    Ok(())
}

/// Write a map file atomically: into a temporary file beside `path`, flushed to disk, then
/// renamed over it (a crash leaves the old file or the new one, never half of one). Returns
/// the bytes written.
pub fn save(path: &Path, f: &MapFile) -> std::io::Result<usize> {
    let bytes = encode(f);
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::other("not a file name"))?;
    let tmp = dir.join(format!(
        ".{}.{}.tmp",
        name.to_string_lossy(),
        std::process::id()
    ));
    let written = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(&bytes)?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.map(|_| bytes.len())
}

/// Read a map file (see [`decode`]).
pub fn load(path: &Path) -> Result<MapFile, MapFileError> {
    decode(&std::fs::read(path)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::place::VocabularyParams;
    use crate::{Feature, Frame};
    use proptest::prelude::*;

    /// A map of three keyframes and 30 points with covisibility, a spanning tree, a culled
    /// keyframe, a loop edge and a vocabulary.
    fn small_map_file() -> MapFile {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        let feats: Vec<Feature> = (0..30)
            .map(|i| Feature {
                x: 10.0 + 20.0 * i as f32,
                y: 100.0 + (i % 5) as f32,
                octave: (i % 3) as u8,
                angle: i as f32,
            })
            .collect();
        let descs: Vec<[u8; 32]> = (0..30u8).map(|i| [i.wrapping_mul(37); 32]).collect();
        let depth = vec![2.0f32; 30];
        let depth = crate::KeypointDepth::PerKeypoint(&depth);
        let mut f = Frame::new_with_mask(0, 0.5, &feats, &descs, depth, &s, &[]).unwrap();
        let mut map = Map::new();
        let mut kfs = Vec::new();
        for k in 0..3 {
            f.pose_cw = Some(Se3::new(
                Vec3::new(0.1 * k as f64, 0.0, 0.0),
                Vec3::new(0.0, 0.02 * k as f64, 0.0),
            ));
            kfs.push(map.add_keyframe(&f).unwrap());
        }
        for i in 0..30 {
            let mp = map
                .add_point(Vec3::new(i as f64, 0.5, 3.0), kfs[0], i)
                .unwrap();
            map.add_observation(mp, kfs[1], i);
            if i < 20 {
                map.add_observation(mp, kfs[2], i);
            }
            map.update_point(mp, &s.scale_factors());
        }
        for &k in &kfs[1..] {
            map.update_connections(k, 15);
        }
        map.set_bad_keyframe(kfs[1], 15);
        let docs: Vec<&[[u8; 32]]> = vec![&descs];
        let vocabulary = Vocabulary::train(&docs, &VocabularyParams::default());
        MapFile {
            sensor: MapSensor::of(&s),
            map,
            vocabulary,
            loop_edges: [(kfs[2], kfs[0])].into(),
        }
    }

    #[test]
    fn a_map_survives_the_round_trip_bit_for_bit() {
        let f = small_map_file();
        let bytes = encode(&f);
        let back = decode(&bytes).unwrap();
        // Same bytes again: every field came back as it was.
        assert_eq!(encode(&back), bytes);
        assert_eq!(back.map.keyframes.len(), 3);
        assert_eq!(back.map.points.len(), f.map.points.len());
        assert!(
            back.map
                .keyframes
                .values()
                .any(|k| k.bad && k.pose_to_parent.is_some())
        );
        assert_eq!(back.loop_edges, f.loop_edges);
        assert_eq!(back.sensor, f.sensor);
        // Ids go on where the saved map stopped.
        let mut m = back.map;
        assert_eq!(m.next_kf_id(), 3);
        // The keypoint grid is rebuilt.
        let k0 = &m.keyframes[&0];
        assert!(k0.features_in_area(10.0, 100.0, 3.0, 0, 7).contains(&0));
    }

    #[test]
    fn refusals_name_what_differs() {
        let f = small_map_file();
        let mut bytes = encode(&f);
        bytes[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
        let e = decode(&bytes).unwrap_err().to_string();
        assert!(e.contains("version 2") && e.contains("up to 1"), "{e}");
        assert!(matches!(decode(b"PNG...."), Err(MapFileError::NotAMap)));
        let other = PinholeCamera::new(250.0, 250.0, 160.0, 120.0, 320, 240);
        let e = f
            .check_settings(&SlamSettings::rgbd(other, 40.0, 30.0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("camera") && e.contains("640x480") && e.contains("320x240"),
            "{e}"
        );
        let mono = SlamSettings::monocular(f.sensor.camera, 30.0);
        assert!(
            f.check_settings(&mono)
                .unwrap_err()
                .to_string()
                .contains("monocular")
        );
        let same = SlamSettings::rgbd(f.sensor.camera, 40.0, 30.0);
        assert!(f.check_settings(&same).is_ok());
        let v = f.vocabulary.clone().unwrap();
        assert!(f.check_vocabulary(&v).is_ok());
        let other_docs = vec![[9u8; 32], [200u8; 32], [77u8; 32]];
        let w = Vocabulary::train(&[&other_docs], &VocabularyParams::default()).unwrap();
        let e = f.check_vocabulary(&w).unwrap_err().to_string();
        assert!(e.contains(&format!("{:016x}", v.fingerprint())), "{e}");
    }

    #[test]
    fn atomic_save_then_load() {
        let dir = std::env::temp_dir().join(format!("stillpoint-map-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.map");
        let f = small_map_file();
        let n = save(&path, &f).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len() as usize, n);
        // Only the file itself is left (the temporary one was renamed).
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        assert_eq!(encode(&load(&path).unwrap()), encode(&f));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// A truncated file, or one with a byte changed, is refused with an error.
        #[test]
        fn truncated_or_flipped_files_are_refused(cut in 0usize..10_000, at in 0usize..10_000, bits in 1u8..=255) {
            let bytes = encode(&small_map_file());
            let cut = cut % bytes.len();
            prop_assert!(decode(&bytes[..cut]).is_err());
            let mut flipped = bytes.clone();
            flipped[at % bytes.len()] ^= bits;
            prop_assert!(decode(&flipped).is_err());
        }

        /// Past the checksum (a payload changed and its checksum rewritten, as a crafted file
        /// would be), decoding and the consistency checks still never panic.
        #[test]
        fn crafted_payloads_never_panic(at in 0usize..10_000, bits in 1u8..=255, cut in 0usize..10_000) {
            let mut bytes = encode(&small_map_file());
            let body_len = bytes.len() - HEADER_LEN;
            bytes[HEADER_LEN + at % body_len] ^= bits;
            let keep = HEADER_LEN + cut % body_len;
            let mut crafted = bytes[..keep].to_vec();
            let body = crafted[HEADER_LEN..].to_vec();
            crafted[16..24].copy_from_slice(&(body.len() as u64).to_le_bytes());
            crafted[24..32].copy_from_slice(&fnv1a64::hash(&body).to_le_bytes());
            let sum = fnv1a64::hash(&bytes[HEADER_LEN..]);
            bytes[24..32].copy_from_slice(&sum.to_le_bytes());
            for file in [crafted, bytes] {
                // What passes the checks is a map that saves and loads again.
                if let Ok(f) = decode(&file) {
                    prop_assert!(decode(&encode(&f)).is_ok());
                }
            }
        }
    }
}
