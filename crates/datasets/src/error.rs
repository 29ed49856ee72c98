//! The crate's error: every message names the file (and the line, where one applies).

use std::path::Path;

/// What can go wrong opening a sequence or reading a frame.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file cannot be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// A malformed line in a text file (list, association, calibration, times).
    #[error("{path}:{line}: {msg}")]
    Parse {
        /// The file.
        path: String,
        /// 1-based line.
        line: usize,
        /// What is wrong with it.
        msg: String,
    },
    /// A settings file without a required key, or with a value of the wrong kind.
    #[error("{path}: {msg}")]
    Settings {
        /// The file.
        path: String,
        /// The key and what is wrong.
        msg: String,
    },
    /// An image that cannot be decoded, or does not fit the sequence.
    #[error("{0}")]
    Image(#[from] stillpoint_image::ImageError),
    /// The directory is not a sequence of any known layout, or lacks a needed file.
    #[error("{path}: {msg}")]
    Layout {
        /// The directory or file.
        path: String,
        /// What is missing.
        msg: String,
    },
    /// An image of another size than the settings' camera.
    #[error(
        "{path}: image is {width}x{height} but the settings say {expected_width}x{expected_height} (give the settings of this camera)"
    )]
    SizeMismatch {
        /// The image.
        path: String,
        /// Its size.
        width: usize,
        /// Its size.
        height: usize,
        /// The camera's size in the settings.
        expected_width: u32,
        /// The camera's size in the settings.
        expected_height: u32,
    },
    /// A recording (MCAP) that cannot be read, or a message in it that cannot be decoded.
    #[error("{path}: {at}: {msg}")]
    Recording {
        /// The file.
        path: String,
        /// Where: a byte offset, or a topic's message index and its byte offset.
        at: String,
        /// What is wrong.
        msg: String,
    },
    /// The source can give this frame and none after it: a video cut short or corrupt at this
    /// sample, a camera unplugged or stopped. A run stops here and keeps what it tracked.
    #[error("{path}: {at}: {msg}")]
    Ended {
        /// The file or device.
        path: String,
        /// Where: the sample and its byte, or the frame.
        at: String,
        /// What happened.
        msg: String,
    },
    /// A frame index past the end.
    #[error("frame {index} is out of range: the sequence has {len} frames")]
    OutOfRange {
        /// The index asked for.
        index: usize,
        /// Frames in the sequence.
        len: usize,
    },
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.display().to_string(),
        source,
    }
}

pub(crate) fn parse_err(path: &Path, line: usize, msg: impl Into<String>) -> DatasetError {
    DatasetError::Parse {
        path: path.display().to_string(),
        line,
        msg: msg.into(),
    }
}

pub(crate) fn layout_err(path: &Path, msg: impl Into<String>) -> DatasetError {
    DatasetError::Layout {
        path: path.display().to_string(),
        msg: msg.into(),
    }
}

pub(crate) fn recording_err(
    path: &Path,
    at: impl Into<String>,
    msg: impl Into<String>,
) -> DatasetError {
    DatasetError::Recording {
        path: path.display().to_string(),
        at: at.into(),
        msg: msg.into(),
    }
}
