//! Top-down pictures of a map: the semantic map, the open-vocabulary query heat map and the E-optimality
//! uncertainty map. They share the column view ([`TopDown`]: the highest voxel with λ ≥ 1 per (x, y)),
//! the framing and scale bar, and the side panel (legend or colour bar).

use super::super::methods::{Decoder, D};
use super::{class_colour, err, figure, register_font, viridis, Area, Error, FONT};
use latentbki::{inference::Spread, key::VoxelKey, stats::VoxelStats, MapConfig};
use plotters::prelude::*;
use std::collections::HashMap;
use std::path::Path;

/// The top voxel of each (x, y) column.
pub struct TopDown {
    /// Column → (z, posterior).
    pub columns: HashMap<(i32, i32), (i32, VoxelStats<D>)>,
    /// Key bounds (min x, min y, max x, max y).
    pub bounds: (i32, i32, i32, i32),
}

impl TopDown {
    /// Select the highest voxel with λ ≥ 1 per column, below `cutaway` metres if given.
    pub fn new(
        snapshot: &[(VoxelKey, VoxelStats<D>)],
        config: &MapConfig,
        cutaway: Option<f32>,
    ) -> Self {
        let vs = config.voxel_size();
        let mut columns: HashMap<(i32, i32), (i32, VoxelStats<D>)> = HashMap::new();
        for (k, v) in snapshot {
            if v.lambda < 1.0 || cutaway.is_some_and(|c| (k.z as f32 + 0.5) * vs > c) {
                continue;
            }
            let e = columns.entry((k.x, k.y)).or_insert((k.z, *v));
            if k.z > e.0 {
                *e = (k.z, *v);
            }
        }
        let mut b = (i32::MAX, i32::MAX, i32::MIN, i32::MIN);
        for &(x, y) in columns.keys() {
            b = (b.0.min(x), b.1.min(y), b.2.max(x), b.3.max(y));
        }
        Self { columns, bounds: b }
    }

    /// The columns the picture frames, and the share of the map's columns inside: the largest group of
    /// columns no farther apart than 5 % of the map's extent (a tile's points can form separate patches —
    /// an L-shaped edge strip and a corner block — whose common box would be mostly empty), less the
    /// 0.2 % of its columns farthest out on each side when there are many (an isolated speck would
    /// otherwise shrink the mapped area to a corner of the picture).
    fn frame(&self) -> ((i32, i32, i32, i32), f64) {
        let b = self.bounds;
        let block = ((b.2 - b.0 + 1).max(b.3 - b.1 + 1) / 64).max(1);
        let block_of = |k: &(i32, i32)| ((k.0 - b.0) / block, (k.1 - b.1) / block);
        let mut counts: HashMap<(i32, i32), usize> = HashMap::new();
        for k in self.columns.keys() {
            *counts.entry(block_of(k)).or_default() += 1;
        }
        let mut keys: Vec<(i32, i32)> = counts.keys().copied().collect();
        keys.sort_unstable();
        // Groups of blocks within 3 blocks of each other, found in key order (deterministic).
        let mut group: HashMap<(i32, i32), usize> = HashMap::new();
        let mut sizes: Vec<usize> = Vec::new();
        for &start in &keys {
            if group.contains_key(&start) {
                continue;
            }
            let id = sizes.len();
            sizes.push(0);
            let mut stack = vec![start];
            group.insert(start, id);
            while let Some(k) = stack.pop() {
                sizes[id] += counts[&k];
                for dx in -3..=3 {
                    for dy in -3..=3 {
                        let n = (k.0 + dx, k.1 + dy);
                        if counts.contains_key(&n) && !group.contains_key(&n) {
                            group.insert(n, id);
                            stack.push(n);
                        }
                    }
                }
            }
        }
        let Some(best) = (0..sizes.len()).max_by_key(|&i| (sizes[i], std::cmp::Reverse(i))) else {
            return ((0, 0, 0, 0), 1.0);
        };
        let inside: Vec<(i32, i32)> = self
            .columns
            .keys()
            .filter(|k| group[&block_of(k)] == best)
            .copied()
            .collect();
        let share = inside.len() as f64 / self.columns.len() as f64;
        let trim = if inside.len() < 1000 {
            0
        } else {
            inside.len() / 500
        };
        let q = |mut v: Vec<i32>| {
            let n = v.len() - 1;
            let lo = *v.select_nth_unstable(trim).1;
            let hi = *v.select_nth_unstable(n - trim).1;
            (lo, hi)
        };
        let (x0, x1) = q(inside.iter().map(|k| k.0).collect());
        let (y0, y1) = q(inside.iter().map(|k| k.1).collect());
        ((x0, y0, x1, y1), share)
    }
}

/// The largest drawing of the map itself (pixels); with the title, scale bar and side panel the picture
/// stays within 1,300 × 1,100 px.
const MAP_MAX: (f32, f32) = (1000.0, 900.0);
/// At most this many pixels per voxel (small maps are magnified up to it).
const MAX_PX_PER_VOXEL: f32 = 64.0;

/// A length of 1, 2 or 5 × 10ᵏ metres close to `m`, and its label.
fn scale_bar_length(m: f32) -> (f32, String) {
    let decade = 10f32.powf(m.max(1e-6).log10().floor());
    let len = [1.0, 2.0, 5.0]
        .into_iter()
        .map(|f| f * decade)
        .rfind(|l| *l <= m)
        .unwrap_or(decade);
    let label = if len >= 1000.0 {
        format!("{} km", len / 1000.0)
    } else if len >= 1.0 {
        format!("{len} m")
    } else if len >= 0.01 {
        format!("{} cm", (len * 100.0).round())
    } else {
        format!("{} mm", (len * 1000.0).round())
    };
    (len, label)
}

/// Draw a top-down raster with a side panel; `colour` maps a voxel to its pixel colour. The picture is
/// framed on the mapped columns and at most [`MAP_MAX`] for the map whatever the tile's size: where a
/// pixel covers several columns it shows the highest one (ties: the smaller key), so the result does not
/// depend on the map's iteration order.
fn raster(
    path: &Path,
    title: &str,
    top: &TopDown,
    config: &MapConfig,
    colour: &dyn Fn(&VoxelStats<D>) -> Option<RGBColor>,
    panel: &dyn Fn(&Area) -> Result<(), Error>,
) -> Result<(), Error> {
    register_font();
    let ((x0, y0, x1, y1), share) = top.frame();
    let title = if share < 0.995 {
        format!(
            "{title} — largest mapped patch, {:.0} % of the map",
            100.0 * share
        )
    } else {
        title.to_string()
    };
    let (w, h) = ((x1 - x0 + 1) as f32, (y1 - y0 + 1) as f32);
    let scale = (MAP_MAX.0 / w).min(MAP_MAX.1 / h).min(MAX_PX_PER_VOXEL);
    let (mw, mh) = (
        (w * scale).ceil().max(1.0) as u32,
        (h * scale).ceil().max(1.0) as u32,
    );
    // Per pixel, the highest column that falls in it.
    let mut pixels: HashMap<(i32, i32), ((i32, i32), i32)> = HashMap::new();
    for (&(x, y), &(z, _)) in &top.columns {
        if x < x0 || x > x1 || y < y0 || y > y1 {
            continue;
        }
        let px = ((x - x0) as f32 * scale) as i32;
        let py = ((y1 - y) as f32 * scale) as i32;
        let e = pixels.entry((px, py)).or_insert(((x, y), z));
        if z > e.1 || (z == e.1 && (x, y) < e.0) {
            *e = ((x, y), z);
        }
    }
    let cell = scale.max(1.0).ceil() as i32;
    let panel_w = 260;
    let height = (mh + 90).max(420);
    // Wide enough for the title (≈ 9 px per character at 20 px).
    let width = (mw + panel_w + 40).max(40 + 9 * title.chars().count() as u32);
    figure(path, (width, height), |root| {
        root.fill(&WHITE).map_err(err)?;
        let (main, side) = root.split_horizontally(mw + 40);
        main.draw(&Text::new(title.clone(), (20, 12), (FONT, 20).into_font()))
            .map_err(err)?;
        let map = main.margin(45, 45, 20, 20);
        map.draw(&Rectangle::new(
            [(0, 0), (mw as i32, mh as i32)],
            RGBColor(245, 245, 245).filled(),
        ))
        .map_err(err)?;
        let mut drawn: Vec<_> = pixels.into_iter().collect();
        drawn.sort_unstable_by_key(|(p, _)| *p);
        for ((px, py), (key, _)) in drawn {
            let v = &top.columns[&key].1;
            if let Some(c) = colour(v) {
                map.draw(&Rectangle::new(
                    [(px, py), (px + cell, py + cell)],
                    c.filled(),
                ))
                .map_err(err)?;
            }
        }
        // Scale bar: a round length near a fifth of the map's width.
        let metres_per_px = config.voxel_size() / scale;
        let (len, label) = scale_bar_length(mw as f32 * metres_per_px / 5.0);
        let bar = (len / metres_per_px).round() as i32;
        let y0 = mh as i32 + 60;
        main.draw(&PathElement::new(
            vec![(20, y0), (20 + bar, y0)],
            BLACK.stroke_width(3),
        ))
        .map_err(err)?;
        main.draw(&Text::new(
            label,
            (26 + bar, y0 - 8),
            (FONT, 14).into_font(),
        ))
        .map_err(err)?;
        panel(&side.margin(45, 10, 0, 10))?;
        Ok(())
    })
}

/// The top-down semantic map: each column coloured by the decoded class of its top voxel.
pub fn semantic_map(
    path: &Path,
    title: &str,
    top: &TopDown,
    config: &MapConfig,
    decoder: &Decoder,
    classes: &[String],
) -> Result<(), Error> {
    let colours: Vec<RGBColor> = classes
        .iter()
        .enumerate()
        .map(|(i, n)| class_colour(n, i))
        .collect();
    let mut present = vec![false; classes.len()];
    for (_, v) in top.columns.values() {
        if let Some((c, _)) = decoder.argmax(&v.mean) {
            present[c] = true;
        }
    }
    raster(
        path,
        title,
        top,
        config,
        &|v| decoder.argmax(&v.mean).map(|(c, _)| colours[c]),
        &|side| {
            let mut y = 0;
            for (i, name) in classes.iter().enumerate().filter(|(i, _)| present[*i]) {
                side.draw(&Rectangle::new([(0, y), (18, y + 18)], colours[i].filled()))
                    .map_err(err)?;
                side.draw(&Text::new(
                    name.clone(),
                    (26, y + 1),
                    (FONT, 16).into_font(),
                ))
                .map_err(err)?;
                y += 24;
            }
            Ok(())
        },
    )
}

/// A colour bar with labels, for heat maps.
fn colour_bar(side: &Area, label: &str, lo: &str, hi: &str) -> Result<(), Error> {
    side.draw(&Text::new(
        label.to_string(),
        (0, 0),
        (FONT, 16).into_font(),
    ))
    .map_err(err)?;
    let h = 240;
    for i in 0..h {
        let c = viridis(1.0 - i as f32 / (h - 1) as f32);
        side.draw(&Rectangle::new([(0, 30 + i), (24, 31 + i)], c.filled()))
            .map_err(err)?;
    }
    side.draw(&Text::new(hi.to_string(), (32, 28), (FONT, 14).into_font()))
        .map_err(err)?;
    side.draw(&Text::new(
        lo.to_string(),
        (32, 30 + h - 14),
        (FONT, 14).into_font(),
    ))
    .map_err(err)?;
    Ok(())
}

/// The open-vocabulary query heat map: the cosine score of `query` (a one-category codebook), min–max
/// normalised over the map, brighter = more like the query.
pub fn query_heatmap(
    path: &Path,
    query: &str,
    top: &TopDown,
    config: &MapConfig,
    query_codebook: &Decoder,
) -> Result<(), Error> {
    let scores: Vec<f32> = top
        .columns
        .values()
        .map(|(_, v)| query_codebook.score(&v.mean, 0))
        .collect();
    let lo = scores.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = scores.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let span = (hi - lo).max(1e-6);
    raster(
        path,
        &format!("Query \"{query}\": cosine similarity of the map's mean"),
        top,
        config,
        &|v| Some(viridis((query_codebook.score(&v.mean, 0) - lo) / span)),
        &|side| colour_bar(side, "cosine", &format!("{lo:.2}"), &format!("{hi:.2}")),
    )
}

/// The E-optimality map in the authors' convention (max t_var, log scale); voxels with λ ≤ 2 (gated, as
/// in their code) are drawn grey.
pub fn uncertainty_map(
    path: &Path,
    title: &str,
    top: &TopDown,
    config: &MapConfig,
) -> Result<(), Error> {
    let logs: Vec<f32> = top
        .columns
        .values()
        .filter_map(|(_, v)| v.optimality(Spread::PAPER).map(|o| o.e))
        .filter(|e| *e > 0.0)
        .map(f32::log10)
        .collect();
    let mut sorted = logs.clone();
    sorted.sort_by(f32::total_cmp);
    // Robust range: 2nd to 98th percentile.
    let q = |p: f32| {
        sorted
            .get(((sorted.len() as f32 - 1.0) * p) as usize)
            .copied()
            .unwrap_or(0.0)
    };
    let (lo, hi) = (q(0.02), q(0.98));
    let span = (hi - lo).max(1e-6);
    raster(
        path,
        title,
        top,
        config,
        &|v| {
            Some(match v.optimality(Spread::PAPER).map(|o| o.e) {
                Some(e) if e > 0.0 => viridis((e.log10() - lo) / span),
                _ => RGBColor(200, 200, 200),
            })
        },
        &|side| {
            colour_bar(
                side,
                "E-optimality",
                &format!("1e{lo:.1}"),
                &format!("1e{hi:.1}"),
            )?;
            side.draw(&Rectangle::new(
                [(0, 290), (24, 308)],
                RGBColor(200, 200, 200).filled(),
            ))
            .map_err(err)?;
            side.draw(&Text::new("λ ≤ 2", (32, 292), (FONT, 14).into_font()))
                .map_err(err)?;
            Ok(())
        },
    )
}
