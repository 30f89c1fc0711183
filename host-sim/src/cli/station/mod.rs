//! `host-sim base-station`: receive robots' streams from any number of links at once — serial ports, ptys,
//! TCP connections from gateways, stdin, recordings — into the global map database, acknowledging each
//! frame on its link once the database holds it; `host-sim map-info` and `host-sim map-query` read that
//! database, also while a base station is writing it; `host-sim map-merge` merges two of them.
//!
//! Every link is read on its own thread, so the receiver commits at the bounded interval (`--commit-ms`)
//! and answers SIGINT/SIGTERM even while every port is silent: the signal commits, prints the summary and
//! exits cleanly (a second signal exits at once).
//!
//! The options are in `args`, the reading of the user's vocabulary (`--pca`, `--classes`, `--query`) in
//! `vocabulary`, the links in `links`, the receiving loop in `receive`, the merge of databases in `merge`.

use crate::base_station::export::write_ply;
use crate::base_station::store::{MapStore, SqliteStore, SCHEMA_VERSION};
use crate::base_station::view::Viewer;
use crate::base_station::{BaseStation, GlobalMap, VOCAB_CAP};
use crate::sim::vocab::D;

/// Where the report goes: stdout, or stderr under `--stdio` (stdout carries the acknowledgements).
pub(crate) static REPORT_TO_STDERR: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

/// `println!` to the report's stream.
macro_rules! say {
    ($($t:tt)*) => {
        if $crate::cli::station::REPORT_TO_STDERR.load(std::sync::atomic::Ordering::Relaxed) {
            eprintln!($($t)*)
        } else {
            println!($($t)*)
        }
    };
}

mod args;
pub mod links;
mod merge;
mod pictures;
mod read;
mod receive;
mod view;
mod vocabulary;
use anyhow::{bail, Context, Result};
pub use args::{BaseStationArgs, MapInfoArgs, MapQueryArgs, OutputArgs, ViewArgs};
use latentbki::decode::Codebook;
pub use merge::{map_merge, MapMergeArgs};
pub use read::{map_info, map_query};
pub use receive::{channel, pump, pump_with, spawn_reader, Ending, LinkReport, PumpOptions};
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;
pub use view::{print_view_summary, serve_until_interrupted, start_view, view_options};
pub use vocabulary::Vocab;
use vocabulary::{check_feature_space, read_vocabulary};

/// Check that `path` (given with `flag`) can be written: its folder exists and it is not a folder itself.
fn check_output(flag: &str, path: &Path, is_prefix: bool) -> Result<()> {
    let folder = match path.parent() {
        Some(f) if !f.as_os_str().is_empty() => f,
        _ => Path::new("."),
    };
    if !folder.is_dir() {
        let (f, p) = (folder.display(), path.display());
        if folder.exists() {
            bail!("{flag} {p}: {f} is not a folder");
        }
        bail!("{flag} {p}: the folder {f} does not exist");
    }
    if !is_prefix && path.is_dir() {
        bail!("{flag} {}: is a folder, not a file", path.display());
    }
    Ok(())
}

/// Check the output options before anything is read. Their folders are created when they are written
/// (a folder that is a file, or an output that is a folder, is refused here).
fn check_outputs(out: &OutputArgs) -> Result<()> {
    let check = |flag: &str, p: &Path, is_prefix: bool| match p.parent() {
        Some(f) if !f.as_os_str().is_empty() && !f.exists() => Ok(()),
        _ => check_output(flag, p, is_prefix),
    };
    if let Some(p) = &out.png {
        check("--png", p, true)?;
    }
    if let Some(p) = &out.ply {
        check("--ply", p, false)?;
    }
    Ok(())
}

/// Open (or create) the receiver's database and continue its map.
pub fn open_station(path: &Path) -> Result<(SqliteStore, BaseStation<D>)> {
    let mut store = SqliteStore::open(path)?;
    let base = BaseStation::<D>::open(&mut store).with_context(|| path.display().to_string())?;
    Ok((store, base))
}

/// Read the map a database holds as of its last commit (read-only: works while a base station writes).
pub fn read_map(path: &Path) -> Result<BaseStation<D>> {
    let mut store = SqliteStore::open_read_only(path)?;
    BaseStation::<D>::open(&mut store).with_context(|| path.display().to_string())
}

/// The receiver's summary lines.
fn print_summary<const D: usize>(base: &BaseStation<D>) {
    let s = base.stats();
    say!(
        "frames accepted {}; summaries merged {}, live {}, ignored copies {}; frames lost {} (late {}); refused: CRC {}, COBS {}, short {}, overflow {}, version {}, malformed {}, wrong config {}, invalid voxel {}, duplicate {}, too old {}; at the codec's ceiling (clamped): mu scale {}, psi {}",
        s.frames, s.merged, s.updated, s.ignored, s.lost, s.late,
        s.decoder.crc_errors, s.decoder.cobs_errors, s.decoder.too_short, s.decoder.overflows,
        s.refused.version, s.refused.malformed, s.refused.wrong_config, s.refused.invalid_voxel,
        s.refused.duplicate_frames, s.refused.too_old, s.clamped_mean_scale, s.clamped_psi
    );
    print_sessions(base);
}

/// One line per `(robot, session)`: its sequence state over its whole life (across restarts).
fn print_sessions<const D: usize>(base: &BaseStation<D>) {
    for ((robot, session), st) in base.sessions() {
        say!(
            "robot {robot} session {session}: {} frames received, {} lost, {} late{}{}",
            st.seq.received,
            st.seq.lost,
            st.seq.late,
            st.seq
                .highest()
                .map_or(String::new(), |h| format!(", highest sequence number {h}")),
            st.link.map_or(String::new(), |l| format!(
                "; robot reports {} frames sent, {} evicted voxels, {} refused by its queue",
                l.frames_sent, l.evicted_sent, l.refused
            ))
        );
    }
}

/// Labels, pictures and the query of a map, as the output options ask.
fn show(
    map: &GlobalMap<D>,
    out: &OutputArgs,
    vocab: Option<&Vocab>,
    query: Option<&Codebook<D, VOCAB_CAP>>,
    top: usize,
) -> Result<()> {
    check_feature_space(out, vocab, map)?;
    let empty = Codebook::<D, VOCAB_CAP>::from_embeddings(&[]).expect("an empty codebook is valid");
    let cb = vocab.map_or(&empty, |v| &v.1);
    if let Some(prefix) = &out.png {
        let query = query.zip(out.query.as_deref());
        for f in pictures::write(map, vocab, query, prefix, out.scale)? {
            say!("wrote {}", f.display());
        }
    }
    if let Some(p) = &out.ply {
        if let Some(folder) = p.parent().filter(|f| !f.as_os_str().is_empty()) {
            std::fs::create_dir_all(folder)
                .with_context(|| format!("--ply: creating the folder {}", folder.display()))?;
        }
        write_ply(map, cb, p)?;
        say!("wrote {}", p.display());
    }
    if let Some((names, _, _)) = vocab {
        let mut counts = vec![0usize; names.len()];
        for k in map.sorted_keys() {
            if let Some((l, _)) = map.label(&k, cb) {
                counts[l] += 1;
            }
        }
        for (n, c) in names.iter().zip(counts) {
            say!("  {n}: {c} voxels");
        }
    }
    if let (Some(q), Some(phrase)) = (query, &out.query) {
        let voxel = map.map_config().voxel_size();
        let mut scored: Vec<_> = map
            .sorted_keys()
            .into_iter()
            .filter_map(|k| Some((map.heat(&k, q, 0)?, k)))
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        for (score, k) in scored.iter().take(top) {
            let c = k.centroid(voxel);
            say!(
                "query \"{phrase}\": score {score:.3} at ({:.2}, {:.2}, {:.2}) m",
                c[0],
                c[1],
                c[2]
            );
        }
    }
    Ok(())
}

/// Run `host-sim base-station`.
pub fn run(args: &BaseStationArgs) -> Result<()> {
    // Every option is checked before the first byte is read: a typo found at the end would lose a whole
    // serial session.
    if let Some(p) = &args.map {
        check_output("--map", p, false)?;
    }
    check_outputs(&args.out)?;
    args.view.check()?;
    let (vocab, query) = read_vocabulary(&args.out)?;
    let (mut store, mut base) = match &args.map {
        Some(p) => {
            let (store, base) = open_station(p)?;
            if let Some(map) = base.map() {
                // A continued map knows the robots' feature space already: check the PCA now.
                check_feature_space(&args.out, vocab.as_ref(), map)?;
                say!(
                    "continuing {} ({} voxels, {} sessions)",
                    p.display(),
                    map.len(),
                    base.sessions().len()
                );
            }
            (Some(store), base)
        }
        None => (None, BaseStation::<D>::adopting()),
    };
    let (events_tx, events) = receive::channel();
    open_links(args, events_tx)?;
    // First signal: stop, commit, summarise. A second one while that runs: exit at once.
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(sig, 130, Arc::clone(&stop))?;
        signal_hook::flag::register(sig, Arc::clone(&stop))?;
    }
    let options = PumpOptions {
        commit_every: Duration::from_millis(args.commit_ms),
        duration: args.duration,
        stop,
    };
    let viewer = start_view(&args.view, vocab.as_ref(), args.out.query.as_deref())?;
    if let Some(v) = &viewer {
        if let Some(m) = base.map() {
            v.push_map(m);
        }
        base.watch();
    }
    let (ending, links) = pump_with(
        &mut base,
        store.as_mut().map(|s| s as &mut dyn MapStore),
        &events,
        &options,
        |base, arrived| {
            if let Some(v) = &viewer {
                let changed = base.take_watched();
                v.push(base, changed, arrived);
            }
        },
    )?;
    if ending == Ending::Signal {
        say!("stopped by a signal");
    }
    if let Some(v) = viewer {
        print_view_summary(&v.finish());
    }
    print_summary(&base);
    print_links(&base, &links);
    let Some(map) = base.map() else {
        bail!(
            "no session header with a {D}-dimensional configuration was received: nothing to keep"
        );
    };
    say!("global map: {} voxels", map.len());
    if let Some(p) = &args.map {
        say!("committed to {}", p.display());
    }
    show(map, &args.out, vocab.as_ref(), query.as_ref(), 0)
}

/// Open every input the options name and start reading them (each on its own thread, into `events`).
/// Everything is opened before anything is read: a port that does not open fails the command at once.
fn open_links(
    args: &BaseStationArgs,
    events: std::sync::mpsc::SyncSender<links::Event>,
) -> Result<()> {
    use std::os::unix::fs::FileTypeExt;
    let ids = links::LinkIds::default();
    let acks = !args.no_acks;
    let one_way = |mut s: links::Source| {
        if !acks {
            s.write = None;
        }
        s
    };
    if args.inputs.is_empty() && args.serial.is_empty() && args.listen.is_none() && !args.stdio {
        bail!(
            "give an input (a recording, a pty, `-` for stdin), --serial PORT, --listen or --stdio"
        );
    }
    let mut live = Vec::new();
    for port in &args.serial {
        let (path, baud) = match port.rsplit_once('@') {
            Some((p, b)) => (
                p,
                b.parse::<u32>()
                    .ok()
                    .filter(|&b| b > 0)
                    .with_context(|| format!("--serial {port}: `{b}` is not a baud rate"))?,
            ),
            None => (port.as_str(), args.baud),
        };
        let s = links::open_terminal(path, baud)
            .with_context(|| format!("opening serial port {path}"))?;
        live.push(one_way(s));
    }
    let mut files = Vec::new();
    for p in &args.inputs {
        if p.as_os_str() == "-" {
            if args.stdio {
                bail!("`-` and --stdio both read stdin: give one");
            }
            live.push(links::Source {
                name: "stdin".into(),
                read: Box::new(std::io::stdin()),
                write: None,
            });
            continue;
        }
        let kind = std::fs::metadata(p)
            .with_context(|| format!("opening {}", p.display()))?
            .file_type();
        if kind.is_char_device() {
            // A pty or another terminal: raw mode, read and acknowledged.
            let path = p
                .to_str()
                .with_context(|| format!("{}: not a UTF-8 path", p.display()))?;
            let s = links::open_terminal(path, args.baud)
                .with_context(|| format!("opening {}", p.display()))?;
            live.push(one_way(s));
        } else if kind.is_fifo() || kind.is_socket() {
            let f = std::fs::File::open(p).with_context(|| format!("opening {}", p.display()))?;
            live.push(links::Source {
                name: p.display().to_string(),
                read: Box::new(f),
                write: None,
            });
        } else {
            let f = std::fs::File::open(p).with_context(|| format!("opening {}", p.display()))?;
            files.push((p.clone(), f));
        }
    }
    if args.stdio {
        REPORT_TO_STDERR.store(true, std::sync::atomic::Ordering::Relaxed);
        live.push(one_way(links::Source {
            name: "stdio".into(),
            read: Box::new(std::io::stdin()),
            write: Some(Box::new(std::io::stdout())),
        }));
    }
    let listener = match args.listen {
        Some(addr) => Some(
            links::bind(addr).with_context(|| format!("--listen {addr}: cannot listen there"))?,
        ),
        None => None,
    };
    // Ids in the order given: recordings first (read one after another), then the live links.
    if !files.is_empty() {
        links::spawn_files(events.clone(), &ids, files);
    }
    for s in live {
        links::spawn_link(events.clone(), &ids, s);
    }
    if let Some(l) = listener {
        if let Ok(a) = l.local_addr() {
            say!("listening on tcp {a} (each connection is a link)");
        }
        if acks {
            links::spawn_listener(events, ids, l);
        } else {
            links::spawn_listener_one_way(events, ids, l);
        }
    }
    Ok(())
}

/// One line per link: what it delivered and what it was sent back.
fn print_links<const D: usize>(
    base: &BaseStation<D>,
    links: &std::collections::BTreeMap<crate::base_station::LinkId, LinkReport>,
) {
    for (id, r) in links {
        let l = base.link_stats(*id);
        let s = l.receive;
        let acks = if r.acknowledged {
            format!(
                "{} acknowledgements written{}",
                l.acks,
                if r.acks_dropped > 0 {
                    format!(
                        " ({} writes dropped: the link did not take them)",
                        r.acks_dropped
                    )
                } else {
                    String::new()
                }
            )
        } else {
            "no back channel".to_string()
        };
        let ended = match &r.ended {
            None => String::new(),
            Some(None) => "; ended".to_string(),
            Some(Some(e)) => format!("; failed: {e}"),
        };
        say!(
            "link {} ({}): {} bytes, {} frames applied ({} summaries merged, {} live), refused: {} damaged, {} other; {acks}{ended}",
            id.0,
            r.name,
            l.bytes,
            s.frames,
            s.merged,
            s.updated,
            s.decoder.refused(),
            s.refused.version
                + s.refused.malformed
                + s.refused.wrong_config
                + s.refused.invalid_voxel
                + s.refused.duplicate_frames
                + s.refused.too_old
                + s.refused.no_session_room,
        );
    }
}

/// Median and 95th percentile (nearest rank).
pub fn median_p95(samples: &[Duration]) -> (Duration, Duration) {
    let mut v = samples.to_vec();
    v.sort_unstable();
    let at = |q: f64| v[((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
    (at(0.5), at(0.95))
}
