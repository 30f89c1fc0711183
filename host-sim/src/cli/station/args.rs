//! The options of `host-sim base-station`, `map-info` and `map-query` (clap) with their value parsers:
//! what a user can ask for, apart from what the commands do with it ([`super`]).

use super::check_output;
use crate::base_station::export::MAX_SIDE;
use crate::base_station::view::DEFAULT_ADDR;
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use std::time::Duration;

/// Options of `host-sim base-station`.
///
/// Every link is read at once, each with its own decoder state, and every frame they carry merges into
/// the one map. On a link with a back channel — a serial port, a pty, a TCP connection, `--stdio` — the
/// base station writes acknowledgements: with `--map`, only for frames its database holds (after the
/// commit that made them durable), so a robot never drops a frame a crash could lose; without, at once.
#[derive(Args, Debug)]
#[command(
    after_help = "Acknowledgements (protocol 3): each accepted or repeated frame is acknowledged \
on the link it came in on — serial ports, ptys and other terminals, TCP connections (--listen) and \
--stdio's stdout; recordings and `-` have no back channel. With --map a frame is acknowledged only after \
the commit that made it durable (at most --commit-ms later), so a crash never loses a frame its robot \
was told is safe; --no-acks writes none."
)]
pub struct BaseStationArgs {
    /// Inputs: recordings (read one after another, in this order, as if fed in turn), ptys and other
    /// terminals (read and acknowledged, all at once), `-` for stdin (read only).
    pub(super) inputs: Vec<PathBuf>,
    /// A serial port to read and acknowledge, as PORT or PORT@BAUD (e.g. /dev/ttyUSB0@921600); repeat it
    /// for several robots' ports.
    #[arg(long, value_name = "PORT[@BAUD]")]
    pub(super) serial: Vec<String>,
    /// Baud rate of ports (and ptys) given without one.
    #[arg(long, default_value_t = 115_200)]
    pub(super) baud: u32,
    /// Accept TCP connections from gateways, each a robot's link (its serial bytes in, acknowledgements
    /// out) [default: 127.0.0.1:7707, this machine only; name another address to listen beyond it].
    /// Write `--listen=ADDR` before a positional argument.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = super::links::DEFAULT_LISTEN)]
    pub(super) listen: Option<std::net::SocketAddr>,
    /// Read a robot's bytes on stdin and write its acknowledgements on stdout (a gateway, e.g. `socat` or
    /// `ssh`, runs the base station at the other end of a pipe); the report goes to stderr.
    #[arg(long)]
    pub(super) stdio: bool,
    /// Write no acknowledgements (a one-way radio, or a line another device also reads).
    #[arg(long)]
    pub(super) no_acks: bool,
    /// Stop after this many seconds (serial ports, ptys and listeners never end by themselves).
    #[arg(long, value_parser = parse_duration, allow_negative_numbers = true)]
    pub(super) duration: Option<Duration>,
    /// The global map database (SQLite): created if missing, continued if present (sessions included:
    /// frames already merged are recognised). Without it the map lives in memory only.
    #[arg(long)]
    pub(super) map: Option<PathBuf>,
    /// Commit accepted frames to the database at least this often (milliseconds): a crash loses at most
    /// the frames of the last interval, which were not acknowledged yet (their robots send them again).
    #[arg(long, default_value_t = 250, value_parser = clap::value_parser!(u64).range(1..=3_600_000))]
    pub(super) commit_ms: u64,
    #[command(flatten)]
    pub(super) view: ViewArgs,
    #[command(flatten)]
    pub(super) out: OutputArgs,
}

/// The live 3D view (Foxglove) and the MCAP recording of the base station's map.
#[derive(Args, Debug, Clone)]
pub struct ViewArgs {
    /// Serve the map live to Foxglove or Lichtblick (Foxglove WebSocket protocol) at ADDR [default:
    /// 127.0.0.1:8765, this machine only; name another address to serve beyond it]. Write `--view=ADDR`
    /// before a positional argument.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = DEFAULT_ADDR)]
    pub view: Option<std::net::SocketAddr>,
    /// Record the view's topics to this MCAP file (Foxglove's protobuf schemas: Foxglove, Lichtblick and PyPI
    /// `mcap` read it; not a ROS 2 bag: `ros2 bag play` cannot publish its messages).
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// At most this many view updates a second (changed voxels are coalesced in between).
    #[arg(long, default_value_t = 10.0, value_parser = parse_rate)]
    pub view_hz: f64,
    /// Messages queued per viewer client before its oldest are dropped (a client that does not read costs
    /// at most this much memory).
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub view_backlog: u64,
}

impl ViewArgs {
    /// Whether a view or a recording is asked for.
    pub fn wanted(&self) -> bool {
        self.view.is_some() || self.record.is_some()
    }
    /// Check the recording's path before anything is read.
    pub fn check(&self) -> Result<()> {
        if let Some(p) = &self.record {
            check_output("--record", p, false)?;
        }
        Ok(())
    }
}

/// `--view-hz`: a finite rate in (0, 1000].
fn parse_rate(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(r) if r.is_finite() && r > 0.0 && r <= 1000.0 => Ok(r),
        _ => Err(format!(
            "`{s}`: give a number of updates per second in (0, 1000]"
        )),
    }
}

/// What to show of the map at the end: vocabulary, query, pictures.
#[derive(Args, Debug)]
pub struct OutputArgs {
    /// PCA of the robots' features (.npz with `mean` (384) and `components` (64×384), float32), to decode
    /// labels and queries; it must match the robots' feature-space id.
    #[arg(long)]
    pub(super) pca: Option<PathBuf>,
    /// Vocabulary: comma-separated phrases of the built-in embedding table (default: the 12 ASPRS classes).
    #[arg(long)]
    pub(super) classes: Option<String>,
    /// Text query for the heatmap (a phrase of the built-in table).
    #[arg(long)]
    pub(super) query: Option<String>,
    /// Write top-down pictures, titled, with a legend or colour bar and a scale bar, sized to the map:
    /// `<prefix>-labels.png` (with --pca), `-heat.png` (with --query), `-uncertainty.png`, and `-gain.png`
    /// (information gain: where to look next; raw, --scale pixels per voxel). The folder is created.
    #[arg(long)]
    pub(super) png: Option<PathBuf>,
    /// Pixels per voxel of `-gain.png` (1..=16384; the image is at most 16384 pixels per side).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_SIDE)))]
    pub(super) scale: u32,
    /// Write the map as an ASCII PLY point cloud.
    #[arg(long)]
    pub(super) ply: Option<PathBuf>,
}

/// Options of `host-sim map-info`.
#[derive(Args, Debug)]
pub struct MapInfoArgs {
    /// The map database (opened read-only; a running base station keeps writing it).
    pub(super) db: PathBuf,
}

/// Options of `host-sim map-query`.
#[derive(Args, Debug)]
pub struct MapQueryArgs {
    /// The map database (opened read-only; a running base station keeps writing it).
    pub(super) db: PathBuf,
    /// With --query: list this many best-matching voxels.
    #[arg(long, default_value_t = 10)]
    pub(super) top: usize,
    /// Export the map as one full scene of the live view's topics to this MCAP file.
    #[arg(long, value_name = "FILE.mcap")]
    pub(super) mcap: Option<PathBuf>,
    #[command(flatten)]
    pub(super) out: OutputArgs,
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
