//! The accuracy that ships: a QEMU firmware's own UART bytes, fed to the base station, against the f32 map
//! of the points that firmware integrated.
//!
//! The self-test firmware (`boards/selftest-firmware`) streams every scenario of
//! `latentbki_selftest::SELF_TEST` as its own session. Here each session's frames go to a base station of
//! their own (`latentbki_station::BaseStation`, what a user deploys), whose global map gathers a posterior
//! for every voxel in reach; the reference is the f32 observation map (`ObsMap`, equal to the paper's update)
//! of the very points the firmware took — which ones, the host twin says (the same core code, scenarios and
//! sizes: `latentbki_selftest::run`, which the QEMU end-to-end test shows streams the firmware's bytes) —
//! with their f32 features (before int8 quantization), each keyed to the voxel the firmware keyed it to.
//! Printed: RMS of ‖Δμ‖/‖μ‖ over every reference voxel of every scenario (a voxel the base station cannot
//! answer counts as ‖Δμ‖ = ‖μ‖), then each scenario's.
//!
//! A voxel the base station does not answer is also named on stderr.
//!
//! Run: `cargo run --release -p host-sim --example firmware_accuracy -- TARGET UART.bin` (`boards/measure.sh`
//! does, for each board's run, with `--row`; TARGET is thumbv7em, thumbv6m or riscv32imac and picks the
//! board's cooling). `-- TARGET --twin` feeds the base station the host twin's own stream instead (no QEMU:
//! the same bytes, as `cargo test -p latentbki-firmware-tests` shows), for measuring a change on the host.

use host_sim::base_station::BaseStation;
use host_sim::ObsMap;
use latentbki::fixed_pose::FixedPose;
use latentbki::frame::{Feed, FrameDecoder};
use latentbki::key::{to_map_frame, VoxelKey};
use latentbki::nalgebra::Isometry3;
use latentbki::obs::ObsStats;
use latentbki::quant::{packed_len, Cooling};
use latentbki::stats::VoxelStats;
use latentbki::wire::parse_body;
use latentbki::Mapper;
use latentbki_selftest::{
    self as selftest, Chunk, Probe, Scenario, SELF_TEST, SELF_TEST_CAPACITY, SELF_TEST_FRAME_BYTES,
    SELF_TEST_QUEUE_BYTES,
};
use std::collections::{BTreeMap, HashMap};

const D: usize = 64;
type Robot =
    Mapper<D, SELF_TEST_CAPACITY, { packed_len(D) }, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>;

/// Builds the f32 reference of the points the map took.
struct Reference {
    map: ObsMap<D>,
    voxel: f32,
}

impl Probe for Reference {
    const SEES_POINTS: bool = true;
    fn point(
        &mut self,
        pose: &Isometry3<f32>,
        point: [f32; 3],
        point_mm: Option<[i32; 3]>,
        feature: &[f32],
        taken: bool,
    ) {
        if !taken {
            return;
        }
        // The voxel the map keyed the point to: in fixed point from millimetres for int8 features.
        let key = match point_mm {
            Some(mm) => FixedPose::new(pose, self.voxel).and_then(|f| f.key_of(mm)),
            None => VoxelKey::from_position(to_map_frame(pose, point), 1.0 / self.voxel).ok(),
        };
        let (Some(key), Ok(mean)) = (key, <[f32; D]>::try_from(feature)) else {
            panic!("a point the map took has no key or a feature of another dimension");
        };
        self.map.merge_observations(
            key,
            &ObsStats {
                count: 1.0,
                mean,
                scatter: [0.0; D],
            },
        );
    }
}

/// A writer that keeps the twin's stream (with `--twin`, what the base station is fed).
struct Collect(Vec<u8>);
impl embedded_io::ErrorType for Collect {
    type Error = core::convert::Infallible;
}
impl embedded_io::Write for Collect {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

fn reference(
    scenario: &Scenario,
    cooling: Cooling,
    robot: &mut Robot,
    stream: &mut Collect,
) -> ObsMap<D> {
    let config = scenario.map_config().expect("self-test configuration");
    let mut probe = Reference {
        map: ObsMap::new(config).expect("self-test configuration"),
        voxel: config.voxel_size(),
    };
    let setup = scenario
        .setup()
        .expect("self-test setup")
        .with_cooling(cooling);
    robot.configure(&setup).expect("self-test setup");
    let mut chunk = Box::new(Chunk::<D, 16>::ZERO);
    selftest::run(
        scenario,
        robot,
        &mut chunk,
        stream,
        &mut probe,
        |_, _, _| {},
    )
    .unwrap_or_else(|e| panic!("twin run of {}: {e:?}", scenario.name));
    probe.map
}

/// The stream's frames by session (each frame with its COBS delimiter, as the UART carried it).
fn by_session(uart: &[u8]) -> BTreeMap<u32, Vec<u8>> {
    let mut out: BTreeMap<u32, Vec<u8>> = BTreeMap::new();
    let mut decoder = Box::new(FrameDecoder::<4096>::new());
    for frame in uart.split_inclusive(|&b| b == 0) {
        if let Feed::Frame { body, .. } = decoder.feed(frame) {
            if let Ok((header, _)) = parse_body(body) {
                out.entry(header.session)
                    .or_default()
                    .extend_from_slice(frame);
            }
        }
    }
    out
}

/// Σ ‖Δμ‖²/‖μ‖² over the reference's voxels, their number and how many the base station did not answer.
fn error(
    got: &[(VoxelKey, VoxelStats<D>)],
    reference: &[(VoxelKey, VoxelStats<D>)],
) -> (f64, usize, usize) {
    let got: HashMap<VoxelKey, &VoxelStats<D>> = got.iter().map(|(k, v)| (*k, v)).collect();
    let (mut sq, mut missing) = (0.0f64, 0usize);
    for (k, r) in reference {
        let den: f64 = r.mean.iter().map(|x| f64::from(x * x)).sum();
        sq += match got.get(k) {
            Some(b) => {
                let num: f64 = b
                    .mean
                    .iter()
                    .zip(&r.mean)
                    .map(|(x, y)| f64::from(x - y).powi(2))
                    .sum();
                num / den.max(1e-30)
            }
            None => {
                missing += 1;
                1.0
            }
        };
    }
    (sq, reference.len(), missing)
}

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    // `--row`: as a row of `boards/measure.sh`'s Markdown table.
    let row = args.first().is_some_and(|a| a == "--row");
    if row {
        args.remove(0);
    }
    let [target, path] = args.as_slice() else {
        anyhow::bail!(
            "usage: firmware_accuracy [--row] TARGET UART.bin|--twin (TARGET: thumbv7em, thumbv6m or riscv32imac)"
        );
    };
    let cooling = match target.as_str() {
        "thumbv7em" => Cooling::Float,
        "thumbv6m" | "riscv32imac" => Cooling::Fixed,
        t => anyhow::bail!("unknown target {t} (thumbv7em, thumbv6m or riscv32imac)"),
    };
    let twin = path == "--twin";
    let mut robot: Box<Robot> = Box::new(Robot::EMPTY);
    let mut stream = Collect(Vec::new());
    let references: Vec<_> = SELF_TEST
        .iter()
        .map(|s| reference(s, cooling, &mut robot, &mut stream).posteriors_sorted())
        .collect();
    let uart = if twin {
        stream.0
    } else {
        std::fs::read(path).map_err(|e| anyhow::anyhow!("{path}: {e}"))?
    };
    let sessions = by_session(&uart);
    let (mut sq, mut n) = (0.0f64, 0usize);
    let mut rows = Vec::new();
    for (scenario, reference) in SELF_TEST.iter().zip(&references) {
        let setup = scenario.setup().expect("self-test setup");
        let mut base = BaseStation::<D>::new(setup.session(D))
            .map_err(|e| anyhow::anyhow!("base station: {e:?}"))?;
        base.receive(
            sessions
                .get(&scenario.session)
                .map_or(&[][..], Vec::as_slice),
        );
        let got = base.map().map(|m| m.posteriors()).unwrap_or_default();
        let (s, k, m) = error(&got, reference);
        if m > 0 {
            eprintln!("{}: {m} of {k} voxels unanswered", scenario.name);
        }
        rows.push(format!(
            "{} {:.4} ({k} voxels)",
            scenario.name,
            (s / k.max(1) as f64).sqrt()
        ));
        sq += s;
        n += k;
    }
    let label = format!(
        "μ RMS ‖Δμ‖/‖μ‖ vs f32 reference, base station from the {} stream ({target})",
        if twin { "host twin's" } else { "firmware's" }
    );
    let value = format!(
        "{:.4} ({} scenarios, {n} voxels; {})",
        (sq / n.max(1) as f64).sqrt(),
        SELF_TEST.len(),
        rows.join(", ")
    );
    if row {
        println!("| {label} | {value} | ≤ 0.03 |");
    } else {
        println!("{label}: {value}");
    }
    Ok(())
}
