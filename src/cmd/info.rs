//! `stillpoint info`: what a ROS recording holds, to pick the topics for `run --bag`: each
//! topic's message type, encoding, message count and rate, and for images the first one's size
//! and encoding.

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// A ROS recording: MCAP (or the `ros2 bag` folder holding one) or a ROS 1 `.bag`.
    pub file: PathBuf,
    /// Print JSON on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let info = stillpoint_datasets::mcap::inspect(&args.file)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&info)?);
    } else {
        print!("{}", info.table());
    }
    Ok(())
}
