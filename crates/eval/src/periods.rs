//! When a moving object was in view: intervals of time, from a sequence's per-frame boxes
//! (`boxes.jsonl`, the generator's annotations) or from a plain text file, for shading plots
//! of the error over time.

use std::path::{Path, PathBuf};

use stillpoint_datasets::FrameBoxes;

/// `[start, end]`, seconds, start <= end.
pub type Interval = (f64, f64);

/// Why the moving periods could not be had.
#[derive(Debug, thiserror::Error)]
pub enum PeriodsError {
    /// The intervals file cannot be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A line of the intervals file is not `start end`.
    #[error("{}:{line}: {msg}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong with it.
        msg: String,
    },
    /// The sequence has no per-frame boxes to take the periods from.
    #[error(
        "{}: no boxes.jsonl (the moving periods come from a sequence's per-frame boxes, as `stillpoint synth` writes them)",
        .0.display()
    )]
    NoBoxes(PathBuf),
    /// The boxes file is malformed.
    #[error(transparent)]
    Boxes(#[from] stillpoint_datasets::annotations::AnnotationsError),
}

/// The intervals in which `frames` (stamp, a moving object in view; in time order) show a
/// moving object: each run of consecutive such frames, widened by half the gap to the frame
/// before and after it (a lone frame covers its own frame period; the first and last frames
/// take their one neighbour's gap).
pub fn moving_intervals(frames: &[(f64, bool)]) -> Vec<Interval> {
    let n = frames.len();
    let gap = |i: usize, j: usize| (frames[j].0 - frames[i].0).abs();
    // Half a frame period before and after frame i.
    let before = |i: usize| match (i, n) {
        (_, 1) => 0.0,
        (0, _) => 0.5 * gap(0, 1),
        _ => 0.5 * gap(i - 1, i),
    };
    let after = |i: usize| match (i, n) {
        (_, 1) => 0.0,
        _ if i + 1 == n => 0.5 * gap(i - 1, i),
        _ => 0.5 * gap(i, i + 1),
    };
    let mut out = Vec::new();
    let mut start: Option<usize> = None;
    for i in 0..=n {
        let moving = i < n && frames[i].1;
        match (moving, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push((frames[s].0 - before(s), frames[i - 1].0 + after(i - 1)));
                start = None;
            }
            _ => {}
        }
    }
    out
}

/// The frames of a sequence's boxes with a moving object in view.
pub fn moving_frames(boxes: &[FrameBoxes]) -> Vec<(f64, bool)> {
    boxes
        .iter()
        .map(|f| {
            let moving = f.boxes.iter().any(|b| b.moving && b.visible_fraction > 0.0);
            (f.timestamp, moving)
        })
        .collect()
}

/// The moving periods of the sequence in `dir`, from its `boxes.jsonl`.
pub fn dataset_moving_intervals(dir: &Path) -> Result<Vec<Interval>, PeriodsError> {
    let path = dir.join("boxes.jsonl");
    if !path.is_file() {
        return Err(PeriodsError::NoBoxes(dir.to_path_buf()));
    }
    let boxes = stillpoint_datasets::annotations::read_boxes(&path)?;
    Ok(moving_intervals(&moving_frames(&boxes)))
}

/// Read an intervals file: one `start end` (seconds, on the estimate's clock) a line, blank
/// lines and `#` comments skipped.
pub fn read_intervals(path: &Path) -> Result<Vec<Interval>, PeriodsError> {
    let text = std::fs::read_to_string(path).map_err(|source| PeriodsError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_intervals(&text).map_err(|(line, msg)| PeriodsError::Parse {
        path: path.to_path_buf(),
        line,
        msg,
    })
}

fn parse_intervals(text: &str) -> Result<Vec<Interval>, (usize, String)> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line
            .split([' ', '\t', ','])
            .filter(|f| !f.is_empty())
            .collect();
        let parsed: Vec<f64> = fields.iter().filter_map(|f| f.parse().ok()).collect();
        match parsed[..] {
            [a, b] if fields.len() == 2 && a.is_finite() && b.is_finite() && a <= b => {
                out.push((a, b))
            }
            [a, b] if fields.len() == 2 && a > b => {
                return Err((i + 1, format!("start {a} after end {b}")));
            }
            _ => {
                return Err((
                    i + 1,
                    format!("expected `start end` in seconds, found {line:?}"),
                ));
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stillpoint_datasets::GtBox;
    use stillpoint_geometry::BBox;

    fn close(a: &[Interval], b: &[Interval]) -> bool {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(x, y)| (x.0 - y.0).abs() < 1e-9 && (x.1 - y.1).abs() < 1e-9)
    }

    #[test]
    fn runs_of_moving_frames_become_intervals_half_a_frame_wider() {
        let t = |i: usize| i as f64 * 0.1;
        let frames: Vec<(f64, bool)> = [false, true, true, false, true, false, false, true]
            .iter()
            .enumerate()
            .map(|(i, &m)| (t(i), m))
            .collect();
        let got = moving_intervals(&frames);
        assert!(
            close(&got, &[(0.05, 0.25), (0.35, 0.45), (0.65, 0.75)]),
            "{got:?}"
        );
        // Moving from the first frame; nothing moving; one frame.
        assert!(close(
            &moving_intervals(&[(1.0, true), (1.2, true), (1.4, false)]),
            &[(0.9, 1.3)]
        ));
        assert!(moving_intervals(&[(0.0, false), (1.0, false)]).is_empty());
        assert!(moving_intervals(&[]).is_empty());
        assert_eq!(moving_intervals(&[(2.0, true)]), vec![(2.0, 2.0)]);
    }

    #[test]
    fn a_frame_moves_when_a_visible_box_moves() {
        let gt = |moving, visible_fraction| GtBox {
            object: 1,
            class_id: 0,
            bbox: BBox::new(0.0, 0.0, 10.0, 10.0),
            moving,
            visible_fraction,
        };
        let frame = |i: usize, boxes| FrameBoxes {
            frame: i,
            timestamp: i as f64,
            boxes,
        };
        let boxes = vec![
            frame(0, vec![gt(false, 1.0)]),
            frame(1, vec![gt(false, 1.0), gt(true, 0.3)]),
            frame(2, vec![gt(true, 0.0)]),
            frame(3, vec![]),
        ];
        assert_eq!(
            moving_frames(&boxes),
            vec![(0.0, false), (1.0, true), (2.0, false), (3.0, false)]
        );
    }

    #[test]
    fn interval_files_parse_and_name_the_bad_line() {
        let ok = parse_intervals("# start end\n1.0 2.5\n\n3,4  # walker\n5\t5\n").unwrap();
        assert_eq!(ok, vec![(1.0, 2.5), (3.0, 4.0), (5.0, 5.0)]);
        assert_eq!(parse_intervals("1 2\n1 x\n").unwrap_err().0, 2);
        assert_eq!(parse_intervals("1 2 3\n").unwrap_err().0, 1);
        assert!(
            parse_intervals("2 1\n")
                .unwrap_err()
                .1
                .contains("after end")
        );
        let dir = tempfile::tempdir().unwrap();
        let err = read_intervals(&dir.path().join("none.txt")).unwrap_err();
        assert!(err.to_string().contains("none.txt"), "{err}");
        let err = dataset_moving_intervals(dir.path()).unwrap_err();
        assert!(err.to_string().contains("no boxes.jsonl"), "{err}");
    }
}
