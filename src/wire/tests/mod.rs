//! The wire: messages and summaries round-trip, refuse what is cut or damaged; Rice sessions in `rice`.

use super::codec::{block_range, hadamard};
use super::summary::{put_varint, unzigzag, zigzag};
use super::*;
use crate::config::{KernelMode, MapConfig, Prior};
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use core::num::NonZeroUsize;

/// Uniform numbers in [−1, 1] from a small deterministic generator (xorshift), so the wire's tests need no
/// RNG crate.
pub(super) fn uniform(seed: u32) -> impl FnMut() -> f32 {
    let mut s = seed.wrapping_mul(2_654_435_761).max(1);
    move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s as f32 / u32::MAX as f32) * 2.0 - 1.0
    }
}

fn sample<const D: usize>(seed: u32) -> ObsStats<D> {
    let mut next = uniform(seed);
    ObsStats {
        count: (3.0 + 10.0 * libm::fabsf(next())) as u32 as f32,
        mean: core::array::from_fn(|i| next() / (1.0 + i as f32 * 0.1)),
        scatter: core::array::from_fn(|i| 1.0 + 5.0 * libm::fabsf(next()) / (1.0 + i as f32 * 0.2)),
    }
}

#[test]
fn varints_match_postcard() {
    for v in [0u32, 1, 127, 128, 300, 16_383, 16_384, u32::MAX] {
        let mut ours = [0u8; 10];
        let mut at = 0;
        put_varint(&mut ours, &mut at, u64::from(v)).unwrap();
        let mut theirs = [0u8; 10];
        let t = postcard::to_slice(&v, &mut theirs).unwrap();
        assert_eq!(&ours[..at], &*t, "varint of {v}");
    }
    for v in [0i32, -1, 1, -64, 64, i32::MIN, i32::MAX] {
        let mut theirs = [0u8; 10];
        let t = postcard::to_slice(&v, &mut theirs).unwrap();
        let mut ours = [0u8; 10];
        let mut at = 0;
        put_varint(&mut ours, &mut at, u64::from(zigzag(v))).unwrap();
        assert_eq!(&ours[..at], &*t, "zigzag of {v}");
        assert_eq!(unzigzag(zigzag(v)), v);
    }
}

#[test]
fn hadamard_is_orthonormal_and_self_inverse() {
    let v: [f32; 8] = [1.0, -2.0, 0.5, 3.0, 0.0, 0.25, -1.0, 2.0];
    let mut t = v;
    hadamard(&mut t);
    let n0: f32 = v.iter().map(|x| x * x).sum();
    let n1: f32 = t.iter().map(|x| x * x).sum();
    assert!((n0 - n1).abs() < 1e-5);
    hadamard(&mut t);
    for (a, b) in v.iter().zip(&t) {
        assert!((a - b).abs() < 1e-6);
    }
}

#[test]
fn default_summary_is_at_most_36_bytes_at_d64_for_neighbouring_keys() {
    let codec = SummaryCodec::DEFAULT;
    assert_eq!(codec.code_len(64), 30);
    let mut codes = [0u8; 64];
    let n = encode_codes(codec, &sample::<64>(1), &mut codes).unwrap();
    let mut base = DeltaBase::default();
    let mut out = [0u8; 64];
    encode_summary(
        &mut base,
        VoxelKey::new(100, -40, 7),
        5000,
        true,
        35,
        &codes[..n],
        &mut out,
    )
    .unwrap();
    let len = encode_summary(
        &mut base,
        VoxelKey::new(101, -40, 7),
        5003,
        true,
        35,
        &codes[..n],
        &mut out,
    )
    .unwrap();
    // 3 key deltas + residency + count + 30 code bytes.
    assert_eq!(len, 3 + 1 + 1 + 30);
    assert!(len <= 36);
}

#[test]
fn summary_round_trip_within_bounds() {
    let codec = SummaryCodec::DEFAULT;
    let mut buf = [0u8; 512];
    let mut at = 0;
    let mut base = DeltaBase::default();
    let keys = [
        VoxelKey::new(-5, 3, 1 << 29),
        VoxelKey::new(-(1 << 30) + 1, (1 << 30) - 1, 0),
        VoxelKey::new(0, 0, 0),
    ];
    let mut sent = [ObsStats::<64>::EMPTY; 3];
    for (i, key) in keys.iter().enumerate() {
        sent[i] = sample::<64>(i as u32 + 7);
        let mut codes = [0u8; 64];
        let n = encode_codes(codec, &sent[i], &mut codes).unwrap();
        at += encode_summary(
            &mut base,
            *key,
            u32::MAX - i as u32,
            i == 1,
            sent[i].count as u32,
            &codes[..n],
            &mut buf[at..],
        )
        .unwrap();
    }
    let batch = VoxelBatch {
        count: 3,
        summaries: &buf[..at],
    };
    let got: heapless::Vec<Summary<64>, 3> = batch.iter::<64>(codec).map(|r| r.unwrap()).collect();
    for (i, s) in got.iter().enumerate() {
        assert_eq!(s.key, keys[i]);
        assert_eq!(s.residency, u32::MAX - i as u32);
        assert_eq!(s.is_final, i == 1);
        assert_eq!(s.obs.count, sent[i].count);
        let err: f32 = libm::sqrtf(
            s.obs
                .mean
                .iter()
                .zip(&sent[i].mean)
                .map(|(a, b)| (a - b) * (a - b))
                .sum(),
        );
        let mut codes = [0u8; 64];
        encode_codes(codec, &sent[i], &mut codes).unwrap();
        assert!(
            err <= mean_error_bound(codec, 64, &codes, sent[i].count as u32) * 1.0001,
            "mean error {err}"
        );
        // The largest block mean is sent relative to the largest entry, rounded up.
        let true_max = sent[i].scatter.iter().fold(0.0f32, |a, &b| a.max(b));
        let got_max = s.obs.scatter.iter().fold(0.0f32, |a, &b| a.max(b));
        assert!(got_max <= true_max * 1.0906, "{got_max} vs {true_max}");
    }
    // One summary fewer than the count says, or one byte too many: refused.
    let short = VoxelBatch {
        count: 4,
        summaries: &buf[..at],
    };
    assert!(short
        .iter::<64>(codec)
        .any(|r| r == Err(WireError::Truncated)));
    let long = VoxelBatch {
        count: 2,
        summaries: &buf[..at],
    };
    assert!(long
        .iter::<64>(codec)
        .any(|r| r == Err(WireError::Malformed)));
}

#[test]
fn block_means_of_the_scatter_merge_additively() {
    let codec = SummaryCodec {
        mean_bits: 8,
        psi_blocks: 8,
        mean_bits_growth: 0,
        lead: 0,
        ..SummaryCodec::DEFAULT
    };
    let s = sample::<64>(3);
    let mut codes = [0u8; 128];
    encode_codes(codec, &s, &mut codes).unwrap();
    let d = decode_codes::<64>(codec, s.count, &codes).unwrap();
    assert_eq!(d.count, s.count);
    for b in 0..8 {
        let r = block_range(64, NonZeroUsize::new(8).unwrap(), b);
        let exact: f32 = s.scatter[r.clone()].iter().sum();
        let got: f32 = d.scatter[r].iter().sum();
        // Half an octave step: within 2^(±1/4).
        assert!(
            got / exact < 1.19 && exact / got < 1.19,
            "block {b}: {got} vs {exact}"
        );
    }
}

#[test]
fn body_round_trip_and_version_check() {
    let config = SessionConfig::new(
        &MapConfig::default(),
        64,
        SummaryCodec::DEFAULT,
        0xdead_beef,
    );
    let header = FrameHeader {
        version: PROTOCOL_VERSION,
        robot: 7,
        session: 99,
        seq: 12,
        config_id: config.id(),
    };
    let mut buf = [0u8; 128];
    let n = encode_body(&header, &Message::Session(config), &mut buf).unwrap();
    let (h, m) = parse_body(&buf[..n]).unwrap();
    assert_eq!((h, m), (header, Message::Session(config)));
    assert_eq!(m, Message::Session(config));
    assert!(config.validate(64).is_ok());
    assert_eq!(config.validate(32), Err(WireError::BadConfig));
    buf[0] = 1;
    assert_eq!(parse_body(&buf[..n]), Err(WireError::UnknownVersion(1)));
    buf[0] = PROTOCOL_VERSION;
    assert_eq!(parse_body(&buf[..n - 1]), Err(WireError::Truncated));
    assert_eq!(parse_body(&buf[..n + 1]), Err(WireError::Malformed));
    // Another voxel size is another configuration id.
    let other = MapConfig::new(0.2, 0.5, 3, Prior::default(), KernelMode::VoxelOffset).unwrap();
    assert_ne!(
        SessionConfig::new(&other, 64, SummaryCodec::DEFAULT, 0xdead_beef).id(),
        config.id()
    );
}

#[test]
fn a_lead_band_codes_the_leading_components_finer_and_keeps_the_rest_as_without_one() {
    // A PCA-like mean: 8 strong leading components, 56 weak ones.
    let mut stats = sample::<64>(7);
    for (i, m) in stats.mean.iter_mut().enumerate() {
        *m *= if i < 8 { 10.0 } else { 0.3 };
    }
    let plain = SummaryCodec {
        mean_bits: 3,
        psi_blocks: 2,
        mean_bits_growth: 0,
        lead: 0,
        ..SummaryCodec::DEFAULT
    };
    let lead = SummaryCodec {
        lead: 8,
        lead_bits: 3,
        ..plain
    };
    lead.validate(64).unwrap();
    let n = stats.count as u32;
    // Lead band: its scale + 8 × 6 bits; the rest: its scale + 56 × 3 bits; then the scatter.
    assert_eq!(lead.lead_len_for(n), 1 + 6);
    assert_eq!(lead.mean_len_for(64, n), 7 + 1 + 21);
    assert_eq!(lead.code_len_for(64, n), 29 + 1 + 1);
    assert_eq!(lead.code_len_for(64, 1), 29, "one point: no scatter");
    // With growth, the lead band gains a bit per doubling of n, the rest one per two doublings.
    let grows = SummaryCodec {
        mean_bits_growth: 3,
        ..lead
    };
    let bits = |n: u32| (grows.lead_bits_for(n), grows.rest_bits_for(n));
    assert_eq!(bits(1), (6, 3));
    assert_eq!(bits(2), (7, 4));
    assert_eq!(bits(4), (8, 4));
    assert_eq!(bits(8), (8, 5));
    assert_eq!(bits(32), (8, 6));
    assert_eq!(bits(1 << 20), (8, 6));
    // Without a lead band, growth is a bit per doubling for all (protocol 3's rule).
    assert_eq!(SummaryCodec { lead: 0, ..grows }.rest_bits_for(8), 6);
    let (mut a, mut b) = ([0u8; 64], [0u8; 64]);
    let la = encode_codes(plain, &stats, &mut a).unwrap();
    let lb = encode_codes(lead, &stats, &mut b).unwrap();
    assert_eq!(lb, lead.code_len_for(64, n));
    let pa = decode_codes::<64>(plain, stats.count, &a[..la]).unwrap();
    let pb = decode_codes::<64>(lead, stats.count, &b[..lb]).unwrap();
    let err = |got: &ObsStats<64>| {
        libm::sqrtf(
            got.mean
                .iter()
                .zip(&stats.mean)
                .map(|(x, y)| (x - y) * (x - y))
                .sum(),
        )
    };
    assert!(err(&pb) <= mean_error_bound(lead, 64, &b[..lb], n) * 1.0001);
    assert!(err(&pa) <= mean_error_bound(plain, 64, &a[..la], n) * 1.0001);
    // Here the lead band's error is a fraction of one band's: the energy is where the bits are.
    assert!(err(&pb) < 0.5 * err(&pa), "{} vs {}", err(&pb), err(&pa));
    // The scatter is sent the same way behind either mean.
    assert_eq!(pa.scatter, pb.scatter);
    // A lead band must leave components for the rest, and at most 6 more bits.
    assert!(SummaryCodec { lead: 64, ..lead }.validate(64).is_err());
    assert!(SummaryCodec {
        lead_bits: 7,
        ..lead
    }
    .validate(64)
    .is_err());
}

#[cfg(feature = "rice-codes")]
mod rice;

/// A session of stored codes: its configuration round-trips (the mode is `mean_bits` 255, no extension),
/// validates whatever its unused fields hold, and its code sizes are the map's (58 and 100 bytes at D = 64).
#[cfg(feature = "stored-codes")]
#[test]
fn a_stored_code_session_round_trips_and_sizes_its_codes_as_the_map() {
    let codec = SummaryCodec::STORED;
    assert!(codec.is_stored() && !SummaryCodec::DEFAULT.is_stored());
    assert_eq!(codec.validate(64), Ok(()));
    let config = SessionConfig::new(&MapConfig::default(), 64, codec, 0);
    let header = FrameHeader {
        version: PROTOCOL_VERSION,
        robot: 1,
        session: 2,
        seq: 0,
        config_id: config.id(),
    };
    let mut buf = [0u8; 128];
    let n = encode_body(&header, &Message::Session(config), &mut buf).unwrap();
    assert_eq!(
        parse_body(&buf[..n]),
        Ok((header, Message::Session(config)))
    );
    assert_ne!(
        config.id(),
        SessionConfig::new(&MapConfig::default(), 64, SummaryCodec::DEFAULT, 0).id()
    );
    assert_eq!(
        crate::quant::STORED_LAYOUT,
        [7, 5, 2],
        "the layout is protocol 5's: bump the version"
    );
    assert_eq!(codec.code_len_for(64, 1), 2 + 56);
    assert_eq!(codec.code_len_for(64, 2), 4 + crate::quant::packed_len(64));
    assert_eq!(codec.code_len(64), 100);
    // A summary of statistics has no stored codes to copy.
    let s = sample::<64>(3);
    assert_eq!(
        encode_codes(codec, &s, &mut [0u8; 128]),
        Err(WireError::BadConfig)
    );
}
