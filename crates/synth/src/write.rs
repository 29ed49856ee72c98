//! Writers: the TUM RGB-D layout (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt,
//! boxes.jsonl, settings.toml), KITTI-layout stereo (image_0/, image_1/, calib.txt, times.txt,
//! poses.txt), dynamic masks, and contact sheets for looking at sequences.

use crate::{Generator, SynthConfig, SynthError, SynthFrame};
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use stillpoint_datasets::annotations::{FrameBoxes, write_frame_boxes};
use stillpoint_datasets::{GtBox, Sensor};
use stillpoint_geometry::{se3_to_3x4, se3_to_tum};
use stillpoint_image::{ImageBuf, Rgb8, rgb_to_gray};

/// What to write besides the TUM layout.
#[derive(Clone, Copy, Debug, Default)]
pub struct WriteOptions {
    /// KITTI-layout stereo (needs `stereo_baseline` in the config).
    pub stereo: bool,
    /// `mask/<timestamp>.png`: 255 where a moving part is seen, 0 elsewhere.
    pub masks: bool,
}

/// What [`write_sequence`] did.
#[derive(Clone, Debug)]
pub struct WriteSummary {
    /// The sequence's folder.
    pub dir: PathBuf,
    /// Frames written.
    pub frames: usize,
    /// Wall time of rendering and writing, seconds.
    pub seconds: f64,
    /// Frames rendered and written a second.
    pub frames_per_second: f64,
    /// Mean fraction of pixels showing something that moves.
    pub mean_dynamic_fraction: f64,
    /// Mean fraction of pixels covered by people.
    pub mean_person_fraction: f64,
    /// Boxes written to `boxes.jsonl`.
    pub boxes: usize,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError + '_ {
    move |source| SynthError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn create(path: &Path) -> Result<std::io::BufWriter<std::fs::File>, SynthError> {
    Ok(std::io::BufWriter::new(
        std::fs::File::create(path).map_err(io(path))?,
    ))
}

/// Per frame: boxes, part boxes, fraction of moving pixels, fraction of person pixels.
type FrameSummary = (Vec<GtBox>, Vec<crate::PartBox>, f64, f64);

/// Write 8-bit pixels (`channels` 1: gray, 3: RGB) as a PNG with fast compression: encoding
/// with the default level took a large share of the writing time, and files stay within ~10 %
/// of the size.
fn write_png8(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    bytes: &[u8],
) -> Result<(), SynthError> {
    let err = |msg: String| SynthError::Write {
        path: path.to_path_buf(),
        msg,
    };
    let file = std::fs::File::create(path).map_err(io(path))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    enc.set_color(if channels == 3 {
        png::ColorType::Rgb
    } else {
        png::ColorType::Grayscale
    });
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut w = enc.write_header().map_err(|e| err(e.to_string()))?;
    w.write_image_data(bytes).map_err(|e| err(e.to_string()))?;
    w.finish().map_err(|e| err(e.to_string()))
}

fn write_rgb_fast(path: &Path, img: &Rgb8) -> Result<(), SynthError> {
    let flat: Vec<u8> = img.data.iter().flat_map(|p| p.iter().copied()).collect();
    write_png8(path, img.width, img.height, 3, &flat)
}

fn write_gray_fast(path: &Path, img: &stillpoint_image::Gray8) -> Result<(), SynthError> {
    write_png8(path, img.width, img.height, 1, &img.data)
}

/// TUM file name of a timestamp.
pub fn stamp_name(t: f64) -> String {
    format!("{t:.6}")
}

/// Write the sequence `config` describes into `out` (created if missing). Frames are rendered
/// and written in parallel; text files are written in frame order.
pub fn write_sequence(
    config: &SynthConfig,
    opts: WriteOptions,
    out: &Path,
) -> Result<WriteSummary, SynthError> {
    if opts.stereo && config.stereo_baseline.is_none() {
        return Err(SynthError::Config(
            "stereo output needs a stereo baseline".into(),
        ));
    }
    let start = std::time::Instant::now();
    let generator = Generator::new(config)?;
    let mut dirs = vec!["rgb", "depth"];
    if opts.masks {
        dirs.push("mask");
    }
    if opts.stereo {
        dirs.extend(["image_0", "image_1"]);
    }
    for d in &dirs {
        let p = out.join(d);
        std::fs::create_dir_all(&p).map_err(io(&p))?;
    }
    let n = generator.len();
    let person_classes: Vec<bool> = generator
        .objects()
        .iter()
        .map(|o| o.class_id == Some(0))
        .collect();
    // per frame: boxes, dynamic fraction, person fraction
    let results: Vec<Result<FrameSummary, SynthError>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let f = generator.frame(i);
            let name = format!("{}.png", stamp_name(f.timestamp));
            write_rgb_fast(&out.join("rgb").join(&name), &f.rgb)?;
            stillpoint_image::write_depth_metres(&out.join("depth").join(&name), &f.depth, 5000.0)?;
            if opts.masks {
                write_gray_fast(&out.join("mask").join(&name), &f.dynamic_mask)?;
            }
            if opts.stereo {
                let kitti = format!("{i:06}.png");
                write_gray_fast(&out.join("image_0").join(&kitti), &rgb_to_gray(&f.rgb))?;
                if let Some(r) = &f.right {
                    write_gray_fast(&out.join("image_1").join(&kitti), &rgb_to_gray(r))?;
                }
            }
            let px = f.dynamic_mask.data.len().max(1) as f64;
            let dynamic = f.dynamic_mask.data.iter().filter(|&&m| m > 0).count() as f64 / px;
            let person = f
                .object_ids
                .data
                .iter()
                .filter(|&&id| id > 0 && person_classes[id as usize - 1])
                .count() as f64
                / px;
            Ok((f.boxes, f.parts, dynamic, person))
        })
        .collect();

    let stamps: Vec<f64> = (0..n).map(|i| generator.timestamp(i)).collect();
    let rgb_txt = out.join("rgb.txt");
    let depth_txt = out.join("depth.txt");
    let gt_txt = out.join("groundtruth.txt");
    let boxes_path = out.join("boxes.jsonl");
    let parts_path = out.join("parts.jsonl");
    let mut rgb_w = create(&rgb_txt)?;
    let mut depth_w = create(&depth_txt)?;
    let mut gt_w = create(&gt_txt)?;
    let mut boxes_w = create(&boxes_path)?;
    let mut parts_w = create(&parts_path)?;
    let name = config.preset.name();
    writeln!(
        rgb_w,
        "# color images\n# file: 'stillpoint synth {name}'\n# timestamp filename"
    )
    .map_err(io(&rgb_txt))?;
    writeln!(
        depth_w,
        "# depth maps\n# file: 'stillpoint synth {name}'\n# timestamp filename"
    )
    .map_err(io(&depth_txt))?;
    writeln!(gt_w, "# ground truth trajectory (camera-to-world)\n# file: 'stillpoint synth {name}'\n# timestamp tx ty tz qx qy qz qw").map_err(io(&gt_txt))?;
    let (mut dyn_sum, mut person_sum, mut nboxes) = (0.0, 0.0, 0);
    for (i, r) in results.into_iter().enumerate() {
        let (boxes, parts, dynamic, person) = r?;
        let s = stamp_name(stamps[i]);
        writeln!(rgb_w, "{s} rgb/{s}.png").map_err(io(&rgb_txt))?;
        writeln!(depth_w, "{s} depth/{s}.png").map_err(io(&depth_txt))?;
        let (t, q) = se3_to_tum(&generator.pose(i));
        writeln!(
            gt_w,
            "{s} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
            t[0], t[1], t[2], q[0], q[1], q[2], q[3]
        )
        .map_err(io(&gt_txt))?;
        nboxes += boxes.len();
        let fb = FrameBoxes {
            frame: i,
            timestamp: stamps[i],
            boxes,
        };
        write_frame_boxes(&mut boxes_w, &fb).map_err(io(&boxes_path))?;
        let line = serde_json::json!({"frame": i, "timestamp": stamps[i], "parts": parts});
        writeln!(parts_w, "{line}").map_err(io(&parts_path))?;
        dyn_sum += dynamic;
        person_sum += person;
    }
    for (w, p) in [
        (&mut rgb_w, &rgb_txt),
        (&mut depth_w, &depth_txt),
        (&mut gt_w, &gt_txt),
        (&mut boxes_w, &boxes_path),
        (&mut parts_w, &parts_path),
    ] {
        w.flush().map_err(io(p))?;
    }

    let settings_path = out.join("settings.toml");
    let toml =
        toml::to_string(&generator.settings(Sensor::Rgbd)).map_err(|e| SynthError::Write {
            path: settings_path.clone(),
            msg: e.to_string(),
        })?;
    std::fs::write(&settings_path, toml).map_err(io(&settings_path))?;
    let objects_path = out.join("objects.json");
    let objects =
        serde_json::to_string_pretty(&generator.objects()).map_err(|e| SynthError::Write {
            path: objects_path.clone(),
            msg: e.to_string(),
        })?;
    std::fs::write(&objects_path, objects).map_err(io(&objects_path))?;

    if opts.stereo {
        write_kitti_text(&generator, out)?;
    }
    let seconds = start.elapsed().as_secs_f64();
    Ok(WriteSummary {
        dir: out.to_path_buf(),
        frames: n,
        seconds,
        frames_per_second: n as f64 / seconds.max(1e-9),
        mean_dynamic_fraction: dyn_sum / n.max(1) as f64,
        mean_person_fraction: person_sum / n.max(1) as f64,
        boxes: nboxes,
    })
}

/// calib.txt (P0..P3 as KITTI writes them), times.txt (the TUM layout's stamps, so that
/// boxes.jsonl and both layouts' trajectories share one clock), poses.txt
/// (left camera poses relative to the first frame, 3x4 row-major) and settings_stereo.toml.
fn write_kitti_text(g: &Generator, out: &Path) -> Result<(), SynthError> {
    let c = &g.config().camera;
    let b = g.config().stereo_baseline.unwrap_or(0.0);
    let calib = out.join("calib.txt");
    let mut w = create(&calib)?;
    let p = |tx: f64| {
        format!(
            "{:e} 0 {:e} {:e} 0 {:e} {:e} 0 0 0 1 0",
            c.fx, c.cx, tx, c.fy, c.cy
        )
    };
    for (k, tx) in [0.0, -c.fx * b, 0.0, -c.fx * b].into_iter().enumerate() {
        writeln!(w, "P{k}: {}", p(tx)).map_err(io(&calib))?;
    }
    w.flush().map_err(io(&calib))?;
    let times = out.join("times.txt");
    let poses = out.join("poses.txt");
    let mut tw = create(&times)?;
    let mut pw = create(&poses)?;
    let first = g.pose(0).inverse();
    for i in 0..g.len() {
        writeln!(tw, "{:.6}", g.timestamp(i)).map_err(io(&times))?;
        let m = se3_to_3x4(&(first * g.pose(i)));
        let line: Vec<String> = m.iter().map(|v| format!("{v:e}")).collect();
        writeln!(pw, "{}", line.join(" ")).map_err(io(&poses))?;
    }
    tw.flush().map_err(io(&times))?;
    pw.flush().map_err(io(&poses))?;
    let sp = out.join("settings_stereo.toml");
    let toml = toml::to_string(&g.settings(Sensor::Stereo)).map_err(|e| SynthError::Write {
        path: sp.clone(),
        msg: e.to_string(),
    })?;
    std::fs::write(&sp, toml).map_err(io(&sp))
}

/// Outline `boxes` on `img`: red for moving objects, green for still ones.
pub fn draw_boxes(img: &mut Rgb8, boxes: &[GtBox]) {
    for b in boxes {
        let c = if b.moving {
            [255, 40, 40]
        } else {
            [40, 220, 40]
        };
        let x0 = (b.bbox.x1 + 0.5).max(0.0) as usize;
        let y0 = (b.bbox.y1 + 0.5).max(0.0) as usize;
        let x1 = ((b.bbox.x2 - 0.5) as usize).min(img.width.saturating_sub(1));
        let y1 = ((b.bbox.y2 - 0.5) as usize).min(img.height.saturating_sub(1));
        if x0 > x1 || y0 > y1 {
            continue;
        }
        for x in x0..=x1 {
            img.set(x, y0, c);
            img.set(x, y1, c);
        }
        for y in y0..=y1 {
            img.set(x0, y, c);
            img.set(x1, y, c);
        }
    }
}

/// Tile `images` in rows of `cols`, each shrunk by an integer `factor` (box filter), with a
/// 4-pixel dark gutter.
pub fn contact_sheet(images: &[Rgb8], cols: usize, factor: usize) -> Rgb8 {
    let factor = factor.max(1);
    let cols = cols.max(1);
    let (tw, th) = images
        .first()
        .map(|i| (i.width / factor, i.height / factor))
        .unwrap_or((1, 1));
    let rows = images.len().div_ceil(cols).max(1);
    let gap = 4;
    let mut sheet = ImageBuf::new(
        cols * (tw + gap) + gap,
        rows * (th + gap) + gap,
        [30u8, 30, 30],
    );
    for (k, img) in images.iter().enumerate() {
        let (ox, oy) = (gap + (k % cols) * (tw + gap), gap + (k / cols) * (th + gap));
        for y in 0..th.min(img.height / factor) {
            for x in 0..tw.min(img.width / factor) {
                let mut acc = [0u32; 3];
                for dy in 0..factor {
                    for dx in 0..factor {
                        let p = img.get(x * factor + dx, y * factor + dy);
                        for c in 0..3 {
                            acc[c] += p[c] as u32;
                        }
                    }
                }
                let n = (factor * factor) as u32;
                sheet.set(
                    ox + x,
                    oy + y,
                    [(acc[0] / n) as u8, (acc[1] / n) as u8, (acc[2] / n) as u8],
                );
            }
        }
    }
    sheet
}

/// Frames `indices` of a sequence with their boxes drawn, for a contact sheet.
pub fn annotated_frames(g: &Generator, indices: &[usize]) -> Vec<Rgb8> {
    indices
        .par_iter()
        .map(|&i| {
            let f: SynthFrame = g.frame(i);
            let mut img = f.rgb;
            draw_boxes(&mut img, &f.boxes);
            img
        })
        .collect()
}
