//! Property tests of the wire: encode → decode round trips for any codec, voxel and chunking, and any
//! bytes into the decoders without a panic.

use host_sim::base_station::BaseStation;
use host_sim::link::ByteLog;
use latentbki::frame::{live, EncoderSettings, Feed, FrameDecoder};
use latentbki::wire::{
    decode_summary, encode_codes, encode_summary, mean_error_bound, parse_body, DeltaBase, Message,
    SessionConfig, SummaryCodec,
};
use latentbki::{frame::FrameEncoder, key::VoxelKey, obs::ObsStats, sink::EvictionSink, MapConfig};
use proptest::prelude::*;

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

fn codec() -> impl Strategy<Value = SummaryCodec> {
    // D = 16: a lead band of 0..=15 components (0 = none), 0..=6 more bits for it.
    (2u8..=8, 1u8..=16, 0u8..=4, 0u8..16, 0u8..=6).prop_map(
        |(mean_bits, psi_blocks, mean_bits_growth, lead, lead_bits)| SummaryCodec {
            mean_bits,
            psi_blocks,
            mean_bits_growth,
            lead,
            lead_bits,
            rice: false,
        },
    )
}

proptest! {
    #[test]
    fn summaries_round_trip(codec in codec(), items in prop::collection::vec((key(), any::<u32>(), any::<bool>(), voxel()), 1..8)) {
        let mut buf = vec![0u8; 64 * items.len()];
        let mut at = 0;
        let mut base = DeltaBase::default();
        let mut sent = Vec::new();
        for (k, r, f, s) in &items {
            let mut codes = [0u8; 64];
            let n = encode_codes(codec, s, &mut codes).unwrap();
            sent.push(codes[..n].to_vec());
            at += encode_summary(&mut base, *k, *r, *f, s.count as u32, &codes[..n], &mut buf[at..]).unwrap();
        }
        let mut base = DeltaBase::default();
        let mut pos = 0;
        for (i, (k, r, f, s)) in items.iter().enumerate() {
            let got = decode_summary::<D>(codec, &mut base, &buf[..at], &mut pos).unwrap();
            prop_assert_eq!((got.key, got.residency, got.is_final), (*k, *r, *f));
            prop_assert_eq!(got.obs.count.to_bits(), s.count.to_bits());
            let err = got.obs.mean.iter().zip(&s.mean).map(|(a, b)| (a - b) * (a - b)).sum::<f32>().sqrt();
            prop_assert!(err <= mean_error_bound(codec, D, &sent[i], s.count as u32) * 1.001 + 1e-6, "mean error {}", err);
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
        voxels in prop::collection::vec((key(), voxel()), 1..120),
        budget in 120usize..3000,
        chunk in 1usize..300,
    ) {
        let config = SessionConfig::new(&MapConfig::default(), D, SummaryCodec::DEFAULT, 9);
        let mut enc = FrameEncoder::<D, 4096, 256>::new(config, EncoderSettings::new(3, 4)).unwrap();
        let mut uart = ByteLog::default();
        let mut sent = Vec::new();
        for (i, (k, s)) in voxels.iter().enumerate() {
            while enc.evict(live(*k, s, i as u32)).is_err() {
                let r = enc.tick(&mut uart, budget, core::iter::empty()).unwrap();
                prop_assert!(r.bytes <= budget);
            }
            sent.push((*k, i as u32, s.count));
        }
        while enc.queued() > 0 {
            let r = enc.tick(&mut uart, budget, core::iter::empty()).unwrap();
            prop_assert!(r.bytes <= budget);
        }
        let mut base = BaseStation::<D>::new(config).unwrap();
        base.keep_journal();
        for c in uart.0.chunks(chunk) {
            base.receive(c);
        }
        let mut got = Vec::new();
        for j in base.journal() {
            if let Ok((_, Message::Voxels(b))) = parse_body(&j.body) {
                for s in b.iter::<D>(config.codec) {
                    let s = s.unwrap();
                    got.push((s.key, s.residency, s.obs.count));
                }
            }
        }
        prop_assert_eq!(got, sent);
        prop_assert_eq!(base.stats().lost, 0);
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

fn r_len(b: usize, blocks: usize) -> usize {
    (b + 1) * D / blocks - b * D / blocks
}
