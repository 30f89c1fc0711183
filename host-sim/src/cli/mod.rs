//! `host-sim`'s commands, all in one place: the command line (`Cli`), and one module per command or
//! family of commands, each with its options and its handler. `main.rs` only calls [`main`]. The rest of
//! the crate is the library the commands are built from; nothing below this module imports it.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod bench;
pub mod calibrate;
pub mod demo;
pub mod eval;
pub mod explore;
pub mod feature_space;
pub mod integrate;
pub mod query;
pub mod station;
mod view_bench;

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
    Integrate(integrate::IntegrateArgs),
    /// The main job for a newcomer: a robot maps the real LiDAR tile; prints the results table and writes
    /// the pictures (out/).
    Demo(demo::DemoArgs),
    /// The paper's experiments on the tile and the procedural house: table, sweep, curves, pictures.
    Eval(eval::EvalArgs),
    /// Exploration: the robot picks its next view by information gain, against random and nearest-frontier
    /// choice; accuracy vs distance driven (out/explore.png).
    Explore(explore::ExploreArgs),
    /// The map scale for a robot over a labelled tile, chosen by validation, printed as the `const
    /// MapConfig` a firmware pastes, with the RAM its map needs and whether its window holds the range.
    Calibrate(calibrate::CalibrateArgs),
    /// Map a scene and show where a free-text query (a committed-vocabulary phrase) matches.
    Query(eval::QueryArgs),
    /// Receive robots' streams (serial port, file, pty or stdin) into the global map database (SQLite,
    /// crash-safe); export PNG/PLY.
    BaseStation(station::BaseStationArgs),
    /// Measure the headline speed figures on this machine (one core, medians): integrate, gather.
    Bench(bench::BenchArgs),
    /// The live view's cost: the full scene of a 100k-voxel map (build + encode, one layer).
    ViewBench(view_bench::ViewBenchArgs),
    /// Summarise a map database (read-only: works while a base station writes it).
    MapInfo(station::MapInfoArgs),
    /// Labels, a text query and PNG/PLY exports of a map database (read-only: works while a base station
    /// writes it).
    MapQuery(station::MapQueryArgs),
    /// Merge map databases into a new one: the map one base station would hold had it received every
    /// frame of each (refuses maps of different configurations).
    MapMerge(station::MapMergeArgs),
    /// The feature space of a robot's classes: the PCA the base station decodes with (DIR/pca.npz), the
    /// firmware's constants (DIR/feature_space.rs: id, int8 scale, per-class int8 prototypes).
    FeatureSpace(feature_space::FeatureSpaceArgs),
    /// Re-embed the vocabulary with the real text encoder and write the table (feature `encoder`).
    #[cfg(feature = "encoder")]
    EmbedVocab(EmbedVocabArgs),
}

/// `embed-vocab`: the project tool that produced `host-sim/data/text-embeddings.tsv`.
#[cfg(feature = "encoder")]
#[derive(clap::Args, Debug)]
struct EmbedVocabArgs {
    /// Output table.
    #[arg(long, default_value = "host-sim/data/text-embeddings.tsv")]
    out: std::path::PathBuf,
    /// Phrases to embed (default: every phrase of the committed table, in order, then the ASPRS class
    /// names it lacks).
    phrases: Vec<String>,
}

/// A user's mistake — bad input, a file that cannot be used — is one line on stderr and exit status 1,
/// with no backtrace even when `RUST_BACKTRACE=1` is set (returning the error from `main` would print
/// anyhow's backtrace under it). Our own bugs panic, and the panic hook still prints their backtrace.
pub fn main() -> std::process::ExitCode {
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
        Command::Demo(args) => demo::run(&args),
        Command::Eval(args) => eval::eval(&args),
        Command::Calibrate(args) => calibrate::calibrate(&args),
        Command::Bench(args) => bench::run(&args),
        Command::ViewBench(args) => view_bench::run(&args),
        Command::Explore(args) => explore::explore(&args),
        Command::Query(args) => query::query(&args),
        #[cfg(feature = "encoder")]
        Command::EmbedVocab(args) => {
            let phrases = if args.phrases.is_empty() {
                // The committed phrases in their order, then any ASPRS class name the table lacks.
                let mut phrases = crate::sim::vocab::TextEmbeddings::builtin().phrases();
                for p in crate::sim::tile::asprs_phrases() {
                    if !phrases.iter().any(|q| q == p) {
                        phrases.push(p.to_string());
                    }
                }
                phrases
            } else {
                args.phrases.clone()
            };
            let refs: Vec<&str> = phrases.iter().map(String::as_str).collect();
            crate::text_encoder::write_table(&args.out, &refs)?;
            println!("wrote {} embeddings to {}", refs.len(), args.out.display());
            Ok(())
        }
        Command::BaseStation(args) => station::run(&args),
        Command::MapInfo(args) => station::map_info(&args),
        Command::MapQuery(args) => station::map_query(&args),
        Command::MapMerge(args) => station::map_merge(&args),
        Command::FeatureSpace(args) => feature_space::run(&args),
        Command::Integrate(args) => integrate::run(&args),
    }
}
