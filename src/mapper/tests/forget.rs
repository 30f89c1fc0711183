//! Forgetting over the link: the half-life in the session header, stamped summaries, the receiver's
//! refusals of summaries that do not match their session.

use crate::config::MapConfig;
use crate::forget::{Fading, Forgetting, Stamped};
use crate::frame::EncoderSettings;
use crate::key::VoxelKey;
use crate::mapper::*;
use crate::quant::packed_len;
use crate::receiver::{Receipt, Receiver, Sessions};
use crate::wire::{
    encode_body, encode_codes, encode_summary, parse_body, DeltaBase, FrameHeader, Message,
    SessionConfig, VoxelBatch, WireError, PROTOCOL_VERSION,
};
use nalgebra::{Translation3, UnitQuaternion};

extern crate std;
use std::boxed::Box;
use std::collections::BTreeMap;
use std::vec::Vec;

const D: usize = 8;
type Fades = Mapper<D, 128, { packed_len(D) }, 4096, 256, 8, Fading>;

fn half_life() -> Forgetting {
    Forgetting::new(6.0).unwrap()
}

fn setup() -> Setup {
    Setup::new(MapConfig::DEFAULT, 0.6, EncoderSettings::new(4, 9))
        .with_forgetting(Some(half_life()))
}

/// 60 points on a strip beside `x`, features that change with the tick.
fn sensor_frame(x: f32, t: u32) -> (Isometry3<f32>, Vec<[f32; 3]>, Vec<[f32; D]>) {
    let pose = Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity());
    let points = (0..60)
        .map(|i| [0.01 * i as f32 - 0.3, 0.2, 0.02])
        .collect();
    let features = (0..60)
        .map(|i| {
            core::array::from_fn(|d| if d == i / 10 % 3 { 0.8 } else { -0.2 } + t as f32 * 0.01)
        })
        .collect();
    (pose, points, features)
}

/// Every summary the receiver accepts, by key: stamped contributions merged by the clock rule.
fn receive(bytes: &[u8]) -> (BTreeMap<VoxelKey, Stamped<D>>, Option<SessionConfig>, u32) {
    let mut rx = Receiver::<D, 512>::new(None);
    let mut sessions = Sessions::<2>::new();
    let mut got = BTreeMap::new();
    let mut input = bytes;
    let f = half_life();
    loop {
        match rx.feed(input, &mut sessions) {
            Receipt::NeedMore => break,
            Receipt::Refused { rest, .. } => input = rest,
            Receipt::Accepted { frame, rest } => {
                if let Message::Voxels(batch) = frame.message {
                    for s in batch.iter::<D>(frame.config.codec) {
                        let s = s.unwrap();
                        assert!(s.is_final, "no live updates in this run");
                        let v = Stamped {
                            obs: s.obs,
                            time: s.time.unwrap_or(0),
                        };
                        got.entry(s.key).or_insert(Stamped::EMPTY).merge(&f, &v);
                    }
                }
                input = rest;
            }
        }
    }
    (got, rx.config().copied(), rx.refusals().invalid_voxel)
}

#[test]
fn the_base_station_gets_the_robots_stamped_statistics() {
    let mut robot = Box::new(Fades::EMPTY);
    robot.configure(&setup()).unwrap();
    let f = half_life();
    let mut tapped: BTreeMap<VoxelKey, Stamped<D>> = BTreeMap::new();
    let mut link = Vec::new();
    for t in 0..30u32 {
        robot.set_time(t);
        let (pose, points, features) = sensor_frame(0.05 * t as f32, t);
        robot.integrate_tapped(
            &pose,
            &points,
            &features,
            |e: &crate::sink::Evicted<'_, D>| {
                let v = Stamped {
                    obs: *e.obs,
                    time: e.time,
                };
                tapped.entry(e.key).or_insert(Stamped::EMPTY).merge(&f, &v);
            },
        );
        robot.tick(&mut link, 4096).unwrap();
    }
    robot
        .drain_tapped(&mut link, |e: &crate::sink::Evicted<'_, D>| {
            let v = Stamped {
                obs: *e.obs,
                time: e.time,
            };
            tapped.entry(e.key).or_insert(Stamped::EMPTY).merge(&f, &v);
        })
        .unwrap();
    let (got, config, invalid) = receive(&link);
    assert_eq!(invalid, 0);
    assert_eq!(
        config.unwrap().half_life,
        6.0,
        "the half-life in the header"
    );
    assert_eq!(config.unwrap().forgetting(), Some(f));
    assert_eq!(got.len(), tapped.len());
    assert!(
        tapped.values().any(|v| v.time < 20),
        "voxels left behind early"
    );
    for (key, want) in &tapped {
        let have = got[key];
        assert_eq!(have.time, want.time, "{key:?}: the stamp travels exactly");
        let (a, b) = (have.at(&f, 40), want.at(&f, 40));
        // n travels as f32 bits and both sides merge in the same order by the same rule.
        assert_eq!(a.count, b.count, "{key:?}");
        // m is quantized on the wire (3 bits per component and one more per doubling of n, against the
        // largest component): within a quarter of its norm at D = 8 (the base-station test in host-sim
        // checks what matters, the argmax, at D = 64).
        let err = (0..D)
            .map(|d| (a.mean[d] - b.mean[d]).powi(2))
            .sum::<f32>()
            .sqrt();
        let norm = (0..D).map(|d| b.mean[d].powi(2)).sum::<f32>().sqrt();
        assert!(
            err <= 0.25 * norm + 1e-3,
            "{key:?}: |Δm| {err} of |m| {norm}"
        );
    }
}

/// A body as the encoder frames it: CRC-32 appended, COBS between two delimiters.
fn framed(body: &[u8]) -> Vec<u8> {
    let mut b = body.to_vec();
    b.extend_from_slice(&crate::wire::CRC32.checksum(body).to_le_bytes());
    let mut out = std::vec![0u8; b.len() + b.len() / 254 + 3];
    let n = cobs::try_encode(&b, &mut out[1..]).unwrap();
    out.truncate(n + 2);
    out
}

/// A frame of one summary (stamped or not) under `config`.
fn voxel_frame(config: &SessionConfig, stamped: bool) -> Vec<u8> {
    let obs = crate::obs::ObsStats::<D> {
        count: 2.0,
        mean: [0.1; D],
        scatter: [0.01; D],
    };
    let mut codes = [0u8; 64];
    let c = encode_codes(config.codec, &obs, &mut codes).unwrap();
    let mut summary = [0u8; 96];
    let mut base = DeltaBase::default();
    let key = VoxelKey::new(1, 2, 3);
    let n = if stamped {
        let h = crate::wire::encode_stamped_head(&mut base, (key, 0, true), 5, 2.0, &mut summary)
            .unwrap();
        let c = crate::wire::encode_codes_as(config.codec, &obs, 2, &mut summary[h..]).unwrap();
        h + c
    } else {
        encode_summary(&mut base, key, 0, true, 2, &codes[..c], &mut summary).unwrap()
    };
    let header = |seq| FrameHeader {
        version: PROTOCOL_VERSION,
        robot: 1,
        session: 1,
        seq,
        config_id: config.id(),
    };
    let mut out = Vec::new();
    for (seq, m) in [
        Message::Session(*config),
        Message::Voxels(VoxelBatch {
            count: 1,
            summaries: &summary[..n],
        }),
    ]
    .iter()
    .enumerate()
    {
        let mut body = [0u8; 256];
        let len = encode_body(&header(seq as u32), m, &mut body).unwrap();
        out.extend_from_slice(&framed(&body[..len]));
    }
    out
}

#[test]
fn summaries_that_do_not_match_their_session_are_refused_and_counted() {
    let plain = setup().with_forgetting(None).session(D);
    let fading = setup().session(D);
    assert_ne!(
        plain.id(),
        fading.id(),
        "the half-life is part of the configuration id"
    );
    for (config, stamped, refused) in [
        (plain, false, 0),
        (plain, true, 1),
        (fading, true, 0),
        (fading, false, 1),
    ] {
        let (got, _, invalid) = receive(&voxel_frame(&config, stamped));
        assert_eq!(invalid, refused, "stamped {stamped} in {config:?}");
        assert_eq!(got.len(), 1 - refused as usize);
    }
}

#[test]
fn the_half_life_extension_is_checked() {
    let fading = setup().session(D);
    let header = FrameHeader {
        version: PROTOCOL_VERSION,
        robot: 1,
        session: 1,
        seq: 0,
        config_id: fading.id(),
    };
    let mut body = [0u8; 128];
    let len = encode_body(&header, &Message::Session(fading), &mut body).unwrap();
    let (_, m) = parse_body(&body[..len]).unwrap();
    assert_eq!(m, Message::Session(fading));
    // A session that does not forget sends no extension: its bytes are those of protocol 4 before.
    let plain = setup().with_forgetting(None).session(D);
    let plain_len = encode_body(&header, &Message::Session(plain), &mut [0u8; 128]).unwrap();
    assert_eq!(plain_len + 4, len);
    for bad in [0.0f32, -1.0, f32::NAN] {
        body[len - 4..len].copy_from_slice(&bad.to_le_bytes());
        assert_eq!(parse_body(&body[..len]), Err(WireError::Malformed), "{bad}");
    }
    // An infinite half-life parses, and the configuration refuses it.
    body[len - 4..len].copy_from_slice(&f32::INFINITY.to_le_bytes());
    let Ok((_, Message::Session(c))) = parse_body(&body[..len]) else {
        panic!("parses")
    };
    assert_eq!(c.validate(D), Err(WireError::BadConfig));
}
