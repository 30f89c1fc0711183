//! The receiving loop of `host-sim base-station`: bytes read on their own thread, fed to the
//! [`BaseStation`], committed to the store at a bounded interval, until the input ends, a deadline passes
//! or a signal arrives.

use super::super::store::MapStore;
use super::super::BaseStation;
use anyhow::{Context, Result};
use std::io::Read;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How [`pump`] ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ending {
    /// The input ended.
    EndOfInput,
    /// `--duration` passed.
    Deadline,
    /// SIGINT or SIGTERM.
    Signal,
}

/// How [`pump`] runs.
#[derive(Clone, Debug)]
pub struct PumpOptions {
    /// Commit at least this often while there are changes.
    pub commit_every: Duration,
    /// Stop after this long.
    pub duration: Option<Duration>,
    /// Stop when this becomes true (set by a signal handler).
    pub stop: Arc<AtomicBool>,
}

/// Read `source` on its own thread (chunks of up to 64 KiB).
pub fn spawn_reader(mut source: Box<dyn Read + Send>) -> Receiver<std::io::Result<Vec<u8>>> {
    let (tx, rx) = sync_channel(16);
    std::thread::spawn(move || {
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            match source.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => {
                    if tx.send(Ok(buf[..n].to_vec())).is_err() {
                        return;
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => {
                    let _ = tx.send(Err(e));
                    return;
                }
            }
        }
    });
    rx
}

/// Receive chunks into `base` and commit to `store` whenever `commit_every` has passed with changes
/// pending, until the input ends, the duration passes or `stop` is set; then commit what is left.
pub fn pump<const D: usize>(
    base: &mut BaseStation<D>,
    store: Option<&mut dyn MapStore>,
    chunks: &Receiver<std::io::Result<Vec<u8>>>,
    options: &PumpOptions,
) -> Result<Ending> {
    pump_with(base, store, chunks, options, |_, _| {})
}

/// [`pump`], calling `received(base, arrival)` after each chunk is applied (a live view's feed).
pub fn pump_with<const D: usize>(
    base: &mut BaseStation<D>,
    mut store: Option<&mut dyn MapStore>,
    chunks: &Receiver<std::io::Result<Vec<u8>>>,
    options: &PumpOptions,
    mut received: impl FnMut(&mut BaseStation<D>, Instant),
) -> Result<Ending> {
    let start = Instant::now();
    let mut last_commit = Instant::now();
    // How long to sleep at most: the stop flag is polled this often.
    const POLL: Duration = Duration::from_millis(50);
    let ending = loop {
        if options.stop.load(Ordering::Relaxed) {
            break Ending::Signal;
        }
        let now = Instant::now();
        if options
            .duration
            .is_some_and(|d| now.duration_since(start) >= d)
        {
            break Ending::Deadline;
        }
        if let Some(s) = store.as_deref_mut() {
            if base.has_changes() && now.duration_since(last_commit) >= options.commit_every {
                base.commit(s).context("committing to the map database")?;
                last_commit = now;
            }
        }
        let mut wait = POLL;
        if base.has_changes() {
            wait = wait.min(
                options
                    .commit_every
                    .saturating_sub(now.duration_since(last_commit)),
            );
        }
        if let Some(d) = options.duration {
            wait = wait.min(d.saturating_sub(now.duration_since(start)));
        }
        match chunks.recv_timeout(wait) {
            Ok(Ok(bytes)) => {
                let arrived = Instant::now();
                base.receive(&bytes);
                received(base, arrived);
            }
            Ok(Err(e)) => {
                // Keep what was received before the error.
                if let Some(s) = store.as_deref_mut() {
                    base.commit(s).context("committing to the map database")?;
                }
                return Err(e).context("reading the input");
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break Ending::EndOfInput,
        }
    };
    if let Some(s) = store {
        base.commit(s).context("committing to the map database")?;
    }
    Ok(ending)
}
