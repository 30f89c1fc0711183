//! `host-sim eval`: the paper's experiments on the tile and the house (and `--scene changing`), with the
//! options `eval` and `query` share; `query`'s handler is [`super::query`], `demo`'s [`super::demo`].

use crate::cli_args::{MapArgs, TileArgs};
use crate::eval::experiment::ExperimentSettings;
use crate::eval::scenes::{self, Report, SceneKind, SceneOptions};
use crate::sim::vocab::{TextEmbeddings, D};
use anyhow::{ensure, Context, Result};
use clap::{Args, ValueEnum};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Which scenes `eval` runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SceneArg {
    /// The real labelled LiDAR tile.
    Tile,
    /// The procedural house.
    Indoor,
    /// Both.
    Both,
    /// The house whose furniture changes class between two loops: forgetting on and off.
    Changing,
}

/// `eval` options.
#[derive(Args, Debug, Clone)]
pub struct EvalArgs {
    /// Scenes to evaluate [default: both; only the tile with --las].
    #[arg(long, value_enum)]
    pub scene: Option<SceneArg>,
    /// Output directory for results.md and the PNGs.
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Seed of the run.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Frames flown over the tile [default: 60 on the loop; on the survey (--las), planned from the tile so
    /// that each surface is observed by about as many frames as on the built-in tile].
    #[arg(long)]
    pub frames: Option<usize>,
    /// LiDAR points per frame on the tile.
    #[arg(long, default_value_t = 3000)]
    pub points: usize,
    /// Camera pixels per frame indoors (1 % of 640 × 480 by default, as VLMap).
    #[arg(long, default_value_t = 3072)]
    pub pixels: usize,
    /// Seed of the house layout.
    #[arg(long, default_value_t = 1)]
    pub layout_seed: u64,
    /// `--scene changing`: the forgetting half-life in frames [default: four loops of the house].
    #[arg(long)]
    pub half_life: Option<u32>,
    /// Indoors, use the 8 × 8 multizone ToF sensor instead of the depth camera.
    #[arg(long)]
    pub tof: bool,
    /// Skip the sparsity sweep.
    #[arg(long)]
    pub no_sweep: bool,
    /// Free-text queries to picture (words of the committed vocabulary); default one per scene.
    #[arg(long = "query")]
    pub queries: Vec<String>,
    /// Probability that a segment is mislabelled in a block of frames (the simulated network's error model).
    #[arg(long, allow_negative_numbers = true)]
    pub confusion_probability: Option<f32>,
    /// Expected norm of per-point feature noise relative to the unit text embedding.
    #[arg(long, allow_negative_numbers = true)]
    pub feature_noise: Option<f32>,
    /// The tile scene's point cloud and flight.
    #[command(flatten)]
    pub tile: TileArgs,
    /// The tile scene's map configuration (the indoor scene keeps the paper's indoor one: 0.05 m voxels).
    #[command(flatten)]
    pub map: MapArgs,
}

impl EvalArgs {
    /// The scenes to run: `--scene`, else both, or only the tile when `--las` names one.
    pub fn scene(&self) -> SceneArg {
        self.scene.unwrap_or(if self.tile.las.is_some() {
            SceneArg::Tile
        } else {
            SceneArg::Both
        })
    }
}

/// `query` options.
#[derive(Args, Debug, Clone)]
pub struct QueryArgs {
    /// Text to look for (a phrase of the committed vocabulary).
    pub text: String,
    /// Scene to map and query (`tile` or `indoor`; one scene at a time).
    #[arg(long, value_enum, default_value = "tile")]
    pub scene: SceneArg,
    /// Output directory for the heat map.
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Seed of the run.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// The tile scene's point cloud and flight.
    #[command(flatten)]
    pub tile: TileArgs,
    /// The tile scene's map configuration.
    #[command(flatten)]
    pub map: MapArgs,
}

pub(super) fn write_results(out: &Path, reports: &[Report], command: &str) -> Result<PathBuf> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut md =
        format!("## Results\n\nProduced by `cargo run --release -p host-sim -- {command}`.\n\n");
    for r in reports {
        md += &r.markdown;
        md += "\n";
    }
    let path = out.join("results.md");
    std::fs::write(&path, md).with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

pub(super) fn print_report(r: &Report) {
    println!("{}", r.markdown);
    if let Some(hint) = &r.hint {
        println!("{hint}\n");
    }
    for f in &r.figures {
        println!("wrote {}", f.display());
    }
}

/// `eval`: both scenes (or one), every method, the sweep, the curves and the pictures.
pub fn eval(args: &EvalArgs) -> Result<()> {
    let start = Instant::now();
    // The PCA fits D components on the training sequence's features: it needs more than D of them.
    let pca_min = D + 1;
    ensure!(args.frames != Some(0), "--frames must be at least 1");
    ensure!(args.points >= 1, "--points must be at least 1");
    ensure!(args.pixels >= 1, "--pixels must be at least 1");
    let scene = args.scene();
    if scene == SceneArg::Changing {
        let outcome =
            crate::changing::run(args.layout_seed, args.seed, args.pixels, args.half_life)?;
        crate::changing::report(&outcome);
        return Ok(());
    }
    let tile_config = args.map.config()?;
    if scene == SceneArg::Indoor {
        ensure!(
            args.tile == TileArgs::default(),
            "--las, --units, --range and --altitude describe the tile scene; --scene indoor does not run it"
        );
        ensure!(
            tile_config == latentbki::MapConfig::default(),
            "the map options (--voxel-size …) apply to the tile scene; --scene indoor uses the paper's indoor configuration"
        );
    }
    if let (true, Some(frames)) = (scene != SceneArg::Indoor, args.frames) {
        ensure!(
            frames.saturating_mul(args.points) >= pca_min,
            "--frames × --points is {} × {}: the tile needs at least {pca_min} points in all to fit the {D}-component PCA",
            frames,
            args.points
        );
    }
    let vocab = TextEmbeddings::builtin();
    for q in &args.queries {
        vocab.get(q)?;
    }
    let mut setup = ExperimentSettings {
        seed: args.seed,
        ..ExperimentSettings::default()
    };
    if let Some(p) = args.confusion_probability {
        anyhow::ensure!(
            (0.0..=1.0).contains(&p),
            "--confusion-probability must be in [0, 1]"
        );
        setup.noise.confusion_probability = p;
    }
    if let Some(n) = args.feature_noise {
        anyhow::ensure!(n >= 0.0 && n.is_finite(), "--feature-noise must be >= 0");
        setup.noise.feature_noise = n;
    }
    // The output folder first: finding it unusable after the runs would waste them.
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("--out: cannot create the folder {}", args.out.display()))?;
    let options = SceneOptions {
        tile_frames: args.frames.unwrap_or(SceneOptions::default().tile_frames),
        plan_frames: args.frames.is_none(),
        tile_points: args.points,
        indoor_pixels: args.pixels,
        layout_seed: args.layout_seed,
        indoor_tof: args.tof,
        queries: args.queries.clone(),
        tile: args.tile.clone(),
        tile_config,
        tile_map: args.tile.las.as_ref().map(|_| args.map.clone()),
        ..SceneOptions::default()
    };
    let scenes = match scene {
        SceneArg::Tile => vec![SceneKind::Tile],
        SceneArg::Indoor => vec![SceneKind::Indoor],
        SceneArg::Both => vec![SceneKind::Tile, SceneKind::Indoor],
        SceneArg::Changing => Vec::new(), // run above
    };
    let mut reports = Vec::new();
    for s in scenes {
        let r = scenes::run(s, &options, &setup, &args.out, !args.no_sweep, None)?;
        print_report(&r);
        reports.push(r);
    }
    let path = write_results(&args.out, &reports, "eval")?;
    println!("wrote {}", path.display());
    println!("done in {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eval_args(out: &Path) -> EvalArgs {
        EvalArgs {
            scene: Some(SceneArg::Tile),
            out: out.to_owned(),
            seed: 7,
            frames: Some(2),
            points: 100,
            pixels: 100,
            layout_seed: 1,
            half_life: None,
            tof: false,
            no_sweep: true,
            queries: Vec::new(),
            confusion_probability: None,
            feature_noise: None,
            tile: TileArgs::default(),
            map: MapArgs::default(),
        }
    }

    #[test]
    fn eval_refuses_empty_budgets() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let err = |change: fn(&mut EvalArgs)| {
            let mut args = eval_args(&out);
            change(&mut args);
            eval(&args).unwrap_err().to_string()
        };
        // `--frames 0` ran one frame; `--points 0|1`, `--pixels 0` failed deep inside the PCA.
        assert_eq!(err(|a| a.frames = Some(0)), "--frames must be at least 1");
        assert_eq!(err(|a| a.points = 0), "--points must be at least 1");
        assert_eq!(err(|a| a.pixels = 0), "--pixels must be at least 1");
        let e = err(|a| {
            a.points = 1;
            a.frames = Some(60);
        });
        assert!(
            e.contains("60 × 1") && e.contains("at least 65 points"),
            "{e}"
        );
        // Indoors the tile's budget does not matter.
        let e = err(|a| {
            a.scene = Some(SceneArg::Indoor);
            a.points = 1;
            a.pixels = 0;
        });
        assert_eq!(e, "--pixels must be at least 1");
        assert!(!out.exists(), "nothing is written");
    }
}
