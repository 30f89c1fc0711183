use super::*;
use crate::config::MapConfig;
use crate::frame::{live, EncoderSettings, FrameEncoder, Resend};
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::sink::EvictionSink;
use crate::wire::{SummaryCodec, NO_FEATURE_SPACE};

extern crate std;
use std::vec::Vec;

const D: usize = 8;
type Enc = FrameEncoder<D, 2048, 256>;

fn config() -> SessionConfig {
    SessionConfig::new(
        &MapConfig::DEFAULT,
        D,
        SummaryCodec::DEFAULT,
        NO_FEATURE_SPACE,
    )
}

fn obs(i: i32) -> ObsStats<D> {
    ObsStats {
        count: 1.0 + i as f32,
        mean: core::array::from_fn(|d| 0.1 * d as f32 - 0.2 + 0.01 * i as f32),
        scatter: [0.5; D],
    }
}

/// A frame accepted (its seq) or refused (why), with its acknowledgement.
type Outcome = Result<(u32, Option<Ack>), (Refusal, Option<Ack>)>;

/// Every frame the receiver accepts or refuses, in order.
fn run(rx: &mut Receiver<D, 512>, sessions: &mut impl SessionTable, bytes: &[u8]) -> Vec<Outcome> {
    let mut out = Vec::new();
    let mut input = bytes;
    loop {
        match rx.feed(input, sessions) {
            Receipt::NeedMore => return out,
            Receipt::Accepted { frame, rest } => {
                out.push(Ok((frame.header.seq, frame.ack)));
                input = rest;
            }
            Receipt::Refused {
                reason, ack, rest, ..
            } => {
                out.push(Err((reason, ack)));
                input = rest;
            }
        }
    }
}

fn frames(settings: EncoderSettings, voxels: i32) -> (Enc, Vec<u8>) {
    let mut enc = Enc::new(config(), settings).unwrap();
    for i in 0..voxels {
        let o = obs(i);
        enc.evict(live(VoxelKey::new(i, 0, 0), &o, i as u32))
            .unwrap();
    }
    let mut out = Vec::new();
    enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
    (enc, out)
}

#[test]
fn an_adopting_receiver_refuses_frames_before_the_first_session_header() {
    let (_, bytes) = frames(EncoderSettings::new(1, 2), 3);
    let header_len = bytes[1..].iter().position(|&b| b == 0).unwrap() + 2;
    let mut rx = Receiver::<D, 512>::new(None);
    let mut sessions = Sessions::<2>::new();
    // Without the header: refused, and not tracked (no acknowledgement, nothing counted lost).
    let got = run(&mut rx, &mut sessions, &bytes[header_len..]);
    assert!(!got.is_empty());
    assert!(got
        .iter()
        .all(|r| matches!(r, Err((Refusal::WrongConfig, None)))));
    assert_eq!(sessions.iter().count(), 0);
    // Header, then the same frames again: accepted in order, each acknowledged.
    let got = run(&mut rx, &mut sessions, &bytes);
    assert_eq!(got[0].as_ref().unwrap().0, 0);
    assert!(got.iter().all(|r| r.is_ok()));
    assert_eq!(rx.config(), Some(&config()));
    let last = got.last().unwrap().as_ref().unwrap();
    let ack = last.1.unwrap();
    assert_eq!((ack.robot, ack.session, ack.highest), (1, 2, last.0));
    assert_eq!(ack.received, (1u64 << (last.0 + 1)) - 1);
}

#[test]
fn duplicates_are_refused_but_acknowledged_and_other_configs_refused() {
    let (_, bytes) = frames(EncoderSettings::new(1, 2), 3);
    let mut rx = Receiver::<D, 512>::new(Some(config()));
    let mut sessions = Sessions::<1>::new();
    let first = run(&mut rx, &mut sessions, &bytes);
    let again = run(&mut rx, &mut sessions, &bytes);
    assert_eq!(again.len(), first.len());
    assert!(again
        .iter()
        .all(|r| matches!(r, Err((Refusal::Duplicate, Some(_))))));
    // A second session does not fit in a one-session table.
    let (_, other) = frames(EncoderSettings::new(1, 3), 1);
    assert!(run(&mut rx, &mut sessions, &other)
        .iter()
        .all(|r| matches!(r, Err((Refusal::NoSessionRoom, None)))));
    // Another configuration.
    let mut c = config();
    c.codec.mean_bits = 4;
    let mut enc = FrameEncoder::<D, 2048, 256>::new(c, EncoderSettings::new(5, 5)).unwrap();
    let mut out = Vec::new();
    enc.tick(&mut out, 1000, core::iter::empty()).unwrap();
    assert!(matches!(
        run(&mut rx, &mut sessions, &out)[..],
        [Err((Refusal::WrongConfig, None))]
    ));
    let r = rx.refusals();
    assert_eq!(
        (r.duplicate_frames, r.no_session_room, r.wrong_config),
        (first.len() as u32, 2, 1)
    );
}

#[test]
fn acknowledgements_free_the_robot_and_lost_frames_are_resent() {
    let settings = EncoderSettings::new(1, 2).with_resend(Resend::new(1200, 3));
    let mut enc = Enc::new(config(), settings).unwrap();
    let mut rx = Receiver::<D, 512>::new(Some(config()));
    let mut sessions = Sessions::<2>::new();
    let mut applied = 0u32;
    let mut next = 0;
    // 40 voxels, 3 per frame at most (small budget); every 3rd frame is lost on the way.
    let mut written = 0u32;
    for _ in 0..200 {
        while next < 40 {
            let o = obs(next);
            if enc
                .evict(live(VoxelKey::new(next, 0, 0), &o, next as u32))
                .is_err()
            {
                break;
            }
            next += 1;
        }
        let mut out = Vec::new();
        enc.tick(&mut out, 150, core::iter::empty()).unwrap();
        // Whole frames (`0x00 … 0x00`); every 3rd is lost on the way.
        for frame in out.split(|&b| b == 0).filter(|f| !f.is_empty()) {
            written += 1;
            if written.is_multiple_of(3) {
                continue;
            }
            let mut input = &[&[0u8][..], frame, &[0]].concat()[..];
            let bytes = input.to_vec();
            input = &bytes;
            while let Step::Accepted { frame, rest } = rx.feed(input, &mut sessions).into_step() {
                input = rest;
                if let Some(f) = frame {
                    if let Message::Voxels(b) = f.message {
                        applied += u32::from(b.count);
                    }
                    enc.acknowledge(&f.ack.unwrap());
                }
            }
        }
        if next == 40 && enc.queued() == 0 && enc.unacknowledged() == 0 {
            break;
        }
    }
    assert_eq!(applied, 40, "every voxel applied exactly once");
    assert_eq!(enc.unacknowledged(), 0);
    assert!(enc.stats().resent > 0);
}

/// A session whose kernel cannot be gathered from per-voxel statistics (sub-voxel cells ≥ 2) is never
/// adopted: its frames are refused as another configuration, not tracked, not acknowledged. One sub-cell
/// per axis (the voxel-offset kernel's weights) is adopted.
#[test]
fn a_session_with_sub_voxel_cells_is_refused_and_one_cell_is_adopted() {
    use crate::config::{KernelMode, Prior};
    for (cells, adopted) in [(2u8, false), (8, false), (1, true)] {
        let map =
            MapConfig::new(0.1, 0.3, 3, Prior::DEFAULT, KernelMode::SubVoxel { cells }).unwrap();
        let c = SessionConfig::new(&map, D, SummaryCodec::DEFAULT, NO_FEATURE_SPACE);
        assert_eq!(receivable::<D>(&c), adopted);
        let mut enc = Enc::new(c, EncoderSettings::new(1, 2)).unwrap();
        enc.evict(live(VoxelKey::new(1, 0, 0), &obs(1), 0)).unwrap();
        let mut out = Vec::new();
        enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
        let mut rx = Receiver::<D, 512>::new(None);
        let mut sessions = Sessions::<2>::new();
        let got = run(&mut rx, &mut sessions, &out);
        assert_eq!(got.len(), 2, "{cells}");
        if adopted {
            assert!(got.iter().all(Result::is_ok), "{cells}: {got:?}");
            assert_eq!(rx.config(), Some(&c));
        } else {
            assert!(got
                .iter()
                .all(|r| matches!(r, Err((Refusal::WrongConfig, None)))));
            assert_eq!((rx.config(), sessions.iter().count()), (None, 0));
            assert_eq!(rx.refusals().wrong_config, 2);
        }
    }
}
