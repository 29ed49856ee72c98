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

/// Where the frames of map `map`, one that never merged with the main one, go for a run writing
/// `out`: `<stem>.map<map>.txt` beside it (their own frame of reference, never the main file's).
pub fn other_map_path(out: &Path, map: u32) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "trajectory".into());
    out.with_file_name(format!("{stem}.map{map}.txt"))
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
    fn other_maps_go_beside_the_trajectory() {
        assert_eq!(
            other_map_path(Path::new("out/run.txt"), 2),
            Path::new("out/run.map2.txt")
        );
    }

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
