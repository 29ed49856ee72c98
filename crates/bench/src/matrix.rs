//! SLAM accuracy over synthetic presets x seeds x front-end modes (off, perfect boxes, YOLOX),
//! with the share of map points that lie on movers. Sequences are generated in-process (with
//! per-pixel masks, so map points on movers can be counted) into the output folder, then each
//! run goes through [`stillpoint_run::run_sequence`], `jobs` at a time.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use serde::Serialize;
use stillpoint_eval::surface::CloudDistance;
use stillpoint_run::RunOptions;
use stillpoint_synth::{Blind, BlindView, Noise, Preset, SynthConfig, WriteOptions};

use crate::BenchError;

/// The front-end modes a matrix knows: off (no front-end), gt (perfect boxes), yolox, none
/// (front-end without a detector).
pub const MODES: [&str; 4] = ["off", "gt", "yolox", "none"];

/// What the matrix generates and runs.
#[derive(Clone, Debug)]
pub struct MatrixOptions {
    /// Presets, in table order.
    pub presets: Vec<Preset>,
    /// Seeds of each preset.
    pub seeds: Vec<u64>,
    /// Front-end modes ([`MODES`]).
    pub modes: Vec<String>,
    /// Frames per sequence.
    pub frames: usize,
    /// Sensor noise of the generated sequences.
    pub noise: Noise,
    /// Folder of photos and person cut-outs for the generator.
    pub textures: Option<PathBuf>,
    /// Where the sequences and trajectories go (kept; a sequence already there is reused).
    pub out: PathBuf,
    /// YOLOX ONNX model for the yolox mode (else the default search).
    pub model: Option<PathBuf>,
    /// Runs at a time.
    pub jobs: usize,
    /// Local mapping in its own thread, as for a camera (`slam.local_mapping_thread`); by
    /// default each run is `run`'s default on a recording, whose result does not depend on
    /// timing.
    pub threaded: bool,
    /// Also write each run's dense cloud (RGB-D) and measure it: points on movers and the
    /// distance to the scene's true static surfaces.
    pub dense: bool,
    /// Run each sequence monocular: its depth withheld (a `PRESET_sSEED_mono` folder beside it
    /// without `depth.txt`); the ATE is then after a Sim(3) alignment.
    pub monocular: bool,
    /// Run each sequence as a rectified stereo pair (KITTI layout written beside the TUM one,
    /// 0.10 m baseline, the street's 0.54 m as KITTI's; read as `--kind kitti`).
    pub stereo: bool,
    /// Blind the camera for a span of frames in every sequence (a covered lens or a blank
    /// wall): tracking is lost, a new map starts, and must merge with the first.
    pub blind: Option<Blind>,
    /// The settings tree's layers (`--config`, `--set`) over each sequence's own, as `run`
    /// takes them; every run of the matrix gets them.
    pub layers: stillpoint_run::Overrides,
    /// Set to stop the runs early.
    pub stop: Option<&'static AtomicBool>,
}

/// One run of the matrix.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// The preset's name.
    pub preset: String,
    /// The scene's seed.
    pub seed: u64,
    /// The front-end mode.
    pub mode: String,
    /// ATE RMSE, cm.
    pub ate_cm: Option<f64>,
    /// Frames in the trajectory: those of the map holding the most frames (another map's are
    /// in a frame of reference of their own).
    pub tracked: usize,
    /// Maps made (the first and each new one after tracking was lost for good).
    pub maps_made: usize,
    /// Older maps merged into the current one.
    pub maps_merged: usize,
    /// Loops closed within a map (merges not counted).
    pub loops: usize,
    /// Frames run.
    pub frames: usize,
    /// Ground-truth frames before the first pose.
    pub first_tracked: Option<usize>,
    /// Map points at the end.
    pub map_points: usize,
    /// Of those, lying on a moving object (made there, or seen there by most keyframes).
    pub map_points_on_movers: Option<usize>,
    /// Of those, seen on a moving object by one keyframe or more.
    pub map_points_seen_on_movers: Option<usize>,
    /// Median over frames of the share of static keypoints (off the masks' movers) culled.
    pub static_culled_share: Option<f64>,
    /// With `dense`: the dense cloud's points, those mostly on movers, and its distance to the
    /// scene's true static surfaces (the cloud aligned as the ATE aligns the trajectory).
    pub dense: Option<DenseRow>,
    /// Why the run failed (its error chain).
    pub error: Option<String>,
}

/// The dense cloud of one run, measured.
#[derive(Clone, Debug, Serialize)]
pub struct DenseRow {
    /// Points (voxels) in the cloud.
    pub points: usize,
    /// Of those, made mostly of pixels the generator marks as moving.
    pub on_movers: Option<usize>,
    /// Distance of the cloud to the static scene's triangles (within 10 cm looked for).
    pub distance: Option<stillpoint_eval::surface::CloudDistance>,
    /// The same for the cloud the same keyframes' depth gives with true poses and every pixel
    /// of a non-static object left out: what sensor noise and the voxels alone cost.
    pub distance_true_poses: Option<stillpoint_eval::surface::CloudDistance>,
}

impl Row {
    /// Share of the map on movers (0..1).
    pub fn movers_share(&self) -> Option<f64> {
        self.map_points_on_movers
            .map(|m| m as f64 / self.map_points.max(1) as f64)
    }
}

fn config(o: &MatrixOptions, preset: Preset, seed: u64) -> SynthConfig {
    SynthConfig {
        preset,
        frames: o.frames,
        seed,
        noise: o.noise,
        textures: o.textures.clone(),
        stereo_baseline: o.stereo.then_some(stereo_baseline(preset)),
        blind: o.blind,
        ..SynthConfig::default()
    }
}

/// The stereo rig's baseline (m): a car's is wide (KITTI's 0.54 m), a room robot's 0.10 m.
fn stereo_baseline(preset: Preset) -> f64 {
    if preset == Preset::Street { 0.54 } else { 0.1 }
}

/// The folder of one sequence: `PRESET_sSEED`, with the blind span when there is one
/// (`_blind200+60`, `_wall200+60`).
fn sequence_dir(o: &MatrixOptions, preset: Preset, seed: u64) -> PathBuf {
    let blind = o.blind.map_or(String::new(), |b| {
        let view = match b.view {
            BlindView::Covered => "blind",
            BlindView::Wall => "wall",
        };
        format!("_{view}{}+{}", b.start, b.frames)
    });
    o.out.join(format!("{}_s{seed}{blind}", preset.name()))
}

fn generate(o: &MatrixOptions, preset: Preset, seed: u64, dir: &Path) -> Result<(), BenchError> {
    if dir.join("groundtruth.txt").is_file()
        && dir.join("mask").is_dir()
        && (!o.stereo || dir.join("image_1").is_dir())
    {
        return Ok(());
    }
    let cfg = config(o, preset, seed);
    let opts = WriteOptions {
        stereo: o.stereo,
        masks: true,
    };
    stillpoint_synth::write_sequence(&cfg, opts, dir).map_err(|source| BenchError::Synth {
        context: format!(
            "writing {} seed {seed} into {}",
            preset.name(),
            dir.display()
        ),
        source,
    })?;
    Ok(())
}

/// A folder beside `dir` (`DIR_mono`) that holds links to everything of it but its depth: the
/// same sequence, read as monocular.
pub(crate) fn without_depth(dir: &Path) -> Result<PathBuf, BenchError> {
    let mut name = dir.file_name().unwrap_or_default().to_os_string();
    name.push("_mono");
    let mono = dir.with_file_name(name);
    link_without_depth(dir, &mono)?;
    Ok(mono)
}

/// Fill `mono` with links to everything of `dir` but its depth (links already there are kept).
pub(crate) fn link_without_depth(dir: &Path, mono: &Path) -> Result<(), BenchError> {
    let io = |what: &str, p: &Path| crate::io_error(format!("{what} {}", p.display()));
    std::fs::create_dir_all(mono).map_err(io("creating", mono))?;
    for entry in std::fs::read_dir(dir).map_err(io("reading", dir))? {
        let entry = entry.map_err(io("reading", dir))?;
        let file = entry.file_name();
        if file == "depth" || file == "depth.txt" {
            continue;
        }
        let link = mono.join(&file);
        if link.symlink_metadata().is_err() {
            let target = std::path::absolute(entry.path()).map_err(io("resolving", dir))?;
            std::os::unix::fs::symlink(&target, &link).map_err(io("linking", &link))?;
        }
    }
    Ok(())
}

fn run_one(
    o: &MatrixOptions,
    (preset, seed, dir, mode): &(String, u64, PathBuf, String),
    out: PathBuf,
) -> Result<Row, BenchError> {
    let cloud = o.dense.then(|| out.with_extension("ply"));
    let s = stillpoint_eval::run_scored(
        &RunOptions {
            out: Some(out),
            kind: o.stereo.then_some(stillpoint_datasets::DatasetKind::Kitti),
            dense_cloud: cloud.clone(),
            detector: (mode != "off").then(|| mode.to_string()),
            model: o.model.clone(),
            stop: o.stop,
            overrides: stillpoint_run::Overrides {
                config: o.layers.config.clone(),
                sets: o
                    .layers
                    .sets
                    .iter()
                    .cloned()
                    .chain(
                        o.threaded
                            .then(|| "slam.local_mapping_thread=true".to_string()),
                    )
                    .collect(),
                ..Default::default()
            },
            ..RunOptions::new(dir.to_path_buf())
        },
        &mut |_| {},
    )?;
    // ATE and alignment come from one evaluation (it associates and aligns every pose).
    let ate_result = s.accuracy().map(|a| a.0);
    let ate = ate_result.as_ref().map(|a| a.stats.rmse * 100.0);
    let first_tracked = s
        .ground_truth
        .as_ref()
        .and_then(|gt| stillpoint_eval::accuracy::frames_before_first_pose(gt, &s.run.trajectory));
    let dense = match (&cloud, &s.run.dense) {
        (Some(path), Some(report)) => {
            let alignment = ate_result.as_ref().map(|a| a.alignment);
            let (distance, distance_true_poses) = match alignment {
                Some(a) => {
                    let (run, truth) = dense_distance(
                        o,
                        preset,
                        *seed,
                        path,
                        &a,
                        &s.run.keyframe_trajectory.stamps,
                    )?;
                    (Some(run), Some(truth))
                }
                None => (None, None),
            };
            Some(DenseRow {
                points: report.points,
                on_movers: report.on_movers,
                distance,
                distance_true_poses,
            })
        }
        _ => None,
    };
    Ok(Row {
        preset: preset.clone(),
        seed: *seed,
        mode: mode.to_string(),
        ate_cm: ate,
        tracked: s.run.trajectory.len(),
        maps_made: s.run.maps.made,
        maps_merged: s.run.maps.merged,
        loops: s.run.loops.as_ref().map_or(0, |l| {
            l.loops.iter().filter(|e| e.merged_map.is_none()).count()
        }),
        frames: s.run.frames,
        first_tracked,
        map_points: s.run.map_points,
        map_points_on_movers: s.moving_map_points.map(|m| m.lying),
        map_points_seen_on_movers: s.moving_map_points.map(|m| m.seen),
        static_culled_share: s.static_culled_stats().map(|(_, median, _)| median),
        dense,
        error: None,
    })
}

/// The cloud at `path`, moved into the generator's world with `alignment` (the trajectory's),
/// against the scene's static triangles; and the cloud of the keyframes at `keyframe_stamps`
/// fused with true poses and true masks (non-static objects' pixels left out).
fn dense_distance(
    o: &MatrixOptions,
    preset: &str,
    seed: u64,
    path: &Path,
    alignment: &stillpoint_geometry::Sim3,
    keyframe_stamps: &[f64],
) -> Result<(CloudDistance, CloudDistance), BenchError> {
    use stillpoint_eval::surface::{SurfaceGrid, cloud_to_surface};
    use stillpoint_pipeline::dense::{DenseFusion, DenseSettings};
    let text = std::fs::read_to_string(path)
        .map_err(crate::io_error(format!("reading {}", path.display())))?;
    let cloud = stillpoint_pipeline::dense::read_dense_ply_positions(&text)
        .ok_or_else(|| BenchError::Invalid(format!("{}: not a dense cloud", path.display())))?;
    let preset = Preset::from_name(preset)
        .ok_or_else(|| BenchError::Invalid(format!("unknown preset {preset}")))?;
    let generator =
        stillpoint_synth::Generator::new(&config(o, preset, seed)).map_err(|source| {
            BenchError::Synth {
                context: format!("rebuilding {} seed {seed}", preset.name()),
                source,
            }
        })?;
    let surface = SurfaceGrid::new(generator.static_triangles(), 0.1, 0.1);
    let aligned: Vec<_> = cloud.iter().map(|p| alignment.transform_point(p)).collect();
    let run = cloud_to_surface(&aligned, &surface);
    let config = generator.config();
    let mut fusion = DenseFusion::new(DenseSettings::default(), config.camera);
    let mut poses = Vec::new();
    for &t in keyframe_stamps {
        let i = ((t - config.start_time) * config.fps).round();
        if !(i >= 0.0 && (i as usize) < generator.len()) {
            continue;
        }
        let f = generator.frame(i as usize);
        let mut not_static = stillpoint_image::Gray8::new(f.depth.width, f.depth.height, 0);
        for (m, &id) in not_static.data.iter_mut().zip(&f.object_ids.data) {
            if id > 0 && !generator.object_is_static(id as usize - 1) {
                *m = 255;
            }
        }
        fusion.add_keyframe(t, &f.depth, None, Some(&not_static), None);
        poses.push((t, f.pose_wc));
    }
    let truth: Vec<_> = fusion
        .fuse(|t| poses.iter().find(|p| p.0 == t).map(|p| p.1))
        .iter()
        .map(|p| p.position)
        .collect();
    Ok((run, cloud_to_surface(&truth, &surface)))
}

/// Generate the sequences (or reuse those in `out`), run every preset x seed x mode, `jobs` at a
/// time, and return the rows in that order. A run that fails is a row with its `error`.
pub fn run_matrix(o: &MatrixOptions) -> Result<Vec<Row>, BenchError> {
    for m in &o.modes {
        if !MODES.contains(&m.as_str()) {
            return Err(BenchError::Invalid(format!(
                "--modes: unknown mode {m:?} (off, gt, yolox, none)"
            )));
        }
    }
    if o.frames == 0 || o.jobs == 0 {
        return Err(BenchError::Invalid(
            "--frames and --jobs must be at least 1".into(),
        ));
    }
    std::fs::create_dir_all(&o.out)
        .map_err(crate::io_error(format!("creating {}", o.out.display())))?;
    let mut jobs = Vec::new();
    for p in &o.presets {
        for &seed in &o.seeds {
            let dir = sequence_dir(o, *p, seed);
            tracing::info!("generating {}", dir.display());
            generate(o, *p, seed, &dir)?;
            let (name, dir) = if o.monocular {
                (format!("{}_mono", p.name()), without_depth(&dir)?)
            } else if o.stereo {
                (format!("{}_stereo", p.name()), dir)
            } else {
                (p.name().to_string(), dir)
            };
            for m in &o.modes {
                jobs.push((name.clone(), seed, dir.clone(), m.clone()));
            }
        }
    }
    let next = AtomicUsize::new(0);
    let rows = Mutex::new(Vec::new());
    std::thread::scope(|sc| {
        for _ in 0..o.jobs.min(jobs.len()) {
            sc.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::SeqCst);
                    let Some(job) = jobs.get(k) else {
                        break;
                    };
                    let (preset, seed, _, mode) = job;
                    let out = o.out.join(format!("{preset}_s{seed}_{mode}.txt"));
                    tracing::info!("[{}/{}] {preset} seed {seed} {mode}", k + 1, jobs.len());
                    let row = run_one(o, job, out).unwrap_or_else(|e| Row {
                        preset: preset.clone(),
                        seed: *seed,
                        mode: mode.clone(),
                        ate_cm: None,
                        tracked: 0,
                        maps_made: 0,
                        maps_merged: 0,
                        loops: 0,
                        frames: o.frames,
                        first_tracked: None,
                        map_points: 0,
                        map_points_on_movers: None,
                        map_points_seen_on_movers: None,
                        static_culled_share: None,
                        dense: None,
                        error: Some(crate::error_chain(&e)),
                    });
                    if let Ok(mut r) = rows.lock() {
                        r.push((k, row));
                    }
                }
            });
        }
    });
    let mut rows = rows.into_inner().unwrap_or_default();
    rows.sort_by_key(|(k, _)| *k);
    Ok(rows.into_iter().map(|(_, r)| r).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(map_points: usize, movers: Option<usize>) -> Row {
        Row {
            preset: "static".into(),
            seed: 0,
            mode: "gt".into(),
            ate_cm: Some(1.0),
            tracked: 10,
            maps_made: 1,
            maps_merged: 0,
            loops: 0,
            frames: 10,
            first_tracked: Some(0),
            map_points,
            map_points_on_movers: movers,
            map_points_seen_on_movers: movers,
            static_culled_share: None,
            dense: None,
            error: None,
        }
    }

    #[test]
    fn the_share_on_movers_survives_an_empty_map() {
        assert_eq!(row(200, Some(5)).movers_share(), Some(0.025));
        assert_eq!(row(0, Some(0)).movers_share(), Some(0.0));
        assert_eq!(row(200, None).movers_share(), None);
    }

    #[test]
    fn a_monocular_copy_links_everything_but_the_depth() {
        let tmp = tempfile::tempdir().unwrap();
        let seq = tmp.path().join("living_cross_s0");
        for d in ["rgb", "depth", "mask"] {
            std::fs::create_dir_all(seq.join(d)).unwrap();
        }
        for f in ["rgb.txt", "depth.txt", "groundtruth.txt"] {
            std::fs::write(seq.join(f), "# x\n").unwrap();
        }
        let mono = without_depth(&seq).unwrap();
        assert_eq!(mono, tmp.path().join("living_cross_s0_mono"));
        let mut names: Vec<String> = std::fs::read_dir(&mono)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["groundtruth.txt", "mask", "rgb", "rgb.txt"]);
        // Again: the links already there are kept.
        assert_eq!(without_depth(&seq).unwrap(), mono);
    }

    #[test]
    fn unknown_modes_and_zero_jobs_are_refused_before_anything_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("m");
        let o = MatrixOptions {
            presets: vec![Preset::Static],
            seeds: vec![0],
            modes: vec!["off".into(), "maybe".into()],
            frames: 10,
            noise: Noise::None,
            textures: None,
            out: out.clone(),
            model: None,
            jobs: 1,
            threaded: false,
            dense: false,
            monocular: false,
            stereo: false,
            blind: None,
            layers: Default::default(),
            stop: None,
        };
        let err = run_matrix(&o).unwrap_err().to_string();
        assert!(err.contains("unknown mode \"maybe\""), "{err}");
        let err = run_matrix(&MatrixOptions {
            modes: vec!["off".into()],
            jobs: 0,
            ..o
        })
        .unwrap_err()
        .to_string();
        assert!(err.contains("must be at least 1"), "{err}");
        assert!(!out.exists());
    }
}
