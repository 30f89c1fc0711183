//! The exploration figure: accuracy and mIoU against metres driven, one line per explorer (mean over seeds),
//! drawn like the evaluation's other figures.

use super::Planner;
use crate::eval::figures::{err, figure, register_font, series_colour, Error, FONT};
use plotters::prelude::*;
use std::path::Path;

/// Two panels (accuracy, mIoU) of `acc`/`miou` (per planner, in [`Planner::ALL`] order) over `grid` metres.
pub fn curves(path: &Path, grid: &[f32], acc: &[Vec<f64>], miou: &[Vec<f64>]) -> Result<(), Error> {
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
            for (i, (planner, ys)) in Planner::ALL.iter().zip(series).enumerate() {
                let c = series_colour(i);
                let data: Vec<(f64, f64)> = grid
                    .iter()
                    .zip(ys)
                    .map(|(&x, &y)| (f64::from(x), 100.0 * y))
                    .collect();
                chart
                    .draw_series(LineSeries::new(data, c.stroke_width(2)))
                    .map_err(err)?
                    .label(planner.name())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                    });
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
