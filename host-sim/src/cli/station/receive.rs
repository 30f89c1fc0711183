//! The receiving loop of `host-sim base-station`: every link's bytes (read on their own threads,
//! [`super::links`]) fed to the one [`BaseStation`], committed to the store at a bounded interval, and the
//! acknowledgements written back on each link — after the commit that made its frames durable, so a crash
//! never acknowledges a frame it loses — until every input ends, a deadline passes or a signal arrives.

use super::links::{try_send, AckSender, Event, Events, LinkIds, Source};
use crate::base_station::store::MapStore;
use crate::base_station::{AckPolicy, BaseStation, LinkId};
use anyhow::{Context, Result};
use std::collections::BTreeMap;
use std::io::Read;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How [`pump`] ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ending {
    /// Every input ended.
    EndOfInput,
    /// `--duration` passed.
    Deadline,
    /// SIGINT or SIGTERM.
    Signal,
}

/// How [`pump`] runs.
#[derive(Clone, Debug)]
pub struct PumpOptions {
    /// Commit at least this often while there are changes (or acknowledgements waiting for one).
    pub commit_every: Duration,
    /// Stop after this long.
    pub duration: Option<Duration>,
    /// Stop when this becomes true (set by a signal handler).
    pub stop: Arc<AtomicBool>,
}

/// What the loop knows of one link.
#[derive(Clone, Debug, Default)]
pub struct LinkReport {
    /// What it is.
    pub name: String,
    /// Acknowledgement writes dropped because the link did not take them.
    pub acks_dropped: u64,
    /// Whether its input ended, and why if it failed.
    pub ended: Option<Option<String>>,
    /// Whether it has a back channel.
    pub acknowledged: bool,
}

/// Events channel capacity: chunks waiting for the loop.
const EVENTS: usize = 64;

/// A channel for links' events (the loop's end and the links' end).
pub fn channel() -> (std::sync::mpsc::SyncSender<Event>, Events) {
    sync_channel(EVENTS)
}

/// Read one input (no back channel) as link 0 on its own thread (chunks of up to 64 KiB).
pub fn spawn_reader(source: Box<dyn Read + Send>) -> Events {
    let (tx, rx) = channel();
    let source = Source {
        name: "input".into(),
        read: source,
        write: None,
    };
    super::links::spawn_link(tx, &LinkIds::default(), source);
    rx
}

/// Receive every link's bytes into `base` and commit to `store` whenever `commit_every` has passed with
/// changes or acknowledgements pending, until every input ends, the duration passes or `stop` is set; then
/// commit what is left. Returns how it ended and what each link did.
pub fn pump<const D: usize>(
    base: &mut BaseStation<D>,
    store: Option<&mut dyn MapStore>,
    events: &Events,
    options: &PumpOptions,
) -> Result<(Ending, BTreeMap<LinkId, LinkReport>)> {
    pump_with(base, store, events, options, |_, _| {})
}

/// The links' back channels.
#[derive(Default)]
struct BackChannels {
    senders: BTreeMap<LinkId, AckSender>,
    reports: BTreeMap<LinkId, LinkReport>,
}

impl BackChannels {
    /// Hand every released acknowledgement to its link's writer (never waiting).
    fn send<const D: usize>(&mut self, base: &mut BaseStation<D>) {
        for (link, tx) in &self.senders {
            let bytes = base.take_acks_on(*link);
            if !bytes.is_empty() && !try_send(tx, bytes) {
                if let Some(r) = self.reports.get_mut(link) {
                    r.acks_dropped += 1;
                }
            }
        }
    }
}

/// [`pump`], calling `received(base, arrival)` after each chunk is applied (a live view's feed).
pub fn pump_with<const D: usize>(
    base: &mut BaseStation<D>,
    mut store: Option<&mut dyn MapStore>,
    events: &Events,
    options: &PumpOptions,
    mut received: impl FnMut(&mut BaseStation<D>, Instant),
) -> Result<(Ending, BTreeMap<LinkId, LinkReport>)> {
    // With a database, a frame is acknowledged once it is durable; in memory, at once.
    base.set_ack_policy(if store.is_some() {
        AckPolicy::AfterCommit
    } else {
        AckPolicy::Immediate
    });
    let start = Instant::now();
    let mut last_commit = Instant::now();
    let mut back = BackChannels::default();
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
        let pending = base.has_changes() || base.has_unreleased_acks();
        if let Some(s) = store.as_deref_mut() {
            if pending && now.duration_since(last_commit) >= options.commit_every {
                base.commit(s).context("committing to the map database")?;
                back.send(base);
                last_commit = now;
            }
        }
        let mut wait = POLL;
        if pending {
            wait = wait.min(
                options
                    .commit_every
                    .saturating_sub(now.duration_since(last_commit)),
            );
        }
        if let Some(d) = options.duration {
            wait = wait.min(d.saturating_sub(now.duration_since(start)));
        }
        match events.recv_timeout(wait) {
            Ok(Event::Opened { link, name, acks }) => {
                base.receive_on(link, &[]); // the link exists from now on (its counters too)
                back.reports.insert(
                    link,
                    LinkReport {
                        name,
                        acknowledged: acks.is_some(),
                        ..LinkReport::default()
                    },
                );
                if let Some(tx) = acks {
                    back.senders.insert(link, tx);
                }
            }
            Ok(Event::Bytes(link, bytes)) => {
                let arrived = Instant::now();
                base.receive_on(link, &bytes);
                received(base, arrived);
                if store.is_none() {
                    back.send(base);
                }
            }
            Ok(Event::Closed { link, error }) => {
                back.senders.remove(&link);
                if let Some(r) = back.reports.get_mut(&link) {
                    r.ended = Some(error);
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break Ending::EndOfInput,
        }
    };
    if let Some(s) = store {
        base.commit(s).context("committing to the map database")?;
    }
    back.send(base);
    Ok((ending, back.reports))
}
