//! `host-sim base-station`: receive robots' streams from a serial port, a file, a pty or stdin; keep, save
//! and export the global map.

use super::export::{write_ply, write_pngs, MAX_SIDE};
use super::file::LoadError;
use super::{BaseStation, GlobalMap, VOCAB_CAP};
use crate::npy_io::NpzReader;
use anyhow::{bail, Context, Result};
use clap::Args;
use latentbki::wire::feature_space_id;
use latentbki::{Codebook, Pca};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Feature dimension the base station is built for (the wire's D).
pub const DIM: usize = 64;
/// Full text-embedding dimension.
pub const FULL: usize = 384;

/// Options of `host-sim base-station`.
#[derive(Args, Debug)]
pub struct BaseStationArgs {
    /// Where the bytes come from: a file or a pty path, or `-` for stdin. Not with `--serial`.
    input: Option<PathBuf>,
    /// Read from a serial port (e.g. /dev/ttyUSB0) instead.
    #[arg(long, conflicts_with = "input")]
    serial: Option<String>,
    /// Serial baud rate.
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// Stop after this many seconds (serial ports and ptys never end by themselves).
    #[arg(long, value_parser = parse_duration, allow_negative_numbers = true)]
    duration: Option<Duration>,
    /// Continue this saved map (if the file exists) and save back to it at the end.
    #[arg(long)]
    map: Option<PathBuf>,
    /// PCA of the robots' features (.npz with `mean` (384) and `components` (64×384), float32), to decode
    /// labels and queries; it must match the robots' feature-space id.
    #[arg(long)]
    pca: Option<PathBuf>,
    /// Vocabulary: comma-separated phrases of the built-in embedding table (default: the 12 ASPRS classes).
    #[arg(long)]
    classes: Option<String>,
    /// Text query for the heatmap (a phrase of the built-in table).
    #[arg(long)]
    query: Option<String>,
    /// Write top-down PNGs `<prefix>-labels.png`, `-heat.png`, `-uncertainty.png`.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Pixels per voxel in the PNGs (1..=16384; the image is at most 16384 pixels per side).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_SIDE)))]
    scale: u32,
    /// Write the map as an ASCII PLY point cloud.
    #[arg(long)]
    ply: Option<PathBuf>,
}

/// `--duration`: seconds, finite, >= 0 and representable as a [`Duration`].
fn parse_duration(s: &str) -> Result<Duration, String> {
    let secs: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number of seconds"))?;
    if !secs.is_finite() || secs < 0.0 {
        return Err(format!("{s} seconds: give a finite number of seconds >= 0"));
    }
    Duration::try_from_secs_f64(secs).map_err(|_| format!("{s} seconds is too long a duration"))
}

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

/// The vocabulary (`--pca`, `--classes`) and the query (`--query`) codebooks.
type Vocab = (Vec<String>, Codebook<DIM, VOCAB_CAP>, Box<Pca<DIM, FULL>>);

fn read_vocabulary(
    args: &BaseStationArgs,
) -> Result<(Option<Vocab>, Option<Codebook<DIM, VOCAB_CAP>>)> {
    let Some(p) = &args.pca else {
        if args.classes.is_some() {
            bail!("--classes needs --pca (the PCA the robots used)");
        }
        if args.query.is_some() {
            bail!("--query needs --pca (the PCA the robots used)");
        }
        return Ok((None, None));
    };
    let pca = read_pca(p)?;
    let table = crate::sim::vocab::Vocabulary::builtin();
    let names: Vec<String> = match &args.classes {
        Some(c) => c.split(',').map(|s| s.trim().to_string()).collect(),
        None => table.phrases().into_iter().take(12).collect(),
    };
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let emb = table
        .embeddings(&refs)
        .map_err(|e| anyhow::anyhow!("--classes: {e}"))?;
    let cb = Codebook::from_pca(&pca, &emb).map_err(|e| anyhow::anyhow!("vocabulary: {e}"))?;
    let query = match &args.query {
        Some(q) => {
            let e = table
                .embeddings(&[q.as_str()])
                .map_err(|e| anyhow::anyhow!("--query: {e}"))?;
            Some(
                Codebook::<DIM, VOCAB_CAP>::from_pca(&pca, &e)
                    .map_err(|e| anyhow::anyhow!("query: {e}"))?,
            )
        }
        None => None,
    };
    Ok((Some((names, cb, pca)), query))
}

/// The PCA must be the robots' (the map's feature-space id) or the labels would be meaningless.
fn check_feature_space(
    args: &BaseStationArgs,
    vocab: Option<&Vocab>,
    map: &GlobalMap<DIM>,
) -> Result<()> {
    if let (Some(p), Some((_, _, pca))) = (&args.pca, vocab) {
        let id = feature_space_id(pca);
        if id != map.config().feature_space {
            bail!(
                "{}: feature-space id {id:#010x} is not the robots' ({:#010x}): labels would be meaningless",
                p.display(),
                map.config().feature_space
            );
        }
    }
    Ok(())
}

/// The `--pca` file, as [`crate::npy_io::write_pca_npz`] writes it (and numpy's `savez`).
fn read_pca(path: &Path) -> Result<Box<Pca<DIM, FULL>>> {
    let mut npz = NpzReader::open(path)?;
    let mut array = |name: &str, len: usize| -> Result<Vec<f32>> {
        let (_, v) = npz.array::<f32>(name)?;
        if v.len() != len {
            bail!(
                "{}: `{name}` has {} values, expected {len}",
                path.display(),
                v.len()
            );
        }
        Ok(v)
    };
    let mean = array("mean", FULL)?;
    let comps = array("components", DIM * FULL)?;
    let mut pca = Box::new(Pca {
        mean: [0.0; FULL],
        components: [[0.0; FULL]; DIM],
    });
    pca.mean.copy_from_slice(&mean);
    for (row, chunk) in pca.components.iter_mut().zip(comps.chunks_exact(FULL)) {
        row.copy_from_slice(chunk);
    }
    Ok(pca)
}

/// Run the command.
pub fn run(args: &BaseStationArgs) -> Result<()> {
    // Every option is checked before the first byte is read: a typo found at the end would lose a whole
    // serial session.
    if let Some(p) = &args.map {
        check_output("--map", p, false)?;
    }
    if let Some(p) = &args.png {
        check_output("--png", p, true)?;
    }
    if let Some(p) = &args.ply {
        check_output("--ply", p, false)?;
    }
    let (vocab, query) = read_vocabulary(args)?;
    let mut base = match &args.map {
        Some(p) if p.exists() => {
            let map = GlobalMap::<DIM>::load(p).map_err(|e| match e {
                LoadError::Io { .. } => anyhow::Error::new(e), // names the file already
                e => anyhow::anyhow!("{}: {e}", p.display()),
            })?;
            // A continued map knows the robots' feature space already: check the PCA now.
            check_feature_space(args, vocab.as_ref(), &map)?;
            println!("continuing {} ({} voxels)", p.display(), map.len());
            BaseStation::from_map(map)
        }
        _ => BaseStation::<DIM>::adopting(),
    };
    let mut source: Box<dyn Read> = match (&args.serial, &args.input) {
        (Some(port), _) => Box::new(
            serialport::new(port, args.baud)
                .timeout(Duration::from_millis(200))
                .open()
                .with_context(|| format!("opening serial port {port}"))?,
        ),
        (None, Some(p)) if p.as_os_str() == "-" => Box::new(std::io::stdin()),
        (None, Some(p)) => {
            Box::new(std::fs::File::open(p).with_context(|| format!("opening {}", p.display()))?)
        }
        (None, None) => bail!("give an input file, `-` for stdin, or --serial PORT"),
    };
    let start = Instant::now();
    let deadline = args.duration;
    let mut buf = [0u8; 4096];
    loop {
        if deadline.is_some_and(|d| start.elapsed() >= d) {
            break;
        }
        match source.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => base.receive(&buf[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(e).context("reading the input"),
        }
    }
    let s = base.stats();
    println!(
        "frames accepted {}; summaries merged {}, live {}, ignored copies {}; frames lost {} (late {}); refused: CRC {}, COBS {}, short {}, overflow {}, version {}, malformed {}, wrong config {}, invalid voxel {}, duplicate {}",
        s.frames, s.merged, s.updated, s.ignored, s.lost, s.late,
        s.decoder.crc_errors, s.decoder.cobs_errors, s.decoder.too_short, s.decoder.overflows,
        s.rejected.version, s.rejected.malformed, s.rejected.wrong_config, s.rejected.invalid_voxel, s.rejected.duplicate_frames
    );
    for ((robot, session), st) in base.sessions() {
        println!(
            "robot {robot} session {session}: {} frames received, {} lost{}",
            st.seq.received,
            st.seq.lost,
            st.link.map_or(String::new(), |l| format!(
                "; robot reports {} frames sent, {} evicted voxels, {} refused by its queue",
                l.frames_sent, l.evicted_sent, l.refused
            ))
        );
    }
    let Some(map) = base.map() else {
        bail!("no session header with a {DIM}-dimensional configuration was received: nothing to keep");
    };
    println!("global map: {} voxels", map.len());
    if let Some(p) = &args.map {
        map.save(p)
            .with_context(|| format!("saving {}", p.display()))?;
        println!("saved {}", p.display());
    }
    check_feature_space(args, vocab.as_ref(), map)?;
    let empty =
        Codebook::<DIM, VOCAB_CAP>::from_embeddings(&[]).expect("an empty codebook is valid");
    let cb = vocab.as_ref().map_or(&empty, |v| &v.1);
    if let Some(prefix) = &args.png {
        for f in write_pngs(map, cb, query.as_ref().map(|q| (q, 0)), prefix, args.scale)? {
            println!("wrote {}", f.display());
        }
    }
    if let Some(p) = &args.ply {
        write_ply(map, cb, p)?;
        println!("wrote {}", p.display());
    }
    if let Some((names, _, _)) = &vocab {
        let mut counts = vec![0usize; names.len()];
        for k in map.sorted_keys() {
            if let Some((l, _)) = map.label(&k, cb) {
                counts[l] += 1;
            }
        }
        for (n, c) in names.iter().zip(counts) {
            println!("  {n}: {c} voxels");
        }
    }
    Ok(())
}
