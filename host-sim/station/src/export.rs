//! Looking at the global map: top-down PNG views and a PLY point cloud.
//!
//! A person checks a map by eye first. The top-down views are one pixel block per (x, y) voxel column:
//! labels and uncertainty show the *topmost* voxel of the column (what a camera above would see), the
//! query heatmap shows the column's *best* score (so a query finds things under a canopy too). The PLY has
//! one vertex per voxel at its centre, coloured by label, with the label, score, λ and D-optimality as
//! extra properties for any point-cloud viewer.

use super::global_map::GlobalMap;
pub use crate::png_io::RgbImage;
use latentbki::{decode::Codebook, key::VoxelKey, stats::VoxelStats};
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// Nothing to draw.
    #[error("the map is empty: nothing to export")]
    Empty,
    /// The map is too wide for an image.
    #[error(
        "the map spans {0} × {1} voxel columns: too large for an image (max {MAX_SIDE} per side)"
    )]
    TooLarge(i64, i64),
    /// The image at this scale would be too large.
    #[error("a map of {w} × {h} voxel columns at {scale} pixels per voxel is too large an image (max {MAX_SIDE} pixels per side): lower the scale")]
    ImageTooLarge {
        /// Columns across.
        w: u32,
        /// Columns down.
        h: u32,
        /// Pixels per voxel.
        scale: u32,
    },
    /// A scale of 0 pixels per voxel.
    #[error("the scale must be at least 1 pixel per voxel")]
    ZeroScale,
    /// Writing failed.
    // The OS error is in the message, so it is not chained as a `source` too (anyhow would print it twice).
    #[error("cannot write {path}: {error}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        error: std::io::Error,
    },
}

/// Largest image side in pixels (a 16384 × 16384 RGB image is 768 MiB).
pub const MAX_SIDE: u32 = 16384;

/// Distinct colours for up to 20 labels (then repeating): Tableau 20.
pub const PALETTE: [[u8; 3]; 20] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
    [174, 199, 232],
    [255, 187, 120],
    [152, 223, 138],
    [255, 152, 150],
    [197, 176, 213],
    [196, 156, 148],
    [247, 182, 210],
    [199, 199, 199],
    [219, 219, 141],
    [158, 218, 229],
];

/// Colour of a label.
pub fn label_colour(label: usize) -> [u8; 3] {
    PALETTE[label % PALETTE.len()]
}

/// Natural colours of the classes people know by sight (ASPRS LiDAR classes, rooms); `None` for a name
/// without one. One table for the demo's figures and the live view, so both paint a class alike.
pub fn natural_colour(name: &str) -> Option<[u8; 3]> {
    Some(match name {
        "ground" => [166, 124, 82],
        "low vegetation" => [170, 220, 100],
        "medium vegetation" => [80, 170, 60],
        "high vegetation" => [20, 100, 40],
        "building" => [200, 60, 60],
        "noise" => [255, 0, 255],
        "wall" => [190, 190, 190],
        "floor" => [230, 210, 170],
        _ => return None,
    })
}

/// A named class's colour: its natural colour, else the palette's by index.
pub fn class_colour(name: &str, index: usize) -> [u8; 3] {
    natural_colour(name).unwrap_or_else(|| label_colour(index))
}

/// A perceptual-ish dark-blue → yellow ramp for t in [0, 1] (viridis control points).
pub fn ramp(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = t - i as f32;
    core::array::from_fn(|c| (STOPS[i][c] + (STOPS[i + 1][c] - STOPS[i][c]) * f).round() as u8)
}

/// A column's voxels (bottom to top) with their posteriors.
type Column<const D: usize> = Vec<(VoxelKey, VoxelStats<D>)>;

/// Per (x, y) column: every voxel the map answers (within the kernel's reach of an observation), gathered
/// in one pass, bottom to top.
fn columns<const D: usize>(map: &GlobalMap<D>) -> HashMap<(i32, i32), Column<D>> {
    let mut cols: HashMap<(i32, i32), Column<D>> = HashMap::new();
    for (k, p) in map.posteriors() {
        cols.entry((k.x, k.y)).or_default().push((k, p)); // sorted: the last one is the topmost
    }
    cols
}

struct Grid {
    x0: i32,
    y1: i32,
    w: u32,
    h: u32,
}

fn grid<T>(cols: &HashMap<(i32, i32), T>) -> Result<Grid, ExportError> {
    let (mut x0, mut x1, mut y0, mut y1) = (i32::MAX, i32::MIN, i32::MAX, i32::MIN);
    for &(x, y) in cols.keys() {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    if cols.is_empty() {
        return Err(ExportError::Empty);
    }
    let (w, h) = (
        i64::from(x1) - i64::from(x0) + 1,
        i64::from(y1) - i64::from(y0) + 1,
    );
    if w > i64::from(MAX_SIDE) || h > i64::from(MAX_SIDE) {
        return Err(ExportError::TooLarge(w, h));
    }
    Ok(Grid {
        x0,
        y1,
        w: w as u32,
        h: h as u32,
    })
}

/// The pixel size of a `w` × `h` column image at `scale` pixels per voxel, if it is a sane image.
fn image_size(w: u32, h: u32, scale: u32) -> Result<(u32, u32), ExportError> {
    if scale == 0 {
        return Err(ExportError::ZeroScale);
    }
    let side = |n: u32| n.checked_mul(scale).filter(|&p| p <= MAX_SIDE);
    match (side(w), side(h)) {
        (Some(pw), Some(ph)) => Ok((pw, ph)),
        _ => Err(ExportError::ImageTooLarge { w, h, scale }),
    }
}

/// Paint one value per column (None = background), north up, `scale` pixels per voxel.
fn paint<const D: usize>(
    cols: &HashMap<(i32, i32), Column<D>>,
    scale: u32,
    mut colour: impl FnMut(&[(VoxelKey, VoxelStats<D>)]) -> Option<[u8; 3]>,
) -> Result<RgbImage, ExportError> {
    let g = grid(cols)?;
    let (w, h) = image_size(g.w, g.h, scale)?;
    let mut img = RgbImage::from_pixel(w, h, [255, 255, 255]);
    for (&(x, y), keys) in cols {
        if let Some(c) = colour(keys) {
            let (px, py) = ((x - g.x0) as u32 * scale, (g.y1 - y) as u32 * scale);
            for dy in 0..scale {
                for dx in 0..scale {
                    img.put_pixel(px + dx, py + dy, c);
                }
            }
        }
    }
    Ok(img)
}

fn save_png(img: &RgbImage, path: &Path) -> Result<(), ExportError> {
    img.save_png(path).map_err(|error| ExportError::Io {
        path: path.display().to_string(),
        error,
    })
}

/// Top-down label image: the topmost voxel's best category per column.
pub fn label_image<const D: usize, const K: usize>(
    map: &GlobalMap<D>,
    vocab: &Codebook<D, K>,
    scale: u32,
) -> Result<RgbImage, ExportError> {
    let cols = columns(map);
    paint(&cols, scale, |column| {
        let (_, top) = column.last()?;
        vocab.argmax(&top.mean).map(|(l, _)| label_colour(l))
    })
}

/// Top-down heatmap of a text query (category `category` of `query`): the best score in each column,
/// normalised over the map's range of column scores.
pub fn heat_image<const D: usize, const K: usize>(
    map: &GlobalMap<D>,
    query: &Codebook<D, K>,
    category: usize,
    scale: u32,
) -> Result<RgbImage, ExportError> {
    let cols = columns(map);
    let best: HashMap<(i32, i32), f32> = cols
        .iter()
        .map(|(c, column)| {
            let s = column
                .iter()
                .map(|(_, p)| query.score(&p.mean, category))
                .fold(f32::NEG_INFINITY, f32::max);
            (*c, s)
        })
        .collect();
    let (lo, hi) = best
        .values()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let span = (hi - lo).max(1e-6);
    paint(&cols, scale, |column| {
        let (k, _) = column.first()?;
        let v = best[&(k.x, k.y)];
        v.is_finite().then(|| ramp((v - lo) / span))
    })
}

/// Top-down uncertainty: log D-optimality of the topmost voxel with λ > 2, normalised over the map.
pub fn uncertainty_image<const D: usize>(
    map: &GlobalMap<D>,
    scale: u32,
) -> Result<RgbImage, ExportError> {
    let cols = columns(map);
    let value = |column: &[(VoxelKey, VoxelStats<D>)]| {
        column
            .iter()
            .rev()
            .find_map(|(_, p)| p.d_optimality())
            .filter(|v| *v > 0.0)
            .map(f32::ln)
    };
    let (lo, hi) = cols
        .values()
        .filter_map(|k| value(k))
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    let span = (hi - lo).max(1e-6);
    paint(&cols, scale, |keys| {
        value(keys).map(|v| ramp((v - lo) / span))
    })
}

/// Top-down information gain: what one more point's worth of kernel weight would teach the topmost voxel
/// of each column ([`latentbki::info_gain::voxel_gain`] at its λ), normalised over the map — where a robot should look
/// next.
pub fn gain_image<const D: usize>(map: &GlobalMap<D>, scale: u32) -> Result<RgbImage, ExportError> {
    let cols = columns(map);
    let value = |column: &[(VoxelKey, VoxelStats<D>)]| {
        column
            .last()
            .map(|(_, p)| latentbki::info_gain::voxel_gain(p.lambda, 1.0))
    };
    let (lo, hi) = cols
        .values()
        .filter_map(|k| value(k))
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    let span = (hi - lo).max(1e-6);
    paint(&cols, scale, |keys| {
        value(keys).map(|v| ramp((v - lo) / span))
    })
}

/// Write the four views: `<prefix>-labels.png`, `<prefix>-heat.png` (if a query is given),
/// `<prefix>-uncertainty.png`, `<prefix>-gain.png`. Returns the files written.
pub fn write_pngs<const D: usize, const K: usize>(
    map: &GlobalMap<D>,
    vocab: &Codebook<D, K>,
    query: Option<(&Codebook<D, K>, usize)>,
    prefix: &Path,
    scale: u32,
) -> Result<Vec<std::path::PathBuf>, ExportError> {
    let name = |s: &str| {
        let mut p = prefix.as_os_str().to_owned();
        p.push(s);
        std::path::PathBuf::from(p)
    };
    let mut written = Vec::new();
    let p = name("-labels.png");
    save_png(&label_image(map, vocab, scale)?, &p)?;
    written.push(p);
    if let Some((q, c)) = query {
        let p = name("-heat.png");
        save_png(&heat_image(map, q, c, scale)?, &p)?;
        written.push(p);
    }
    let p = name("-uncertainty.png");
    save_png(&uncertainty_image(map, scale)?, &p)?;
    written.push(p);
    let p = name("-gain.png");
    save_png(&gain_image(map, scale)?, &p)?;
    written.push(p);
    Ok(written)
}

/// Write an ASCII PLY: one vertex per voxel centre with label colour, label, score, λ, D-optimality.
pub fn write_ply<const D: usize, const K: usize>(
    map: &GlobalMap<D>,
    vocab: &Codebook<D, K>,
    path: &Path,
) -> Result<(), ExportError> {
    let io = |error| ExportError::Io {
        path: path.display().to_string(),
        error,
    };
    let f = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::new(f);
    let posteriors = map.posteriors();
    let voxel = map.map_config().voxel_size();
    write!(
        w,
        "ply\nformat ascii 1.0\ncomment latentbki global map\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         property int label\nproperty float score\nproperty float lambda\nproperty float d_optimality\n\
         end_header\n",
        posteriors.len()
    )
    .map_err(io)?;
    for (k, p) in &posteriors {
        let c = k.centroid(voxel);
        let (label, score) = vocab
            .argmax(&p.mean)
            .map_or((-1, 0.0), |(l, s)| (l as i64, s));
        let rgb = if label >= 0 {
            label_colour(label as usize)
        } else {
            [128; 3]
        };
        let d = p.d_optimality().unwrap_or(-1.0); // -1: undefined (λ ≤ 2)
        writeln!(
            w,
            "{} {} {} {} {} {} {} {} {} {}",
            c[0], c[1], c[2], rgb[0], rgb[1], rgb[2], label, score, p.lambda, d
        )
        .map_err(io)?;
    }
    w.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cols(keys: &[(i32, i32)]) -> HashMap<(i32, i32), Column<2>> {
        keys.iter()
            .map(|&(x, y)| ((x, y), vec![(VoxelKey::new(x, y, 0), VoxelStats::EMPTY)]))
            .collect()
    }

    #[test]
    fn refuses_zero_and_oversized_scales() {
        let two_by_one = cols(&[(0, 0), (1, 0)]);
        let red = |_: &[(VoxelKey, VoxelStats<2>)]| Some([255, 0, 0]);
        let img = paint(&two_by_one, 3, red).unwrap();
        assert_eq!((img.width(), img.height()), (6, 3));
        assert!(matches!(
            paint(&two_by_one, 0, red),
            Err(ExportError::ZeroScale)
        ));
        // 2 × 8192 = 16384 pixels is the largest side; one more pixel per voxel is refused.
        assert_eq!(
            image_size(2, 1, MAX_SIDE / 2).unwrap(),
            (MAX_SIDE, MAX_SIDE / 2)
        );
        assert_eq!(image_size(1, 1, MAX_SIDE).unwrap(), (MAX_SIDE, MAX_SIDE));
        // 100000 asked for 120 GB; 2147483648 × 2 wrapped to a zero width.
        for scale in [MAX_SIDE / 2 + 1, 100_000, 2_147_483_648, u32::MAX] {
            let err = paint(&two_by_one, scale, red).unwrap_err();
            assert!(
                matches!(err, ExportError::ImageTooLarge { w: 2, h: 1, .. }),
                "{scale}: {err}"
            );
            assert!(err.to_string().contains("too large an image"), "{err}");
        }
    }
}
