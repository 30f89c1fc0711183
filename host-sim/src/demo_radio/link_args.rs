//! The demo's link as the command line sets it: its faults both ways, the robot's re-send timeout and
//! the live-update budget (`host-sim demo --ber …`).

use super::TICK_MS;
use crate::link::Faults;
use clap::Args;

/// The demo's link, from the command line.
#[derive(Args, Debug, Clone)]
pub struct LinkArgs {
    /// Byte error rate of the link (both directions); dropped bytes and bursts of garbage scale with it.
    #[arg(long, default_value_t = 1e-4)]
    pub ber: f64,
    /// Fraction of frames dropped whole.
    #[arg(long, default_value_t = 0.02)]
    pub frame_drops: f64,
    /// Longest delay of a delayed frame (5 % are delayed, so later frames overtake them), ms.
    #[arg(long, default_value_t = 300)]
    pub max_delay_ms: u64,
    /// An outage of `--outage-secs` every this many seconds (0 = none).
    #[arg(long, default_value_t = 0.0)]
    pub outage_every_secs: f64,
    /// How long each outage lasts (s).
    #[arg(long, default_value_t = 3.0)]
    pub outage_secs: f64,
    /// No back channel: frames are sent once and what the link loses is lost (and counted).
    #[arg(long)]
    pub no_back_channel: bool,
    /// Bytes per tick for live updates of the voxels the robot holds (0 = only final voxels).
    #[arg(long, default_value_t = 2048)]
    pub live_bytes: u32,
    /// Bytes of the robot's queue budget that hold unacknowledged frames.
    #[arg(long, default_value_t = 16 * 1024)]
    pub resend_bytes: u32,
    /// Ticks without acknowledgement before a frame is re-sent (a frame shown missing by a later one's
    /// acknowledgement waits half of it). Default: the longest round trip, 2 × `--max-delay-ms`, in
    /// ticks, plus 2 (8 at 300 ms). A shorter timeout re-sends frames that were only delayed and drains
    /// the window sooner, so voxels leave the map and come back: at 5 the demo printed 13.79–14.22 B per
    /// point over link seeds 7–13, at 8 13.44–13.63 (docs/numbers.md); the price is a later repair of
    /// real losses (the run drained in 339 ticks instead of 265).
    #[arg(long)]
    pub resend_ticks: Option<u32>,
    /// Seed of the link's faults.
    #[arg(long, default_value_t = 7)]
    pub link_seed: u64,
    /// After the run, measure other summary codecs on the robot's map (where the base station's error
    /// comes from; `demo_radio::study`).
    #[arg(long)]
    pub codec_study: bool,
}

impl LinkArgs {
    /// The re-send timeout in ticks: `--resend-ticks`, or the longest round trip (both directions at
    /// `--max-delay-ms`) in ticks plus 2, so that a frame only delayed is not re-sent.
    pub fn resend_timeout_ticks(&self) -> u32 {
        self.resend_ticks
            .unwrap_or_else(|| {
                let round_trip = (2 * self.max_delay_ms).div_ceil(TICK_MS);
                u32::try_from(round_trip)
                    .unwrap_or(u32::MAX)
                    .saturating_add(2)
            })
            .max(1)
    }

    /// The faults of one direction.
    pub fn faults(&self) -> anyhow::Result<Faults> {
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.ber) && (0.0..=1.0).contains(&self.frame_drops),
            "--ber and --frame-drops are probabilities in [0, 1]"
        );
        anyhow::ensure!(
            self.outage_every_secs >= 0.0 && self.outage_secs >= 0.0,
            "--outage-every-secs and --outage-secs must be >= 0"
        );
        let every = (self.outage_every_secs * 1000.0) as u64;
        let outage = ((self.outage_secs * 1000.0) as u64).min(every);
        Ok(
            Faults::with_drops_and_delays(self.ber, self.frame_drops, self.max_delay_ms)
                .with_outages(every, outage),
        )
    }
}
