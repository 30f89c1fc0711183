//! The pictures: top-down semantic map, open-vocabulary query heat map, E-optimality uncertainty map
//! ([`maps`]), the sparsity sweep (paper Fig. 3), the sparsification curves (Fig. 4) and the exploration's
//! curves ([`curves`]), as PNG. This module holds what they share: the font, the PNG writer and the colours.
//!
//! Drawn with `plotters`' bitmap backend and a font compiled in from `epaint_default_fonts` (Ubuntu Light),
//! so nothing depends on the machine's fonts or fontconfig. Top-down views show, for each (x, y) column,
//! the highest voxel with at least one point's worth of kernel mass (λ ≥ 1) — below the ceiling indoors.

use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

pub mod curves;
pub mod maps;

pub use curves::{distance_curves, sparsification_plot, sweep_plot};
pub use maps::{query_heatmap, semantic_map, uncertainty_map, TopDown};

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

/// Tile classes get natural colours (the live view's table, `export::natural_colour`); anything else takes
/// the palette.
pub(crate) fn class_colour(name: &str, i: usize) -> RGBColor {
    let (r, g, b) = match crate::base_station::export::natural_colour(name) {
        Some([r, g, b]) => (r, g, b),
        None => PALETTE[i % PALETTE.len()],
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

/// The colour of the `i`-th curve of a line chart.
pub(crate) fn series_colour(i: usize) -> RGBColor {
    let (r, g, b) = PALETTE[i % PALETTE.len()];
    RGBColor(r, g, b)
}
