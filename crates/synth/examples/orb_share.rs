//! How many ORB keypoints (ORB-SLAM's TUM settings: 1000 features, 8 levels, FAST 20/7) a
//! synthetic sequence gives per frame, and what share of them lies on people (object ids, so a
//! person standing still counts too). Renders the frames in memory exactly as `stillpoint synth`
//! writes them (same config, same bytes). Analysis, not a test:
//!
//! `cargo run --release -p stillpoint-synth --example orb_share -- PRESET SEED [FRAMES]
//! [--textures DIR] [--noise none|kinect] [--antialias N] [--step K] [--frames-out] [--grid]`
//!
//! Prints a JSON summary: keypoints on frames without a person (the room alone), and on frames
//! with one: the share on the person (median, p90, max), the person's share of the image.

use stillpoint_features::{OrbExtractor, OrbParams};
use stillpoint_synth::{KinectNoise, Noise, Preset, SynthConfig, generate};

fn pct(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut take = |flag: &str| -> Option<String> {
        let i = args.iter().position(|a| a == flag)?;
        let v = args.get(i + 1).cloned();
        args.drain(i..(i + 2).min(args.len()));
        v
    };
    let textures = take("--textures");
    let noise = take("--noise");
    let antialias: usize = take("--antialias").map_or(Ok(1), |s| s.parse())?;
    let step: usize = take("--step").map_or(Ok(1), |s| s.parse())?;
    let mut flag = |name: &str| {
        let i = args.iter().position(|a| a == name);
        if let Some(i) = i {
            args.remove(i);
        }
        i.is_some()
    };
    let per_frame = flag("--frames-out");
    let grid = flag("--grid");
    let preset = Preset::from_name(args.first().ok_or("PRESET")?).ok_or("unknown preset")?;
    let seed: u64 = args.get(1).ok_or("SEED")?.parse()?;
    let frames: usize = args.get(2).map_or(Ok(300), |s| s.parse())?;
    let noise = match noise.as_deref() {
        None => preset.default_noise(),
        Some("none") => Noise::None,
        Some("kinect") => Noise::Kinect(KinectNoise::default()),
        Some(o) => return Err(format!("--noise {o}").into()),
    };
    let cfg = SynthConfig {
        preset,
        seed,
        frames,
        noise,
        textures: textures.map(Into::into),
        antialias,
        ..SynthConfig::default()
    };
    let g = generate(&cfg)?;
    let people: Vec<u16> = g
        .objects()
        .iter()
        .filter(|o| o.class_id == Some(0))
        .map(|o| o.object as u16 + 1)
        .collect();
    let mut orb = OrbExtractor::new(OrbParams::default());
    let (mut room_kp, mut share, mut area, mut total_with) = (vec![], vec![], vec![], vec![]);
    let mut first_500 = None;
    for i in (0..frames).step_by(step.max(1)) {
        let f = g.frame(i);
        let gray = stillpoint_image::rgb_to_gray(&f.rgb);
        let feats = orb.extract(&gray);
        let n = feats.keypoints.len();
        let person_px = f
            .object_ids
            .data
            .iter()
            .filter(|id| people.contains(id))
            .count();
        let on_person = feats
            .keypoints
            .iter()
            .filter(|k| {
                let (x, y) = (k.x.round() as usize, k.y.round() as usize);
                x < f.object_ids.width
                    && y < f.object_ids.height
                    && people.contains(&f.object_ids.get(x, y))
            })
            .count();
        let a = person_px as f64 / f.object_ids.data.len() as f64;
        if first_500.is_none() && n > 500 {
            first_500 = Some(i);
        }
        if grid {
            // keypoints per 80x80 cell and per level, to see where they come from
            let mut cells = [[0usize; 8]; 6];
            let mut levels = [0usize; 8];
            for k in &feats.keypoints {
                cells[(k.y as usize / 80).min(5)][(k.x as usize / 80).min(7)] += 1;
                levels[(k.octave as usize).min(7)] += 1;
            }
            println!("frame {i}: per level {levels:?}");
            for row in cells {
                println!("  {row:?}");
            }
        }
        if per_frame {
            println!(
                "frame {i}: {n} keypoints, {on_person} on people, people {:.1} % of the image",
                100.0 * a
            );
        }
        if person_px < 200 {
            room_kp.push(n as f64);
        } else {
            share.push(on_person as f64 / n.max(1) as f64);
            area.push(a);
            total_with.push(n as f64);
        }
    }
    let frames_with = share.len();
    let close: Vec<f64> = share
        .iter()
        .zip(&area)
        .filter(|(_, a)| **a >= 0.15)
        .map(|(s, _)| *s)
        .collect();
    let mut close = close;
    let v = serde_json::json!({
        "preset": preset.name(),
        "seed": seed,
        "frames_sampled": room_kp.len() + frames_with,
        "first_frame_over_500_keypoints": first_500,
        "room_only": {"frames": room_kp.len(), "keypoints_min": pct(&mut room_kp, 0.0),
            "keypoints_median": pct(&mut room_kp, 0.5), "keypoints_max": pct(&mut room_kp, 1.0)},
        "with_person": {"frames": frames_with,
            "keypoints_median": pct(&mut total_with, 0.5),
            "share_median": pct(&mut share, 0.5), "share_p90": pct(&mut share, 0.9),
            "share_max": pct(&mut share, 1.0),
            "area_median": pct(&mut area, 0.5), "area_max": pct(&mut area, 1.0),
            "frames_area_over_15pct": close.len(),
            "share_median_area_over_15pct": pct(&mut close, 0.5)},
    });
    println!("{v}");
    Ok(())
}
