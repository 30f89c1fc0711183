//! The demo's radio: the robot's `Mapper` ticks into a simulated faulty serial link, a base station
//! receives what arrives and acknowledges it over the link's other direction (faulty too), and the robot
//! reads the acknowledgements — exactly as a robot's UART pair would carry them. No robot is assembled
//! here: the robot is the evaluation's on-device `Mapper`, and this is only the air and the base station.
//!
//! Time: one tick per sensor frame, [`TICK_MS`] of link time, [`BUDGET`] bytes (a 115,200 baud UART at
//! ten ticks per second). At the end the robot drains and the radio keeps ticking until the base station
//! has acknowledged everything (with a back channel) or the robot has sent everything (without one).

use crate::base_station::BaseStation;
use crate::eval::methods::{Decoder, DeviceRobot, Radio, D};
use crate::link::{ByteLog, FaultyWriter, Pipe};
use crate::ObsMap;
use latentbki::frame::Resend;
use latentbki::wire::SessionConfig;
use latentbki::{key::VoxelKey, sink::Evicted, stats::VoxelStats, Setup};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

mod link_args;
mod study;
pub use link_args::LinkArgs;

/// The demo's summary codec: a Rice session (`latentbki::wire::rice`: each summary one bit stream, its
/// mean's steps following ‖m‖ and the point count, `rice::Policy::DEFAULT`), the 4 leading (PCA) mean
/// components as a band of their own, 2 scatter blocks. Against the packed codes below (protocol 4's lead
/// band of 8) on the demo's link, seed 7: 13.91 instead of 13.78 B per point, and the base station's RMS
/// ‖Δμ‖/‖μ‖ against the f32 reference 0.0287 instead of 0.0432 (`demo --codec-study` compares step
/// policies and, with `LATENTBKI_RICE_LEAD`, lead bands on the robot's map: 4 leading components cost
/// ≈ 1.4 B less than 8 for the same error, argmax 99.94 % at the lead's finer steps). What follows is the
/// packed codec's reasoning, still the fields' meaning when `rice` is off.
///
/// Packed: the 8 leading (PCA) mean components as a band of their own with 3 more bits,
/// the other 56 with 3 bits for a one-point voxel, one more bit per doubling of its points (up to 3 more),
/// 2 scatter blocks. (The classes live in the leading components: they take 3 B more per summary and
/// bring the base station's argmax agreement with the robot from 99.72 % to 99.95 % on the demo's map,
/// where one more bit for all 64 components costs 8 B for 99.88 % — `demo --codec-study`. The tile's
/// LiDAR voxels hold 3.5 points on average: most bytes go to voxels of one or two points. Ψ in 2 blocks
/// instead of 8 saves 3 B per summary of ≥ 2 points; μ and the argmax do not depend on it.)
pub const CODEC: latentbki::wire::SummaryCodec = latentbki::wire::SummaryCodec {
    mean_bits: 3,
    psi_blocks: 2,
    mean_bits_growth: 3,
    lead: 4,
    lead_bits: 3,
    rice: true,
};

/// Bytes the robot may send per tick.
pub const BUDGET: usize = 11_520;
/// Link time per tick (ms).
pub const TICK_MS: u64 = 100;
/// Ticks the end of a run may take to get everything acknowledged before the radio gives up (and counts
/// what is missing).
const DRAIN_TICKS: u32 = 20_000;

/// What the robot reported about its link at the end.
#[derive(Clone, Copy, Debug)]
struct RobotAccount {
    /// Points it integrated (all handed to the link by the end).
    points: f64,
    /// Final summaries it sent (voxels evicted).
    voxels: u32,
    /// Its link counters.
    stats: latentbki::wire::LinkStats,
    resent_bytes: u64,
    /// Points its map refused (counted by reason; e.g. no room while the link could not keep up).
    refused: latentbki::RejectionCounts,
    /// Whether its map's mean codes are weighed (`mean-weights`).
    weighed: bool,
}

/// The air between robot and base station, the base station, and the account of the run.
pub struct DemoRadio {
    /// Robot → base station.
    up: FaultyWriter<ByteLog>,
    /// Base station → robot (its receiving end is what the robot reads).
    down: FaultyWriter<Pipe>,
    base: BaseStation<D>,
    config: SessionConfig,
    args: LinkArgs,
    robot_map: Option<HashMap<VoxelKey, VoxelStats<D>>>,
    /// The robot's observed voxels (for `--codec-study`).
    robot_obs: Option<(
        latentbki::MapConfig,
        Vec<(VoxelKey, latentbki::obs::ObsStats<D>)>,
    )>,
    /// At the end, `--codec-study`'s table.
    study: Option<String>,
    /// Bytes of live-update frames.
    live_bytes: u64,
    /// The robot's link counters at the end.
    robot: Option<RobotAccount>,
    drained: bool,
    ticks: u64,
    /// At the end: agreement with the robot's own map.
    agreement: Option<(usize, f64)>,
    decoder: Option<Decoder>,
    /// At the end: against the f32 reference of all points (argmax, RMS ‖Δμ‖/‖μ‖, voxels).
    reference: Option<(f64, f64, usize)>,
    /// The same for the robot's own map (what no link can improve on).
    robot_reference: Option<(f64, f64, usize)>,
    /// The base station against the robot's own map (what the wire alone costs).
    wire_error: Option<(f64, f64, usize)>,
    /// The live view / recording of the base station, if asked for.
    viewer: Option<crate::base_station::phrases::StationViewer>,
}

impl DemoRadio {
    /// A radio with this link; the base station expects `config`'s sessions.
    pub fn new(config: SessionConfig, args: &LinkArgs) -> anyhow::Result<Arc<Mutex<Self>>> {
        let faults = args.faults()?;
        let base = BaseStation::new(config).map_err(|e| anyhow::anyhow!("base station: {e:?}"))?;
        Ok(Arc::new(Mutex::new(Self {
            up: FaultyWriter::new(ByteLog::default(), faults, args.link_seed),
            down: FaultyWriter::new(Pipe::default(), faults, args.link_seed ^ 0xACC),
            base,
            config,
            robot_map: None,
            robot_obs: None,
            study: None,
            args: args.clone(),
            live_bytes: 0,
            robot: None,
            drained: false,
            ticks: 0,
            agreement: None,
            decoder: None,
            reference: None,
            robot_reference: None,
            wire_error: None,
            viewer: None,
        })))
    }

    /// Show the base station's map in `viewer` as frames arrive.
    pub fn attach_viewer(&mut self, viewer: crate::base_station::phrases::StationViewer) {
        self.base.watch();
        self.viewer = Some(viewer);
    }

    /// The viewer, at the end of the run (to keep serving, then finish).
    pub fn take_viewer(&mut self) -> Option<crate::base_station::phrases::StationViewer> {
        self.viewer.take()
    }

    /// Deliver what the air carries this tick, both ways, and move its clocks.
    fn carry(&mut self, robot: &mut DeviceRobot) {
        let _ = self.up.advance(TICK_MS);
        let arrived = std::mem::take(&mut self.up.inner().0);
        let arrived_at = std::time::Instant::now();
        self.base.receive(&arrived);
        if let Some(v) = &self.viewer {
            let changed = self.base.take_watched();
            v.push(&self.base, changed, arrived_at);
        }
        let acks = self.base.take_acks();
        if !self.args.no_back_channel {
            use embedded_io::Write;
            let _ = self.down.write_all(&acks);
            let _ = self.down.advance(TICK_MS);
            let _ = robot.poll_acks(self.down.inner());
        }
        self.ticks += 1;
    }

    fn tick_robot(&mut self, robot: &mut DeviceRobot) {
        let Ok(r) = robot.tick_live(&mut self.up, BUDGET, self.args.live_bytes as usize);
        self.live_bytes += r.live_bytes as u64;
        self.carry(robot);
    }

    fn drain_robot(&mut self, robot: &mut DeviceRobot, tap: &mut dyn FnMut(&Evicted<'_, D>)) {
        let mut map_done = false;
        for _ in 0..DRAIN_TICKS {
            if map_done {
                self.tick_robot(robot);
            } else {
                map_done = robot.drain_tapped(&mut self.up, &mut *tap).is_ok();
                self.carry(robot);
            }
            if map_done && (self.args.no_back_channel || robot.is_drained()) {
                self.drained = true;
                break;
            }
        }
        let voxels = robot.map().counters().evicted;

        self.robot = Some(RobotAccount {
            points: 0.0,
            voxels,
            stats: robot.encoder().stats(),
            resent_bytes: u64::from(robot.encoder().resent_bytes()),
            refused: robot.map().rejections(),
            weighed: !robot.map().mean_weights().is_ones(),
        });
    }

    /// Compare the base station's map with the robot's own (every voxel either answers, by argmax).
    fn compare(&mut self, robot: &ObsMap<D>, decoder: &Decoder) {
        self.decoder = Some(decoder.clone());
        if let Some(a) = &mut self.robot {
            a.points = robot
                .observed_voxels()
                .map(|(_, o)| f64::from(o.count))
                .sum();
        }
        let mut m = HashMap::new();
        robot.for_each_posterior(|k, r| {
            m.insert(k, *r);
        });
        let Some(base) = self.base.map() else { return };
        let ours: HashMap<VoxelKey, VoxelStats<D>> = base.posteriors().into_iter().collect();
        let (mut both, mut agree) = (0usize, 0usize);
        let label = |m: &[f32; D]| decoder.argmax(m).map(|(c, _)| c);
        for (k, r) in &m {
            both += 1;
            agree += usize::from(ours.get(k).map(|b| label(&b.mean)) == Some(label(&r.mean)));
        }
        self.agreement = Some((both, agree as f64 / both.max(1) as f64));
        self.robot_map = Some(m);
        if self.args.codec_study {
            let obs = robot.observed_voxels().map(|(k, o)| (k, *o)).collect();
            self.robot_obs = Some((*robot.config(), obs));
        }
    }

    /// Compare the base station's posteriors with the f32 reference map of all points (sorted `(key,
    /// posterior)`): argmax agreement and RMS of ‖Δμ‖/‖μ‖ over the reference's voxels (a voxel the base
    /// station cannot answer counts as a disagreement with ‖Δμ‖ = ‖μ‖).
    pub fn compare_reference(&mut self, reference: &[(VoxelKey, VoxelStats<D>)]) {
        let (Some(base), Some(decoder), Some(robot)) =
            (self.base.map(), &self.decoder, &self.robot_map)
        else {
            return;
        };
        let ours: HashMap<VoxelKey, VoxelStats<D>> = base.posteriors().into_iter().collect();
        self.reference = Some(against(&ours, reference, decoder));
        self.robot_reference = Some(against(robot, reference, decoder));
        let mut robot_sorted: Vec<(VoxelKey, VoxelStats<D>)> =
            robot.iter().map(|(k, v)| (*k, *v)).collect();
        robot_sorted.sort_unstable_by_key(|(k, _)| *k);
        self.wire_error = Some(against(&ours, &robot_sorted, decoder));
        if let Some((config, obs)) = &self.robot_obs {
            let mut t = study::table(*config, obs, &robot_sorted, reference, decoder);
            t += &format!(
                "  robot map vs reference: {}\n  base station vs reference: {}\n  base station vs robot map: {}\n",
                study::profile(robot, reference),
                study::profile(&ours, reference),
                study::profile(&ours, &robot_sorted),
            );
            self.study = Some(t);
        }
    }

    /// The link's account in stable lines: points lost, bytes per integrated point by what they carried,
    /// and how the base station's map agrees with the robot's and with the f32 reference.
    pub fn summary(&self) -> String {
        let s = self.base.stats();
        let up = self.up.link().log();
        let down = self.down.link().log();
        let Some(robot) = self.robot else {
            return "the robot never drained".into();
        };
        let settled: f64 = self.base.map().map_or(0.0, |m| {
            m.voxels().map(|(_, v)| f64::from(v.settled.count)).sum()
        });
        let lost = (robot.points - settled).max(0.0);
        let per = |b: u64| b as f64 / robot.points.max(1.0);
        let total = self.up.bytes_in;
        let finals = total - robot.resent_bytes - self.live_bytes;
        let channel = if self.args.no_back_channel {
            "no back channel: what the link loses is lost"
        } else if self.drained {
            "back channel: every frame acknowledged, applied once"
        } else {
            "back channel, but the run ended before every frame was acknowledged"
        };
        let mut out = format!(
            "points lost on the link: {lost:.0} of {:.0} ({channel}; the base station counted {} frames never received)\n\
             wire bytes per integrated point: {:.2} (final voxels, headers and statistics: {finals} B sent first + {} B re-sent)\n\
             wire bytes per integrated point, live updates: {:.2} ({} B)\n\
             wire bytes per integrated point, acknowledgements (other direction): {:.2} ({} B)\n\
             summaries sent per global voxel: {:.2} ({} final summaries for {} voxels)\n",
            robot.points,
            s.lost,
            per(finals + robot.resent_bytes),
            robot.resent_bytes,
            per(self.live_bytes),
            self.live_bytes,
            per(self.down.bytes_in),
            self.down.bytes_in,
            f64::from(robot.voxels) / self.base.map().map_or(1, |m| m.len().max(1)) as f64,
            robot.voxels,
            self.base.map().map_or(0, |m| m.len()),
        );
        let r = robot.refused;
        out += &format!(
            "points the robot's map refused (counted, never sent): {} (no room {}, outside its window {}, bad input {})\n",
            r.total(),
            r.no_room,
            r.outside_window,
            r.total() - r.no_room - r.outside_window
        );
        let c = self.config.codec;
        // The optional `latentbki` features the robot's build links and its setup uses, against the boards'
        // build. The fixed-point cooling's sparse path is linked wherever the crate's defaults are (the
        // robot's too); `stored-codes` is linked, but this link streams Rice codes: stored codes are
        // ≈ 100 B a summary (this radio's budget is 14 B a point) and need weights without shifts, which
        // the PCA spreads give (the boards' self-test streams them: docs/numbers.md).
        let used: Vec<&str> = [
            ("rice-codes", c.is_rice()),
            ("mean-weights", robot.weighed),
            ("sparse-cooling", latentbki::quant::Cooling::SPARSE),
            (
                "stored-codes",
                latentbki::wire::SummaryCodec::STORED.is_stored(),
            ),
        ]
        .into_iter()
        .filter_map(|(f, on)| on.then_some(f))
        .collect();
        let boards = latentbki_selftest::BOARD_FEATURES;
        let same = used.len() == boards.len() && used.iter().all(|f| boards.contains(f));
        out += &if same {
            format!(
                "robot features: {} (exactly the boards' build, `latentbki-selftest/full`; its summaries \
                 Rice-coded, where the boards' self-test streams stored codes)\n",
                used.join(", ")
            )
        } else {
            format!(
                "robot features: {} (NOT the boards' build: {})\n",
                used.join(", "),
                boards.join(", ")
            )
        };
        out += &if c.is_rice() {
            format!(
                "summary codec: Rice-coded heads and means (a lead band of {}), scatter in {} blocks\n",
                c.lead, c.psi_blocks
            )
        } else {
            format!(
                "summary codec: packed means, {} bits (+{} growth), a lead band of {} at +{}, scatter in {} blocks\n",
                c.mean_bits, c.mean_bits_growth, c.lead, c.lead_bits, c.psi_blocks
            )
        };
        if let Some((n, a)) = self.agreement {
            out += &format!(
                "base station vs robot map, argmax agreement: {:.2} % of {n} voxels\n",
                100.0 * a
            );
        }
        if let Some((a, rms, n)) = self.reference {
            out += &format!(
                "base station vs f32 reference of all points: argmax {:.2} %, RMS ‖Δμ‖/‖μ‖ {rms:.4} ({n} voxels)\n",
                100.0 * a
            );
        }
        if let Some((a, rms, _)) = self.robot_reference {
            out += &format!(
                "robot's own map vs f32 reference of all points: argmax {:.2} %, RMS ‖Δμ‖/‖μ‖ {rms:.4}\n",
                100.0 * a
            );
        }
        if let Some((_, rms, _)) = self.wire_error {
            out += &format!(
                "base station vs robot map (the wire's own error): RMS ‖Δμ‖/‖μ‖ {rms:.4}\n"
            );
        }
        out += &format!(
            "link: {} ticks of {TICK_MS} ms; up: {} frames written ({} re-sent), {} dropped, {} truncated, {} delayed, \
             {} lost to outages; the base station applied {} frames and {} live updates, refused {} damaged runs of \
             bytes and {} repeated frames ({} copies made by the link); down: {} acknowledgements, {} lost to \
             outages; the robot refused {} damaged or foreign ones.",
            self.ticks,
            up.frames,
            robot.stats.resent,
            up.dropped,
            up.truncated,
            up.delayed,
            up.outage_dropped,
            s.frames,
            s.updated,
            s.decoder.refused(),
            s.refused.duplicate_frames,
            up.duplicated,
            down.frames,
            down.outage_dropped,
            robot.stats.bad_acks,
        );
        if let Some(t) = &self.study {
            out += "\n";
            out += t;
        }
        out
    }
}

/// Argmax agreement and RMS of ‖Δμ‖/‖μ‖ of `got` against the reference's voxels (sorted `(key,
/// posterior)`); a voxel `got` cannot answer counts as a disagreement with ‖Δμ‖ = ‖μ‖.
fn against(
    got: &HashMap<VoxelKey, VoxelStats<D>>,
    reference: &[(VoxelKey, VoxelStats<D>)],
    decoder: &Decoder,
) -> (f64, f64, usize) {
    let label = |m: &[f32; D]| decoder.argmax(m).map(|(c, _)| c);
    let (mut agree, mut sq) = (0usize, 0.0f64);
    for (k, r) in reference {
        let den: f64 = r.mean.iter().map(|x| f64::from(x * x)).sum();
        match got.get(k) {
            Some(b) => {
                agree += usize::from(label(&b.mean) == label(&r.mean));
                let num: f64 = b
                    .mean
                    .iter()
                    .zip(&r.mean)
                    .map(|(x, y)| f64::from((x - y) * (x - y)))
                    .sum();
                sq += num / den.max(1e-12);
            }
            None => sq += 1.0,
        }
    }
    let n = reference.len().max(1);
    (agree as f64 / n as f64, (sq / n as f64).sqrt(), n)
}

/// The demo's radio as the evaluation's [`Radio`] (shared, so the demo reports after the run).
pub struct DemoRadioLink(pub Arc<Mutex<DemoRadio>>);

impl Radio for DemoRadioLink {
    fn setup(&self, setup: Setup) -> Setup {
        let Ok(r) = self.0.lock() else { return setup };
        let resend = if r.args.no_back_channel {
            Resend::OFF
        } else {
            Resend::new(r.args.resend_bytes, r.args.resend_timeout_ticks())
        };
        Setup {
            link: setup.link.with_resend(resend),
            codec: r.config.codec,
            ..setup
        }
    }
    fn feature_space(
        &mut self,
        classes: &[String],
        pca: &latentbki::decode::Pca<D, { crate::sim::vocab::FULL_DIM }>,
        decoder: &Decoder,
    ) {
        if let Some(v) = self.0.lock().ok().as_ref().and_then(|r| r.viewer.as_ref()) {
            v.set_vocabulary(crate::base_station::phrases::vocabulary(
                classes.to_vec(),
                decoder.clone(),
                Box::new(pca.clone()),
            ));
            // The heat layer starts on the query the demo pictures; a viewer types another.
            let table = crate::sim::vocab::TextEmbeddings::builtin();
            if let Some(q) = crate::eval::scenes::tile_query(classes, &table) {
                v.set_phrase(&q);
            }
        }
    }
    fn tick(&mut self, robot: &mut DeviceRobot) {
        if let Ok(mut r) = self.0.lock() {
            r.tick_robot(robot);
        }
    }
    fn drain(&mut self, robot: &mut DeviceRobot, tap: &mut dyn FnMut(&Evicted<'_, D>)) {
        if let Ok(mut r) = self.0.lock() {
            r.drain_robot(robot, tap);
        }
    }
    fn finish(&mut self, robot: &ObsMap<D>, decoder: &Decoder) {
        if let Ok(mut r) = self.0.lock() {
            r.compare(robot, decoder);
        }
    }
}
