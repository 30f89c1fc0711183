//! `host-sim`: the command line of the desktop twin.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use host_sim::cli_args::MapArgs;
use host_sim::las_frame::{is_point_cloud, read_cloud_frame};
use host_sim::npy_io::{read_frame, read_poses, write_map_npz, Compression, Frame};
use host_sim::sim::tile::LengthUnit;
use host_sim::{ObsMap, ReferenceMap};
use latentbki::nalgebra::Isometry3;
use latentbki::{KernelMode, MapConfig};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "host-sim",
    version,
    about = "LatentBKI desktop twin: simulator, evaluation, base station"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Integrate recorded frames ((N, 3+D) float32 .npy, xyz then feature; or .las/.laz clouds with an
    /// (N, D) .npy of features beside each) into a map; write it as .npz.
    Integrate(IntegrateArgs),
    /// The main job for a newcomer: a robot maps the real LiDAR tile; prints the results table and writes
    /// the pictures (out/).
    Demo(host_sim::eval::cli::DemoArgs),
    /// The paper's experiments on the tile and the procedural house: table, sweep, curves, pictures.
    Eval(host_sim::eval::cli::EvalArgs),
    /// Exploration: the robot picks its next view by information gain, against random and nearest-frontier
    /// choice; accuracy vs distance driven (out/explore.png).
    Explore(host_sim::explore::ExploreArgs),
    /// The map scale for a robot over a labelled tile, chosen by validation, printed as the `const
    /// MapConfig` a firmware pastes, with the RAM its map needs and whether its window holds the range.
    Calibrate(host_sim::eval::cli::CalibrateArgs),
    /// Map a scene and show where a free-text query (a committed-vocabulary phrase) matches.
    Query(host_sim::eval::cli::QueryArgs),
    /// Receive robots' streams (serial port, file, pty or stdin) into the global map database (SQLite,
    /// crash-safe); export PNG/PLY.
    BaseStation(host_sim::base_station::cli::BaseStationArgs),
    /// Measure the headline speed figures on this machine (one core, medians): integrate, gather.
    Bench(host_sim::bench::BenchArgs),
    /// The live view's cost: the full scene of a 100k-voxel map (build + encode, one layer).
    ViewBench(host_sim::view_bench::ViewBenchArgs),
    /// Summarise a map database (read-only: works while a base station writes it).
    MapInfo(host_sim::base_station::cli::MapInfoArgs),
    /// Labels, a text query and PNG/PLY exports of a map database (read-only: works while a base station
    /// writes it).
    MapQuery(host_sim::base_station::cli::MapQueryArgs),
    /// Merge map databases into a new one: the map one base station would hold had it received every
    /// frame of each (refuses maps of different configurations).
    MapMerge(host_sim::base_station::cli::MapMergeArgs),
    /// The feature space of a robot's classes: the PCA the base station decodes with (DIR/pca.npz), the
    /// firmware's constants (DIR/feature_space.rs: id, int8 scale, per-class int8 prototypes).
    FeatureSpace(host_sim::feature_space::FeatureSpaceArgs),
    /// Re-embed the vocabulary with the real text encoder and write the table (feature `encoder`).
    #[cfg(feature = "encoder")]
    EmbedVocab(EmbedVocabArgs),
}

/// `embed-vocab`: the project tool that produced `host-sim/data/text-embeddings.tsv`.
#[cfg(feature = "encoder")]
#[derive(Args, Debug)]
struct EmbedVocabArgs {
    /// Output table.
    #[arg(long, default_value = "host-sim/data/text-embeddings.tsv")]
    out: PathBuf,
    /// Phrases to embed (default: every phrase of the committed table, in order, then the ASPRS class
    /// names it lacks).
    phrases: Vec<String>,
}

#[derive(Args, Debug)]
struct IntegrateArgs {
    /// Frames, applied as batches in the order given: (N, 3+D) float32 .npy files, or .las/.laz point
    /// clouds, each with its features in the .npy of the same name beside it ((N, D) float32, row i =
    /// point i; coordinates become metres from the first cloud's minimum corner).
    #[arg(required = true)]
    frames: Vec<PathBuf>,
    /// Units of .las/.laz coordinates [default: from the file's CRS (WKT, else GeoTIFF keys); metres if it
    /// has none].
    #[arg(long, value_enum)]
    units: Option<LengthUnit>,
    /// Output .npz with arrays keys (V×3 int32), lambda (V), mean (V×D), psi (V×D).
    #[arg(long, short)]
    out: PathBuf,
    /// Optional pose file: one `tx ty tz qx qy qz qw` line (sensor → map) per frame. Without it, points are
    /// taken to be in the map frame already.
    #[arg(long)]
    poses: Option<PathBuf>,
    /// Deflate the .npz members (numpy's `savez_compressed`; smaller, much slower to write). Default:
    /// stored, as numpy's `savez`.
    #[arg(long)]
    compress: bool,
    #[command(flatten)]
    map: MapArgs,
}

/// The map `integrate` builds: per-voxel observation statistics gathered on output (voxel-offset kernel),
/// or the literal paper update for the sub-voxel kernel, which per-voxel statistics cannot express.
enum IntegrateMap<const D: usize> {
    Observations(Box<ObsMap<D>>),
    Reference(ReferenceMap<D>),
}

impl<const D: usize> IntegrateMap<D> {
    fn new(config: MapConfig) -> Result<Self> {
        Ok(match config.mode() {
            KernelMode::VoxelOffset => Self::Observations(Box::new(ObsMap::new(config)?)),
            KernelMode::SubVoxel { .. } => Self::Reference(ReferenceMap::new(config)?),
        })
    }
    fn integrate(&mut self, pose: &Isometry3<f32>, points: &[[f32; 3]], features: &[[f32; D]]) {
        match self {
            Self::Observations(m) => m.integrate(pose, points, features),
            Self::Reference(m) => m.integrate(pose, points, features),
        };
    }
    fn points(&self) -> u64 {
        match self {
            Self::Observations(m) => m.points(),
            Self::Reference(m) => m.points(),
        }
    }
    fn rejections(&self) -> latentbki::RejectionCounts {
        match self {
            Self::Observations(m) => m.rejections(),
            Self::Reference(m) => m.rejections(),
        }
    }
    /// Every voxel in reach of an observation, with its posterior, sorted by key.
    fn posteriors(&self) -> Vec<(latentbki::key::VoxelKey, latentbki::stats::VoxelStats<D>)> {
        match self {
            Self::Observations(m) => m.posteriors_sorted(),
            Self::Reference(m) => m.sorted().into_iter().map(|(k, s)| (k, *s)).collect(),
        }
    }
}

/// Reads each frame by its kind; point clouds share the first one's origin.
struct FrameLoader {
    units: Option<LengthUnit>,
    origin: Option<[f64; 3]>,
}

impl FrameLoader {
    fn load(&mut self, path: &std::path::Path) -> Result<Frame> {
        if !is_point_cloud(path) {
            return Ok(read_frame(path)?);
        }
        let cloud = read_cloud_frame(path, self.units, self.origin)?;
        if self.origin.is_none() {
            let o = cloud.origin;
            println!(
                "{}: units {}; positions in metres from the origin ({}, {}, {}) in file units (its minimum corner), D = {}",
                path.display(),
                cloud.units.describe(),
                o[0],
                o[1],
                o[2],
                cloud.frame.dim
            );
            self.origin = Some(o);
        }
        Ok(cloud.frame)
    }
}

fn integrate<const D: usize>(
    args: &IntegrateArgs,
    config: MapConfig,
    first: Frame,
    loader: &mut FrameLoader,
) -> Result<()> {
    let poses = match &args.poses {
        Some(p) => {
            let poses = read_poses(p)?;
            if poses.len() != args.frames.len() {
                bail!(
                    "{}: {} poses for {} frames",
                    p.display(),
                    poses.len(),
                    args.frames.len()
                );
            }
            poses
        }
        None => vec![Isometry3::identity(); args.frames.len()],
    };
    let mut map = IntegrateMap::<D>::new(config)?;
    let mut frame = Some(first);
    for (i, path) in args.frames.iter().enumerate() {
        let f = match frame.take() {
            Some(f) => f,
            None => loader.load(path)?,
        };
        if f.dim != D {
            return Err(host_sim::npy_io::IoError::DimensionMismatch {
                path: path.clone(),
                expected: D,
                found: f.dim,
            }
            .into());
        }
        let features: Vec<[f32; D]> = f
            .features
            .chunks_exact(D)
            .map(|c| c.try_into().expect("chunks_exact gives D values"))
            .collect();
        map.integrate(&poses[i], &f.positions, &features);
    }
    let r = map.rejections();
    let reasons = format!(
        "non-finite position {}, non-finite feature {}, out of range {}",
        r.non_finite_position, r.non_finite_feature, r.key_out_of_range
    );
    if map.points() == 0 {
        // An empty map is never what was meant: say why instead of writing one.
        bail!(
            "no point was integrated: {} rejected ({reasons}) in {} frames; nothing written to {}",
            r.total(),
            args.frames.len(),
            args.out.display()
        );
    }
    let voxels = map.posteriors();
    let refs: Vec<_> = voxels.iter().map(|(k, s)| (*k, s)).collect();
    let compression = if args.compress {
        Compression::Deflated
    } else {
        Compression::Stored
    };
    write_map_npz(&args.out, &refs, compression)?;
    println!(
        "integrated {} points from {} frames into {} voxels (D = {D}); rejected {} ({reasons})",
        map.points(),
        args.frames.len(),
        voxels.len(),
        r.total(),
    );
    println!("wrote {}", args.out.display());
    Ok(())
}

/// A user's mistake — bad input, a file that cannot be used — is one line on stderr and exit status 1,
/// with no backtrace even when `RUST_BACKTRACE=1` is set (returning the error from `main` would print
/// anyhow's backtrace under it). Our own bugs panic, and the panic hook still prints their backtrace.
fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("Error: {}", one_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line (`outer: inner`), any line breaks inside them folded.
fn one_line(e: &anyhow::Error) -> String {
    format!("{e:#}")
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}

fn run() -> Result<()> {
    match Cli::parse().command {
        // The robot's link: a simulated faulty serial link both ways to a base station.
        Command::Demo(args) => {
            let session = latentbki::wire::SessionConfig::new(
                &host_sim::eval::cli::demo_config(&args)?,
                host_sim::eval::methods::D,
                host_sim::demo_radio::CODEC,
                latentbki::wire::NO_FEATURE_SPACE,
            );
            let radio = host_sim::demo_radio::DemoRadio::new(session, &args.link)?;
            // The view decodes once the run has fitted the robot's feature space (`Radio::feature_space`).
            if let Some(v) = host_sim::base_station::cli::start_view(&args.view, None, None)? {
                radio
                    .lock()
                    .map_err(|_| anyhow::anyhow!("link state poisoned"))?
                    .attach_viewer(v);
            }
            let link = host_sim::demo_radio::DemoRadioLink(radio.clone());
            let report = host_sim::eval::cli::demo(&args, Some(Box::new(link)))?;
            let mut radio = radio
                .lock()
                .map_err(|_| anyhow::anyhow!("link state poisoned"))?;
            // The f32 reference of all points: the LatentBKI f32 map at the robot's filter size.
            let f = host_sim::eval::cli::demo_config(&args)?.filter_size();
            if let Some(r) = report
                .results
                .iter()
                .find(|r| r.method == host_sim::eval::experiment::Method::LatentBki(f))
            {
                radio.compare_reference(&r.mapper.snapshot());
            }
            println!("{}", radio.summary());
            let viewer = radio.take_viewer();
            drop(radio);
            if let Some(v) = viewer {
                host_sim::base_station::cli::serve_until_interrupted(v, &args.view)?;
            }
            Ok(())
        }
        Command::Eval(args) => host_sim::eval::cli::eval(&args),
        Command::Calibrate(args) => host_sim::eval::cli::calibrate(&args),
        Command::Bench(args) => host_sim::bench::run(&args),
        Command::ViewBench(args) => host_sim::view_bench::run(&args),
        Command::Explore(args) => host_sim::explore::explore(&args),
        Command::Query(args) => host_sim::eval::cli::query(&args),
        #[cfg(feature = "encoder")]
        Command::EmbedVocab(args) => {
            let phrases = if args.phrases.is_empty() {
                // The committed phrases in their order, then any ASPRS class name the table lacks.
                let mut phrases = host_sim::sim::vocab::Vocabulary::builtin().phrases();
                for p in host_sim::sim::tile::asprs_phrases() {
                    if !phrases.iter().any(|q| q == p) {
                        phrases.push(p.to_string());
                    }
                }
                phrases
            } else {
                args.phrases.clone()
            };
            let refs: Vec<&str> = phrases.iter().map(String::as_str).collect();
            host_sim::text_encoder::write_table(&args.out, &refs)?;
            println!("wrote {} embeddings to {}", refs.len(), args.out.display());
            Ok(())
        }
        Command::BaseStation(args) => host_sim::base_station::cli::run(&args),
        Command::MapInfo(args) => host_sim::base_station::cli::map_info(&args),
        Command::MapQuery(args) => host_sim::base_station::cli::map_query(&args),
        Command::MapMerge(args) => host_sim::base_station::cli::map_merge(&args),
        Command::FeatureSpace(args) => host_sim::feature_space::run(&args),
        Command::Integrate(args) => {
            let config = args.map.config()?;
            let clouds = args.frames.iter().filter(|p| is_point_cloud(p)).count();
            if clouds != 0 && clouds != args.frames.len() {
                bail!("give either .npy frames or .las/.laz clouds, not both ({clouds} of {} frames are clouds)", args.frames.len());
            }
            let mut loader = FrameLoader {
                units: args.units,
                origin: None,
            };
            let first = loader
                .load(&args.frames[0])
                .context("reading the first frame")?;
            // The map is generic over D at compile time; these are the dimensions the CLI carries.
            macro_rules! by_dim {
                ($($d:literal)*) => {
                    match first.dim {
                        $($d => integrate::<$d>(&args, config, first, &mut loader),)*
                        other => bail!("feature dimension {other} is not compiled in; supported: {:?}", [$($d),*]),
                    }
                };
            }
            by_dim!(1 2 3 4 8 16 32 64 128 256 384 512 768)
        }
    }
}
