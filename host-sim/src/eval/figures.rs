//! The pictures: top-down semantic map, open-vocabulary query heat map, E-optimality uncertainty map,
//! the sparsity sweep (paper Fig. 3) and the sparsification curves (Fig. 4), as PNG.
//!
//! Drawn with `plotters`' bitmap backend and a font compiled in from `epaint_default_fonts` (Ubuntu Light),
//! so nothing depends on the machine's fonts or fontconfig. Top-down views show, for each (x, y) column,
//! the highest voxel with at least one point's worth of kernel mass (λ ≥ 1) — below the ceiling indoors.

use super::experiment::SweepPoint;
use super::methods::{Decoder, D};
use super::sparsification::Sparsification;
use latentbki::{inference::Spread, key::VoxelKey, stats::VoxelStats, MapConfig};
use plotters::prelude::*;
use std::collections::HashMap;
use std::path::Path;
use std::sync::Once;

pub(crate) const FONT: &str = "sans-serif";

pub(crate) fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is a valid TTF shipped by the crate; failure would be a packaging bug.
        plotters::style::register_font(FONT, FontStyle::Normal, epaint_default_fonts::UBUNTU_LIGHT)
            .unwrap_or_else(|_| panic!("the bundled font is valid"));
    });
}

pub(crate) type Error = Box<dyn std::error::Error + Send + Sync>;
pub(crate) type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

pub(crate) fn err<E: std::fmt::Display>(e: E) -> Error {
    e.to_string().into()
}

/// Draw a `size` picture with `draw` into memory, then write it to `path` as a PNG.
pub(crate) fn figure(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&Area) -> Result<(), Error>,
) -> Result<(), Error> {
    let mut rgb = vec![0; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
        draw(&root)?;
        root.present().map_err(err)?;
    }
    crate::png_io::write_png(path, size.0, size.1, &rgb)
        .map_err(|e| format!("cannot write {}: {e}", path.display()).into())
}

/// Distinct class colours (tab20 and a few more).
pub const PALETTE: [(u8, u8, u8); 24] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
    (174, 199, 232),
    (255, 187, 120),
    (152, 223, 138),
    (255, 152, 150),
    (197, 176, 213),
    (196, 156, 148),
    (247, 182, 210),
    (199, 199, 199),
    (219, 219, 141),
    (158, 218, 229),
    (57, 59, 121),
    (99, 121, 57),
    (140, 109, 49),
    (132, 60, 57),
];

/// Tile classes get natural colours; anything else takes the palette.
fn class_colour(name: &str, i: usize) -> RGBColor {
    let (r, g, b) = match name {
        "ground" => (166, 124, 82),
        "low vegetation" => (170, 220, 100),
        "medium vegetation" => (80, 170, 60),
        "high vegetation" => (20, 100, 40),
        "building" => (200, 60, 60),
        "noise" => (255, 0, 255),
        "wall" => (190, 190, 190),
        "floor" => (230, 210, 170),
        _ => PALETTE[i % PALETTE.len()],
    };
    RGBColor(r, g, b)
}

/// Viridis, approximated by 9 stops.
pub fn viridis(t: f32) -> RGBColor {
    const STOPS: [(f32, f32, f32); 9] = [
        (68.0, 1.0, 84.0),
        (71.0, 44.0, 122.0),
        (59.0, 81.0, 139.0),
        (44.0, 113.0, 142.0),
        (33.0, 144.0, 141.0),
        (39.0, 173.0, 129.0),
        (92.0, 200.0, 99.0),
        (170.0, 220.0, 50.0),
        (253.0, 231.0, 37.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f32;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f32;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let l = |u: f32, v: f32| (u + (v - u) * f).round() as u8;
    RGBColor(l(a.0, b.0), l(a.1, b.1), l(a.2, b.2))
}

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

pub(crate) fn series_colour(i: usize) -> RGBColor {
    let (r, g, b) = PALETTE[i % PALETTE.len()];
    RGBColor(r, g, b)
}

/// Accuracy and mIoU vs points per frame, one line per filter size (paper Fig. 3).
pub fn sweep_plot(path: &Path, scene: &str, points: &[SweepPoint]) -> Result<(), Error> {
    register_font();
    figure(path, (1100, 460), |root| {
        root.fill(&WHITE).map_err(err)?;
        let panels = root.split_evenly((1, 2));
        let mut filters: Vec<u8> = points.iter().map(|p| p.filter).collect();
        filters.sort_unstable();
        filters.dedup();
        let xs: Vec<f64> = points.iter().map(|p| p.points_per_frame.max(1.0)).collect();
        let (x0, x1) = (
            xs.iter().copied().fold(f64::INFINITY, f64::min) * 0.8,
            xs.iter().copied().fold(f64::NEG_INFINITY, f64::max) * 1.25,
        );
        for (panel, (name, get)) in panels.iter().zip([
            (
                "Accuracy (%)",
                (|p: &SweepPoint| p.accuracy) as fn(&SweepPoint) -> f64,
            ),
            ("mIoU (%)", |p: &SweepPoint| p.miou),
        ]) {
            let ys: Vec<f64> = points.iter().map(|p| 100.0 * get(p)).collect();
            let y0 = ys.iter().copied().fold(f64::INFINITY, f64::min);
            let y1 = ys.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let pad = ((y1 - y0) * 0.1).max(0.5);
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("{scene}: {name} vs input sparsity"), (FONT, 18))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(50)
                .build_cartesian_2d((x0..x1).log_scale(), (y0 - pad)..(y1 + pad))
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("points per frame (log)")
                .x_labels(8)
                .x_label_formatter(&|x| format!("{x:.0}"))
                .light_line_style(WHITE)
                .y_desc(name)
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .draw()
                .map_err(err)?;
            for (i, f) in filters.iter().enumerate() {
                let c = series_colour(i);
                let data: Vec<(f64, f64)> = points
                    .iter()
                    .filter(|p| p.filter == *f)
                    .map(|p| (p.points_per_frame.max(1.0), 100.0 * get(p)))
                    .collect();
                chart
                    .draw_series(LineSeries::new(data.clone(), c.stroke_width(2)))
                    .map_err(err)?
                    .label(format!("f = {f}"))
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                    });
                chart
                    .draw_series(
                        data.iter()
                            .map(|&(x, y)| Circle::new((x, y), 4, c.filled())),
                    )
                    .map_err(err)?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::LowerRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font((FONT, 14))
                .draw()
                .map_err(err)?;
        }
        Ok(())
    })
}

/// Accuracy and mIoU of the remaining points as the most uncertain are removed (paper Fig. 4), with AUSE.
pub fn sparsification_plot(path: &Path, scene: &str, s: &Sparsification) -> Result<(), Error> {
    register_font();
    figure(path, (1100, 460), |root| {
        root.fill(&WHITE).map_err(err)?;
        let panels = root.split_evenly((1, 2));
        for (pi, panel) in panels.iter().enumerate() {
            let name = if pi == 0 { "Accuracy (%)" } else { "mIoU (%)" };
            let val = |c: &super::sparsification::Curve, i: usize| {
                100.0 * if pi == 0 { c.accuracy[i] } else { c.miou[i] }
            };
            let all: Vec<f64> = s
                .curves
                .iter()
                .flat_map(|c| (0..c.removed.len()).map(move |i| (c, i)))
                .map(|(c, i)| val(c, i))
                .collect();
            let y0 = all.iter().copied().fold(f64::INFINITY, f64::min);
            let y1 = all.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let pad = ((y1 - y0) * 0.05).max(0.5);
            let mut chart = ChartBuilder::on(panel)
                .caption(
                    format!("{scene}: {name} vs uncertainty removed"),
                    (FONT, 18),
                )
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(50)
                .build_cartesian_2d(0.0..95.0, (y0 - pad)..(y1 + pad))
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("most uncertain points removed (%)")
                .y_desc(name)
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .draw()
                .map_err(err)?;
            for (i, c) in s.curves.iter().enumerate() {
                let colour = match c.name.as_str() {
                    "oracle" => RGBColor(0, 0, 0),
                    "random" => RGBColor(150, 150, 150),
                    _ => series_colour(i),
                };
                let data: Vec<(f64, f64)> = (0..c.removed.len())
                    .map(|k| (100.0 * c.removed[k], val(c, k)))
                    .collect();
                let label = match s.ause.iter().find(|a| a.0 == c.name) {
                    Some(a) => format!(
                        "{} (AUSE {:.2})",
                        c.name,
                        100.0 * if pi == 0 { a.1 } else { a.2 }
                    ),
                    None => c.name.clone(),
                };
                let style = if c.name == "oracle" {
                    colour.stroke_width(1)
                } else {
                    colour.stroke_width(2)
                };
                chart
                    .draw_series(LineSeries::new(data, style))
                    .map_err(err)?
                    .label(label)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::LowerRight)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font((FONT, 13))
                .draw()
                .map_err(err)?;
        }
        Ok(())
    })
}
