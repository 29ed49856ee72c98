//! One error type for the crate; every message names the file (and line, where one applies).

/// What can go wrong reading, evaluating or plotting trajectories.
#[derive(Debug, thiserror::Error)]
pub enum TrajectoryError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// A line of a trajectory file is malformed (wrong column count, not a number, NaN, ...).
    #[error("{path}:{line}: {msg}")]
    Parse {
        /// The file.
        path: String,
        /// 1-based line.
        line: usize,
        /// What is wrong with it.
        msg: String,
    },
    /// The file holds no pose at all.
    #[error("{path}: no poses in file")]
    Empty {
        /// The file.
        path: String,
    },
    /// Inputs that cannot be evaluated together (no matching stamps, too few poses, ...).
    #[error("{0}")]
    Invalid(String),
    /// The plot could not be drawn or written.
    #[error("{path}: plot failed: {msg}")]
    Plot {
        /// The image file.
        path: String,
        /// Why.
        msg: String,
    },
}

pub(crate) fn io_err(
    path: &std::path::Path,
) -> impl FnOnce(std::io::Error) -> TrajectoryError + '_ {
    move |source| TrajectoryError::Io {
        path: path.display().to_string(),
        source,
    }
}
