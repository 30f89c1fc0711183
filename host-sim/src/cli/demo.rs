//! `host-sim demo`, the main job for a newcomer: a robot maps the real tile with the on-device map and
//! streams it over a simulated faulty radio to a base station; the results table, the pictures and the
//! link's summary.

use super::eval::{print_report, write_results};
use crate::cli_args::{MapArgs, TileArgs};
use crate::eval::experiment::{self, ExperimentSettings, Method};
use crate::eval::methods::Radio;
use crate::eval::scenes::{self, SceneKind, SceneOptions, SceneSource};
use crate::sim::vocab::{TextEmbeddings, D};
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

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
    pub view: super::station::ViewArgs,
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
    let mut source = SceneSource::new(SceneKind::Tile, &options, args.seed)?;
    if source.validates_scale().is_none() {
        return Ok(source.config());
    }
    let setup = demo_setup(args);
    let (train, test) = source.train_and_test()?;
    let dec = experiment::decoding(&TextEmbeddings::builtin(), &train, &setup)?;
    let frames = experiment::encode(&test, &dec, &setup);
    Ok(source.resolve_config(&frames, &dec, &setup)?.0)
}

fn demo_setup(args: &DemoArgs) -> ExperimentSettings {
    ExperimentSettings {
        seed: args.seed,
        ..ExperimentSettings::default()
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
    let report = scenes::run(SceneKind::Tile, &options, &setup, &args.out, true, link)?;
    print_report(&report);
    let path = write_results(&args.out, std::slice::from_ref(&report), "demo")?;
    println!("wrote {}", path.display());
    println!("done in {:.1} s", start.elapsed().as_secs_f64());
    Ok(report)
}

/// `demo` with its radio: the robot's link is a simulated faulty serial link both ways to a base station,
/// which is compared with the f32 reference at the end (and served to a viewer with `--view`).
pub fn run(args: &DemoArgs) -> Result<()> {
    let session = latentbki::wire::SessionConfig::new(
        &demo_config(args)?,
        D,
        crate::demo_radio::CODEC,
        latentbki::wire::NO_FEATURE_SPACE,
    );
    let radio = crate::demo_radio::DemoRadio::new(session, &args.link)?;
    // The view decodes once the run has fitted the robot's feature space (`Radio::feature_space`).
    if let Some(v) = super::station::start_view(&args.view, None, None)? {
        radio
            .lock()
            .map_err(|_| anyhow::anyhow!("link state poisoned"))?
            .attach_viewer(v);
    }
    let link = crate::demo_radio::DemoRadioLink(radio.clone());
    let report = demo(args, Some(Box::new(link)))?;
    let mut radio = radio
        .lock()
        .map_err(|_| anyhow::anyhow!("link state poisoned"))?;
    // The f32 reference of all points: the LatentBKI f32 map at the robot's filter size.
    let f = demo_config(args)?.filter_size();
    if let Some(r) = report
        .results
        .iter()
        .find(|r| r.method == Method::LatentBki(f))
    {
        radio.compare_reference(&r.mapper.snapshot());
    }
    println!("{}", radio.summary());
    let viewer = radio.take_viewer();
    drop(radio);
    if let Some(v) = viewer {
        super::station::serve_until_interrupted(v, &args.view)?;
    }
    Ok(())
}
