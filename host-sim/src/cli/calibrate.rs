//! The `calibrate` command: the map scale a robot should fly with over a labelled tile, chosen by validation
//! as `eval --las` chooses it, printed as the `const` a firmware pastes, with the RAM its map needs to hold
//! the sensor's window and whether the device map's window can span the range. Apart from `eval` because
//! it scores no method: it is the firmware author's question, answered in seconds to minutes.

use crate::cli_args::{MapArgs, ScaleArg, TileArgs};
use crate::eval::experiment::{self, ExperimentSettings};
use crate::eval::methods::D;
use crate::eval::scenes::{SceneKind, SceneOptions, SceneSource};
use crate::sim::tile::{significant, Tile};
use crate::sim::vocab::TextEmbeddings;
use anyhow::{ensure, Result};
use clap::Args;
use latentbki::local_map::{LocalMap, MAX_WINDOW_VOXELS};
use latentbki::{packed_len, KernelMode, MapConfig, Prior};
use std::collections::HashSet;

/// `calibrate` options.
#[derive(Args, Debug, Clone)]
pub struct CalibrateArgs {
    /// Seed of the run (network noise, hold-out and validation splits, sensor subsampling).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// LiDAR points per frame.
    #[arg(long, default_value_t = 3000)]
    pub points: usize,
    /// Frames flown [default: planned from the tile, as `eval --las`].
    #[arg(long)]
    pub frames: Option<usize>,
    /// RAM the firmware can give the map, KiB [default: 192, the default memory.x's].
    #[arg(long, default_value_t = 192)]
    pub ram_kib: usize,
    /// The point cloud and the flight.
    #[command(flatten)]
    pub tile: TileArgs,
    /// The map options (prior, kernel mode; `--filter-size` is the largest filter the robot affords).
    #[command(flatten)]
    pub map: MapArgs,
}

/// Bytes of the link queue and wire frame the firmware guide's robot uses (docs/firmware.md).
const QUEUE: usize = 4096;
const WIRE_FRAME: usize = 512;
const P: usize = packed_len(D);
type NoVoxels = latentbki::Mapper<D, 0, P, QUEUE, WIRE_FRAME>;

/// What the robot's map needs at a configuration: the voxels inside its window and the RAM they take.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceNeeds {
    /// The window radius the library gives for the sensor's range ([`MapConfig::window_for_range`]), m.
    pub window_m: f32,
    /// The window radius in voxels.
    pub window_voxels: f32,
    /// Whether the device map's window can span it ([`MAX_WINDOW_VOXELS`]).
    pub window_fits: bool,
    /// The most voxels holding tile points inside the window, over the flight's poses.
    pub voxels: usize,
    /// The map's capacity to compile in: `voxels` with a quarter of headroom, rounded up to 256.
    pub capacity: usize,
    /// `Mapper::RAM_BYTES` at that capacity.
    pub ram_bytes: usize,
}

/// What the robot's map needs over `tile` at `config`, for a sensor of `range` metres flown through `poses`.
pub fn device_needs(
    tile: &Tile,
    config: &MapConfig,
    range: f32,
    poses: &[[f32; 3]],
) -> DeviceNeeds {
    let window_m = config.window_for_range(range);
    let window_voxels = (window_m / config.voxel_size()).ceil();
    let inv = 1.0 / config.voxel_size();
    let step = (poses.len() / 256).max(1);
    let voxels = poses
        .iter()
        .step_by(step)
        .map(|s| {
            tile.points
                .iter()
                .filter(|p| {
                    let d = [p[0] - s[0], p[1] - s[1], p[2] - s[2]];
                    d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= window_m * window_m
                })
                .map(|p| p.map(|x| (x * inv).floor() as i64))
                .collect::<HashSet<_>>()
                .len()
        })
        .max()
        .unwrap_or(0);
    let capacity = (voxels + voxels / 4).div_ceil(256).max(1) * 256;
    let ram_bytes = NoVoxels::RAM_BYTES + capacity * LocalMap::<D, 0, P>::BYTES_PER_VOXEL;
    DeviceNeeds {
        window_m,
        window_voxels,
        window_fits: (1.0..=MAX_WINDOW_VOXELS as f32).contains(&window_voxels),
        voxels,
        capacity,
        ram_bytes,
    }
}

/// The configuration as Rust source a firmware pastes (a `const`, validated at compile time).
pub fn config_const(config: &MapConfig) -> String {
    let prior = config.prior();
    let prior = if prior == Prior::DEFAULT {
        "Prior::DEFAULT".to_string()
    } else {
        format!(
            "Prior {{ lambda: {:?}, mean: {:?}, psi: {:?} }}",
            prior.lambda, prior.mean, prior.psi
        )
    };
    let mode = match config.mode() {
        KernelMode::VoxelOffset => "KernelMode::VoxelOffset".to_string(),
        KernelMode::SubVoxel { cells } => format!("KernelMode::SubVoxel {{ cells: {cells} }}"),
    };
    format!(
        "const MAP: MapConfig = match MapConfig::new({:?}, {:?}, {}, {prior}, {mode}) {{\n    Ok(c) => c,\n    Err(_) => panic!(\"invalid map configuration\"),\n}};",
        config.voxel_size(),
        config.kernel_length(),
        config.filter_size()
    )
}

/// `calibrate`: fly the tile, choose the scale by validation, print the firmware's configuration.
pub fn calibrate(args: &CalibrateArgs) -> Result<()> {
    ensure!(args.frames != Some(0), "--frames must be at least 1");
    ensure!(args.points >= 1, "--points must be at least 1");
    let mut tile = args.tile.clone();
    if !args.map.scale_given() {
        tile.scale = Some(tile.scale.unwrap_or(ScaleArg::Validate));
    }
    let options = SceneOptions {
        tile_frames: args.frames.unwrap_or(SceneOptions::default().tile_frames),
        plan_frames: args.frames.is_none(),
        tile_points: args.points,
        tile_config: args.map.config()?,
        tile_map: tile.las.as_ref().map(|_| args.map.clone()),
        tile,
        ..SceneOptions::default()
    };
    let setup = ExperimentSettings {
        seed: args.seed,
        ..ExperimentSettings::default()
    };
    let mut source = SceneSource::new(SceneKind::Tile, &options, args.seed)?;
    let (train, test) = source.train_and_test()?;
    let dec = experiment::decoding(&TextEmbeddings::builtin(), &train, &setup)?;
    let frames = experiment::encode(&test, &dec, &setup);
    let (chosen, choice) = source.resolve_config(&frames, &dec, &setup)?;
    let config = if choice.is_some() {
        chosen
    } else {
        test.config
    };
    if let Some(c) = &choice {
        println!("\n{}", c.table());
    }
    println!("map scale: {}", source.scale_note());
    let tile = source.tile().expect("the tile scene");
    let poses: Vec<[f32; 3]> = test
        .frames
        .iter()
        .map(|f| f.pose.translation.vector.into())
        .collect();
    let range = source.range();
    let needs = device_needs(tile, &config, range, &poses);
    println!("\nfor the firmware (docs/firmware.md; `use latentbki::{{KernelMode, MapConfig, Prior}};`):\n");
    println!("{}", config_const(&config));
    println!(
        "const VOXELS: usize = {}; // the most voxels holding points within the window on this flight: {}, and a quarter more",
        needs.capacity, needs.voxels
    );
    println!(
        "// Setup::new(MAP, MAP.window_for_range({}), …): the LiDAR's range {} m",
        significant(range),
        significant(range)
    );
    let budget = args.ram_kib * 1024;
    println!(
        "\nRAM: {} B ({:.1} KiB) for a Mapper<{D}, {}, {{ packed_len({D}) }}, {QUEUE}, {WIRE_FRAME}> ({} B per voxel, {} B fixed): {}",
        needs.ram_bytes,
        needs.ram_bytes as f64 / 1024.0,
        needs.capacity,
        LocalMap::<D, 0, P>::BYTES_PER_VOXEL,
        NoVoxels::RAM_BYTES,
        if needs.ram_bytes <= budget {
            format!("fits the {} KiB given (--ram-kib)", args.ram_kib)
        } else {
            format!(
                "does not fit the {} KiB given (--ram-kib): a shorter --range (the window's area grows with its square) or a coarser --voxel-size lowers it",
                args.ram_kib
            )
        }
    );
    println!(
        "window: {} m = {:.0} voxels of {} m; the device map's window spans at most {MAX_WINDOW_VOXELS}: {}",
        significant(needs.window_m),
        needs.window_voxels,
        significant(config.voxel_size()),
        if needs.window_fits {
            "the device map can hold the window"
        } else {
            "the device map cannot hold the window: a coarser voxel or a shorter --range"
        }
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_const_is_the_configuration_and_the_ram_is_the_mappers() {
        let c = MapConfig::new(0.6, 1.2, 3, Prior::DEFAULT, KernelMode::VoxelOffset).unwrap();
        let s = config_const(&c);
        assert!(
            s.contains("MapConfig::new(0.6, 1.2, 3, Prior::DEFAULT, KernelMode::VoxelOffset)"),
            "{s}"
        );
        // The RAM formula is the Mapper's own at that capacity.
        type Robot = latentbki::Mapper<D, 1024, P, QUEUE, WIRE_FRAME>;
        assert_eq!(
            NoVoxels::RAM_BYTES + 1024 * LocalMap::<D, 0, P>::BYTES_PER_VOXEL,
            Robot::RAM_BYTES
        );
    }
}
