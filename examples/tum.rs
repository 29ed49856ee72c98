//! YOLOX, the dynamic front-end and SLAM over a TUM RGB-D folder, with `stillpoint` as the one
//! dependency: `cargo run --release --example tum -- DATASET_DIR trajectory.txt`.
use stillpoint::{DetectSettings, DynamicFrontEnd, FrontEndSettings, Pipeline, PipelineSettings};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, dir, out] = &args[..] else {
        return Err("usage: tum DATASET_DIR TRAJECTORY.txt".into());
    };
    let seq = stillpoint::open(dir.as_ref(), None, None)?;
    let detect = DetectSettings::default();
    let yolox = stillpoint::open_detector("yolox", &detect, None, Default::default())?;
    let front_end = DynamicFrontEnd::new(yolox, FrontEndSettings::default());
    let settings = PipelineSettings::from_dataset(seq.settings());
    let mut slam = Pipeline::new(settings, Some(Box::new(front_end)), None);
    for i in 0..seq.len() {
        let r = slam.track(&seq.frame(i)?)?;
        eprintln!("frame {i}: {:?}, {} keypoints culled", r.state, r.culled());
    }
    let run = slam.finish()?;
    stillpoint::write_tum(out.as_ref(), &run.trajectory)?;
    eprintln!(
        "{} poses, {} map points",
        run.trajectory.len(),
        run.map_points
    );
    Ok(())
}
