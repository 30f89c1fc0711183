//! End to end on every emulated target: the self-test firmware (`boards/selftest-firmware`) runs the
//! self-test (`latentbki_selftest::SELF_TEST`) in QEMU with its UART captured to a file, on a Cortex-M4F
//! (`boards/qemu-mps2-an386`, thumbv7em), on the Cortex-M0 instruction set (`boards/qemu-mps2-an385`,
//! thumbv6m: soft float) and on RISC-V (`boards/qemu-riscv32-virt`, riscv32imac); the host twin runs the same
//! core code (`latentbki_selftest::run` on the same `Mapper`, scenarios, map capacity, encoder sizes and
//! seeds, cooling int8 sums by the board's method: f32 on the M4F, fixed point on the two without an FPU)
//! and every target must produce the same bytes as its twin. Both streams are decoded (COBS + CRC frames, wire
//! summaries) into global maps that must be equal, non-trivial and semantically right (voxels decode to the
//! category of the surface they lie on).
//!
//! A board's firmware ELF is taken from its environment variable if set (`LATENTBKI_FIRMWARE_ELF` for the
//! an386, `…_ELF_AN385`, `…_ELF_RISCV32`), else it is built (`cargo build --release` in the board
//! directory, with `boards/measure.sh`'s flags so that either reuses the other's build: CI builds each
//! firmware once). Without the board's QEMU (`qemu-system-arm`, `qemu-system-riscv32`) or its Rust target a
//! test fails with the one line that fixes it (`cargo xtask setup`); `LATENTBKI_NO_QEMU=1` makes them
//! ignored instead (the crate's build script).

use latentbki::frame::FrameDecoder;
use latentbki::key::{to_map_frame, VoxelKey};
use latentbki::obs::ObsStats;
use latentbki::quant::{packed_len, Cooling};
use latentbki::wire::{parse_body, Message, SessionConfig};
use latentbki::Mapper;
use latentbki_firmware_tests::{Board, AN385, AN386, RISCV32_VIRT};
use latentbki_selftest::{
    self as selftest, CategoryVectors, Chunk, Scenario, CATEGORIES, SELF_TEST, SELF_TEST_CAPACITY,
    SELF_TEST_FRAME_BYTES, SELF_TEST_QUEUE_BYTES,
};
use std::collections::BTreeMap;

const D: usize = 64;
const P: usize = packed_len(D);
type Robot = Mapper<D, SELF_TEST_CAPACITY, P, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>;

/// What the host twin computes: the same scenarios through the same core code, plus the ground truth
/// (per voxel, how many points of each category fell in it).
struct Twin {
    bytes: Vec<u8>,
    reports: Vec<selftest::RunReport>,
    truth: Vec<BTreeMap<VoxelKey, [u32; CATEGORIES]>>,
}

fn twin(cooling: Cooling) -> Twin {
    // One mapper for all scenarios, reconfigured in place as the firmware does with its static.
    let mut mapper: Box<Robot> = Box::new(Robot::EMPTY);
    let mut chunk = Box::new(Chunk::<D, 16>::ZERO);
    let mut buf = vec![0u8; 8 << 20];
    let capacity = buf.len();
    let mut out: &mut [u8] = &mut buf[..];
    let mut reports = Vec::new();
    let mut truth = Vec::new();
    for scenario in &SELF_TEST {
        scenario.configure_cooling(&mut mapper, cooling).unwrap();
        let r = selftest::run(
            scenario,
            &mut mapper,
            &mut chunk,
            &mut out,
            &mut (),
            |_, _, _| {},
        )
        .unwrap_or_else(|e| panic!("twin run: {e:?}"));
        reports.push(r);
        truth.push(ground_truth(scenario));
    }
    let written = capacity - out.len();
    buf.truncate(written);
    Twin {
        bytes: buf,
        reports,
        truth,
    }
}

fn ground_truth(scenario: &Scenario) -> BTreeMap<VoxelKey, [u32; CATEGORIES]> {
    let inv = 1.0 / scenario.map_config().unwrap().voxel_size();
    let mut truth = BTreeMap::new();
    let mut f = [0.0f32; D];
    for frame in 0..scenario.frames {
        let view = scenario.scene.view(frame);
        let pose = view.pose();
        for zone in 0..scenario.scene.sensor.zones() {
            if let Some(o) = scenario.scene.observe(&view, frame, zone, &mut f) {
                let key = VoxelKey::from_position(to_map_frame(&pose, o.point), inv).unwrap();
                truth.entry(key).or_insert([0; CATEGORIES])[usize::from(o.category)] += 1;
            }
        }
    }
    truth
}

/// A global map per session configuration, from a byte stream: every final summary of every session
/// merged (residencies are disjoint observations). Returns (maps by configuration id, frames, finals).
type Global = BTreeMap<u32, (SessionConfig, BTreeMap<VoxelKey, ObsStats<D>>)>;

fn decode(bytes: &[u8]) -> (Global, u32, u32) {
    let mut decoder = Box::new(FrameDecoder::<4096>::new());
    let mut configs: BTreeMap<u32, SessionConfig> = BTreeMap::new();
    let mut maps: Global = BTreeMap::new();
    let (mut frames, mut finals) = (0, 0);
    let mut rest = bytes;
    loop {
        match decoder.feed(rest) {
            latentbki::frame::Feed::NeedMore => break,
            latentbki::frame::Feed::Error { error, .. } => panic!("frame error {error:?}"),
            latentbki::frame::Feed::Frame { body, rest: r } => {
                rest = r;
                frames += 1;
                let (header, message) = parse_body(body).expect("parse");
                match message {
                    Message::Session(c) => {
                        assert_eq!(c.id(), header.config_id);
                        configs.insert(c.id(), c);
                    }
                    Message::Stats(_) => {}
                    Message::Voxels(batch) => {
                        let config = configs[&header.config_id];
                        let (_, map) = maps
                            .entry(header.config_id)
                            .or_insert((config, BTreeMap::new()));
                        for s in batch.iter::<D>(config.codec) {
                            let s = s.expect("summary");
                            assert!(s.is_final, "the self-test streams evicted voxels only");
                            finals += 1;
                            map.entry(s.key)
                                .and_modify(|v| v.merge(&s.obs))
                                .or_insert(s.obs);
                        }
                    }
                }
            }
        }
    }
    assert_eq!(decoder.stats().refused(), 0);
    (maps, frames, finals)
}

#[test]
#[cfg_attr(
    latentbki_no_qemu,
    ignore = "LATENTBKI_NO_QEMU is set: the QEMU firmware tests are opted out"
)]
fn cortex_m4f_firmware_in_qemu_streams_the_map_the_host_twin_computes() {
    streams_the_map_the_host_twin_computes(&AN386);
}

#[test]
#[cfg_attr(
    latentbki_no_qemu,
    ignore = "LATENTBKI_NO_QEMU is set: the QEMU firmware tests are opted out"
)]
fn thumbv6m_firmware_in_qemu_streams_the_map_the_host_twin_computes() {
    streams_the_map_the_host_twin_computes(&AN385);
}

#[test]
#[cfg_attr(
    latentbki_no_qemu,
    ignore = "LATENTBKI_NO_QEMU is set: the QEMU firmware tests are opted out"
)]
fn riscv32_firmware_in_qemu_streams_the_map_the_host_twin_computes() {
    streams_the_map_the_host_twin_computes(&RISCV32_VIRT);
}

fn streams_the_map_the_host_twin_computes(board: &Board) {
    if let Err(line) = board.ready() {
        panic!("{line}");
    }
    let elf = board.firmware_elf();
    let (uart, stdout) = board.run_firmware(&elf);
    let twin = twin(board.cooling);

    // The firmware's own report agrees with the twin's, scenario by scenario.
    for (s, r) in twin.reports.iter().enumerate() {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&format!("scenario s={s} ")))
            .unwrap_or_else(|| panic!("no report for scenario {s}:\n{stdout}"));
        let expect = format!(
            "points={} integrated={} peak_voxels={}",
            r.points, r.integrated, r.peak_voxels
        );
        assert!(
            line.contains(&expect),
            "scenario {s}: firmware says `{line}`, twin `{expect}`"
        );
        assert!(
            line.contains(&format!(
                "frames_sent={} bytes_sent={}",
                r.link.frames_sent, r.link.bytes_sent
            )),
            "scenario {s}: `{line}` vs twin {:?}",
            r.link
        );
    }

    // Byte for byte the same stream.
    assert_eq!(
        uart.len(),
        twin.bytes.len(),
        "{}: UART stream length",
        board.dir
    );
    if let Some(i) = uart.iter().zip(&twin.bytes).position(|(a, b)| a != b) {
        panic!(
            "{}: UART stream differs from the twin's at byte {i} of {}",
            board.dir,
            uart.len()
        );
    }

    // Kept next to the ELF: the stream this very build printed, equal to the twin's. The link-time no-panic
    // proof (`boards/measure.sh --panic-never`) compares its build's stream with it instead of running
    // this build in QEMU a second time (minutes of soft float on thumbv6m).
    let mut kept = elf.clone().into_os_string();
    kept.push(".twin.uart");
    std::fs::write(&kept, &uart).expect("keep the twin-checked UART stream");

    // The same global maps, decoded.
    let (fw_maps, frames, finals) = decode(&uart);
    let (twin_maps, _, _) = decode(&twin.bytes);
    // One configuration per (filter size, feature type) in the self-test: its session headers.
    let configs: std::collections::BTreeSet<u32> = SELF_TEST
        .iter()
        .map(|sc| sc.setup().unwrap().session(D).id())
        .collect();
    assert_eq!(
        fw_maps.len(),
        configs.len(),
        "f = 1, f = 3, f = 3 with int8 features"
    );
    assert_eq!(configs.len(), 3);
    for (id, (config, fw)) in &fw_maps {
        let (_, tw) = &twin_maps[id];
        assert_eq!(fw.len(), tw.len());
        for (k, v) in fw {
            assert_eq!(Some(v), tw.get(k), "voxel {k:?} (config {id:#x})");
        }
        assert!(
            fw.len() > 300,
            "config f={}: only {} voxels",
            config.filter_size,
            fw.len()
        );
    }
    let sent: u32 = twin.reports.iter().map(|r| r.link.evicted_sent).sum();
    assert_eq!(finals, sent);
    assert!(frames > 100);

    // Semantics: a voxel's observed mean decodes to the category most of its points had.
    let s = 1;
    let id = SELF_TEST[s].setup().unwrap().session(D).id();
    let (_, global) = &fw_maps[&id];
    let (mut right, mut total) = (0, 0);
    for (key, counts) in &twin.truth[s] {
        let n: u32 = counts.iter().sum();
        let majority = (0..CATEGORIES).max_by_key(|&c| counts[c]).unwrap();
        if n < 20 || counts[majority] * 10 < n * 9 {
            continue; // sparse or mixed voxels
        }
        let v = global
            .get(key)
            .expect("an observed voxel reached the base station");
        total += 1;
        if CategoryVectors::<D>::classify(&v.mean) == Some(majority as u8) {
            right += 1;
        }
    }
    assert!(total > 100, "{total} clear voxels");
    assert!(
        right * 100 >= total * 95,
        "{right} of {total} voxels decode to their category"
    );
}
