//! `stillpoint bench matrix`: SLAM accuracy over synthetic presets x seeds x front-end modes
//! (off, perfect boxes, YOLOX), with the share of map points that lie on movers. Sequences are
//! generated in-process (with per-pixel masks, so map points on movers can be counted) into
//! `--out`, then each run goes through `run::run_sequence`, `--jobs` at a time.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, bail};
use stillpoint_synth::{KinectNoise, Noise, Preset, SynthConfig, WriteOptions};

use crate::cmd::run::{RunOptions, accuracy, run_sequence};

#[derive(clap::Args)]
pub struct Args {
    /// Presets, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "living_cross,living_close,living_turn,living_empty"
    )]
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
    /// Local mapping in its own thread (the default of `run`); sequential by default here, so
    /// that tables are reproducible.
    #[arg(long)]
    pub threaded: bool,
    #[arg(long)]
    pub json: bool,
}

/// One run of the matrix.
#[derive(Clone, Debug, serde::Serialize)]
struct Row {
    preset: String,
    seed: u64,
    mode: String,
    ate_cm: Option<f64>,
    tracked: usize,
    frames: usize,
    first_tracked: Option<usize>,
    map_points: usize,
    map_points_on_movers: Option<usize>,
    error: Option<String>,
}

impl Row {
    fn movers_share(&self) -> Option<f64> {
        self.map_points_on_movers
            .map(|m| m as f64 / self.map_points.max(1) as f64)
    }
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

fn generate(args: &Args, preset: Preset, seed: u64, dir: &Path) -> anyhow::Result<()> {
    if dir.join("groundtruth.txt").is_file() && dir.join("mask").is_dir() {
        return Ok(());
    }
    let noise = match args.noise.as_str() {
        "none" => Noise::None,
        "kinect" => Noise::Kinect(KinectNoise::default()),
        other => bail!("--noise {other:?}: expected none or kinect"),
    };
    let cfg = SynthConfig {
        preset,
        frames: args.frames,
        seed,
        noise,
        textures: args.textures.clone(),
        ..SynthConfig::default()
    };
    let opts = WriteOptions {
        stereo: false,
        masks: true,
    };
    stillpoint_synth::write_sequence(&cfg, opts, dir).with_context(|| {
        format!(
            "writing {} seed {seed} into {}",
            preset.name(),
            dir.display()
        )
    })?;
    Ok(())
}

fn run_one(args: &Args, dir: &Path, mode: &str, out: PathBuf) -> anyhow::Result<Row> {
    let s = run_sequence(&RunOptions {
        realtime: false,
        dataset: dir.to_path_buf(),
        kind: None,
        settings: None,
        out: Some(out),
        detector: (mode != "off").then(|| mode.to_string()),
        sequential: !args.threaded,
        frames: None,
        progress: false,
        paper_cull: false,
        model: args.model.clone(),
        overrides: Default::default(),
    })?;
    let ate = accuracy(&s).map(|a| a.0.stats.rmse * 100.0);
    let first_tracked = s.ground_truth.as_ref().and_then(|gt| {
        let t0 = *s.trajectory.stamps.first()?;
        Some(gt.stamps.iter().filter(|&&t| t < t0 - 1e-6).count())
    });
    Ok(Row {
        preset: String::new(),
        seed: 0,
        mode: mode.to_string(),
        ate_cm: ate,
        tracked: s.tracked,
        frames: s.frames,
        first_tracked,
        map_points: s.map_points,
        map_points_on_movers: s.moving_map_points,
        error: None,
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let seeds = parse_seeds(&args.seeds)?;
    let presets: Vec<Preset> = args
        .presets
        .iter()
        .map(|p| {
            Preset::from_name(p).with_context(|| {
                let names: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
                format!("unknown preset {p:?}; known: {}", names.join(", "))
            })
        })
        .collect::<anyhow::Result<_>>()?;
    for m in &args.modes {
        if !["off", "gt", "yolox", "none"].contains(&m.as_str()) {
            bail!("--modes: unknown mode {m:?} (off, gt, yolox, none)");
        }
    }
    if args.frames == 0 || args.jobs == 0 {
        bail!("--frames and --jobs must be at least 1");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mut jobs = Vec::new();
    for p in &presets {
        for &seed in &seeds {
            let dir = args.out.join(format!("{}_s{seed}", p.name()));
            tracing::info!("generating {}", dir.display());
            generate(&args, *p, seed, &dir)?;
            for m in &args.modes {
                jobs.push((p.name().to_string(), seed, dir.clone(), m.clone()));
            }
        }
    }
    let next = AtomicUsize::new(0);
    let rows = Mutex::new(Vec::new());
    std::thread::scope(|sc| {
        for _ in 0..args.jobs.min(jobs.len()) {
            sc.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::SeqCst);
                    let Some((preset, seed, dir, mode)) = jobs.get(k) else {
                        break;
                    };
                    let out = args.out.join(format!("{preset}_s{seed}_{mode}.txt"));
                    tracing::info!("[{}/{}] {preset} seed {seed} {mode}", k + 1, jobs.len());
                    let mut row = run_one(&args, dir, mode, out).unwrap_or_else(|e| Row {
                        preset: String::new(),
                        seed: 0,
                        mode: mode.clone(),
                        ate_cm: None,
                        tracked: 0,
                        frames: args.frames,
                        first_tracked: None,
                        map_points: 0,
                        map_points_on_movers: None,
                        error: Some(format!("{e:#}")),
                    });
                    row.preset = preset.clone();
                    row.seed = *seed;
                    if let Ok(mut r) = rows.lock() {
                        r.push((k, row));
                    }
                }
            });
        }
    });
    let mut rows = rows.into_inner().unwrap_or_default();
    rows.sort_by_key(|(k, _)| *k);
    let rows: Vec<Row> = rows.into_iter().map(|(_, r)| r).collect();
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
        let tracked = modes
            .iter()
            .filter_map(|m| of(m))
            .map(|r| format!("{}", r.tracked))
            .collect::<Vec<_>>()
            .join("/");
        print!("{p:<16} {s:>4} {tracked:>7}");
        for m in modes {
            print!(" {:>15}", cell(of(m)));
        }
        println!();
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
