//! `host-sim integrate`: recorded frames (`.npy`, or `.las`/`.laz` clouds with their features beside them)
//! into a map, written as `.npz`.

use crate::cli_args::MapArgs;
use crate::las_frame::{is_point_cloud, read_cloud_frame};
use crate::npy_io::{read_frame, read_poses, write_map_npz, Compression, Frame};
use crate::sim::tile::LengthUnit;
use crate::{ObsMap, ReferenceMap};
use anyhow::{bail, Context, Result};
use clap::Args;
use latentbki::nalgebra::Isometry3;
use latentbki::{KernelMode, MapConfig};
use std::path::PathBuf;

/// Run `host-sim integrate`.
pub fn run(args: &IntegrateArgs) -> Result<()> {
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
                $($d => integrate::<$d>(args, config, first, &mut loader),)*
                other => bail!("feature dimension {other} is not compiled in; supported: {:?}", [$($d),*]),
            }
        };
    }
    by_dim!(1 2 3 4 8 16 32 64 128 256 384 512 768)
}

#[derive(Args, Debug)]
pub struct IntegrateArgs {
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
pub struct FrameLoader {
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

pub fn integrate<const D: usize>(
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
            return Err(crate::npy_io::IoError::DimensionMismatch {
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
