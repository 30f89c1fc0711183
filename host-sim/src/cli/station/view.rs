//! The `--view` / `--record` wiring of `base-station`, `map-query --mcap` and `demo`: the view's options
//! from the command line, serving a finished run until the user interrupts, and the summary lines. What
//! decodes the viewed map (the phrases a viewer types) is [`crate::base_station::phrases`], which the
//! demo's radio uses too.

use super::{median_p95, ViewArgs, Vocab};
use crate::base_station::phrases::{vocabulary, StationViewer};
use crate::base_station::view::{RecordingSummary, ViewOptions, Viewer, ViewerSummary};
use crate::base_station::VOCAB_CAP;
use crate::sim::vocab::D;
use anyhow::Result;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// The view's options: the vocabulary and query of the output options.
pub fn view_options(
    args: &ViewArgs,
    vocab: Option<&Vocab>,
    phrase: Option<&str>,
) -> ViewOptions<D, VOCAB_CAP> {
    let mut o = ViewOptions::new();
    o.listen = args.view;
    o.record = args.record.clone();
    o.rate_hz = args.view_hz;
    o.backlog = args.view_backlog as usize;
    o.vocabulary = vocab.map(|(names, cb, pca)| vocabulary(names.clone(), cb.clone(), pca.clone()));
    o.phrase = phrase.map(String::from);
    o
}

/// Start the view the options ask for (None if none), saying where it serves.
pub fn start_view(
    args: &ViewArgs,
    vocab: Option<&Vocab>,
    phrase: Option<&str>,
) -> Result<Option<StationViewer>> {
    if !args.wanted() {
        return Ok(None);
    }
    args.check()?;
    let v = Viewer::start(view_options(args, vocab, phrase))?;
    if let (Some(a), Some(port)) = (args.view, v.port()) {
        println!(
            "viewer: serving ws://{}:{port} (Foxglove or Lichtblick: Open connection → Foxglove WebSocket)",
            a.ip()
        );
    }
    Ok(Some(v))
}

/// At the end of a run: close the recording (its last snapshot written), keep serving the final map to
/// viewers until SIGINT/SIGTERM, then stop and print the viewer's lines.
pub fn serve_until_interrupted(viewer: StationViewer, args: &ViewArgs) -> Result<()> {
    if let (Some(path), Some(r)) = (&args.record, viewer.end_recording()) {
        print_recording(&path.display().to_string(), &r);
    }
    if let (Some(a), Some(port)) = (args.view, viewer.port()) {
        let stop = Arc::new(AtomicBool::new(false));
        for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            signal_hook::flag::register_conditional_shutdown(sig, 130, Arc::clone(&stop))?;
            signal_hook::flag::register(sig, Arc::clone(&stop))?;
        }
        println!(
            "viewer: the run is over; still serving the final map at ws://{}:{port} until interrupted (Ctrl-C)",
            a.ip()
        );
        while !stop.load(Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(100));
        }
        println!("viewer: interrupted: stopping");
    }
    let mut summary = viewer.finish();
    if args.record.is_some() {
        summary.recording = None; // its line is above
    }
    print_view_summary(&summary);
    Ok(())
}

fn print_recording(path: &str, r: &RecordingSummary) {
    println!(
        "viewer: recorded {path}: {} snapshots (each changed layer whole), {} messages, {} bytes ({} on disk, LZ4); last scene {} voxels",
        r.snapshots, r.messages, r.bytes, r.file_bytes, r.voxels
    );
}

/// The viewer's lines: the scene and the stream, the update latency, refusals.
pub fn print_view_summary(s: &ViewerSummary) {
    println!(
        "viewer: {} voxels in the scene, {} messages, {} bytes to live clients",
        s.voxels, s.messages, s.bytes
    );
    let secs = s.elapsed.as_secs_f64().max(1e-9);
    if s.messages > 0 {
        println!(
            "viewer: stream {:.1} messages/s, {:.0} bytes/s over {:.1} s",
            s.messages as f64 / secs,
            s.bytes as f64 / secs,
            secs
        );
    }
    if !s.latencies.is_empty() {
        let (median, p95) = median_p95(&s.latencies);
        println!(
            "viewer: frame arrival to view update: median {:.1} ms, p95 {:.1} ms ({} chunks, {} updates)",
            median.as_secs_f64() * 1e3,
            p95.as_secs_f64() * 1e3,
            s.latencies.len(),
            s.updates
        );
    }
    if !s.query_latencies.is_empty() {
        let (median, _) = median_p95(&s.query_latencies);
        let max = s.query_latencies.iter().max().copied().unwrap_or_default();
        println!(
            "viewer: query phrase to heat layer: median {:.1} ms, max {:.1} ms ({} phrases)",
            median.as_secs_f64() * 1e3,
            max.as_secs_f64() * 1e3,
            s.query_latencies.len()
        );
    }
    if let Some(r) = &s.recording {
        print_recording("the recording", r);
    }
    println!("viewer: client messages refused {}", s.refused);
    for e in &s.phrase_errors {
        println!("viewer: query refused: {e}");
    }
}
