//! What the command-line tests share: the binary and its plainest run.
#![allow(dead_code)] // each test binary uses its own part

use std::path::Path;
use std::process::{Command, Output};

/// The `stillpoint` binary under test.
pub fn stillpoint() -> Command {
    Command::new(env!("CARGO_BIN_EXE_stillpoint"))
}

/// `stillpoint run --detector none --sequential --json --dataset SEQ --out TRAJ`.
pub fn run_without_detector(seq: &Path, traj: &Path) -> Output {
    stillpoint()
        .args(["run", "--detector", "none", "--sequential", "--json"])
        .arg("--dataset")
        .arg(seq)
        .arg("--out")
        .arg(traj)
        .output()
        .unwrap()
}

/// `stillpoint synth --preset static --frames N --seed S --out DIR`; must succeed.
pub fn synth_static(dir: &Path, frames: usize, seed: u64) {
    let st = stillpoint()
        .args(["synth", "--preset", "static", "--frames"])
        .arg(frames.to_string())
        .arg("--seed")
        .arg(seed.to_string())
        .arg("--out")
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
}
