//! The simulator's commands (`demo`, `eval`, `query`): argument types and handlers, kept here so that
//! `main.rs` only dispatches. `query`'s handler is its own module ([`query()`]).

use super::experiment::Setup;
use super::methods::{Radio, D};
use super::scenes::{self, Report, Scene, SceneOptions, SceneSource};
use crate::cli_args::{MapArgs, TileArgs};
use crate::sim::vocab::Vocabulary;
use anyhow::{ensure, Context, Result};
use clap::{Args, ValueEnum};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod calibrate;
mod query;
pub use calibrate::{calibrate, config_const, device_needs, CalibrateArgs, DeviceNeeds};
pub use query::query;

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

/// `demo` options.
#[derive(Args, Debug, Clone)]
pub struct DemoArgs {
    /// Output directory for results.md and the PNGs.
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Seed of the run (network noise, hold-out split, sensor subsampling).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// The point cloud and the flight.
    #[command(flatten)]
    pub tile: TileArgs,
    /// The map configuration.
    #[command(flatten)]
    pub map: MapArgs,
    /// The robot's link to the base station.
    #[command(flatten)]
    pub link: crate::demo_radio::LinkArgs,
    /// Watch the demo's base station live (`--view`) or record it (`--record FILE.mcap`).
    #[command(flatten)]
    pub view: crate::base_station::cli::ViewArgs,
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

fn write_results(out: &Path, reports: &[Report], command: &str) -> Result<PathBuf> {
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

fn print_report(r: &Report) {
    println!("{}", r.markdown);
    if let Some(hint) = &r.hint {
        println!("{hint}\n");
    }
    for f in &r.figures {
        println!("wrote {}", f.display());
    }
}

/// The map configuration `demo` will run with: the given one, or with `--las` the one chosen by validation
/// (or from the file's point spacing with `--scale spacing`): the base station's link must be set up with
/// the robot's configuration before the run. The choice is remembered, so the run does not repeat it.
pub fn demo_config(args: &DemoArgs) -> Result<latentbki::MapConfig> {
    if args.tile.las.is_none() && args.tile.scale.is_none() {
        return args.map.config();
    }
    let options = SceneOptions {
        quiet: true,
        ..demo_options(args)?
    };
    let mut source = SceneSource::new(Scene::Tile, &options, args.seed)?;
    if source.validates_scale().is_none() {
        return Ok(source.config());
    }
    let setup = demo_setup(args);
    let (train, test) = source.train_and_test()?;
    let dec = super::experiment::decoding(&Vocabulary::builtin(), &train, &setup)?;
    let frames = super::experiment::encode(&test, &dec, &setup);
    Ok(source.resolve_config(&frames, &dec, &setup)?.0)
}

fn demo_setup(args: &DemoArgs) -> Setup {
    Setup {
        seed: args.seed,
        ..Setup::default()
    }
}

fn demo_options(args: &DemoArgs) -> Result<SceneOptions> {
    Ok(SceneOptions {
        tile: args.tile.clone(),
        tile_config: args.map.config()?,
        tile_map: args.tile.las.as_ref().map(|_| args.map.clone()),
        ..SceneOptions::default()
    })
}

/// `demo`: the real tile, default configuration, the on-device map, the table and the pictures.
///
/// The robot's link goes to `link`: the base station's simulated radio plugs in here. Returns the report
/// (its methods' maps, e.g. the f32 reference the radio compares the base station with).
pub fn demo(args: &DemoArgs, link: Option<Box<dyn Radio>>) -> Result<scenes::Report> {
    let start = Instant::now();
    let setup = demo_setup(args);
    let options = demo_options(args)?;
    match &args.tile.las {
        None => println!("LatentBKI demo: a robot maps the real labelled LiDAR tile (ASPRS classes) with a simulated vision-language network."),
        Some(p) => println!("LatentBKI demo: a robot maps {} (ASPRS classes) with a simulated vision-language network.", p.display()),
    }
    let report = scenes::run(Scene::Tile, &options, &setup, &args.out, true, link)?;
    print_report(&report);
    let path = write_results(&args.out, std::slice::from_ref(&report), "demo")?;
    println!("wrote {}", path.display());
    println!("done in {:.1} s", start.elapsed().as_secs_f64());
    Ok(report)
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
    let vocab = Vocabulary::builtin();
    for q in &args.queries {
        vocab.get(q)?;
    }
    let mut setup = Setup {
        seed: args.seed,
        ..Setup::default()
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
        SceneArg::Tile => vec![Scene::Tile],
        SceneArg::Indoor => vec![Scene::Indoor],
        SceneArg::Both => vec![Scene::Tile, Scene::Indoor],
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
