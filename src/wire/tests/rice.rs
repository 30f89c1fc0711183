//! Rice-coded sessions (`rice-codes`): summaries round-trip within their bound, take exactly the bytes
//! they say, refuse cut or damaged input, and the session says which coding it uses.

use crate::config::MapConfig;
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::wire::*;

const RICE: SummaryCodec = SummaryCodec {
    mean_bits: 3,
    psi_blocks: 2,
    mean_bits_growth: 3,
    lead: 8,
    lead_bits: 3,
    rice: true,
};

/// Deterministic statistics: a few large leading components, small equal noise in the rest.
fn sample(seed: u32, count: f32) -> ObsStats<64> {
    let mut next = super::uniform(seed);
    ObsStats {
        count,
        mean: core::array::from_fn(|i| next() * if i < 5 { 0.5 } else { 0.05 }),
        scatter: core::array::from_fn(|_| 0.01 * (1.0 + libm::fabsf(next()))),
    }
}

fn error(a: &[f32; 64], b: &[f32; 64]) -> f32 {
    libm::sqrtf(a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum())
}

#[test]
fn rice_summaries_round_trip_within_their_bound_and_take_the_bytes_they_say() {
    for codec in [RICE, SummaryCodec { lead: 0, ..RICE }] {
        let mut frame = [0u8; 4096];
        let mut at = 0;
        let mut base = DeltaBase::default();
        let mut sent = [ObsStats::<64>::EMPTY; 12];
        for (i, s) in sent.iter_mut().enumerate() {
            *s = sample(i as u32 + 1, (1u32 << (i % 8)) as f32 + (i / 8) as f32);
            let mut codes = [0u8; 128];
            let n = encode_codes(codec, s, &mut codes).unwrap();
            assert!(
                n <= codec.code_len(64),
                "{n} > the most a summary's codes take"
            );
            assert_eq!(codec.codes_len(64, s.count as u32, &codes).unwrap(), n);
            let key = VoxelKey::new(i as i32, -(i as i32), 3);
            let id = (key, 1 + i as u32 / 3, i % 2 == 0);
            let w = (s.count as u32, None);
            at += encode_rice_summary(codec, &mut base, id, w, s, &mut frame[at..]).unwrap();
        }
        let batch = VoxelBatch {
            count: sent.len() as u16,
            summaries: &frame[..at],
        };
        let got: heapless::Vec<Summary<64>, 12> =
            batch.iter::<64>(codec).map(|r| r.unwrap()).collect();
        assert_eq!(got.len(), sent.len());
        for (i, (g, s)) in got.iter().zip(&sent).enumerate() {
            assert_eq!(g.key, VoxelKey::new(i as i32, -(i as i32), 3));
            assert_eq!((g.residency, g.is_final), (1 + i as u32 / 3, i % 2 == 0));
            let mut codes = [0u8; 128];
            encode_codes(codec, s, &mut codes).unwrap();
            let bound = mean_error_bound(codec, 64, &codes, s.count as u32);
            let e = error(&g.obs.mean, &s.mean);
            assert!(e <= bound * 1.001 + 1e-7, "error {e} > bound {bound}");
            // The default policy keeps the error within a few percent of ‖m‖.
            let norm = libm::sqrtf(s.mean.iter().map(|v| v * v).sum());
            assert!(e < 0.1 * norm, "error {e} of ‖m‖ {norm}");
            assert_eq!(g.obs.count, s.count);
        }
    }
}

#[test]
fn rice_codes_are_smaller_than_packed_codes_of_the_same_error() {
    // Same steps as 6-bit packed codes would need: the Rice codes take fewer bytes on typical means.
    let (mut rice, mut packed) = (0usize, 0usize);
    let six = SummaryCodec {
        mean_bits: 6,
        lead_bits: 2,
        rice: false,
        ..RICE
    };
    for i in 0..64 {
        let s = sample(i + 100, 1.0);
        let mut codes = [0u8; 128];
        rice += encode_codes(RICE, &s, &mut codes).unwrap();
        packed += encode_codes(six, &s, &mut codes).unwrap();
    }
    assert!(rice < packed, "{rice} ≥ {packed}");
}

#[test]
fn extreme_means_fit_the_most_a_summary_takes_and_zero_means_take_only_their_steps() {
    let mut s = sample(9, 64.0);
    s.mean[0] = 5.0e4;
    s.mean[40] = -3.0e-6;
    let mut codes = [0u8; 128];
    let n = encode_codes(RICE, &s, &mut codes).unwrap();
    assert!(n <= RICE.code_len(64));
    let back = decode_codes::<64>(RICE, 64.0, &codes[..n]).unwrap();
    assert!(error(&back.mean, &s.mean) <= mean_error_bound(RICE, 64, &codes, 64) * 1.001);
    // Means beyond every step code (the fuzz target `roundtrip` found an overflow here): encoded
    // within the bound on bytes, decoded finite.
    let mut huge = sample(11, 3.0);
    huge.mean = core::array::from_fn(|i| if i % 2 == 0 { 3.0e38 } else { -1.0e30 });
    let n = encode_codes(RICE, &huge, &mut codes).unwrap();
    assert!(n <= RICE.code_len(64));
    let back = decode_codes::<64>(RICE, 3.0, &codes[..n]).unwrap();
    assert!(back.mean.iter().all(|v| v.is_finite()));
    let zero = ObsStats::<64> {
        count: 1.0,
        mean: [0.0; 64],
        scatter: [0.0; 64],
    };
    // The lead step byte 0, then the rest step's residual: 0 − the prediction (0 − 5), 7 bits.
    assert_eq!(encode_codes(RICE, &zero, &mut codes).unwrap(), 2);
    assert_eq!(codes[0], 0);
    assert_eq!(
        decode_codes::<64>(RICE, 1.0, &codes[..2]).unwrap().mean,
        [0.0; 64]
    );
    let one_band = SummaryCodec { lead: 0, ..RICE };
    assert_eq!(encode_codes(one_band, &zero, &mut codes).unwrap(), 1);
    assert_eq!(codes[0], 0);
}

#[test]
fn cut_or_damaged_rice_codes_are_refused_or_decode_to_finite_values() {
    let s = sample(3, 5.0);
    let mut codes = [0u8; 128];
    let n = encode_codes(RICE, &s, &mut codes).unwrap();
    for cut in 0..n {
        assert!(
            decode_codes::<64>(RICE, 5.0, &codes[..cut]).is_err(),
            "cut at {cut} of {n} accepted"
        );
    }
    // Garbage never panics; what decodes is finite.
    let mut x = 0x1234_5678u32;
    for _ in 0..2000 {
        let mut junk = [0u8; 96];
        for b in junk.iter_mut() {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            *b = x as u8;
        }
        if let Ok(o) = decode_codes::<64>(RICE, 3.0, &junk) {
            assert!(o.mean.iter().all(|v| v.is_finite()));
        }
    }
}

#[test]
fn a_session_says_it_rice_codes_and_packed_sessions_keep_their_bytes() {
    let packed = SessionConfig::new(
        &MapConfig::default(),
        64,
        SummaryCodec {
            rice: false,
            ..RICE
        },
        5,
    );
    let rice = SessionConfig::new(&MapConfig::default(), 64, RICE, 5);
    assert_ne!(packed.id(), rice.id(), "codings never merge");
    let header = FrameHeader {
        version: PROTOCOL_VERSION,
        robot: 1,
        session: 2,
        seq: 0,
        config_id: rice.id(),
    };
    let (mut a, mut b) = ([0u8; 128], [0u8; 128]);
    let na = encode_body(&header, &Message::Session(packed), &mut a).unwrap();
    let nb = encode_body(&header, &Message::Session(rice), &mut b).unwrap();
    assert_eq!(nb, na + 1, "one extension byte");
    assert_eq!(&a[..na], &b[..na]);
    assert_eq!(b[na], messages::RICE_EXTENSION);
    assert_eq!(parse_body(&b[..nb]).unwrap().1, Message::Session(rice));
    assert_eq!(parse_body(&a[..na]).unwrap().1, Message::Session(packed));
    // Another extension byte is malformed.
    b[na] = 2;
    assert_eq!(parse_body(&b[..nb]), Err(WireError::Malformed));
    // With forgetting: half-life, then the Rice byte.
    #[cfg(feature = "forgetting")]
    {
        let f = rice.with_forgetting(crate::forget::Forgetting::new(100.0));
        let n = encode_body(&header, &Message::Session(f), &mut b).unwrap();
        assert_eq!(n, na + 5);
        assert_eq!(parse_body(&b[..n]).unwrap().1, Message::Session(f));
        assert_ne!(f.id(), rice.id());
    }
}

#[test]
fn a_rice_head_is_a_few_bits_per_field_and_round_trips_stamps() {
    let mut out = [0u8; 32];
    let mut base = DeltaBase::default();
    // Neighbouring keys, same residency, one point: dx 1 (3 bits), dy and dz 0 (1 each), final (1),
    // residency delta 0 (1), count 1 (1): 8 bits.
    encode_rice_head(
        &mut base,
        (VoxelKey::new(0, 1, 0), 0, true),
        1,
        None,
        &mut out,
    )
    .unwrap();
    let id = (VoxelKey::new(1, 1, 0), 0, true);
    assert_eq!(
        encode_rice_head(&mut base, id, 1, None, &mut out).unwrap(),
        8
    );
    // A stamped summary: count 0, the tick, the weight's bits; its codes in the same stream.
    let codec = SummaryCodec { lead: 0, ..RICE };
    let s = sample(5, 2.5);
    let mut base = DeltaBase::default();
    let mut frame = [0u8; 256];
    let id = (VoxelKey::new(-7, 1 << 20, 3), u32::MAX, false);
    let n = encode_rice_summary(
        codec,
        &mut base,
        id,
        (0, Some((123_456, 2.5))),
        &s,
        &mut frame,
    )
    .unwrap();
    let (mut base, mut at) = (DeltaBase::default(), 0);
    let got = decode_summary::<64>(codec, &mut base, &frame[..n], &mut at).unwrap();
    assert_eq!(at, n);
    assert_eq!(got.time, Some(123_456));
    assert_eq!(got.obs.count, 2.5);
    assert_eq!((got.key, got.residency, got.is_final), id);
    let (h, c) = (0, n);
    // Cut anywhere: refused.
    for cut in 0..h + c {
        let (mut base, mut at) = (DeltaBase::default(), 0);
        assert!(decode_summary::<64>(codec, &mut base, &frame[..cut], &mut at).is_err());
    }
}

/// The default policy's rest step is what the receiver predicts from the lead's (`rest_step` is the one
/// bit `0` the spec promises): c_R = c_L + 5 + 2·min(⌊log₂ n⌋, 6) whenever neither band's step was raised to
/// keep its largest value within ±127 steps (one lead component carrying nearly all of ‖m‖).
#[test]
fn the_default_policy_rest_step_is_predicted_and_costs_one_bit() {
    let (mut one_bit, mut all) = (0, 0);
    for count in [1u32, 2, 3, 7, 8, 100, 1 << 10, 1 << 20] {
        for seed in 1..40 {
            let s = sample(seed, count as f32);
            let mut codes = [0u8; 128];
            encode_codes(RICE, &s, &mut codes).unwrap();
            let mut r = rice::BitReader {
                bytes: &codes,
                bit: 0,
            };
            let [lead, rest] = rice::read_steps(&mut r, true, count).unwrap();
            let d = if count > 1 { count.ilog2().min(6) } else { 0 };
            let predicted = u32::from(rest) == u32::from(lead) + 5 + 2 * d;
            // A predicted step is the bit `0`; any other is longer.
            assert_eq!(predicted, r.bit == 9, "n = {count}, seed {seed}");
            one_bit += usize::from(predicted);
            all += 1;
        }
    }
    // This sample puts half of ‖m‖² in one lead component: at many points its step is raised.
    assert!(one_bit * 2 >= all, "{one_bit} of {all} one bit");
}
