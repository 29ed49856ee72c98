//! One module per subcommand; each owns its clap arguments and its `run`.

pub mod bench;
pub mod demo;
pub mod detect;
pub mod eval;
pub mod info;
pub mod ros2;
pub mod run;
pub mod settings;
pub mod synth;
