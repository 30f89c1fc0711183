//! The worker pool the experiment's runs share: a progress bar, the threads, and the scheduling weights
//! (heaviest run first). Kept apart from [`super::experiment`] because it is about running jobs, not
//! about what a run computes; results never depend on the scheduling.

use super::experiment::Method;
use super::methods::EncodedFrame;
use indicatif::{ProgressBar, ProgressStyle};
use std::sync::Mutex;

/// A progress bar over `len` steps (drawn only on a terminal).
pub fn progress(len: u64, message: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{msg:28} [{bar:40}] {pos}/{len} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(message.to_string());
    bar
}

/// Worker threads: the machine's cores (at least one); stacks are large because the device map is.
fn workers() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Run `work` on every job on the worker threads, heaviest (by `weight`) first so the last thread to finish
/// is not the slowest job started last. Results come back in the order of `jobs`.
pub(super) fn parallel<J: Sync, R: Send>(
    jobs: &[J],
    weight: impl Fn(&J) -> u64,
    work: impl Fn(&J) -> R + Sync,
) -> Vec<R> {
    let mut queue: Vec<usize> = (0..jobs.len()).collect();
    queue.sort_by_key(|&i| std::cmp::Reverse(weight(&jobs[i])));
    let queue = Mutex::new(queue.into_iter());
    let results: Mutex<Vec<Option<R>>> = Mutex::new((0..jobs.len()).map(|_| None).collect());
    std::thread::scope(|s| {
        for _ in 0..workers().min(jobs.len()) {
            std::thread::Builder::new()
                .stack_size(256 << 20)
                .spawn_scoped(s, || loop {
                    let next = queue.lock().expect("queue").next();
                    let Some(i) = next else { break };
                    let r = work(&jobs[i]);
                    results.lock().expect("results")[i] = Some(r);
                })
                .expect("spawning a worker");
        }
    });
    results
        .into_inner()
        .expect("results")
        .into_iter()
        .map(|r| r.expect("every job ran"))
        .collect()
}

/// How heavy a run of `m` is per point, for scheduling: the kernel's reach f³ dominates, and the device map
/// also quantizes and streams its evictions (about four times the f32 map's time).
pub(super) fn weight(m: &Method) -> u64 {
    match m {
        Method::OnDevice(f) | Method::OnDeviceInt8(f) => 4 * (10 + u64::from(*f).pow(3)),
        Method::LatentBki(f) => 10 + u64::from(*f).pow(3),
        Method::ConvBki(f) => 5 + u64::from(*f).pow(3),
        _ => 1,
    }
}

pub(super) fn points(frames: &[EncodedFrame]) -> u64 {
    frames.iter().map(|f| f.points.len() as u64).sum()
}
