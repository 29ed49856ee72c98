//! A soak run: one long synthetic sequence (the `loop` preset, lapping the room every 20 s),
//! rendered in memory frame by frame and fed to the pipeline, with the process's memory and the
//! time per frame sampled along the run. Keyframe and map point culling (and loop closing on the
//! revisits) should keep both flat: a lap adds nothing the map does not already hold.

use std::time::Instant;

use stillpoint_datasets::{Frame, Sensor};
use stillpoint_pipeline::{Pipeline, PipelineSettings};
use stillpoint_synth::{Generator, KinectNoise, Noise, Preset, SynthConfig};

use crate::BenchError;

/// What the soak run generates and how often it samples.
#[derive(Clone, Debug)]
pub struct SoakOptions {
    /// Frames in all (30 a second, a lap every 600).
    pub frames: usize,
    /// Image size (width, height).
    pub size: (u32, u32),
    /// Kinect-like depth and image noise (else none).
    pub noise: bool,
    /// A sample every this many frames.
    pub every: usize,
    /// Local mapping and loop closing on their own threads (`run`'s default); sequential
    /// otherwise, which puts their time into the frame that triggers them.
    pub threaded: bool,
}

impl Default for SoakOptions {
    fn default() -> Self {
        Self {
            frames: 10_000,
            size: (320, 240),
            noise: true,
            every: 500,
            threaded: false,
        }
    }
}

/// The state of the run after a frame.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SoakSample {
    /// Frames processed so far.
    pub frame: usize,
    /// Resident memory of the process, MiB (`None` where /proc is not there).
    pub rss_mib: Option<f64>,
    /// Keyframes in the map.
    pub keyframes: usize,
    /// Map points in the map.
    pub map_points: usize,
    /// Mean pipeline time per frame since the previous sample, ms.
    pub ms_per_frame: f64,
    /// Frames tracked since the previous sample.
    pub tracked: usize,
}

/// The whole run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SoakReport {
    /// The options' frames, size and noise, as run.
    pub frames: usize,
    /// One sample every `every` frames.
    pub samples: Vec<SoakSample>,
    /// Peak resident memory of the process, MiB (`None` where /proc is not there).
    pub peak_rss_mib: Option<f64>,
    /// ATE RMSE of the final trajectory against the generator's poses, cm.
    pub ate_cm: Option<f64>,
}

impl SoakReport {
    /// The sample at or just after frame `n`.
    pub fn at(&self, n: usize) -> Option<&SoakSample> {
        self.samples.iter().find(|s| s.frame >= n)
    }
}

use stillpoint_core::memory_mib;

/// Run the soak; `progress(sample)` after each sample.
pub fn run_soak(
    o: &SoakOptions,
    progress: &mut dyn FnMut(&SoakSample),
) -> Result<SoakReport, BenchError> {
    if o.frames == 0 || o.every == 0 {
        return Err(BenchError::Invalid(
            "a soak run needs frames and a sample interval above 0".into(),
        ));
    }
    let cfg = SynthConfig {
        preset: Preset::Loop,
        frames: o.frames,
        camera: stillpoint_synth::tum_fr3_camera_sized(o.size.0, o.size.1),
        noise: if o.noise {
            Noise::Kinect(KinectNoise::default())
        } else {
            Noise::None
        },
        ..SynthConfig::default()
    };
    let generator = Generator::new(&cfg).map_err(|source| BenchError::Synth {
        context: "building the loop preset".into(),
        source,
    })?;
    let mut settings = PipelineSettings::from_dataset(&generator.settings(Sensor::Rgbd));
    settings.slam.local_mapping_thread = o.threaded;
    let mut pipeline = Pipeline::new(settings, None, None);
    let mut samples = Vec::new();
    let (mut busy_ms, mut tracked) = (0.0, 0);
    for i in 0..o.frames {
        let f = generator.frame(i);
        let frame = Frame {
            index: i,
            timestamp: f.timestamp,
            gray: stillpoint_image::rgb_to_gray(&f.rgb),
            rgb: Some(f.rgb),
            depth: Some(f.depth),
            right: None,
        };
        let started = Instant::now();
        let r = pipeline.track(&frame)?;
        busy_ms += stillpoint_core::ms_since(started);
        tracked += usize::from(r.pose_wc.is_some());
        if (i + 1) % o.every == 0 || i + 1 == o.frames {
            let since = (i + 1 - samples.last().map_or(0, |s: &SoakSample| s.frame)) as f64;
            let sample = SoakSample {
                frame: i + 1,
                rss_mib: memory_mib().0,
                keyframes: pipeline.system().keyframe_count(),
                map_points: pipeline.system().map_point_count(),
                ms_per_frame: busy_ms / since,
                tracked,
            };
            progress(&sample);
            samples.push(sample);
            (busy_ms, tracked) = (0.0, 0);
        }
    }
    let fin = pipeline.finish()?;
    let truth = stillpoint_trajectory::Trajectory::from_parts(
        (0..o.frames).map(|i| generator.timestamp(i)).collect(),
        (0..o.frames).map(|i| generator.pose(i)).collect(),
    )?;
    let ate_cm = stillpoint_trajectory::ate(
        &truth,
        &fin.trajectory,
        &stillpoint_trajectory::AteOptions {
            align: stillpoint_trajectory::Alignment::Se3,
            ..Default::default()
        },
    )
    .ok()
    .map(|a| a.stats.rmse * 100.0);
    Ok(SoakReport {
        frames: o.frames,
        samples,
        peak_rss_mib: memory_mib().1,
        ate_cm,
    })
}
