//! Fault injection: `stillpoint run` over a corpus of broken inputs, made from one small
//! synthetic sequence. Each case states how the run must end (exit code), the words its one-line
//! error or warning must hold (the file, and what is wrong with it), and that nothing panics, hangs,
//! or leaves a partial line in the trajectory.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use crate::common::{stillpoint, synth_static};

/// Longest a case may run; a case that takes longer has hung.
const HANG: Duration = Duration::from_secs(300);

/// How a broken input must end.
enum Ends {
    /// Exit 0, every frame but `skipped` tracked, a warning holding each of the words.
    Recovers {
        skipped: usize,
        warning: &'static [&'static str],
    },
    /// Non-zero exit with one `error:` line holding each of the words.
    Fails(&'static [&'static str]),
}

struct Case {
    name: &'static str,
    /// Breaks the copy of the sequence in the folder given.
    breaks: fn(&Path),
    /// Extra arguments to `run` (the folder's path is spliced in for `{seq}`).
    args: &'static [&'static str],
    ends: Ends,
}

fn nth_file(dir: &Path, n: usize) -> PathBuf {
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    names.sort();
    names.swap_remove(n)
}

/// Rewrites the data lines (not the `#` comments) of a list file.
fn edit_list(file: &Path, edit: impl FnOnce(&mut Vec<String>)) {
    let text = std::fs::read_to_string(file).unwrap();
    let (mut head, mut data): (Vec<String>, Vec<String>) = (Vec::new(), Vec::new());
    for l in text.lines() {
        if l.starts_with('#') {
            head.push(l.to_string());
        } else {
            data.push(l.to_string());
        }
    }
    edit(&mut data);
    head.extend(data);
    std::fs::write(file, head.join("\n") + "\n").unwrap();
}

fn set_line(file: &Path, prefix: &str, line: &str) {
    let text = std::fs::read_to_string(file).unwrap();
    let out: Vec<String> = text
        .lines()
        .map(|l| {
            if l.starts_with(prefix) {
                line.to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    std::fs::write(file, out.join("\n") + "\n").unwrap();
}

fn corpus() -> Vec<Case> {
    vec![
        Case {
            name: "no rgb.txt",
            breaks: |d| std::fs::remove_file(d.join("rgb.txt")).unwrap(),
            args: &[],
            ends: Ends::Fails(&["no known dataset layout", "rgb.txt"]),
        },
        Case {
            name: "a colour PNG of random bytes",
            breaks: |d| std::fs::write(nth_file(&d.join("rgb"), 4), [7u8; 100]).unwrap(),
            args: &[],
            ends: Ends::Recovers {
                skipped: 1,
                warning: &["frame 4: skipped", ".png", "cannot read image"],
            },
        },
        Case {
            name: "an empty colour file",
            breaks: |d| std::fs::write(nth_file(&d.join("rgb"), 6), []).unwrap(),
            args: &[],
            ends: Ends::Recovers {
                skipped: 1,
                warning: &["frame 6: skipped", ".png", "cannot read image"],
            },
        },
        Case {
            name: "an 8-bit depth PNG",
            breaks: |d| {
                let gray = stillpoint_image::Gray8::new(640, 480, 40);
                stillpoint_image::write_gray(&nth_file(&d.join("depth"), 3), &gray).unwrap();
            },
            args: &[],
            ends: Ends::Recovers {
                skipped: 1,
                warning: &["frame 3: skipped", "depth", "16-bit"],
            },
        },
        Case {
            name: "unsorted timestamps",
            breaks: |d| edit_list(&d.join("rgb.txt"), |l| l.swap(3, 6)),
            args: &[],
            ends: Ends::Fails(&["rgb.txt:", "before the previous one", "sorted"]),
        },
        Case {
            name: "a duplicate timestamp",
            breaks: |d| {
                edit_list(&d.join("rgb.txt"), |l| {
                    let dup = l[4].clone();
                    l.insert(5, dup)
                })
            },
            args: &[],
            ends: Ends::Fails(&["rgb.txt:", "duplicate timestamp"]),
        },
        Case {
            name: "a focal length of NaN",
            breaks: |d| set_line(&d.join("settings.toml"), "fx =", "fx = nan"),
            args: &[],
            ends: Ends::Fails(&["settings.toml", "camera.fx", "focal length"]),
        },
        Case {
            name: "a depth factor of 0",
            breaks: |d| {
                set_line(
                    &d.join("settings.toml"),
                    "depth_factor =",
                    "depth_factor = 0.0",
                )
            },
            args: &[],
            ends: Ends::Fails(&["settings.toml", "depth_factor"]),
        },
        Case {
            name: "an ONNX model of random bytes",
            breaks: |d| std::fs::write(d.join("bogus.onnx"), [0x5au8; 3000]).unwrap(),
            args: &["--detector", "yolox", "--model", "{seq}/bogus.onnx"],
            ends: Ends::Fails(&["bogus.onnx", "not a loadable ONNX model"]),
        },
        Case {
            name: "a ground-truth line cut short",
            breaks: |d| {
                let mut f = std::fs::OpenOptions::new()
                    .append(true)
                    .open(d.join("groundtruth.txt"))
                    .unwrap();
                std::io::Write::write_all(&mut f, b"1341846313.9 0.1 0.2\n").unwrap();
            },
            args: &[],
            ends: Ends::Recovers {
                skipped: 0,
                warning: &[
                    "ground truth unreadable",
                    "groundtruth.txt:",
                    "expected 8 numbers",
                ],
            },
        },
        Case {
            name: "a misspelt setting",
            breaks: |d| {
                set_line(
                    &d.join("settings.toml"),
                    "n_features =",
                    "n_features = 1000\nn_featurez = 5",
                )
            },
            args: &[],
            ends: Ends::Fails(&["settings.toml", "n_featurez"]),
        },
    ]
}

/// Runs `cmd` to its end, or fails the test when it outlives [`HANG`] (and kills it).
fn run_bounded(mut cmd: std::process::Command, what: &str) -> Output {
    let child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(HANG) {
        Ok(out) => out.unwrap(),
        Err(_) => {
            let _ = std::process::Command::new("kill")
                .args(["-9", &pid.to_string()])
                .status();
            panic!("{what}: still running after {HANG:?}");
        }
    }
}

/// Every line of a TUM trajectory whole: a comment, or 8 numbers. Returns the pose count.
fn whole_lines(traj: &Path) -> usize {
    let text = std::fs::read_to_string(traj).unwrap();
    assert!(
        text.is_empty() || text.ends_with('\n'),
        "{traj:?} ends mid-line"
    );
    let poses: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    for l in &poses {
        let n = l
            .split_whitespace()
            .filter(|v| v.parse::<f64>().is_ok())
            .count();
        assert_eq!(n, 8, "{traj:?}: partial line {l:?}");
    }
    poses.len()
}

#[test]
fn broken_inputs_end_with_a_clear_line_and_no_loss() {
    let tmp = tempfile::tempdir().unwrap();
    let base = tmp.path().join("base");
    synth_static(&base, 12, 0);
    let frames = 12;
    for (i, case) in corpus().into_iter().enumerate() {
        let seq = tmp.path().join(format!("case{i}"));
        copy_dir(&base, &seq);
        (case.breaks)(&seq);
        let traj = tmp.path().join(format!("case{i}.txt"));
        let mut cmd = stillpoint();
        cmd.args(["run", "--sequential", "--json", "--dataset"])
            .arg(&seq)
            .arg("--out")
            .arg(&traj);
        let seq_str = seq.to_string_lossy().into_owned();
        cmd.args(case.args.iter().map(|a| a.replace("{seq}", &seq_str)));
        if !case.args.contains(&"--detector") {
            cmd.args(["--detector", "none"]);
        }
        let out = run_bounded(cmd, case.name);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!stderr.contains("panicked"), "{}: {stderr}", case.name);
        match case.ends {
            Ends::Fails(words) => {
                assert!(!out.status.success(), "{}: exit 0\n{stderr}", case.name);
                let errors: Vec<&str> =
                    stderr.lines().filter(|l| l.starts_with("error:")).collect();
                assert_eq!(errors.len(), 1, "{}: {stderr}", case.name);
                for w in words {
                    assert!(
                        errors[0].contains(w),
                        "{}: no {w:?} in {:?}",
                        case.name,
                        errors[0]
                    );
                }
            }
            Ends::Recovers { skipped, warning } => {
                assert!(out.status.success(), "{}: {stderr}", case.name);
                assert!(
                    stderr
                        .lines()
                        .any(|l| l.contains("WARN") && warning.iter().all(|w| l.contains(w))),
                    "{}: no warning with {warning:?} in\n{stderr}",
                    case.name
                );
                let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
                assert_eq!(
                    summary["tracked"].as_u64(),
                    Some((frames - skipped) as u64),
                    "{}: {summary}",
                    case.name
                );
                assert_eq!(whole_lines(&traj), frames - skipped, "{}", case.name);
            }
        }
    }
}

/// SIGINT in the middle of a run: the run stops, says so, exits non-zero, and the trajectory
/// holds every frame tracked until then, in whole lines.
#[cfg(unix)]
#[test]
fn an_interrupted_run_keeps_what_it_tracked() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth_static(&seq, 150, 1);
    let traj = tmp.path().join("traj.txt");
    let mut child = stillpoint()
        .args([
            "run",
            "--sequential",
            "--detector",
            "none",
            "--log",
            "debug",
            "--dataset",
        ])
        .arg(&seq)
        .arg("--out")
        .arg(&traj)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait (blocking on the log, no sleep) until frame 5 is tracked, then interrupt.
    let stderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let mut log = Vec::new();
    for line in lines.by_ref() {
        let line = line.unwrap();
        let tracked_5 = line.contains("tracked frame=5 ");
        log.push(line);
        if tracked_5 {
            break;
        }
    }
    // SAFETY: a signal to our own child process.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGINT);
    }
    log.extend(lines.map_while(Result::ok));
    let status = child.wait().unwrap();
    let log = log.join("\n");
    assert!(!status.success(), "{log}");
    assert!(!log.contains("panicked"), "{log}");
    let poses = whole_lines(&traj);
    assert!((6..150).contains(&poses), "{poses} poses\n{log}");
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}
