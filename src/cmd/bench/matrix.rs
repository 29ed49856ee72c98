//! `stillpoint bench matrix`: SLAM accuracy over synthetic presets x seeds x front-end modes
//! (off, perfect boxes, YOLOX), with the share of map points that lie on movers. Sequences are
//! generated in-process (with per-pixel masks, so map points on movers can be counted) into
//! `--out`, then each run goes through `stillpoint_run::run_sequence`, `--jobs` at a time
//! (`stillpoint_bench::matrix`).

use std::path::PathBuf;

use anyhow::{Context, bail};
use stillpoint_bench::matrix::{MatrixOptions, Row, run_matrix};
use stillpoint_synth::{KinectNoise, Noise, Preset};

#[derive(clap::Args)]
pub struct Args {
    /// Presets, comma-separated [default: living_cross, living_close, living_turn,
    /// living_empty; with --monocular, street too].
    #[arg(long, value_delimiter = ',')]
    pub presets: Vec<String>,
    /// Seeds: a list (0,1,2) or a range (0-4).
    #[arg(long, default_value = "0-4")]
    pub seeds: String,
    /// Front-end modes, comma-separated: off (no front-end), gt (perfect boxes), yolox, none
    /// (front-end without a detector).
    #[arg(long, value_delimiter = ',', default_value = "off,gt,yolox")]
    pub modes: Vec<String>,
    /// Frames per sequence.
    #[arg(long, default_value_t = 300)]
    pub frames: usize,
    /// Sensor noise of the generated sequences: none or kinect.
    #[arg(long, default_value = "kinect")]
    pub noise: String,
    /// Folder of photos and person cut-outs for the generator (e.g.
    /// ../shared/data/tum/fr3_walking_xyz_first_frame: a real photographed person).
    #[arg(long)]
    pub textures: Option<PathBuf>,
    /// Where the sequences and trajectories go (kept; a sequence already there is reused).
    #[arg(long)]
    pub out: PathBuf,
    /// YOLOX ONNX model for the yolox mode (else the default search).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Runs at a time.
    #[arg(long, default_value_t = 2)]
    pub jobs: usize,
    /// Local mapping in its own thread, as `run` maps a camera or `--realtime` (by default each
    /// run is `run`'s default on a recording, which does not depend on timing).
    #[arg(long)]
    pub threaded: bool,
    /// Run each sequence monocular (its depth withheld; ATE after a Sim(3) alignment), in a
    /// `PRESET_sSEED_mono` folder of links beside it.
    #[arg(long)]
    pub monocular: bool,
    /// Run each sequence as a rectified stereo pair (0.10 m baseline, the street's 0.54 m;
    /// read as KITTI).
    #[arg(long, conflicts_with = "monocular")]
    pub stereo: bool,
    /// Blind the camera for a span of frames while it moves on: START+FRAMES (a covered lens)
    /// or START+FRAMES:wall (a blank wall), as `synth --blind`; tracking is lost, a new map
    /// starts, and should merge with the first when the path comes back.
    #[arg(long)]
    pub blind: Option<stillpoint_synth::Blind>,
    /// Also write each run's dense cloud and measure it: points on movers and distance to the
    /// scene's true static surfaces.
    #[arg(long)]
    pub dense: bool,
    /// The settings tree's layers over each sequence's own, as `run` takes them (every run
    /// gets them; `--threaded` is `--set slam.local_mapping_thread=true`).
    #[command(flatten)]
    pub layers: crate::cmd::run::SettingsArgs,
    #[arg(long)]
    pub json: bool,
}

fn parse_seeds(s: &str) -> anyhow::Result<Vec<u64>> {
    if let Some((a, b)) = s.split_once('-') {
        let (a, b): (u64, u64) = (
            a.trim().parse().with_context(|| format!("--seeds {s:?}"))?,
            b.trim().parse().with_context(|| format!("--seeds {s:?}"))?,
        );
        if a > b {
            bail!("--seeds {s:?}: empty range");
        }
        return Ok((a..=b).collect());
    }
    s.split(',')
        .map(|x| x.trim().parse().with_context(|| format!("--seeds {s:?}")))
        .collect()
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let seeds = parse_seeds(&args.seeds)?;
    let mut names: Vec<&str> = args.presets.iter().map(String::as_str).collect();
    if names.is_empty() {
        names = vec![
            "living_cross",
            "living_close",
            "living_turn",
            "living_empty",
        ];
        if args.monocular {
            names.push("street");
        }
    }
    let presets: Vec<Preset> = names
        .iter()
        .map(|p| {
            Preset::from_name(p).with_context(|| {
                let names: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
                format!("unknown preset {p:?}; known: {}", names.join(", "))
            })
        })
        .collect::<anyhow::Result<_>>()?;
    let noise = match args.noise.as_str() {
        "none" => Noise::None,
        "kinect" => Noise::Kinect(KinectNoise::default()),
        other => bail!("--noise {other:?}: expected none or kinect"),
    };
    let rows = run_matrix(&MatrixOptions {
        presets,
        seeds,
        modes: args.modes.clone(),
        frames: args.frames,
        noise,
        textures: args.textures.clone(),
        out: args.out.clone(),
        model: args.model.clone(),
        jobs: args.jobs,
        threaded: args.threaded,
        monocular: args.monocular,
        stereo: args.stereo,
        blind: args.blind,
        dense: args.dense,
        layers: stillpoint_run::Overrides {
            config: args.layers.config.clone(),
            sets: args.layers.sets.clone(),
            ..Default::default()
        },
        stop: Some(crate::interrupt_flag()),
    })?;
    if args.json {
        println!("{}", serde_json::to_string(&rows)?);
    } else {
        print_table(&rows, &args.modes);
    }
    if rows.iter().any(|r| r.error.is_some()) {
        for r in rows.iter().filter(|r| r.error.is_some()) {
            eprintln!(
                "{} seed {} {}: {}",
                r.preset,
                r.seed,
                r.mode,
                r.error.as_deref().unwrap_or("")
            );
        }
        bail!("some runs failed");
    }
    Ok(())
}

fn print_table(rows: &[Row], modes: &[String]) {
    let cell = |r: Option<&Row>| match r {
        Some(r) => match (r.ate_cm, r.movers_share()) {
            (Some(a), Some(m)) => format!("{a:7.2} ({:4.1}%)", 100.0 * m),
            (Some(a), None) => format!("{a:7.2}        "),
            _ => "  failed       ".to_string(),
        },
        None => String::new(),
    };
    print!("{:<16} {:>4} {:>7}", "preset", "seed", "tracked");
    for m in modes {
        print!(" {:>15}", format!("{m} ATE cm (movers)"));
    }
    println!();
    let mut keys: Vec<(&str, u64)> = rows.iter().map(|r| (r.preset.as_str(), r.seed)).collect();
    keys.dedup();
    for (p, s) in &keys {
        let of = |m: &str| {
            rows.iter()
                .find(|r| r.preset == *p && r.seed == *s && r.mode == m)
        };
        // Maps made > merged + 1: frames of a map that never merged are not in the trajectory.
        let tracked = modes
            .iter()
            .filter_map(|m| of(m))
            .map(|r| match r.maps_made {
                0 | 1 => format!("{}", r.tracked),
                made => format!("{} [{made} maps, {} merged]", r.tracked, r.maps_merged),
            })
            .collect::<Vec<_>>()
            .join("/");
        print!("{p:<16} {s:>4} {tracked:>7}");
        for m in modes {
            print!(" {:>15}", cell(of(m)));
        }
        println!();
    }
    if rows.iter().any(|r| r.dense.is_some()) {
        println!(
            "\ndense cloud: points, on movers, distance to the static scene (median / p95 cm, \
             share within 2 cm; with true poses and masks)"
        );
        for r in rows {
            let Some(d) = &r.dense else { continue };
            print!(
                "{:<16} {:>4} {:<6} {:>9}",
                r.preset, r.seed, r.mode, d.points
            );
            match d.on_movers {
                Some(m) => print!(" {m:>7}"),
                None => print!(" {:>7}", "-"),
            }
            match &d.distance {
                Some(x) => {
                    let cell = |x: &stillpoint_eval::surface::CloudDistance| {
                        format!(
                            "{:6.2} / {:6.2}  {:5.1}%",
                            100.0 * x.median_m,
                            100.0 * x.p95_m,
                            100.0 * x.within_2cm
                        )
                    };
                    let truth = d.distance_true_poses.as_ref().map(cell).unwrap_or_default();
                    println!(" {}   ({truth})", cell(x));
                }
                None => println!("  (no ground truth)"),
            }
        }
    }
    // Per preset: the worst seed of each mode.
    let mut presets: Vec<&str> = rows.iter().map(|r| r.preset.as_str()).collect();
    presets.dedup();
    println!("\nworst seed per preset (ATE cm; map points on movers, worst share):");
    for p in presets {
        print!("{p:<16}");
        for m in modes {
            let rs: Vec<&Row> = rows
                .iter()
                .filter(|r| r.preset == p && r.mode == *m)
                .collect();
            let worst = rs.iter().filter_map(|r| r.ate_cm).fold(f64::NAN, f64::max);
            let movers = rs
                .iter()
                .filter_map(|r| r.movers_share())
                .fold(f64::NAN, f64::max);
            print!(
                "  {m}: {worst:.2} ({:.1}%)",
                if movers.is_nan() { 0.0 } else { 100.0 * movers }
            );
        }
        println!();
    }
}
