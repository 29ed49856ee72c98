//! The run's files: the trajectory locked for the whole run, and the keyframe file beside it.

use std::path::{Path, PathBuf};

use crate::RunError;

/// Where the keyframe trajectory of a run writing `out` goes: `<stem>_keyframes.txt` beside it.
pub fn keyframe_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "trajectory".into());
    out.with_file_name(format!("{stem}_keyframes.txt"))
}

/// An exclusive lock on the trajectory file for the whole run, taken before the file is
/// emptied: a second run given the same `--out` fails at once instead of writing into it.
pub(crate) fn lock_output(path: &Path) -> Result<std::fs::File, RunError> {
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .map_err(|source| RunError::Io {
            context: format!("opening {}", path.display()),
            source,
        })?;
    match file.try_lock() {
        Ok(()) => Ok(file),
        Err(std::fs::TryLockError::WouldBlock) => Err(RunError::Refused(format!(
            "{}: another run is writing this trajectory (give each run its own --out)",
            path.display()
        ))),
        Err(std::fs::TryLockError::Error(source)) => Err(RunError::Io {
            context: format!("locking {}", path.display()),
            source,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keyframes_go_beside_the_trajectory() {
        assert_eq!(
            keyframe_path(Path::new("/tmp/run/a.txt")),
            Path::new("/tmp/run/a_keyframes.txt")
        );
        assert_eq!(
            keyframe_path(Path::new("traj")),
            Path::new("traj_keyframes.txt")
        );
    }

    #[test]
    fn a_second_lock_on_the_same_file_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.txt");
        let _held = lock_output(&path).unwrap();
        let err = lock_output(&path).unwrap_err();
        assert!(err.to_string().contains("another run is writing"), "{err}");
    }
}
