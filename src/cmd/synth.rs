//! `stillpoint synth`: write a synthetic dynamic sequence (TUM layout, optional KITTI stereo and
//! masks) and/or a contact sheet of it.

use anyhow::{Context, bail};
use std::path::PathBuf;
use stillpoint_synth::{KinectNoise, Noise, Preset, SynthConfig, WriteOptions};

#[derive(clap::Args)]
pub struct Args {
    /// Scene and camera motion: walking_xyz, walking_static, walking_halfsphere, walking_rpy,
    /// sitting_xyz, sitting_static, sitting_halfsphere, crowd, placing_box, person_tracking,
    /// static, loop (a lap of 20 s round the room); living_cross, living_close, living_turn,
    /// living_empty (a low-texture living room, a hand-held camera and one textured person
    /// close to it; Kinect noise by default); street (a camera on a car driving down a town
    /// street past parked and moving cars); "all" only with --contact-sheet.
    #[arg(long, default_value = "walking_xyz")]
    preset: String,
    /// Output folder (TUM layout). Optional when only a contact sheet is wanted.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Number of frames (30 Hz).
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Seed of all random choices.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Start this many seconds into the camera path (and the people's motion): the same room
    /// from another stretch of the path, e.g. to localise in a map made from the first one.
    #[arg(long, default_value_t = 0.0)]
    path_offset: f64,
    /// Folder of photos (posters) and person cut-outs (an image with a `<stem>_person_mask*.png`).
    #[arg(long)]
    textures: Option<PathBuf>,
    /// Image size WxH; the TUM fr3 intrinsics are scaled to it.
    #[arg(long, default_value = "640x480")]
    size: String,
    /// Sensor noise: none or kinect. Default: kinect for the living_* presets, none for the
    /// others.
    #[arg(long)]
    noise: Option<String>,
    /// Also write a KITTI-layout stereo sequence (image_0, image_1, calib.txt, times.txt, poses.txt,
    /// settings_stereo.toml) in the same folder; `stillpoint run --kind kitti` reads it as stereo.
    #[arg(long)]
    stereo: bool,
    /// Stereo baseline in metres.
    #[arg(long, default_value_t = 0.1)]
    baseline: f64,
    /// Write per-pixel dynamic masks (mask/*.png: 255 moving, 0 static).
    #[arg(long)]
    masks: bool,
    /// With --masks: mark a moving part's pixel only where it moved more than this many pixels
    /// since the previous frame (0 = any motion).
    #[arg(long, default_value_t = 0.0)]
    mask_min_motion: f64,
    /// Colour samples a pixel along each axis (odd, 1 to 9; 1 = point sampling: edges then
    /// move in whole-pixel steps; 3 integrates over the pixel as a camera does, ~6.7x slower).
    #[arg(long, default_value_t = 1)]
    antialias: usize,
    /// Blind the camera for a span of frames while it moves on: START+FRAMES (a covered lens:
    /// black, no depth) or START+FRAMES:wall (a blank grey wall 0.4 m away), e.g. 200+60.
    #[arg(long)]
    blind: Option<stillpoint_synth::Blind>,
    /// Write a contact sheet PNG (frames with their boxes: red moving, green still).
    #[arg(long)]
    contact_sheet: Option<PathBuf>,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
}

fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("--size {s:?}: expected WxH, e.g. 640x480"))?;
    let w: u32 = w
        .trim()
        .parse()
        .with_context(|| format!("--size {s:?}: bad width"))?;
    let h: u32 = h
        .trim()
        .parse()
        .with_context(|| format!("--size {s:?}: bad height"))?;
    if !(16..=8192).contains(&w) || !(16..=8192).contains(&h) {
        bail!("--size {s:?}: width and height must be within 16..8192");
    }
    Ok((w, h))
}

fn config(args: &Args, preset: Preset) -> anyhow::Result<SynthConfig> {
    let (w, h) = parse_size(&args.size)?;
    let cam = stillpoint_synth::tum_fr3_camera_sized(w, h);
    let noise = match args.noise.as_deref() {
        None => preset.default_noise(),
        Some("none") => Noise::None,
        Some("kinect") => Noise::Kinect(KinectNoise::default()),
        Some(other) => bail!("--noise {other:?}: expected none or kinect"),
    };
    if args.mask_min_motion.is_nan() || args.mask_min_motion < 0.0 {
        bail!(
            "--mask-min-motion {} must be 0 or more",
            args.mask_min_motion
        );
    }
    if args.antialias == 0 || args.antialias > 9 || args.antialias.is_multiple_of(2) {
        bail!("--antialias {} must be odd, 1 to 9", args.antialias);
    }
    if args.stereo && (args.baseline.is_nan() || args.baseline <= 0.0) {
        bail!("--baseline {} must be positive", args.baseline);
    }
    Ok(SynthConfig {
        preset,
        blind: args.blind,
        frames: args.frames,
        seed: args.seed,
        camera: cam,
        noise,
        textures: args.textures.clone(),
        stereo_baseline: args.stereo.then_some(args.baseline),
        mask_min_motion_px: args.mask_min_motion,
        antialias: args.antialias,
        path_offset: args.path_offset,
        ..SynthConfig::default()
    })
}

fn parse_preset(s: &str) -> anyhow::Result<Preset> {
    Preset::from_name(s).with_context(|| {
        let names: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
        format!("unknown preset {s:?}; known: {}", names.join(", "))
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.out.is_none() && args.contact_sheet.is_none() {
        bail!("nothing to do: give --out DIR and/or --contact-sheet PNG");
    }
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if let Some(sheet) = &args.contact_sheet {
        let presets = if args.preset == "all" {
            Preset::ALL.to_vec()
        } else {
            vec![parse_preset(&args.preset)?]
        };
        let per_row = if presets.len() > 1 { 4 } else { 6 };
        let mut images = Vec::new();
        for p in &presets {
            let cfg = config(&args, *p)?;
            let g =
                stillpoint_synth::generate(&cfg).with_context(|| format!("preset {}", p.name()))?;
            let idx: Vec<usize> = (0..per_row)
                .map(|k| k * (args.frames - 1) / (per_row - 1).max(1))
                .collect();
            images.extend(stillpoint_synth::write::annotated_frames(&g, &idx));
        }
        let img = stillpoint_synth::contact_sheet(&images, per_row, 2);
        stillpoint_image::write_rgb(sheet, &img)
            .with_context(|| format!("writing contact sheet {}", sheet.display()))?;
        tracing::info!(
            "contact sheet of {} presets in {}",
            presets.len(),
            sheet.display()
        );
    }
    let Some(out) = &args.out else {
        return Ok(());
    };
    let preset = parse_preset(&args.preset)?;
    let cfg = config(&args, preset)?;
    let opts = WriteOptions {
        stereo: args.stereo,
        masks: args.masks,
    };
    tracing::info!(
        "writing {} frames of {} to {}",
        cfg.frames,
        preset.name(),
        out.display()
    );
    let s = stillpoint_synth::write_sequence(&cfg, opts, out)
        .with_context(|| format!("writing {} into {}", preset.name(), out.display()))?;
    if args.json {
        let v = serde_json::json!({
            "preset": preset.name(),
            "dir": s.dir,
            "frames": s.frames,
            "seconds": s.seconds,
            "frames_per_second": s.frames_per_second,
            "mean_dynamic_fraction": s.mean_dynamic_fraction,
            "mean_person_fraction": s.mean_person_fraction,
            "boxes": s.boxes,
        });
        println!("{v}");
    } else {
        println!(
            "{}: {} frames in {:.2} s ({:.1} frames/s), people cover {:.1} % and moving parts {:.1} % of the image on average, {} boxes -> {}",
            preset.name(),
            s.frames,
            s.seconds,
            s.frames_per_second,
            100.0 * s.mean_person_fraction,
            100.0 * s.mean_dynamic_fraction,
            s.boxes,
            s.dir.display()
        );
    }
    Ok(())
}
