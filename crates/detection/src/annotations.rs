//! Per-frame object boxes that come with a sequence (`boxes.jsonl`, written by `stillpoint synth`
//! and read by the `gt` detector and the dynamic benchmarks): one JSON object per line, one line
//! per frame, in frame order.
//!
//! ```text
//! {"frame":0,"timestamp":1.0,"boxes":[{"object":3,"class_id":0,"bbox":{"x1":10,"y1":20,"x2":90,"y2":300},"moving":true,"visible_fraction":0.8}]}
//! ```

use serde::{Deserialize, Serialize};
use std::io::{BufRead, Write};
use std::path::Path;
use stillpoint_geometry::BBox;

/// A `boxes.jsonl` that cannot be read: the file, and the line where it is wrong.
#[derive(Debug, thiserror::Error)]
pub enum AnnotationsError {
    /// The file cannot be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// A line is not a frame's boxes.
    #[error("{path}:{line}: {msg}")]
    Parse {
        /// The file.
        path: String,
        /// 1-based line.
        line: usize,
        /// What is wrong with it.
        msg: String,
    },
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> AnnotationsError + '_ {
    move |source| AnnotationsError::Io {
        path: path.display().to_string(),
        source,
    }
}

fn parse_err(path: &Path, line: usize, msg: impl Into<String>) -> AnnotationsError {
    AnnotationsError::Parse {
        path: path.display().to_string(),
        line,
        msg: msg.into(),
    }
}

/// One visible object in one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GtBox {
    /// Object identity, stable across frames.
    pub object: u32,
    /// COCO class id (0 person, 56 chair, 62 tv, 73 book, ...).
    pub class_id: u16,
    /// Tight box of the object's visible pixels.
    pub bbox: BBox,
    /// Whether the object (or part of it) moves in the world in this frame.
    pub moving: bool,
    /// Visible pixels / pixels if unoccluded (1.0 = fully visible).
    #[serde(default = "one")]
    pub visible_fraction: f32,
}

fn one() -> f32 {
    1.0
}

/// All boxes of one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameBoxes {
    /// Frame index.
    pub frame: usize,
    /// Frame time, seconds.
    pub timestamp: f64,
    /// The objects' boxes.
    pub boxes: Vec<GtBox>,
}

/// Read `boxes.jsonl`. Blank lines are skipped; anything else that does not parse is an error
/// naming the line.
pub fn read_boxes(path: &Path) -> Result<Vec<FrameBoxes>, AnnotationsError> {
    let file = std::fs::File::open(path).map_err(io_err(path))?;
    let mut out = Vec::new();
    for (i, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line = line.map_err(io_err(path))?;
        if line.trim().is_empty() {
            continue;
        }
        let fb: FrameBoxes =
            serde_json::from_str(&line).map_err(|e| parse_err(path, i + 1, e.to_string()))?;
        out.push(fb);
    }
    Ok(out)
}

/// Append one frame's boxes as a line.
pub fn write_frame_boxes<W: Write>(w: &mut W, fb: &FrameBoxes) -> std::io::Result<()> {
    serde_json::to_writer(&mut *w, fb)?;
    w.write_all(b"\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roundtrip_and_line_numbered_errors() {
        let dir = std::env::temp_dir().join(format!("sp-ann-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("boxes.jsonl");
        let fb = FrameBoxes {
            frame: 0,
            timestamp: 1.5,
            boxes: vec![GtBox {
                object: 1,
                class_id: 0,
                bbox: BBox::new(1.0, 2.0, 30.0, 90.0),
                moving: true,
                visible_fraction: 0.5,
            }],
        };
        let mut buf = Vec::new();
        write_frame_boxes(&mut buf, &fb).unwrap();
        buf.extend_from_slice(b"\n");
        std::fs::write(&path, &buf).unwrap();
        assert_eq!(read_boxes(&path).unwrap(), vec![fb]);
        buf.extend_from_slice(b"{\"frame\": oops}\n");
        std::fs::write(&path, &buf).unwrap();
        let err = read_boxes(&path).unwrap_err().to_string();
        assert!(err.contains(":3:"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
