//! The end-to-end tests: the `stillpoint` binary and the crates together, one module per
//! capability. One test binary instead of one per file: it is linked once, and its tests share
//! the two cores instead of running one binary after another.
//!
//! Run one module with `cargo test --test end_to_end MODULE::` (for example `slam_loop::`).

mod common;

mod camera_run;
mod dynamic_real_tum;
mod dynamic_synth;
mod eval_cli;
mod fault_injection;
mod file_runs;
mod map_files;
mod mcap_run;
mod record_run;
mod rosbag_run;
mod settings_cli;
mod slam_dynamic_demo;
mod slam_icl_pairs;
mod slam_loop;
mod slam_mono;
mod slam_robustness;
mod slam_stereo;
mod synth_detector_rate;
mod synth_layout;
mod video_run;
mod visual_outputs;
