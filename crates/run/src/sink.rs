//! Where a run's outputs go: each [`Sink`] hears every tracked frame, then the end. `run` makes
//! one per output asked for (the trajectory file, the overlays, the recording, the clouds, the
//! saved map); a caller adds its own ([`crate::run_with`]): the benches' scoring against a
//! sequence's truth is one (`stillpoint_eval::scoring`), so the production loop holds none.

use std::path::{Path, PathBuf};
use std::time::Instant;

use stillpoint_core::ms_since;
use stillpoint_datasets::{Frame, Sequence};
use stillpoint_image::Gray8;
use stillpoint_pipeline::{Finished, FrameResult};
use stillpoint_slam::System;
use stillpoint_trajectory::TumWriter;

use crate::output::keyframe_path;
use crate::record::{FrameRecord, RecordReport, Recorder};
use crate::{DenseReport, MapFileReport, RunError};

/// One frame as the sinks hear it: the frame, what the pipeline made of it, the system (its
/// map) after it.
pub struct Tracked<'a> {
    /// The frame as read.
    pub frame: &'a Frame,
    /// The pipeline's result.
    pub result: &'a FrameResult,
    /// The SLAM system after the frame.
    pub system: &'a System,
}

/// The end of a run as the sinks hear it.
pub struct Ended<'a> {
    /// What the pipeline left: the refined trajectory, the keyframes, the stopped system.
    pub finished: &'a Finished,
    /// The sequence the run read (its ground truth, its name).
    pub sequence: &'a dyn Sequence,
    /// The run started in a map read from a file (whose keyframes carry another sequence's
    /// timestamps).
    pub map_loaded: bool,
}

/// An output of a run.
pub trait Sink {
    /// After each tracked frame.
    fn frame(&mut self, tracked: &Tracked) -> Result<(), RunError>;
    /// Once, after the pipeline finished.
    fn finish(&mut self, _ended: &Ended) -> Result<(), RunError> {
        Ok(())
    }
}

/// Which pixels of a frame lie on moving objects, as a sequence's own truth says (a synthetic
/// sequence's masks): given by a caller that scores runs, so that the dense cloud can count
/// its points on movers. A production run has none.
pub trait MovingPixels {
    /// The mask (non-zero: moving) of the frame at `timestamp`, when there is one.
    fn moving_mask(&self, timestamp: f64) -> Option<Gray8>;
}

/// The per-frame trajectory, written line by line as the run goes (what a crash leaves), then
/// rewritten through the refined keyframes with the keyframe trajectory beside it.
pub(crate) struct TrajectoryFile {
    path: PathBuf,
    writer: TumWriter,
    written: Option<f64>,
}

impl TrajectoryFile {
    pub(crate) fn create(path: &Path) -> Result<Self, RunError> {
        let writer = TumWriter::create(path).map_err(|source| RunError::Trajectory {
            context: format!("creating {}", path.display()),
            source,
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            writer,
            written: None,
        })
    }
}

impl Sink for TrajectoryFile {
    fn frame(&mut self, t: &Tracked) -> Result<(), RunError> {
        // Earlier frames a new monocular map took in come first, in time order.
        for (index, stamp, pose) in t.result.poses_in_time_order() {
            if self.written.is_none_or(|l| stamp > l) {
                self.written = Some(stamp);
                self.writer
                    .write(stamp, &pose)
                    .map_err(|source| RunError::Trajectory {
                        context: format!("writing frame {index}"),
                        source,
                    })?;
            }
        }
        Ok(())
    }

    fn finish(&mut self, e: &Ended) -> Result<(), RunError> {
        let write = |path: &Path, trajectory, doing: &str| {
            stillpoint_trajectory::write_tum(path, trajectory).map_err(|source| {
                RunError::Trajectory {
                    context: format!("{doing} {}", path.display()),
                    source,
                }
            })
        };
        write(&self.path, &e.finished.trajectory, "rewriting")?;
        for (map, t) in &e.finished.other_maps {
            let path = crate::output::other_map_path(&self.path, *map);
            write(&path, t, "writing")?;
            tracing::info!(
                map,
                frames = t.len(),
                "frames of a map that never merged written to {}",
                path.display()
            );
        }
        if e.finished.loop_closed {
            tracing::info!("loop closed: trajectory rebuilt through the keyframes");
        }
        write(
            &keyframe_path(&self.path),
            &e.finished.keyframe_trajectory,
            "writing",
        )
    }
}

/// A picture of each frame in a folder ([`crate::overlay`]).
pub(crate) struct Overlays {
    pub(crate) dir: PathBuf,
}

impl Sink for Overlays {
    fn frame(&mut self, t: &Tracked) -> Result<(), RunError> {
        let img = crate::overlay::draw_overlay(t.frame, t.result);
        let path = crate::overlay::overlay_path(&self.dir, t.frame.index);
        stillpoint_image::write_rgb(&path, &img).map_err(|e| RunError::Io {
            context: format!("writing {}", path.display()),
            source: std::io::Error::other(e.to_string()),
        })
    }
}

/// The run as an MCAP file ([`crate::record`]), and the time each frame's messages took.
pub(crate) struct Recording {
    pub(crate) path: PathBuf,
    pub(crate) recorder: Option<Recorder>,
    pub(crate) camera: stillpoint_geometry::PinholeCamera,
    pub(crate) ms: Vec<f64>,
    pub(crate) report: Option<RecordReport>,
}

impl Sink for Recording {
    fn frame(&mut self, t: &Tracked) -> Result<(), RunError> {
        let Some(rec) = self.recorder.as_mut() else {
            return Ok(());
        };
        let t0 = Instant::now();
        rec.frame(&FrameRecord {
            frame: t.frame,
            result: t.result,
            camera: &self.camera,
        })?;
        if t.result.new_keyframe {
            let map = t.system.map();
            if let Ok(map) = map.lock() {
                rec.keyframe(&map)?;
            }
        }
        self.ms.push(ms_since(t0));
        Ok(())
    }

    fn finish(&mut self, e: &Ended) -> Result<(), RunError> {
        if let Some(rec) = self.recorder.take() {
            let map = e.finished.system.map();
            let map = map.lock().ok();
            let report = rec.finish(map.as_deref(), &e.finished.trajectory)?;
            tracing::info!(
                "recording written to {} ({:.1} MB, {} messages)",
                self.path.display(),
                report.bytes as f64 / 1e6,
                report.messages.values().sum::<usize>()
            );
            self.report = Some(report);
        }
        Ok(())
    }
}

/// RGB-D and stereo: keyframe depth fused into a dense cloud of the static scene, the pixels of movers and
/// people left out, written as PLY at the end.
pub(crate) struct DenseCloud<'a> {
    pub(crate) path: PathBuf,
    pub(crate) fusion: stillpoint_pipeline::dense::DenseFusion,
    pub(crate) truth: Option<&'a dyn MovingPixels>,
    pub(crate) report: Option<DenseReport>,
}

impl Sink for DenseCloud<'_> {
    fn frame(&mut self, t: &Tracked) -> Result<(), RunError> {
        let (Some(depth), true) = (t.result.depth(t.frame), t.result.new_keyframe) else {
            return Ok(());
        };
        // The pixels of movers and of people (still or not) stay out of the static cloud.
        let skip = t
            .result
            .objects
            .movable
            .mask(Some(depth), depth.width, depth.height);
        let truth = self.truth.and_then(|m| m.moving_mask(t.frame.timestamp));
        self.fusion.add_keyframe(
            t.frame.timestamp,
            depth,
            t.frame.rgb.as_ref(),
            skip.as_ref(),
            truth.as_ref(),
        );
        Ok(())
    }

    fn finish(&mut self, e: &Ended) -> Result<(), RunError> {
        let trajectory = &e.finished.trajectory;
        let poses: std::collections::HashMap<u64, stillpoint_geometry::Se3> = trajectory
            .stamps
            .iter()
            .zip(&trajectory.poses)
            .map(|(t, p)| (t.to_bits(), *p))
            .collect();
        let points = self.fusion.fuse(|t| poses.get(&t.to_bits()).copied());
        let io = |source| RunError::Io {
            context: format!("writing {}", self.path.display()),
            source,
        };
        let file = std::fs::File::create(&self.path).map_err(io)?;
        stillpoint_pipeline::dense::write_dense_ply(&points, std::io::BufWriter::new(file))
            .map_err(io)?;
        let on_movers = self
            .truth
            .map(|_| points.iter().filter(|p| p.on_mover).count());
        tracing::info!(
            "{} dense points from {} keyframes written to {}{}",
            points.len(),
            self.fusion.keyframes(),
            self.path.display(),
            on_movers.map_or(String::new(), |m| format!(" ({m} on movers)"))
        );
        self.report = Some(DenseReport {
            points: points.len(),
            on_movers,
        });
        Ok(())
    }
}

/// The map's points at the end, as PLY.
pub(crate) struct MapCloud {
    pub(crate) path: PathBuf,
}

impl Sink for MapCloud {
    fn frame(&mut self, _: &Tracked) -> Result<(), RunError> {
        Ok(())
    }

    fn finish(&mut self, e: &Ended) -> Result<(), RunError> {
        let io = |source| RunError::Io {
            context: format!("writing {}", self.path.display()),
            source,
        };
        let file = std::fs::File::create(&self.path).map_err(io)?;
        let map = e.finished.system.map();
        let written = match map.lock() {
            Ok(map) => {
                stillpoint_slam::io::write_map_points_ply(&map, std::io::BufWriter::new(file))
                    .map_err(io)?
            }
            Err(_) => 0,
        };
        tracing::info!("{written} map points written to {}", self.path.display());
        Ok(())
    }
}

/// The whole map at the end, in a map file ([`stillpoint_slam::map_file`]), written atomically.
pub(crate) struct SavedMap {
    pub(crate) path: PathBuf,
    pub(crate) report: Option<MapFileReport>,
}

impl Sink for SavedMap {
    fn frame(&mut self, _: &Tracked) -> Result<(), RunError> {
        Ok(())
    }

    fn finish(&mut self, e: &Ended) -> Result<(), RunError> {
        let t0 = Instant::now();
        let file = e.finished.system.map_file();
        let bytes = stillpoint_slam::map_file::save(&self.path, &file).map_err(|source| {
            RunError::MapFile {
                path: self.path.clone(),
                source: source.into(),
            }
        })?;
        let report = MapFileReport {
            keyframes: file.map.keyframes.len(),
            map_points: file.map.points.len(),
            bytes,
            ms: ms_since(t0),
        };
        tracing::info!(
            "map saved to {}: {} keyframes, {} map points, vocabulary {}, {} bytes in {:.1} ms",
            self.path.display(),
            report.keyframes,
            report.map_points,
            file.vocabulary
                .as_ref()
                .map_or("none".to_string(), |v| format!("{} words", v.words())),
            report.bytes,
            report.ms
        );
        self.report = Some(report);
        Ok(())
    }
}
