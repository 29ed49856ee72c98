//! `stillpoint settings`: the effective settings tree of a run, one `key = value` line per
//! setting with where its value came from (default, FILE:LINE or --set).

use std::path::PathBuf;

use anyhow::Context;
use stillpoint_datasets::Sensor;

use stillpoint_run::{Overrides, settings_layers};

use crate::cmd::run::{SettingsArgs, parse_kind};

#[derive(clap::Args)]
pub struct Args {
    /// Sequence whose settings (camera, frame rate, depth, ORB) start the tree; ORB-SLAM's TUM
    /// fr3 RGB-D settings when omitted.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Dataset kind (tum, bonn, synth, kitti, euroc, folder); detected when omitted.
    #[arg(long)]
    pub kind: Option<String>,
    /// ORB-SLAM YAML or stillpoint TOML dataset settings, as for `run`.
    #[arg(long)]
    pub settings: Option<PathBuf>,
    #[command(flatten)]
    pub layers: SettingsArgs,
    /// Start from `run --paper-cull`'s preset.
    #[arg(long)]
    pub paper_cull: bool,
    /// One JSON array of {key, value, source} instead of TOML lines.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let ds = match &args.dataset {
        Some(dir) => {
            let kind = parse_kind(args.kind.as_deref())?;
            let seq = stillpoint_datasets::open(dir, kind, args.settings.as_deref())
                .with_context(|| format!("opening {}", dir.display()))?;
            seq.settings().clone()
        }
        None => {
            let camera =
                stillpoint_geometry::PinholeCamera::new(535.4, 539.2, 320.1, 247.6, 640, 480);
            stillpoint_datasets::Settings::with_camera(Sensor::Rgbd, camera)
        }
    };
    let overrides = Overrides {
        config: args.layers.config.clone(),
        sets: args.layers.sets.clone(),
        ..Overrides::default()
    };
    let layers = settings_layers(&ds, args.settings.as_deref(), args.paper_cull, &overrides)?;
    if args.json {
        let rows: Vec<serde_json::Value> = layers
            .entries()
            .into_iter()
            .map(|(key, value, source)| {
                serde_json::json!({ "key": key, "value": value, "source": source })
            })
            .collect();
        println!("{}", serde_json::Value::Array(rows));
    } else {
        print!("{}", layers.describe());
    }
    Ok(())
}
