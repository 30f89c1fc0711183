//! The `host-sim explore` command: every explorer on every seed of one house or several, the table, the
//! headline line per house, the plot; and over several houses one summary line, so that a claim about
//! exploration can be checked on houses the planner was not tuned on.

use crate::eval::experiment::{decoding, ExperimentSettings};
use crate::explore::{
    mean_curve, run, world::World, Explorer, Planner, Sample, Truth, UTILITY_OFFSET_M,
};
use crate::sim::indoor::{self, IndoorRun, IndoorScene};
use crate::sim::mix_all;
use crate::sim::sensor::DepthCamera;
use crate::sim::vocab::TextEmbeddings;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// `host-sim explore`.
#[derive(clap::Args, Debug)]
pub struct ExploreArgs {
    /// Driving budget per run, metres.
    #[arg(long, default_value_t = 40.0)]
    pub budget: f32,
    /// Runs per explorer (seeds 1..=N of the camera's pixel sampling, the encoder noise and random choice).
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// The first seed (seeds S..S+N-1): another set of seeds measures how much a house's figures move.
    #[arg(long, default_value_t = 1)]
    pub first_seed: u64,
    /// Seed of the house layout.
    #[arg(long, default_value_t = 1, conflicts_with = "layouts")]
    pub layout_seed: u64,
    /// Several house layouts (comma-separated seeds, e.g. 1,2,3): each one's table and headline, then one
    /// summary line over them.
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    pub layouts: Vec<u64>,
    /// Information gain's utility is score / (path + this many metres).
    #[arg(long, default_value_t = UTILITY_OFFSET_M)]
    pub utility_offset: f32,
    /// Information gain's distance discount per metre: utility score · e^(−discount · path) instead of
    /// score / (path + offset) (0: off).
    #[arg(long, default_value_t = 0.0)]
    pub discount: f32,
    /// Information gain chooses again at every frame on the way (every 0.5 m), not only on arrival.
    #[arg(long)]
    pub replan: bool,
    /// Information gain takes the best view in the first room of the best tour of the house's rooms, each
    /// room worth its views' summed score.
    #[arg(long)]
    pub rooms: bool,
    /// Information gain scores only the voxels that hold a surface some candidate view sees (not the air
    /// the kernel reaches).
    #[arg(long)]
    pub surface: bool,
    /// Information gain plans tours of this many views and drives to the first (1: the best single view).
    #[arg(long, default_value_t = 1)]
    pub horizon: usize,
    /// Reuse the random and nearest-frontier runs kept in this directory by an earlier call with the same
    /// house, seed and budget by the same build (files are named with a hash of the executable, so another
    /// build's runs are never read back): they do not depend on information gain's settings, so
    /// comparing its designs costs a third of the time. Runs not found there are made and kept.
    #[arg(long)]
    pub baselines: Option<PathBuf>,
    /// Directory for the plot (`explore.png`; `explore-<layout>.png` with `--layouts`).
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
}

/// One house's outcome, for the summary.
struct Outcome {
    layout: u64,
    /// Share of random's distance at which information gain reaches random's final accuracy (None: never).
    share: Option<f64>,
    /// Information gain minus nearest-frontier accuracy there (at the end if never), points.
    lead: f64,
}

/// Run every explorer on every seed of each house, print the tables and headlines, write the plots.
pub fn explore(args: &ExploreArgs) -> Result<()> {
    if !(args.budget > 0.0 && args.budget.is_finite()) || args.seeds == 0 {
        anyhow::bail!("--budget must be a positive number of metres and --seeds at least 1");
    }
    if !(args.utility_offset > 0.0 && args.utility_offset.is_finite()) {
        anyhow::bail!("--utility-offset must be a positive number of metres");
    }
    if !(args.discount >= 0.0 && args.discount.is_finite()) {
        anyhow::bail!("--discount must be a non-negative number per metre");
    }
    if !(1..=4).contains(&args.horizon) {
        anyhow::bail!("--horizon must be 1 to 4 views");
    }
    for dir in std::iter::once(&args.out).chain(&args.baselines) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    if args.layouts.is_empty() {
        house(args, args.layout_seed, "explore.png")?;
        return Ok(());
    }
    let mut outcomes = Vec::new();
    for &layout in &args.layouts {
        outcomes.push(house(args, layout, &format!("explore-{layout}.png"))?);
    }
    println!("{}", summary(&outcomes));
    Ok(())
}

/// One house: the table, the headline, the plot.
fn house(args: &ExploreArgs, layout: u64, png: &str) -> Result<Outcome> {
    let scene = IndoorScene::generate(layout);
    let training = IndoorScene::generate(mix_all(&[layout, 0x7EA1]));
    let train_seq = indoor::sequence(
        &training,
        &IndoorRun {
            seed: mix_all(&[layout, 0x7EA1]),
            ..IndoorRun::default()
        },
    );
    let config = train_seq.config;
    // A quarter of the voxels (spatially even): the curves are measured after every frame.
    let truth = Truth::from_loop(&scene, &config).thinned(4);
    let world = World::new(scene, &config, DepthCamera::default().pixels_per_frame)?;
    let mut runs: Vec<Vec<Vec<Sample>>> = vec![Vec::new(); Planner::ALL.len()];
    let seeds = args.first_seed..args.first_seed.saturating_add(args.seeds);
    for seed in seeds.clone() {
        let setup = ExperimentSettings {
            seed,
            ..ExperimentSettings::default()
        };
        let dec = decoding(&TextEmbeddings::builtin(), &train_seq, &setup)?;
        let results: Vec<Result<Vec<Sample>>> = std::thread::scope(|s| {
            let handles: Vec<_> = Planner::ALL
                .iter()
                .map(|&p| {
                    let (world, dec, truth, config) = (&world, &dec, &truth, &config);
                    s.spawn(move || {
                        let explorer = Explorer {
                            planner: p,
                            seed,
                            budget: args.budget,
                            utility_offset: args.utility_offset,
                            discount: args.discount,
                            horizon: args.horizon,
                            replan: args.replan,
                            rooms: args.rooms,
                            surface_only: args.surface,
                        };
                        let kept = (p != Planner::InformationGain)
                            .then_some(args.baselines.as_deref())
                            .flatten()
                            .map(|dir| {
                                dir.join(format!(
                                    "{}-house{layout}-seed{seed}-budget{}-build{}.txt",
                                    p.name().replace(' ', "-"),
                                    args.budget,
                                    build_id()
                                ))
                            });
                        if let Some(samples) = kept.as_deref().and_then(read_samples) {
                            return Ok(samples);
                        }
                        let samples = run(world, dec, truth, config, &explorer)?;
                        if let Some(path) = kept {
                            write_samples(&path, &samples)?;
                        }
                        Ok(samples)
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| {
                    h.join()
                        .unwrap_or_else(|_| Err(anyhow::anyhow!("a run panicked")))
                })
                .collect()
        });
        for (i, r) in results.into_iter().enumerate() {
            runs[i].push(r?);
        }
    }
    let step = 0.25;
    let grid: Vec<f32> = (0..=(args.budget / step).ceil() as usize)
        .map(|i| (i as f32 * step).min(args.budget))
        .collect();
    let acc: Vec<Vec<f64>> = runs
        .iter()
        .map(|r| mean_curve(r, &grid, |s| s.accuracy))
        .collect();
    let miou: Vec<Vec<f64>> = runs
        .iter()
        .map(|r| mean_curve(r, &grid, |s| s.miou))
        .collect();
    println!(
        "explore: house {} ({} ground-truth voxels, {} candidate views), budget {} m, {}",
        layout,
        truth.len(),
        world.views.len(),
        args.budget,
        if args.first_seed == 1 {
            format!("{} seeds", args.seeds)
        } else {
            format!("seeds {}–{}", seeds.start, seeds.end - 1)
        }
    );
    for (i, p) in Planner::ALL.iter().enumerate() {
        let frames: f64 = runs[i]
            .iter()
            .map(|r| f64::from(r.last().map_or(0, |s| s.frames)))
            .sum::<f64>()
            / args.seeds as f64;
        let driven: f64 = runs[i]
            .iter()
            .map(|r| f64::from(r.last().map_or(0.0, |s| s.distance)))
            .sum::<f64>()
            / args.seeds as f64;
        println!(
            "  {:<17} final accuracy {:5.1} %, mIoU {:5.1} %, {:5.1} frames, {:4.1} m driven",
            p.name(),
            100.0 * acc[i].last().copied().unwrap_or(0.0),
            100.0 * miou[i].last().copied().unwrap_or(0.0),
            frames,
            driven
        );
    }
    if args.seeds > 1 {
        println!("{}", per_seed(&grid, &runs));
    }
    let (line, outcome) = headline(layout, &grid, &acc, &runs[1]);
    println!("{line}");
    let path = args.out.join(png);
    let names = Planner::ALL.map(Planner::name);
    crate::eval::figures::distance_curves(&path, &names, &grid, &acc, &miou)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    println!("wrote {}", path.display());
    Ok(outcome)
}

/// The headline: where information gain reaches random's final accuracy, and the accuracies there.
fn headline(
    layout: u64,
    grid: &[f32],
    acc: &[Vec<f64>],
    random_runs: &[Vec<Sample>],
) -> (String, Outcome) {
    let (ig, random, frontier) = (&acc[0], &acc[1], &acc[2]);
    let target = random.last().copied().unwrap_or(0.0);
    let random_distance = mean_distance(random_runs);
    match ig.iter().position(|&a| a >= target) {
        Some(i) => {
            let share = f64::from(grid[i]) / random_distance.max(1e-9);
            (
                format!(
                    "exploration: information gain reaches random's final accuracy at {:.0} % of its distance; at that distance nearest-frontier {:.1} %, information gain {:.1} %",
                    100.0 * share,
                    100.0 * frontier[i],
                    100.0 * ig[i]
                ),
                Outcome {
                    layout,
                    share: Some(share),
                    lead: 100.0 * (ig[i] - frontier[i]),
                },
            )
        }
        None => {
            let (f, g) = (
                frontier.last().copied().unwrap_or(0.0),
                ig.last().copied().unwrap_or(0.0),
            );
            (
                format!(
                    "exploration: information gain does not reach random's final accuracy ({:.1} %) within the budget; at the end nearest-frontier {:.1} %, information gain {:.1} %",
                    100.0 * target,
                    100.0 * f,
                    100.0 * g
                ),
                Outcome {
                    layout,
                    share: None,
                    lead: 100.0 * (g - f),
                },
            )
        }
    }
}

/// The mean distance at the end of `runs`.
fn mean_distance(runs: &[Vec<Sample>]) -> f64 {
    runs.iter()
        .map(|r| f64::from(r.last().map_or(0.0, |s| s.distance)))
        .sum::<f64>()
        / runs.len().max(1) as f64
}

/// Where each seed's information-gain run reaches the same seed's random final accuracy, as a share of that
/// random run's distance, and their median: how much one house's figure moves between seeds.
fn per_seed(grid: &[f32], runs: &[Vec<Vec<Sample>>]) -> String {
    let mut shares: Vec<f64> = (0..runs[0].len())
        .map(|k| {
            let ig = mean_curve(&runs[0][k..=k], grid, |s| s.accuracy);
            let random = &runs[1][k..=k];
            let target = random[0].last().map_or(0.0, |s| s.accuracy);
            ig.iter()
                .position(|&a| a >= target)
                .map_or(f64::INFINITY, |i| {
                    f64::from(grid[i]) / mean_distance(random).max(1e-9)
                })
        })
        .collect();
    let each: Vec<String> = shares.iter().map(|&s| pct(s)).collect();
    shares.sort_by(f64::total_cmp);
    format!(
        "  per seed: information gain reaches that seed's random final accuracy at {} of its distance (median {})",
        each.join(", "),
        pct(shares[shares.len() / 2])
    )
}

/// A share as a whole percentage, or "never".
fn pct(s: f64) -> String {
    if s.is_finite() {
        format!("{:.0} %", 100.0 * s)
    } else {
        "never".to_string()
    }
}

/// One line over several houses: how many meet the goal (≤ 60 % of random's distance, ahead of
/// nearest-frontier there), the median and worst share.
fn summary(outcomes: &[Outcome]) -> String {
    let met = outcomes
        .iter()
        .filter(|o| o.share.is_some_and(|s| s <= 0.605) && o.lead > 0.0)
        .count();
    let mut shares: Vec<f64> = outcomes
        .iter()
        .map(|o| o.share.unwrap_or(f64::INFINITY))
        .collect();
    shares.sort_by(f64::total_cmp);
    let median = shares.get(shares.len() / 2).copied().unwrap_or(f64::NAN);
    let worst = outcomes
        .iter()
        .max_by(|a, b| {
            a.share
                .unwrap_or(f64::INFINITY)
                .total_cmp(&b.share.unwrap_or(f64::INFINITY))
        })
        .map_or(0, |o| o.layout);
    let ahead = outcomes.iter().filter(|o| o.lead > 0.0).count();
    format!(
        "exploration over {} houses: information gain reaches random's final accuracy within 60 % of its distance and ahead of nearest-frontier there on {} of {}; share of random's distance median {}, worst {} (house {}); ahead of nearest-frontier on {}",
        outcomes.len(),
        met,
        outcomes.len(),
        pct(median),
        pct(shares.last().copied().unwrap_or(f64::NAN)),
        worst,
        ahead
    )
}

/// Samples kept by [`write_samples`], if the file is there and whole.
/// A fingerprint of this executable (a hash of its bytes, computed once): baseline runs kept by
/// `--baselines` are named with it, so a run made by another build (other predictions, other planners) is
/// never read back as if it were this one's.
fn build_id() -> &'static str {
    static ID: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    ID.get_or_init(|| {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        match std::env::current_exe().and_then(std::fs::read) {
            Ok(bytes) => bytes.hash(&mut h),
            // Unreadable: a fresh id per process, so nothing is reused rather than something stale.
            Err(_) => std::process::id().hash(&mut h),
        }
        format!("{:012x}", h.finish() & 0xffff_ffff_ffff)
    })
}

fn read_samples(path: &Path) -> Option<Vec<Sample>> {
    let text = std::fs::read_to_string(path).ok()?;
    let samples: Option<Vec<Sample>> = text
        .lines()
        .map(|line| {
            let mut f = line.split_whitespace();
            Some(Sample {
                distance: f.next()?.parse().ok()?,
                accuracy: f.next()?.parse().ok()?,
                miou: f.next()?.parse().ok()?,
                frames: f.next()?.parse().ok()?,
            })
        })
        .collect();
    samples.filter(|s| !s.is_empty())
}

/// Keep a run's samples as text, one per line (Rust prints floats so that they parse back exactly).
fn write_samples(path: &Path, samples: &[Sample]) -> Result<()> {
    let text: String = samples
        .iter()
        .map(|s| format!("{} {} {} {}\n", s.distance, s.accuracy, s.miou, s.frames))
        .collect();
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_build_id_names_this_executable_the_same_way_each_time() {
        let id = super::build_id();
        assert_eq!(id.len(), 12, "{id}");
        assert!(id.chars().all(|c| c.is_ascii_hexdigit()), "{id}");
        assert_eq!(id, super::build_id());
    }
}
