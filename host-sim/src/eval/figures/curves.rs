//! Line charts: two panels (accuracy, mIoU) of curves with a legend — the sparsity sweep (paper Fig. 3),
//! the sparsification curves (Fig. 4) and the exploration's curves over distance driven. One module so the
//! three charts share one way of drawing a curve's legend entry and the legend box.

use super::super::sparsification::{Curve, Sparsification};
use super::super::sweep::SweepPoint;
use super::{err, figure, register_font, series_colour, Error, FONT};
use plotters::coord::CoordTranslate;
use plotters::prelude::*;
use std::path::Path;

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
                    .legend(legend_line(c.stroke_width(2)));
                chart
                    .draw_series(
                        data.iter()
                            .map(|&(x, y)| Circle::new((x, y), 4, c.filled())),
                    )
                    .map_err(err)?;
            }
            draw_legend(&mut chart, 14)?;
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
            let val = |c: &Curve, i: usize| 100.0 * if pi == 0 { c.accuracy[i] } else { c.miou[i] };
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
                    .legend(legend_line(style));
            }
            draw_legend(&mut chart, 13)?;
        }
        Ok(())
    })
}

/// The exploration figure: two panels (accuracy, mIoU) of `acc`/`miou` (one curve per explorer, named by
/// `names`, mean over seeds) over `grid` metres driven.
pub fn distance_curves(
    path: &Path,
    names: &[&str],
    grid: &[f32],
    acc: &[Vec<f64>],
    miou: &[Vec<f64>],
) -> Result<(), Error> {
    register_font();
    figure(path, (1100, 460), |root| {
        root.fill(&WHITE).map_err(err)?;
        let panels = root.split_evenly((1, 2));
        let x1 = f64::from(grid.last().copied().unwrap_or(1.0)).max(1e-3);
        for (panel, (name, series)) in panels
            .iter()
            .zip([("Accuracy (%)", acc), ("mIoU (%)", miou)])
        {
            let y1 = series
                .iter()
                .flatten()
                .fold(0.0f64, |a, &b| a.max(100.0 * b));
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("house: {name} vs distance driven"), (FONT, 18))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(50)
                .build_cartesian_2d(0.0..x1, 0.0..(y1 * 1.1).max(1.0))
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("distance driven (m)")
                .light_line_style(WHITE)
                .y_desc(name)
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .draw()
                .map_err(err)?;
            for (i, (name, ys)) in names.iter().zip(series).enumerate() {
                let c = series_colour(i);
                let data: Vec<(f64, f64)> = grid
                    .iter()
                    .zip(ys)
                    .map(|(&x, &y)| (f64::from(x), 100.0 * y))
                    .collect();
                chart
                    .draw_series(LineSeries::new(data, c.stroke_width(2)))
                    .map_err(err)?
                    .label(*name)
                    .legend(legend_line(c.stroke_width(2)));
            }
            draw_legend(&mut chart, 14)?;
        }
        Ok(())
    })
}

/// A curve's legend entry: a 20 px line in the curve's style.
fn legend_line(style: ShapeStyle) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style)
}

/// The legend box: lower right, on translucent white, framed in black.
fn draw_legend<'a, 'b: 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, BitMapBackend<'b>, CT>,
    font_size: u32,
) -> Result<(), Error> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT, font_size))
        .draw()
        .map_err(err)
}
