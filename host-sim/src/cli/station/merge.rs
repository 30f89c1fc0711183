//! `host-sim map-merge A.db B.db --out C.db`: two map databases as one — the database one base station
//! would hold had it received every frame of both (`BaseStation::merge_from`), written in one commit.
//! Maps of different configurations (feature space, voxels, kernel, priors, codec) are refused with one
//! line naming the first difference.

use super::{check_output, read_map};
use crate::base_station::store::{MapStore, SqliteStore};
use crate::sim::vocab::D;
use anyhow::{bail, Context, Result};
use clap::Args;
use std::path::PathBuf;

/// Options of `host-sim map-merge`.
#[derive(Args, Debug)]
pub struct MapMergeArgs {
    /// The map databases to merge (read-only; base stations may be writing them).
    #[arg(required = true, num_args = 2..)]
    pub(super) inputs: Vec<PathBuf>,
    /// The merged database (must not exist yet).
    #[arg(long)]
    pub(super) out: PathBuf,
}

/// Run `host-sim map-merge`.
pub fn map_merge(args: &MapMergeArgs) -> Result<()> {
    check_output("--out", &args.out, false)?;
    if args.out.exists() {
        bail!(
            "--out {}: already exists (the merge writes a new database)",
            args.out.display()
        );
    }
    let (first, rest) = args.inputs.split_first().context("give two databases")?;
    let mut merged = read_map(first)?;
    for p in rest {
        let other = read_map(p)?;
        if let (Some(a), Some(b)) = (merged.map(), other.map()) {
            if let Some(d) =
                crate::base_station::global_map::config_difference(a.config(), b.config())
            {
                bail!(
                    "{} and {} cannot be merged: {d}",
                    first.display(),
                    p.display()
                );
            }
        }
        let r = merged
            .merge_from(&other)
            .with_context(|| format!("merging {}", p.display()))?;
        say!(
            "{}: {} voxels added, {} closed contributions added, {} already held{}",
            p.display(),
            r.voxels_added,
            r.parts_added,
            r.parts_shared,
            if r.parts_conflicting > 0 {
                format!(
                    ", {} held by both with different statistics (the first database's kept)",
                    r.parts_conflicting
                )
            } else {
                String::new()
            }
        );
    }
    let mut store = SqliteStore::open(&args.out)?;
    merged
        .commit(&mut store as &mut dyn MapStore)
        .context("writing the merged database")?;
    let n = merged.map().map_or(0, |m| m.len());
    say!(
        "wrote {}: {n} voxels, {} sessions (D = {D})",
        args.out.display(),
        merged.sessions().len()
    );
    Ok(())
}
