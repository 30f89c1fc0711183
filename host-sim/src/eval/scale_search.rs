//! The map's scale chosen by validation: candidate voxel sizes, kernel lengths ℓ and filter sizes f, each
//! scored on a validation split of the *integrated* points, the best used.
//!
//! Why: a rule picked once ("voxel ≈ point spacing, ℓ = 5 voxels") cannot fit every survey — on a public
//! aerial tile it over-smoothed boundaries and the map lost to the segmentation it fused. The data can say
//! which scale predicts unseen observations best, if the question is asked without the test's answers.
//!
//! **The split.** The test protocol holds out 20 % of each frame's points and scores each one against the
//! map after its frame is integrated. The validation repeats that protocol one level down, on the other
//! 80 % only: a seeded fifth of each frame's integrated points (a hash of its own, independent of the
//! hold-out's) is set aside, each candidate's map integrates the rest (the *fit* points) frame by frame,
//! and after each frame the frame's validation points are predicted. So the validation score estimates,
//! for each candidate, the figure the test will measure, from data the test never scores:
//! - the held-out points are not read at all — [`split`] takes the frames' integrated points, their
//!   features and their true classes and nothing else (`tests/scale_validation.rs` scrambles every held-out
//!   point and asserts the choice and every score stay bit-identical, and that scrambling the integrated
//!   classes does change the scores, so the test can fail);
//! - a validation point is never in the map it is scored against (nor through a neighbouring voxel: it is
//!   in no map at all), as a held-out point is never in the test's map. Its surface is, through other
//!   frames' observations of it — as the held-out points' surfaces are in the test; that is what the
//!   protocol measures. The fit maps hold 64 % of the points where the test's hold 80 %, so the validation
//!   leans slightly towards more smoothing than the test would pick; the spacing of the grid below is
//!   coarser than that effect.
//!
//! **The candidates** come from the tile's point spacing s (1/√density over the occupied area), not
//! from any result: voxel sizes s·2^(k/2) for k = −2 … 2 (a factor of four around the spacing in half-octave
//! steps: smaller voxels leave most of them unobserved, larger ones merge surfaces), rounded to the
//! preferred numbers of [`crate::sim::scale::SERIES`]; for each voxel v, ℓ ∈ {1, 1.5, 2, 3, 5}·v at
//! f = 3 (ℓ = v spreads nothing: its map predicts as f = 1; 5·v is the paper's ratio) and ℓ ∈ {3, 5}·v at
//! f = 5. f = 5 updates 125 voxels per point where f = 3 updates 27 (4.6 times the robot's work per point),
//! so it is scored only when `--filter-size` allows it: `--filter-size` is the largest filter the robot
//! affords. Score: the mean of validation accuracy and mIoU (unknown counts as wrong, as in the test).

use super::experiment::ExperimentSettings;
use super::methods::{Decoder, EncodedFrame, Feature, LatentBki, MappingMethod, D};
use super::metrics::Confusion;
use crate::sim::scale::preferred;
use crate::sim::{mix_all, unit};
use latentbki::MapConfig;

/// Share of each frame's integrated points set aside for validation.
pub const VALIDATION_SHARE: f32 = 0.2;

/// Kernel lengths scored at f = 3, in voxels.
pub const KERNELS_F3: [f32; 5] = [1.0, 1.5, 2.0, 3.0, 5.0];
/// Kernel lengths scored at f = 5, in voxels.
pub const KERNELS_F5: [f32; 2] = [3.0, 5.0];

/// One frame of the validation split: fit points (integrated by the candidate maps) and validation points
/// (scored), both drawn from the frame's integrated points only.
#[derive(Clone, Debug)]
pub struct SplitFrame {
    /// The fit points as a map integrates them (the frame's pose, sensor-frame points, features).
    pub fit: EncodedFrame,
    /// Validation points, map frame.
    pub points: Vec<[f32; 3]>,
    /// Their true classes.
    pub classes: Vec<u16>,
    /// Their own features (unused by the maps; kept for the [`MappingMethod::predict`] signature).
    pub features: Vec<Feature>,
}

/// Split the integrated points of `frames` into fit and validation points, a seeded
/// [`VALIDATION_SHARE`] of each frame (a hash of its own). Reads each frame's pose, integrated points,
/// their features and true classes — never the held-out points.
pub fn split(frames: &[EncodedFrame], seed: u64) -> Vec<SplitFrame> {
    frames
        .iter()
        .enumerate()
        .map(|(t, f)| {
            let mut fit = EncodedFrame {
                pose: f.pose,
                points: Vec::new(),
                map_points: Vec::new(),
                features: Vec::new(),
                classes: Vec::new(),
                held_points: Vec::new(),
                held_classes: Vec::new(),
                held_features: Vec::new(),
            };
            let mut out = SplitFrame {
                fit: fit.clone(),
                points: Vec::new(),
                classes: Vec::new(),
                features: Vec::new(),
            };
            for i in 0..f.points.len() {
                let v = unit(mix_all(&[seed, t as u64, i as u64, 0x7A1D])) < VALIDATION_SHARE;
                if v {
                    out.points.push(f.map_points[i]);
                    out.classes.push(f.classes[i]);
                    out.features.push(f.features[i]);
                } else {
                    fit.points.push(f.points[i]);
                    fit.map_points.push(f.map_points[i]);
                    fit.features.push(f.features[i]);
                    fit.classes.push(f.classes[i]);
                }
            }
            out.fit = fit;
            out
        })
        .collect()
}

/// A scale to score.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Voxel edge, metres.
    pub voxel: f32,
    /// Kernel length ℓ, metres.
    pub kernel: f32,
    /// Filter size.
    pub filter: u8,
}

impl Candidate {
    /// The map configuration, with the prior and kernel mode of `base`.
    pub fn config(&self, base: &MapConfig) -> anyhow::Result<MapConfig> {
        MapConfig::new(
            self.voxel,
            self.kernel,
            self.filter,
            base.prior(),
            base.mode(),
        )
        .map_err(|e| anyhow::anyhow!("candidate scale {self:?}: {e}"))
    }
}

/// The candidate grid for a tile of point spacing `spacing` (see the module documentation); f = 5 only
/// when `max_filter` ≥ 5.
pub fn candidates(spacing: f32, max_filter: u8) -> Vec<Candidate> {
    let mut voxels: Vec<f32> = (-2..=2)
        .map(|k| preferred(spacing * 2f32.powf(k as f32 / 2.0)))
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    voxels.dedup_by(|a, b| (*a / *b - 1.0).abs() < 1e-4);
    let mut out = Vec::new();
    for &voxel in &voxels {
        for &k in &KERNELS_F3 {
            out.push(Candidate {
                voxel,
                kernel: k * voxel,
                filter: 3,
            });
        }
        if max_filter >= 5 {
            for &k in &KERNELS_F5 {
                out.push(Candidate {
                    voxel,
                    kernel: k * voxel,
                    filter: 5,
                });
            }
        }
    }
    out
}

/// One candidate's validation figures.
#[derive(Clone, Debug, PartialEq)]
pub struct ScoredCandidate {
    /// The candidate.
    pub candidate: Candidate,
    /// Validation accuracy (unknown = wrong).
    pub accuracy: f64,
    /// Validation mIoU.
    pub miou: f64,
    /// Share of validation points in voxels no fit point reached.
    pub unknown: f64,
    /// Whether the robot's map window can hold the sensor's range at this voxel size.
    pub fits_device: bool,
}

impl ScoredCandidate {
    /// What is maximised: the mean of accuracy and mIoU.
    pub fn score(&self) -> f64 {
        0.5 * (self.accuracy + self.miou)
    }
}

/// The result of the search.
#[derive(Clone, Debug)]
pub struct Choice {
    /// Every candidate, scored, in grid order.
    pub scored: Vec<ScoredCandidate>,
    /// Index of the best in `scored`.
    pub best: usize,
    /// The chosen configuration.
    pub config: MapConfig,
    /// Fit and validation points.
    pub fit_points: usize,
    /// Validation points.
    pub validation_points: usize,
}

/// Score one candidate: its LatentBKI f32 map integrates the fit points frame by frame; after each frame
/// the frame's validation points are predicted.
pub fn score(
    split: &[SplitFrame],
    config: &MapConfig,
    decoder: &Decoder,
    classes: usize,
) -> anyhow::Result<Confusion> {
    let mut map = LatentBki::new(*config).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut confusion = Confusion::new(classes);
    for f in split {
        map.integrate(&f.fit);
        for ((p, c), own) in f.points.iter().zip(&f.classes).zip(&f.features) {
            confusion.add(usize::from(*c), map.predict(decoder, *p, own));
        }
    }
    Ok(confusion)
}

/// Score every candidate on the split of `frames` (in parallel, with a progress bar) and choose the best;
/// `fits_device` says whether the robot's window holds the sensor's range at a configuration.
pub fn choose(
    frames: &[EncodedFrame],
    candidates: &[Candidate],
    base: &MapConfig,
    decoder: &Decoder,
    classes: usize,
    setup: &ExperimentSettings,
    fits_device: &(dyn Fn(&MapConfig) -> bool + Sync),
) -> anyhow::Result<Choice> {
    anyhow::ensure!(!candidates.is_empty(), "no candidate scale to score");
    let key = memo_key(frames, candidates, base, setup.seed);
    if let Some(c) = MEMO
        .lock()
        .ok()
        .and_then(|m| m.iter().find(|(k, _)| *k == key).map(|(_, c)| c.clone()))
    {
        return Ok(c);
    }
    let choice = choose_uncached(
        frames,
        candidates,
        base,
        decoder,
        classes,
        setup,
        fits_device,
    )?;
    if let Ok(mut m) = MEMO.lock() {
        m.push((key, choice.clone()));
    }
    Ok(choice)
}

/// [`choose`] without its memo: every candidate scored anew.
pub fn choose_uncached(
    frames: &[EncodedFrame],
    candidates: &[Candidate],
    base: &MapConfig,
    decoder: &Decoder,
    classes: usize,
    setup: &ExperimentSettings,
    fits_device: &(dyn Fn(&MapConfig) -> bool + Sync),
) -> anyhow::Result<Choice> {
    anyhow::ensure!(!candidates.is_empty(), "no candidate scale to score");
    let split = split(frames, setup.seed);
    let bar = super::runner::progress(candidates.len() as u64, "choosing the scale");
    let results = super::runner::parallel(
        candidates,
        |c| u64::from(c.filter).pow(3),
        |c| -> anyhow::Result<ScoredCandidate> {
            let config = c.config(base)?;
            let m = score(&split, &config, decoder, classes)?;
            bar.inc(1);
            Ok(ScoredCandidate {
                candidate: *c,
                accuracy: m.accuracy(),
                miou: m.miou(),
                unknown: m.unknown() as f64 / m.total().max(1) as f64,
                fits_device: fits_device(&config),
            })
        },
    );
    bar.finish_and_clear();
    let scored: Vec<ScoredCandidate> = results.into_iter().collect::<anyhow::Result<_>>()?;
    // The best score; on a tie the earlier candidate (smaller voxel, shorter ℓ: less smoothing).
    let best = (0..scored.len())
        .max_by(|&a, &b| {
            scored[a]
                .score()
                .total_cmp(&scored[b].score())
                .then(b.cmp(&a))
        })
        .expect("candidates are not empty");
    let config = scored[best].candidate.config(base)?;
    let choice = Choice {
        config,
        best,
        fit_points: split.iter().map(|f| f.fit.points.len()).sum(),
        validation_points: split.iter().map(|f| f.points.len()).sum(),
        scored,
    };
    Ok(choice)
}

/// Choices already made in this process, by a hash of what they were made from: `demo` needs the robot's
/// configuration for its base station before the run that reports the choice, and the search is the
/// costly part.
static MEMO: std::sync::Mutex<Vec<(u64, Choice)>> = std::sync::Mutex::new(Vec::new());

/// A hash of everything [`choose`] reads: the integrated points, their classes and features, the poses,
/// the candidates, the base configuration and the seed.
fn memo_key(frames: &[EncodedFrame], candidates: &[Candidate], base: &MapConfig, seed: u64) -> u64 {
    let mut h = mix_all(&[seed, frames.len() as u64, candidates.len() as u64]);
    let mut eat = |w: u64| h = crate::sim::mix(h ^ w);
    for c in candidates {
        eat(u64::from(c.voxel.to_bits()) << 32 | u64::from(c.kernel.to_bits()));
        eat(u64::from(c.filter));
    }
    eat(u64::from(base.prior().lambda.to_bits()) << 32 | u64::from(base.prior().psi.to_bits()));
    eat(u64::from(base.prior().mean.to_bits()) << 8 | u64::from(base.subvoxel_cells()));
    for f in frames {
        for v in f
            .pose
            .translation
            .vector
            .iter()
            .chain(f.pose.rotation.coords.iter())
        {
            eat(u64::from(v.to_bits()));
        }
        for ((p, y), c) in f.points.iter().zip(&f.features).zip(&f.classes) {
            eat(u64::from(p[0].to_bits()) << 32 | u64::from(p[1].to_bits()));
            eat(u64::from(p[2].to_bits()) << 32 | u64::from(y[0].to_bits()));
            eat(u64::from(y[D - 1].to_bits()) << 16 | u64::from(*c));
        }
    }
    h
}

impl Choice {
    /// The candidates and their scores as a Markdown table (the chosen one in bold).
    pub fn table(&self) -> String {
        let mut s = format!(
            "Scale chosen by validation: {} candidates, each a LatentBKI f32 map of {} fit points scored on {} validation points (a fifth of each frame's integrated points; the held-out points are not read):\n\n| Voxel (m) | ℓ (m) | ℓ / voxel | f | Val. acc. (%) | Val. mIoU (%) | Unknown (%) | Score | Device window |\n|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
            self.scored.len(),
            self.fit_points,
            self.validation_points
        );
        for (i, r) in self.scored.iter().enumerate() {
            let c = r.candidate;
            let b = if i == self.best { "**" } else { "" };
            s += &format!(
                "| {b}{}{b} | {b}{}{b} | {:.1} | {} | {:.2} | {:.2} | {:.2} | {b}{:.2}{b} | {} |\n",
                crate::sim::tile::significant(c.voxel),
                crate::sim::tile::significant(c.kernel),
                c.kernel / c.voxel,
                c.filter,
                100.0 * r.accuracy,
                100.0 * r.miou,
                100.0 * r.unknown,
                100.0 * r.score(),
                if r.fits_device { "fits" } else { "too small" },
            );
        }
        s
    }

    /// One phrase: the chosen scale and where it came from.
    pub fn describe(&self) -> String {
        let r = &self.scored[self.best];
        format!(
            "voxel {} m, ℓ = {} m, f = {} (chosen by validation: best of {} candidates, validation accuracy {:.2} %, mIoU {:.2} %)",
            crate::sim::tile::significant(r.candidate.voxel),
            crate::sim::tile::significant(r.candidate.kernel),
            r.candidate.filter,
            self.scored.len(),
            100.0 * r.accuracy,
            100.0 * r.miou
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_spans_a_factor_of_four_around_the_spacing() {
        let c = candidates(0.56, 3);
        let voxels: Vec<f32> = c.iter().map(|c| c.voxel).collect();
        let (lo, hi) = (voxels[0], voxels[voxels.len() - 1]);
        assert!(
            (0.25..=0.3).contains(&lo) && (1.0..=1.25).contains(&hi),
            "{voxels:?}"
        );
        assert!(c.iter().all(|c| c.filter == 3));
        assert_eq!(c.len(), 5 * KERNELS_F3.len());
        let c5 = candidates(0.56, 5);
        assert_eq!(c5.len(), 5 * (KERNELS_F3.len() + KERNELS_F5.len()));
        // The built-in tile's spacing (0.094 m) has the paper's 0.1 m / 0.5 m among its candidates.
        assert!(candidates(0.094, 3)
            .iter()
            .any(|c| (c.voxel - 0.1).abs() < 1e-6 && (c.kernel - 0.5).abs() < 1e-6));
    }
}
