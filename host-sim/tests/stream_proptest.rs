//! Property tests of the wire, for every codec — packed and Rice-coded sessions (`rice-codes`) alike:
//! encode → decode round trips for any codec parameters, voxel and chunking (finals and live updates); any
//! stream through a faulty link is never corrupted and its losses are counted; any damage to a frame's
//! summaries behind a valid CRC is refused and counted, or decodes to finite statistics; any bytes into the
//! decoders without a panic.

use host_sim::base_station::BaseStation;
use host_sim::link::{frame_body, split_frames, ByteLog, Faults, FaultyLink};
use latentbki::frame::{live, EncoderSettings, Feed, FrameDecoder};
use latentbki::wire::{
    decode_summary, encode_body, encode_codes, encode_rice_summary, encode_summary,
    mean_error_bound, parse_body, DeltaBase, Message, SessionConfig, SummaryCodec, VoxelBatch,
};
use latentbki::{frame::FrameEncoder, key::VoxelKey, obs::ObsStats, sink::EvictionSink, MapConfig};
use proptest::prelude::*;
use std::collections::{BTreeMap, BTreeSet};

const D: usize = 16;

fn voxel() -> impl Strategy<Value = ObsStats<D>> {
    (
        1u32..=(1 << 24),
        prop::array::uniform16(-10.0f32..10.0),
        prop::array::uniform16(1e-3f32..1e4),
    )
        .prop_map(|(n, mean, scatter)| ObsStats {
            count: n as f32,
            mean,
            // A single point has no scatter (and the wire sends none for it).
            scatter: if n == 1 { [0.0; 16] } else { scatter },
        })
}

fn key() -> impl Strategy<Value = VoxelKey> {
    let c = -(1 << 30) + 1..(1 << 30);
    (c.clone(), c.clone(), c).prop_map(|(x, y, z)| VoxelKey::new(x, y, z))
}

/// Any codec: packed or Rice-coded (half the cases each), with any parameters.
fn codec() -> impl Strategy<Value = SummaryCodec> {
    // D = 16: a lead band of 0..=15 components (0 = none), 0..=6 more bits for it (Rice sessions use
    // only `lead` and `psi_blocks` of these).
    (2u8..=8, 1u8..=16, 0u8..=4, 0u8..16, 0u8..=6, any::<bool>()).prop_map(
        |(mean_bits, psi_blocks, mean_bits_growth, lead, lead_bits, rice)| SummaryCodec {
            mean_bits,
            psi_blocks,
            mean_bits_growth,
            lead,
            lead_bits,
            rice,
        },
    )
}

fn session(codec: SummaryCodec) -> SessionConfig {
    SessionConfig::new(&MapConfig::default(), D, codec, 9)
}

/// What a robot sent: its bytes, the final summaries `(key, residency, count)` in order, and the live
/// updates by residency (each `(key, count, its statistics)`).
struct Sent {
    bytes: Vec<u8>,
    finals: Vec<(VoxelKey, u32, f32)>,
    lives: BTreeMap<u32, (VoxelKey, ObsStats<D>)>,
}

/// A robot's stream: `voxels` evicted one by one (a tick whenever the queue is full, then until it is
/// empty), `lives` offered as live updates at every tick (residencies from 1,000,000 on), `budget` bytes
/// per tick.
fn stream(
    codec: SummaryCodec,
    voxels: &[(VoxelKey, ObsStats<D>)],
    lives: &[(VoxelKey, ObsStats<D>)],
    budget: usize,
) -> Result<Sent, TestCaseError> {
    let mut enc =
        FrameEncoder::<D, 4096, 256>::new(session(codec), EncoderSettings::new(3, 4)).unwrap();
    let mut uart = ByteLog::default();
    let live_items = || {
        lives
            .iter()
            .enumerate()
            .map(|(j, (k, s))| live(*k, s, 1_000_000 + j as u32))
    };
    let mut finals = Vec::new();
    for (i, (k, s)) in voxels.iter().enumerate() {
        while enc.evict(live(*k, s, i as u32)).is_err() {
            let r = enc.tick(&mut uart, budget, live_items()).unwrap();
            prop_assert!(r.bytes <= budget);
        }
        finals.push((*k, i as u32, s.count));
    }
    while enc.queued() > 0 {
        let r = enc.tick(&mut uart, budget, live_items()).unwrap();
        prop_assert!(r.bytes <= budget);
    }
    let lives = live_items()
        .map(|v| (v.residency, (v.key, *v.obs)))
        .collect();
    Ok(Sent {
        bytes: uart.0,
        finals,
        lives,
    })
}

/// Each accepted voxel summary of a base station's journal, in order.
fn received(base: &BaseStation<D>, codec: SummaryCodec) -> Vec<latentbki::wire::Summary<D>> {
    let mut got = Vec::new();
    for j in base.journal() {
        if let Ok((_, Message::Voxels(b))) = parse_body(&j.body) {
            got.extend(b.iter::<D>(codec).map(Result::unwrap));
        }
    }
    got
}

/// The decoded mean is within the codec's bound of the sent one (the bound from the codes the sender
/// writes for these statistics).
fn mean_within_bound(
    codec: SummaryCodec,
    sent: &ObsStats<D>,
    got: &ObsStats<D>,
) -> Result<(), TestCaseError> {
    let mut codes = [0u8; 64];
    encode_codes(codec, sent, &mut codes).unwrap();
    let bound = mean_error_bound(codec, D, &codes, sent.count as u32);
    let err = got
        .mean
        .iter()
        .zip(&sent.mean)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f32>()
        .sqrt();
    prop_assert!(
        err <= bound * 1.001 + 1e-6,
        "mean error {} > bound {}",
        err,
        bound
    );
    Ok(())
}

proptest! {
    #[test]
    fn summaries_round_trip(codec in codec(), items in prop::collection::vec((key(), any::<u32>(), any::<bool>(), voxel()), 1..8)) {
        // A Rice summary's head (Exp-Golomb codes of keys as far apart as ±2³¹) takes up to 38 bytes.
        let mut buf = vec![0u8; 128 * items.len()];
        let mut at = 0;
        let mut base = DeltaBase::default();
        for (k, r, f, s) in &items {
            let start = at;
            at += if codec.rice {
                let id = (*k, *r, *f);
                encode_rice_summary(codec, &mut base, id, (s.count as u32, None), s, &mut buf[at..]).unwrap()
            } else {
                let mut codes = [0u8; 64];
                let n = encode_codes(codec, s, &mut codes).unwrap();
                encode_summary(&mut base, *k, *r, *f, s.count as u32, &codes[..n], &mut buf[at..]).unwrap()
            };
            // Within what an encoder reserves for one summary (frames are sized by it).
            prop_assert!(at - start <= codec.max_summary_len(D), "{} B > {} B", at - start, codec.max_summary_len(D));
        }
        let mut base = DeltaBase::default();
        let mut pos = 0;
        for (k, r, f, s) in &items {
            let got = decode_summary::<D>(codec, &mut base, &buf[..at], &mut pos).unwrap();
            prop_assert_eq!((got.key, got.residency, got.is_final), (*k, *r, *f));
            prop_assert_eq!(got.obs.count.to_bits(), s.count.to_bits());
            mean_within_bound(codec, s, &got.obs)?;
            let max = s.scatter.iter().fold(0.0f32, |a, &b| a.max(b));
            let got_max = got.obs.scatter.iter().fold(0.0f32, |a, &b| a.max(b));
            prop_assert!(got_max <= max * 1.0906 + 1e-9);
            // Block sums of S within half an octave step (2^±¼), for every block.
            let blocks = usize::from(codec.psi_blocks);
            for b in 0..blocks {
                let r = (b * D / blocks)..((b + 1) * D / blocks);
                let exact: f32 = s.scatter[r.clone()].iter().sum();
                let dec: f32 = got.obs.scatter[r].iter().sum();
                // Block means below Ψ_max · 2^-7.5 saturate at the smallest code.
                if exact / (r_len(b, blocks) as f32) >= max * 0.007 {
                    prop_assert!(dec / exact < 1.19 && exact / dec < 1.19, "block {}: {} vs {}", b, dec, exact);
                }
            }
        }
        prop_assert_eq!(pos, at);
    }

    #[test]
    fn frames_round_trip_in_any_chunking(
        codec in codec(),
        voxels in prop::collection::vec((key(), voxel()), 1..120),
        lives in prop::collection::vec((key(), voxel()), 0..6),
        budget in 120usize..3000,
        chunk in 1usize..300,
    ) {
        let sent = stream(codec, &voxels, &lives, budget)?;
        let mut base = BaseStation::<D>::new(session(codec)).unwrap();
        base.keep_journal();
        for c in sent.bytes.chunks(chunk) {
            base.receive(c);
        }
        let got = received(&base, codec);
        // Every final summary, in the order evicted, with its statistics within the codec's bound.
        let finals: Vec<_> = got.iter().filter(|s| s.is_final).collect();
        prop_assert_eq!(
            finals.iter().map(|s| (s.key, s.residency, s.obs.count)).collect::<Vec<_>>(),
            sent.finals
        );
        for (s, (_, v)) in finals.iter().zip(&voxels) {
            mean_within_bound(codec, v, &s.obs)?;
        }
        // Every live update is one the robot offered, decoded within the bound.
        for s in got.iter().filter(|s| !s.is_final) {
            let offered = sent.lives.get(&s.residency);
            prop_assert!(offered.is_some(), "live residency {} never offered", s.residency);
            let (k, v) = offered.unwrap();
            prop_assert_eq!((s.key, s.obs.count), (*k, v.count));
            mean_within_bound(codec, v, &s.obs)?;
        }
        prop_assert_eq!(base.stats().lost, 0);
        prop_assert_eq!(base.stats().refused, Default::default());
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..2048), chunk in 1usize..64) {
        let mut dec = FrameDecoder::<256>::new();
        for c in bytes.chunks(chunk) {
            let mut input = c;
            loop {
                match dec.feed(input) {
                    Feed::NeedMore => break,
                    Feed::Error { rest, .. } => input = rest,
                    Feed::Frame { body, rest } => {
                        let _ = parse_body(body);
                        input = rest;
                    }
                }
            }
        }
        let _ = parse_body(&bytes);
        let mut base = BaseStation::<D>::adopting();
        base.receive(&bytes);
    }
}

proptest! {
    // Each case builds, damages and replays a whole stream: fewer cases keep CI's time small.
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The link breaks; the map does not: whatever the codec, no corrupted frame is accepted, every frame
    /// that arrived intact is, every loss is counted, and the map is exactly the accepted frames' map.
    #[test]
    fn faulty_links_never_corrupt_the_map_and_count_every_loss(
        codec in codec(),
        voxels in prop::collection::vec((key(), voxel()), 1..120),
        lives in prop::collection::vec((key(), voxel()), 0..6),
        budget in 120usize..3000,
        byte_error_rate in 0.0f64..0.01,
        seed in any::<u64>(),
    ) {
        let sent = stream(codec, &voxels, &lives, budget)?;
        let frames: Vec<&[u8]> = split_frames(&sent.bytes);
        let mut clean = BaseStation::<D>::new(session(codec)).unwrap();
        clean.keep_journal();
        clean.receive(&sent.bytes);
        prop_assert_eq!(clean.journal().len(), frames.len());
        let originals: BTreeMap<u32, &[u8]> =
            clean.journal().iter().map(|j| (j.seq, &j.body[..])).collect();

        let mut link = FaultyLink::new(Faults::everything(byte_error_rate), seed);
        let mut rx = Vec::new();
        let mut intact = BTreeSet::new();
        for (seq, f) in frames.iter().enumerate() {
            if link.send(f, &mut rx) > 0 {
                intact.insert(seq as u32);
            }
        }
        // The last frame comes through a clean moment, so trailing losses are countable too.
        let last = frames.len() as u32 - 1;
        if intact.insert(last) {
            rx.extend_from_slice(frames[last as usize]);
        }
        let mut base = BaseStation::<D>::new(session(codec)).unwrap();
        base.keep_journal();
        base.receive(&rx);
        let accepted: BTreeSet<u32> = base.journal().iter().map(|j| j.seq).collect();
        for j in base.journal() {
            prop_assert_eq!(Some(&&j.body[..]), originals.get(&j.seq), "frame {} corrupted", j.seq);
        }
        prop_assert_eq!(base.journal().len(), accepted.len(), "a frame accepted twice");
        prop_assert!(intact.is_subset(&accepted), "an intact frame was refused");
        prop_assert_eq!(base.stats().lost as usize, frames.len() - accepted.len());
        // The map holds only the accepted frames: replayed on a clean base station, the same map.
        let mut replay = BaseStation::<D>::new(session(codec)).unwrap();
        for seq in &accepted {
            replay.receive(frames[*seq as usize]);
        }
        prop_assert_eq!(replay.map().unwrap().posteriors(), base.map().unwrap().posteriors());
    }

    /// Damage behind a valid CRC (bytes of a frame's summaries replaced): the base station refuses and
    /// counts the frame, leaving its map untouched, or accepts summaries that decode to finite
    /// statistics — never a panic, never a non-finite posterior.
    #[test]
    fn damaged_summaries_are_refused_and_counted_or_decode_finite(
        codec in codec(),
        voxels in prop::collection::vec((key(), voxel()), 1..40),
        damage in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
    ) {
        let sent = stream(codec, &voxels, &[], 3000)?;
        let mut clean = BaseStation::<D>::new(session(codec)).unwrap();
        clean.keep_journal();
        clean.receive(&sent.bytes);
        let (header, summaries, count) = clean
            .journal()
            .iter()
            .find_map(|j| match parse_body(&j.body) {
                Ok((h, Message::Voxels(b))) => Some((h, b.summaries.to_vec(), b.count)),
                _ => None,
            })
            .unwrap();
        let mut bad = summaries.clone();
        for (at, byte) in &damage {
            let i = at.index(bad.len());
            bad[i] = *byte;
        }
        prop_assume!(bad != summaries);
        let mut body = vec![0u8; 4096];
        let message = Message::Voxels(VoxelBatch { count, summaries: &bad });
        let n = encode_body(&header, &message, &mut body).unwrap();
        let mut base = BaseStation::<D>::new(session(codec)).unwrap();
        base.receive(&frame_body(&body[..n]));
        let s = base.stats();
        let r = s.refused;
        let refused = r.malformed + r.invalid_voxel + r.wrong_config + r.version;
        prop_assert_eq!(s.frames + refused, 1, "{:?}", s);
        let map = base.map().unwrap();
        if refused == 1 {
            prop_assert!(map.is_empty());
        }
        for (k, p) in map.posteriors() {
            let finite = p.lambda.is_finite()
                && p.mean.iter().chain(&p.psi).all(|v| v.is_finite());
            prop_assert!(finite, "voxel {:?}: {:?}", k, p);
        }
    }
}

fn r_len(b: usize, blocks: usize) -> usize {
    (b + 1) * D / blocks - b * D / blocks
}
