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
