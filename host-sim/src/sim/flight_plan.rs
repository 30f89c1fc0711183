//! A user's tile flown as often as the built-in one: the number of survey laps ([`super::tile::survey`])
//! that returns each surface point in about as many frames as the built-in tile's loop does.
//!
//! Why apart from the survey: the plan flies candidate laps ([`super::flight`]) to measure them, and the
//! flight lays a survey's laps out; the plan stands above both.

use super::flight::{sequence_poses, TileRun};
use super::sensor::RangeLidar;
use super::tile::survey::{
    for_points_in_range, frames_per_surface, median, quantile, Survey, MAX_LAPS,
};
use super::tile::Tile;
use latentbki::nalgebra::Isometry3;
use std::sync::OnceLock;

/// How often the built-in tile's flight (the default [`TileRun`]: 60 frames of 3000 points, 10 m range)
/// returns a surface point: the median of [`frames_per_surface`] over its points, computed once.
pub fn builtin_frames_per_surface() -> f32 {
    static ONCE: OnceLock<f32> = OnceLock::new();
    *ONCE.get_or_init(|| {
        let t = Tile::builtin().expect("the built-in tile loads");
        let run = TileRun::default();
        let poses: Vec<Isometry3<f32>> = sequence_poses(&t, &run);
        median(&frames_per_surface(&t, &poses, &run.lidar))
    })
}

/// A planned flight and what it returns.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Frames to fly.
    pub frames: usize,
    /// Laps of the survey.
    pub laps: usize,
    /// Frames per lap.
    pub lap_len: usize,
    /// Median frames per surface point.
    pub median: f32,
    /// Its 5th percentile.
    pub p5: f32,
    /// Share of the tile's points no frame returns.
    pub unobserved: f32,
    /// The built-in tile's median, the target.
    pub target: f32,
    /// Points per frame the sensor keeps: the run's budget, or a quarter of the points in its range where
    /// the tile holds fewer than four budgets within it.
    pub budget: usize,
}

impl Plan {
    /// One phrase for the summary line.
    pub fn describe(&self) -> String {
        format!(
            "each surface point returned by {:.1} frames (median; 5th percentile {:.1}, {:.1} % never) against the built-in tile's {:.1}: {} laps of {} frames, {} points per frame",
            self.median,
            self.p5,
            100.0 * self.unobserved,
            self.target,
            self.laps,
            self.lap_len,
            self.budget
        )
    }
}

/// The revisiting flight over `tile` for a run like `run` (its sensor and altitude): laps are added until
/// the median frames per surface point reaches `target` (or [`MAX_LAPS`]).
///
/// A frame keeps at most a quarter of the points within its range (of the frame that sees the median
/// surface point on a lap): the
/// range rule ([`crate::sim::scale::scaled_sensor`]) sizes the sensor so that its sphere holds four frames'
/// budget, and a tile smaller than that sphere (a few hundred points, or a small site under the 10 m
/// floor) would otherwise be returned whole by every frame, its frames per surface reached in a handful of
/// consecutive frames: one view, not revisits.
pub fn plan(tile: &Tile, run: &TileRun, target: f32) -> Plan {
    let survey = Survey::new(tile, run.lidar.range_m);
    let m = survey.lap_len();
    let lap = sequence_poses(
        tile,
        &TileRun {
            frames: m,
            survey: true,
            ..*run
        },
    );
    let mut visible: Vec<usize> = Vec::with_capacity(m);
    for_points_in_range(tile, &lap, run.lidar.range_m, |seen| {
        visible.push(seen.len())
    });
    // The points in range of the frame that sees the median surface point (a median weighted by points:
    // on a clustered tile most returns come from the frames over the dense clusters).
    visible.sort_unstable();
    let total: usize = visible.iter().sum();
    let mut acc = 0;
    let typical = visible
        .iter()
        .find(|&&v| {
            acc += v;
            2 * acc >= total
        })
        .copied()
        .unwrap_or(0);
    let quarter = typical.div_ceil(4).max(1);
    let budget = run.lidar.points_per_frame.min(quarter);
    let run = &TileRun {
        lidar: RangeLidar {
            points_per_frame: budget,
            ..run.lidar
        },
        ..*run
    };
    let mut laps = 1;
    loop {
        let probe = TileRun {
            frames: laps * m,
            survey: true,
            ..*run
        };
        let poses = sequence_poses(tile, &probe);
        let counts = frames_per_surface(tile, &poses, &run.lidar);
        let med = median(&counts);
        if med >= target || laps >= MAX_LAPS {
            // The lap count closest to the target (in ratio): one lap fewer may be nearer.
            let per_lap = med / laps as f32;
            let laps = if laps > 1
                && per_lap > 0.0
                && (target / (per_lap * (laps - 1) as f32)) < (med / target)
            {
                laps - 1
            } else {
                laps
            };
            let probe = TileRun {
                frames: laps * m,
                survey: true,
                ..*run
            };
            let poses = sequence_poses(tile, &probe);
            let counts = frames_per_surface(tile, &poses, &run.lidar);
            let never = counts.iter().filter(|&&c| c <= 0.0).count();
            return Plan {
                frames: laps * m,
                laps,
                lap_len: m,
                median: median(&counts),
                p5: quantile(&counts, 0.05),
                unobserved: never as f32 / counts.len().max(1) as f32,
                target,
                budget,
            };
        }
        // Jump close to the target: laps add about the same each.
        let per_lap = med / laps as f32;
        let next = if per_lap > 0.0 {
            ((target / per_lap).ceil() as usize).max(laps + 1)
        } else {
            laps * 2
        };
        laps = next.min(MAX_LAPS);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_builtin_flight_returns_each_surface_about_seven_times() {
        let t = builtin_frames_per_surface();
        assert!((5.0..10.0).contains(&t), "{t}");
        eprintln!("builtin frames per surface: {t}");
    }
}
