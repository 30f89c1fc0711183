//! The sparsity sweep (paper Fig. 3): the same mapper at several sensor budgets and filter sizes. Its
//! own module because it is a second kind of job for the worker pool, with its own inputs (one encoded
//! sequence per budget) and its own result (a point per budget and filter), beside the methods' runs ([`super::runner`]).

use super::experiment::{encode, run_one, Decoding, ExperimentSettings, Inputs, Method};
use super::methods::EncodedFrame;
use crate::sim::Sequence;
use indicatif::ProgressBar;
use latentbki::MapConfig;

/// One point of the sparsity sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweepPoint {
    /// Sensor budget: points (or pixels) per frame asked for.
    pub budget: usize,
    /// Points per frame actually returned, on average.
    pub points_per_frame: f64,
    /// Filter size.
    pub filter: u8,
    /// Accuracy.
    pub accuracy: f64,
    /// mIoU.
    pub miou: f64,
}

/// The sparsity sweep (paper Fig. 3): accuracy and mIoU of LatentBKI with each filter size at each sensor
/// budget. Each budget's sequence is built and encoded once; the runs go to
/// [`run_with_sweep`](super::runner::run_with_sweep).
pub struct Sweep {
    pub(super) runs: Vec<SweepRun>,
    filters: Vec<u8>,
}

pub(super) struct SweepRun {
    budget: usize,
    config: MapConfig,
    pub(super) frames: Vec<EncodedFrame>,
    points_per_frame: f64,
}

impl Sweep {
    /// No sweep.
    pub fn none() -> Self {
        Sweep {
            runs: Vec::new(),
            filters: Vec::new(),
        }
    }

    /// The sequence `make(b)` of each budget `b`, encoded, to be run with each of `filters`.
    pub fn new(
        make: &dyn Fn(usize) -> Sequence,
        budgets: &[usize],
        filters: &[u8],
        dec: &Decoding,
        setup: &ExperimentSettings,
    ) -> Self {
        let runs = budgets
            .iter()
            .map(|&budget| {
                let seq = make(budget);
                SweepRun {
                    budget,
                    config: seq.config,
                    frames: encode(&seq, dec, setup),
                    points_per_frame: seq.points() as f64 / seq.frames.len().max(1) as f64,
                }
            })
            .collect();
        Sweep {
            runs,
            filters: filters.to_vec(),
        }
    }

    /// (run, filter) pairs, budget by budget, in the order of the results.
    pub(super) fn jobs(&self) -> impl Iterator<Item = (usize, u8)> + '_ {
        (0..self.runs.len()).flat_map(|r| self.filters.iter().map(move |&f| (r, f)))
    }

    /// Frames integrated over all runs (progress steps).
    pub(super) fn steps(&self) -> usize {
        self.runs.iter().map(|r| r.frames.len()).sum::<usize>() * self.filters.len()
    }

    /// One run; only its scores are kept (the map is dropped here, not held until the pool is done).
    pub(super) fn run(
        &self,
        r: usize,
        filter: u8,
        dec: &Decoding,
        setup: &ExperimentSettings,
        bar: &ProgressBar,
    ) -> anyhow::Result<SweepPoint> {
        let run = &self.runs[r];
        let inputs = Inputs {
            frames: &run.frames,
            config: &run.config,
            dec,
            setup,
        };
        let res = run_one(Method::LatentBki(filter), &inputs, false, None, bar)?;
        Ok(SweepPoint {
            budget: run.budget,
            points_per_frame: run.points_per_frame,
            filter,
            accuracy: res.confusion.accuracy(),
            miou: res.confusion.miou(),
        })
    }
}
