//! `--png PREFIX`: the global map's top-down pictures, drawn as the demo draws its own (the same code,
//! `eval::figures`): a title, a legend or colour bar, a scale bar, sized to the map (at most ≈ 1,300 ×
//! 1,100 px, small maps magnified) — a person reads them without knowing the voxel size or the palette.
//! The folder of PREFIX is created. `-gain.png`, the information-gain raster, stays the station crate's raw
//! one at `--scale` pixels per voxel (it is computed first, so a scale too large for the map fails before
//! any file is written).

use super::{Vocab, VOCAB_CAP};
use crate::base_station::export::gain_image;
use crate::base_station::GlobalMap;
use crate::eval::figures::{query_heatmap, semantic_map, uncertainty_map, TopDown};
use crate::sim::vocab::D;
use anyhow::{Context, Result};
use latentbki::decode::Codebook;
use std::path::{Path, PathBuf};

/// Write the pictures; returns the files written.
pub(super) fn write(
    map: &GlobalMap<D>,
    vocab: Option<&Vocab>,
    query: Option<(&Codebook<D, VOCAB_CAP>, &str)>,
    prefix: &Path,
    scale: u32,
) -> Result<Vec<PathBuf>> {
    let gain = gain_image(map, scale)?;
    if let Some(folder) = prefix.parent().filter(|f| !f.as_os_str().is_empty()) {
        std::fs::create_dir_all(folder)
            .with_context(|| format!("--png: creating the folder {}", folder.display()))?;
    }
    let name = |s: &str| {
        let mut p = prefix.as_os_str().to_owned();
        p.push(s);
        PathBuf::from(p)
    };
    let posteriors = map.posteriors();
    let config = map.map_config();
    let top = TopDown::new(&posteriors, config, None);
    let voxels = posteriors.len();
    let mut written = Vec::new();
    let figure = |r: Result<(), crate::eval::figures::Error>, p: &Path| {
        r.map_err(|e| anyhow::anyhow!("--png {}: {e}", p.display()))
    };
    if let Some((names, book, _)) = vocab {
        let p = name("-labels.png");
        let title = format!(
            "Global map: class of the top voxel per column ({voxels} voxels, {} m voxels)",
            config.voxel_size()
        );
        figure(semantic_map(&p, &title, &top, config, book, names), &p)?;
        written.push(p);
    }
    if let Some((q, phrase)) = query {
        let p = name("-heat.png");
        figure(query_heatmap(&p, phrase, &top, config, q), &p)?;
        written.push(p);
    }
    let p = name("-uncertainty.png");
    let title = "Global map: uncertainty (E-optimality, max t_var, log scale; grey: λ ≤ 2)";
    figure(uncertainty_map(&p, title, &top, config), &p)?;
    written.push(p);
    let p = name("-gain.png");
    gain.save_png(&p)
        .with_context(|| format!("cannot write {}", p.display()))?;
    written.push(p);
    Ok(written)
}
