//! Running the experiment: every method over the same frames, and the sparsity sweep's runs, on one pool
//! of worker threads (heaviest run first), with a progress bar. Kept apart from [`super::experiment`],
//! which says what one run computes, because this is about scheduling runs; results never depend on it
//! (one run per thread, frames in order).

use super::experiment::{points, run_one, weight, Inputs, Method, MethodResult};
use super::methods::Radio;
use super::sweep::{Sweep, SweepPoint};
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

/// Run `methods` over the same frames in parallel; `score` names the method whose held-out points get
/// uncertainties; `link` receives the device map's evictions. Results come back in the order asked.
pub fn run(
    methods: &[Method],
    inputs: &Inputs<'_>,
    score: Option<Method>,
    link: Option<Box<dyn Radio>>,
    message: &str,
) -> anyhow::Result<Vec<MethodResult>> {
    let (results, _) = run_with_sweep(methods, inputs, score, link, &Sweep::none(), message)?;
    Ok(results)
}

/// [`run`], and the sparsity sweep's runs in the same pool of worker threads (one pool keeps both cores
/// busy: the slow device map would otherwise leave the other idle).
pub fn run_with_sweep(
    methods: &[Method],
    inputs: &Inputs<'_>,
    score: Option<Method>,
    link: Option<Box<dyn Radio>>,
    sweep: &Sweep,
    message: &str,
) -> anyhow::Result<(Vec<MethodResult>, Vec<SweepPoint>)> {
    enum Job {
        Method(Method),
        Sweep(usize, u8),
    }
    enum Done {
        Method(anyhow::Result<MethodResult>),
        Sweep(anyhow::Result<SweepPoint>),
    }
    let jobs: Vec<Job> = methods
        .iter()
        .map(|&m| Job::Method(m))
        .chain(sweep.jobs().map(|(r, f)| Job::Sweep(r, f)))
        .collect();
    let steps = methods.len() * inputs.frames.len() + sweep.steps();
    let bar = progress(steps as u64, message);
    let link = Mutex::new(link);
    let done = parallel(
        &jobs,
        |job| match job {
            Job::Method(m) => points(inputs.frames) * weight(m),
            Job::Sweep(r, f) => points(&sweep.runs[*r].frames) * weight(&Method::LatentBki(*f)),
        },
        |job| match *job {
            Job::Method(m) => {
                let l = if matches!(m, Method::OnDevice(_)) {
                    link.lock().expect("link").take()
                } else {
                    None
                };
                Done::Method(run_one(m, inputs, score == Some(m), l, &bar))
            }
            Job::Sweep(r, f) => Done::Sweep(sweep.run(r, f, inputs.dec, inputs.setup, &bar)),
        },
    );
    bar.finish_and_clear();
    let (mut results, mut points) = (Vec::new(), Vec::new());
    for d in done {
        match d {
            Done::Method(r) => results.push(r?),
            Done::Sweep(p) => points.push(p?),
        }
    }
    Ok((results, points))
}
