//! YOLOX + dynamic front-end + SLAM over a TUM RGB-D folder: `--example tum -- DIR traj.txt`
use stillpoint_detect::{DetectSettings, GtDetectorParams, open_detector};
use stillpoint_frontend::{DynamicFrontEnd, FrontEndSettings};
use stillpoint_pipeline::{Pipeline, PipelineSettings};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, dir, out] = &args[..] else {
        return Err("usage: tum DATASET_DIR TRAJECTORY.txt".into());
    };
    let seq = stillpoint_datasets::open(dir.as_ref(), None, None)?;
    let (detect, gt) = (DetectSettings::default(), GtDetectorParams::default());
    let yolox = open_detector("yolox", &detect, None, gt)?;
    let front_end = DynamicFrontEnd::new(yolox, FrontEndSettings::default());
    let settings = PipelineSettings::from_dataset(seq.settings());
    let mut slam = Pipeline::new(settings, Some(front_end), None);
    for i in 0..seq.len() {
        let r = slam.track(&seq.frame(i)?)?;
        eprintln!("frame {i}: {:?}, {} culled", r.state, r.culled());
    }
    let run = slam.finish()?;
    stillpoint_trajectory::write_tum(out.as_ref(), &run.trajectory)?;
    eprintln!(
        "{} poses, {} map points",
        run.trajectory.len(),
        run.map_points
    );
    Ok(())
}
