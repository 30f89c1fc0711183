//! The link breaks; the map does not. At byte error rates 1e-4, 1e-3 and 1e-2, with dropped, truncated
//! and duplicated frames, lost bytes and bursts of garbage: no corrupted frame (so no corrupted voxel) is
//! ever accepted, every frame that arrived intact is accepted (re-synchronisation costs no intact frame),
//! and every frame that did not is counted lost. Wrong versions and configurations are refused and counted.

mod stream_common;

use host_sim::base_station::BaseStation;
use host_sim::link::{frame_body, split_frames, ByteLog, Faults, FaultyLink, SplitMix};
use latentbki::frame::{live, EncoderSettings};
use latentbki::wire::{parse_body, Message, SessionConfig, SummaryCodec, PROTOCOL_VERSION};
use latentbki::{
    frame::FrameEncoder, key::VoxelKey, obs::ObsStats, sink::Evicted, sink::EvictionSink, MapConfig,
};
use std::collections::{BTreeMap, BTreeSet};

use host_sim::sim::vocab::D;

fn config() -> SessionConfig {
    SessionConfig::new(&MapConfig::default(), D, SummaryCodec::DEFAULT, 0x1234_5678)
}

fn stats(rng: &mut SplitMix) -> ObsStats<D> {
    ObsStats {
        count: 1.0 + rng.below(20) as f32,
        mean: core::array::from_fn(|_| rng.unit() as f32 - 0.5),
        scatter: core::array::from_fn(|_| 1.0 + 3.0 * rng.unit() as f32),
    }
}

/// A robot's whole output: evicted and live voxels over many ticks. Returns (frames, original bodies by seq).
fn stream(
    robot: u16,
    config: SessionConfig,
    voxels: usize,
) -> (Vec<Vec<u8>>, BTreeMap<u32, Vec<u8>>) {
    let mut enc = Box::new(
        FrameEncoder::<D, 8192, 512>::new(config, EncoderSettings::new(robot, 42)).unwrap(),
    );
    let mut uart = ByteLog::default();
    let mut rng = SplitMix::new(u64::from(robot));
    let mut residency = 0u32;
    let mut sent = 0;
    while sent < voxels {
        for _ in 0..40 {
            let s = stats(&mut rng);
            let key = VoxelKey::new(
                rng.below(200) as i32 - 100,
                rng.below(200) as i32 - 100,
                rng.below(10) as i32,
            );
            residency += 1;
            if enc
                .evict(Evicted {
                    key,
                    obs: &s,
                    residency,
                    time: 0,
                })
                .is_ok()
            {
                sent += 1;
            }
        }
        let lives: Vec<_> = (0..30)
            .map(|_| (VoxelKey::new(rng.below(50) as i32, 0, 0), stats(&mut rng)))
            .collect();
        enc.tick(
            &mut uart,
            2048,
            lives
                .iter()
                .enumerate()
                .map(|(i, (k, s))| live(*k, s, 1_000_000 + i as u32)),
        )
        .unwrap();
    }
    enc.tick(&mut uart, usize::MAX, core::iter::empty())
        .unwrap();
    let frames: Vec<Vec<u8>> = split_frames(&uart.0)
        .into_iter()
        .map(<[u8]>::to_vec)
        .collect();
    // The originals, decoded on a perfect link.
    let mut clean = BaseStation::<D>::new(config).unwrap();
    clean.keep_journal();
    clean.receive(&uart.0);
    assert_eq!(clean.journal().len(), frames.len());
    let bodies = clean
        .journal()
        .iter()
        .map(|j| (j.seq, j.body.clone()))
        .collect();
    (frames, bodies)
}

#[test]
fn faulty_links_never_corrupt_the_map_and_count_every_loss() {
    let (frames, originals) = stream(1, config(), 6000);
    println!(
        "{} frames, {} bytes",
        frames.len(),
        frames.iter().map(Vec::len).sum::<usize>()
    );
    println!("byte error rate | intact / sent | accepted | lost counted | duplicates | CRC | COBS | short | corrupted accepted");
    for (i, ber) in [1e-4, 1e-3, 1e-2].into_iter().enumerate() {
        let mut link = FaultyLink::new(Faults::everything(ber), 100 + i as u64);
        let mut rx = Vec::new();
        let mut intact_seqs = BTreeSet::new();
        let mut intact_copies = 0u64;
        for (seq, f) in frames.iter().enumerate() {
            let n = link.send(f, &mut rx);
            if n > 0 {
                intact_seqs.insert(seq as u32);
            }
            intact_copies += u64::from(n);
        }
        // The robot's last frame comes through a clean moment, so trailing losses are countable too.
        let last = frames.len() as u32 - 1;
        if !intact_seqs.contains(&last) {
            rx.extend_from_slice(&frames[last as usize]);
            intact_seqs.insert(last);
            intact_copies += 1;
        }
        let mut base = BaseStation::<D>::new(config()).unwrap();
        base.keep_journal();
        stream_common::feed_chunked(&mut base, &rx, i as u64);
        let s = base.stats();
        // 1. Nothing corrupted accepted: every accepted body is byte-identical to what was sent.
        let corrupted = base
            .journal()
            .iter()
            .filter(|j| originals.get(&j.seq) != Some(&j.body))
            .count();
        // 2. Re-sync within one frame: the accepted frames are exactly those that arrived intact.
        let accepted: BTreeSet<u32> = base.journal().iter().map(|j| j.seq).collect();
        // 3. Every lost frame counted.
        let truly_lost = frames.len() as u32 - accepted.len() as u32;
        println!(
            "{ber:.0e} | {} / {} | {} | {} (true {truly_lost}) | {} | {} | {} | {} | {corrupted}",
            intact_seqs.len(),
            frames.len(),
            accepted.len(),
            s.lost,
            s.refused.duplicate_frames,
            s.decoder.crc_errors,
            s.decoder.cobs_errors,
            s.decoder.too_short,
        );
        assert_eq!(corrupted, 0);
        // Every intact frame is accepted. A copy whose only damage fell on a delimiter (a dropped leading
        // 0x00 after a cleanly ended frame) still carries its body unchanged and may be accepted too: the
        // link calls it damaged, `corrupted == 0` above proves its body is the original.
        assert!(
            intact_seqs.is_subset(&accepted),
            "an intact frame was not accepted: {:?}",
            intact_seqs.difference(&accepted).collect::<Vec<_>>()
        );
        assert!(
            accepted.len() - intact_seqs.len() <= 2,
            "{}",
            accepted.len()
        );
        assert_eq!(
            base.journal().len(),
            accepted.len(),
            "a frame was accepted twice"
        );
        assert_eq!(s.lost, truly_lost);
        // Every further intact copy of a frame is a refused duplicate.
        assert!(u64::from(s.refused.duplicate_frames) >= intact_copies - intact_seqs.len() as u64);
        let log = link.log();
        assert!(
            log.dropped > 0 && log.truncated > 0 && log.duplicated > 0 && log.corrupted_bytes > 0
        );
        if ber >= 1e-3 {
            assert!(
                s.decoder.crc_errors > 0,
                "errors at {ber} must reach the CRC check"
            );
        }
        // The map holds only voxels of accepted frames: replaying them on a clean base gives the same map.
        let mut replay = BaseStation::<D>::new(config()).unwrap();
        let mut ordered: Vec<_> = base.journal().iter().collect();
        ordered.sort_by_key(|j| j.seq);
        let mut bytes = Vec::new();
        for j in ordered {
            bytes.extend_from_slice(&frames[j.seq as usize]);
        }
        replay.receive(&bytes);
        assert_eq!(
            replay.map().unwrap().posteriors(),
            base.map().unwrap().posteriors()
        );
    }
}

#[test]
fn wrong_version_and_wrong_config_are_refused_and_counted() {
    let (_, good) = stream(1, config(), 200);
    let other = SessionConfig::new(
        &MapConfig::new(
            0.2,
            0.5,
            3,
            Default::default(),
            latentbki::KernelMode::VoxelOffset,
        )
        .unwrap(),
        D,
        SummaryCodec::DEFAULT,
        0x1234_5678,
    );
    let (foreign_frames, _) = stream(2, other, 200);
    let mut base = BaseStation::<D>::new(config()).unwrap();
    for f in &foreign_frames {
        base.receive(f);
    }
    assert_eq!(
        base.stats().refused.wrong_config as usize,
        foreign_frames.len()
    );
    assert!(base.map().unwrap().is_empty());
    // A future protocol version with a valid CRC: refused as a version, not as garbage.
    let (seq, body) = good.iter().next().unwrap();
    let mut v2 = body.clone();
    v2[0] = PROTOCOL_VERSION + 1;
    base.receive(&frame_body(&v2));
    assert_eq!(base.stats().refused.version, 1);
    // A summary with a point count of 0 in a frame with a valid CRC: the whole frame is refused.
    let voxel_body = good
        .values()
        .find(|b| matches!(parse_body(b), Ok((_, Message::Voxels(_)))))
        .unwrap();
    let (h, Message::Voxels(_)) = parse_body(voxel_body).unwrap() else {
        unreachable!()
    };
    let mut codes = [0u8; 64];
    let c = latentbki::wire::encode_codes(
        SummaryCodec::DEFAULT,
        &stats(&mut SplitMix::new(3)),
        &mut codes,
    )
    .unwrap();
    let mut summaries = [0u8; 128];
    let len = latentbki::wire::encode_summary(
        &mut latentbki::wire::DeltaBase::default(),
        VoxelKey::new(1, 2, 3),
        7,
        true,
        0,
        &codes[..c],
        &mut summaries,
    )
    .unwrap();
    let mut out = [0u8; 1024];
    let msg = Message::Voxels(latentbki::wire::VoxelBatch {
        count: 1,
        summaries: &summaries[..len],
    });
    let n = latentbki::wire::encode_body(&h, &msg, &mut out).unwrap();
    base.receive(&frame_body(&out[..n]));
    assert_eq!(base.stats().refused.invalid_voxel, 1);
    assert!(base.map().unwrap().is_empty());
    let _ = seq;
    // An adopting base station takes the first valid session header's configuration, refuses others.
    let mut adopting = BaseStation::<D>::adopting();
    for b in good.values() {
        adopting.receive(&frame_body(b));
    }
    for f in &foreign_frames {
        adopting.receive(f);
    }
    assert_eq!(adopting.map().unwrap().config(), &config());
    assert_eq!(
        adopting.stats().refused.wrong_config as usize,
        foreign_frames.len()
    );
    assert!(!adopting.map().unwrap().is_empty());
}
