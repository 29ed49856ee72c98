//! `stillpoint`: a thin command line over the library crates. Results go to stdout, progress and
//! logs to stderr; every command that reports numbers takes `--json`.

use clap::{Parser, Subcommand};
use tracing_subscriber::filter::Targets;
use tracing_subscriber::prelude::*;

mod cmd;

/// Large buffers mapped and reused, not left as holes in the heap (see the type).
#[cfg(target_os = "linux")]
#[global_allocator]
static ALLOCATOR: stillpoint_core::alloc::LargeBlockCache = stillpoint_core::alloc::LargeBlockCache;

#[derive(Parser)]
#[command(
    name = "stillpoint",
    version,
    about = "Visual SLAM that stays accurate when the world moves"
)]
struct Cli {
    /// Log level for stderr (error, warn, info, debug, trace); RUST_LOG overrides it.
    #[arg(long, global = true, default_value = "info")]
    log: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate a synthetic dynamic sequence, run SLAM with the dynamic front-end off and on, print ATE.
    Demo(cmd::demo::Args),
    /// Run SLAM on a dataset and write the trajectory.
    Run(Box<cmd::run::Args>),
    /// List a ROS recording's topics: message types, counts, image sizes and encodings.
    Info(cmd::info::Args),
    /// SLAM as a ROS 2 node (no ROS install): camera topics in, odometry, /tf, path and map out.
    Ros2(Box<cmd::ros2::Args>),
    /// Print the effective settings tree and where each value came from.
    Settings(cmd::settings::Args),
    /// Write a synthetic dynamic sequence with exact ground truth.
    Synth(cmd::synth::Args),
    /// Detect objects (YOLOX) in images.
    Detect(cmd::detect::Args),
    /// Evaluate trajectories (ATE, RPE, KITTI metric).
    #[command(subcommand)]
    Eval(cmd::eval::EvalCommand),
    /// Benchmarks: speed and accuracy, reported as ratios against references.
    #[command(subcommand)]
    Bench(cmd::bench::BenchCommand),
}

fn main() -> std::process::ExitCode {
    die_quietly_on_closed_stdout();
    finish_cleanly_on_interrupt();
    let cli = Cli::parse();
    if let Err(e) = check_log_level(&cli.log) {
        eprintln!("error: {e}");
        return std::process::ExitCode::FAILURE;
    }
    // `target=level` directives (RUST_LOG first, then --log), without the regular expressions
    // of tracing-subscriber's EnvFilter (the regex crates were ~20 s of a cold build).
    // The DDS stack of `stillpoint ros2` logs every socket and discovery step at info: its
    // warnings only, unless RUST_LOG asks for more.
    let filter = std::env::var("RUST_LOG")
        .ok()
        .and_then(|v| v.parse::<Targets>().ok())
        .unwrap_or_else(|| {
            cli.log
                .parse::<Targets>()
                .unwrap_or_else(|_| Targets::new().with_default(tracing::Level::INFO))
                .with_target("rustdds", tracing::Level::WARN)
                .with_target("ros2_client", tracing::Level::ERROR)
        });
    tracing_subscriber::registry()
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_target(false)
                .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr())),
        )
        .with(filter)
        .init();
    let result = match cli.command {
        Command::Demo(a) => cmd::demo::run(a),
        Command::Run(a) => cmd::run::run(*a),
        Command::Info(a) => cmd::info::run(a),
        Command::Ros2(a) => cmd::ros2::run(*a),
        Command::Settings(a) => cmd::settings::run(a),
        Command::Synth(a) => cmd::synth::run(a),
        Command::Detect(a) => cmd::detect::run(a),
        Command::Eval(c) => cmd::eval::run(c),
        Command::Bench(c) => cmd::bench::run(c),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// `--log` takes a level or a RUST_LOG-style filter; a bare word that is no level would be read
/// as a target name and silence every log line.
fn check_log_level(log: &str) -> Result<(), String> {
    const LEVELS: [&str; 6] = ["off", "error", "warn", "info", "debug", "trace"];
    let is_filter = log.contains('=') || log.contains(',');
    if is_filter || LEVELS.contains(&log.to_ascii_lowercase().as_str()) {
        Ok(())
    } else {
        Err(format!(
            "--log {log}: expected one of {} (or a filter such as info,stillpoint_slam=debug)",
            LEVELS.join(", ")
        ))
    }
}

/// The error and its causes on one line. Library errors often print their cause in their own
/// message too, so a cause already said is not repeated.
fn error_chain(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let msg = cause.to_string();
        if line.contains(&msg) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&msg);
    }
    line
}

/// `stillpoint bench ... | head` closes stdout early. Rust ignores SIGPIPE, so the next
/// `println!` would panic; like other Unix filters we let the signal end the process instead.
/// Files written so far (trajectories are flushed line by line) stay valid.
fn die_quietly_on_closed_stdout() {
    #[cfg(unix)]
    // SAFETY: called first in main, before any thread exists; SIG_DFL is a valid action.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

static INTERRUPTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Ctrl-C or SIGTERM was received: long commands stop taking frames and finish their files
/// (the trajectory rewritten through the keyframes, the keyframe file) instead of dying with
/// them half written. A second signal ends the process at once.
pub fn interrupted() -> bool {
    INTERRUPTED.load(std::sync::atomic::Ordering::SeqCst)
}

/// The flag [`interrupted`] reads, for the library's runs to stop on (`RunOptions::stop`).
pub fn interrupt_flag() -> &'static std::sync::atomic::AtomicBool {
    &INTERRUPTED
}

extern "C" fn on_interrupt(signal: libc::c_int) {
    INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
    // SAFETY: signal() is async-signal-safe; SIG_DFL is a valid action.
    unsafe {
        libc::signal(signal, libc::SIG_DFL);
    }
}

fn finish_cleanly_on_interrupt() {
    #[cfg(unix)]
    // SAFETY: called at the start of main; the handler only stores an atomic and resets itself.
    unsafe {
        let handler = on_interrupt as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
}
