use super::*;
use crate::config::MapConfig;
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::sink::{EvictionSink, SinkFull};
use crate::wire::{parse_body, Message, SessionConfig, SummaryCodec};

type Enc = FrameEncoder<8, 1024, 256>;

fn config() -> SessionConfig {
    SessionConfig::new(&MapConfig::default(), 8, SummaryCodec::DEFAULT, 0)
}

fn voxel(i: i32) -> ObsStats<8> {
    ObsStats {
        count: 1.0 + i as f32,
        mean: core::array::from_fn(|d| (d as f32 - 3.5) * 0.1 + i as f32 * 0.01),
        scatter: [1.5; 8],
    }
}

/// A Write into a fixed buffer.
struct Buf {
    data: [u8; 8192],
    len: usize,
}
impl embedded_io::ErrorType for Buf {
    type Error = embedded_io::ErrorKind;
}
impl embedded_io::Write for Buf {
    fn write(&mut self, b: &[u8]) -> Result<usize, Self::Error> {
        let n = b.len().min(self.data.len() - self.len);
        if n == 0 && !b.is_empty() {
            return Err(embedded_io::ErrorKind::OutOfMemory);
        }
        self.data[self.len..self.len + n].copy_from_slice(&b[..n]);
        self.len += n;
        Ok(n)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[test]
fn queue_refuses_when_full_and_tick_respects_the_budget() {
    let mut enc = Enc::new(config(), EncoderSettings::new(1, 2)).unwrap();
    let cap = enc.capacity();
    let stats: [ObsStats<8>; 64] = core::array::from_fn(|i| voxel(i as i32));
    for (i, s) in stats.iter().enumerate().take(cap) {
        assert_eq!(
            enc.evict(live(VoxelKey::new(i as i32, 0, 0), s, i as u32)),
            Ok(())
        );
    }
    assert_eq!(
        enc.evict(live(VoxelKey::new(99, 0, 0), &stats[0], 99)),
        Err(SinkFull)
    );
    assert_eq!(enc.stats().refused, 1);
    let mut out = Buf {
        data: [0; 8192],
        len: 0,
    };
    let r = enc.tick(&mut out, 100, core::iter::empty()).unwrap();
    assert!(r.bytes <= 100 && r.bytes == out.len);
    assert_eq!(r.frames, 1, "only the session header fits in 100 bytes");
    let r2 = enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
    assert_eq!(r2.evicted_sent as usize, cap);
    assert_eq!(enc.queued(), 0);
    // Decode everything: a header, then exactly the queued voxels in order.
    let mut dec = FrameDecoder::<256>::new();
    let mut input = &out.data[..out.len];
    let mut keys = heapless::Vec::<i32, 64>::new();
    let mut seqs = heapless::Vec::<u32, 16>::new();
    loop {
        match dec.feed(input) {
            Feed::NeedMore => break,
            Feed::Error { error, .. } => panic!("{error:?}"),
            Feed::Frame { body, rest } => {
                let (h, m) = parse_body(body).unwrap();
                seqs.push(h.seq).unwrap();
                if let Message::Voxels(b) = m {
                    for s in b.iter::<8>(SummaryCodec::DEFAULT) {
                        let s = s.unwrap();
                        assert!(s.is_final);
                        assert_eq!(s.obs.count, stats[s.key.x as usize].count);
                        keys.push(s.key.x).unwrap();
                    }
                }
                input = rest;
            }
        }
    }
    assert!(keys.iter().copied().eq(0..cap as i32));
    assert!(seqs.iter().copied().eq(0..seqs.len() as u32));
}

#[test]
fn live_voxels_follow_evicted_ones_and_report_a_prefix() {
    let mut enc = Enc::new(config(), EncoderSettings::new(1, 2)).unwrap();
    let s = voxel(1);
    enc.evict(live(VoxelKey::new(0, 0, 0), &s, 1)).unwrap();
    let lives: [ObsStats<8>; 40] = core::array::from_fn(|i| voxel(i as i32));
    let mut out = Buf {
        data: [0; 8192],
        len: 0,
    };
    let budget = 600;
    let r = enc
        .tick(
            &mut out,
            budget,
            lives
                .iter()
                .enumerate()
                .map(|(i, s)| live(VoxelKey::new(i as i32, 1, 0), s, 100 + i as u32)),
        )
        .unwrap();
    assert_eq!(r.evicted_sent, 1);
    assert!(
        r.live_sent > 0 && (r.live_sent as usize) < lives.len(),
        "{r:?}"
    );
    assert!(r.bytes <= budget);
}

/// A Rice session's head grows with the key and residency deltas (Exp-Golomb codes): a summary of keys
/// far apart is longer than a packed one can be, and still fits the smallest frame the encoder accepts,
/// so it is sent rather than stuck in the queue.
#[cfg(feature = "rice-codes")]
#[test]
fn a_rice_summary_of_far_keys_fits_the_smallest_frame_the_encoder_accepts() {
    const RICE: SummaryCodec = SummaryCodec {
        rice: true,
        psi_blocks: 1,
        ..SummaryCodec::DEFAULT
    };
    const SMALLEST: usize = wire_len(encoder::VOXEL_FRAME_OVERHEAD + RICE.max_summary_len(16));
    let config = SessionConfig::new(&MapConfig::default(), 16, RICE, 0);
    let settings = EncoderSettings::new(1, 2);
    assert!(FrameEncoder::<16, 1024, { SMALLEST - 1 }>::new(config, settings).is_err());
    let mut enc = FrameEncoder::<16, 1024, SMALLEST>::new(config, settings).unwrap();
    let far = (1 << 30) - 1;
    let key = VoxelKey::new(-far, far, -far);
    let s = ObsStats::<16> {
        count: (1 << 24) as f32,
        mean: core::array::from_fn(|d| {
            [0.3, -7.0, 0.001, 2.5, -0.02, 9.0, -3.3, 0.7][d % 8] * d as f32
        }),
        scatter: [1.5; 16],
    };
    // The residency delta from 0 is i32::MIN: the longest code of all.
    enc.evict(live(key, &s, 1 << 31)).unwrap();
    let mut out = Buf {
        data: [0; 8192],
        len: 0,
    };
    enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
    assert_eq!(enc.queued(), 0, "the summary did not fit a frame");
    let mut dec = FrameDecoder::<SMALLEST>::new();
    let mut input = &out.data[..out.len];
    let mut got = heapless::Vec::<(VoxelKey, u32, usize), 2>::new();
    while let Feed::Frame { body, rest } = dec.feed(input) {
        if let (_, Message::Voxels(b)) = parse_body(body).unwrap() {
            for v in b.iter::<16>(RICE) {
                let v = v.unwrap();
                got.push((v.key, v.residency, b.summaries.len())).unwrap();
            }
        }
        input = rest;
    }
    // Longer than a packed head and the codes could be.
    let packed_max = crate::wire::codec::PACKED_HEAD_MAX + RICE.code_len(16);
    assert!(
        matches!(got[..], [(k, r, len)] if k == key && r == 1 << 31 && len > packed_max),
        "{got:?}, packed at most {packed_max}"
    );
}

#[test]
fn live_voxels_the_decoder_would_refuse_are_skipped_not_sent() {
    // n = 0 (nothing observed) and NaN among good live voxels: a sent one would make the
    // base station refuse the whole frame, final summaries included.
    let mut enc = Enc::new(config(), EncoderSettings::new(1, 2)).unwrap();
    enc.evict(live(VoxelKey::new(0, 0, 0), &voxel(1), 1))
        .unwrap();
    let mut lives: [ObsStats<8>; 6] = core::array::from_fn(|i| voxel(i as i32));
    lives[1].count = 0.0;
    lives[4].mean[2] = f32::NAN;
    let mut out = Buf {
        data: [0; 8192],
        len: 0,
    };
    let r = enc
        .tick(
            &mut out,
            10_000,
            lives
                .iter()
                .enumerate()
                .map(|(i, s)| live(VoxelKey::new(i as i32, 1, 0), s, 10 + i as u32)),
        )
        .unwrap();
    assert_eq!((r.evicted_sent, r.live_sent), (1, 6), "{r:?}");
    let mut dec = FrameDecoder::<256>::new();
    let mut input = &out.data[..out.len];
    let mut live_keys = heapless::Vec::<i32, 8>::new();
    while let Feed::Frame { body, rest } = dec.feed(input) {
        if let (_, Message::Voxels(b)) = parse_body(body).unwrap() {
            for s in b.iter::<8>(SummaryCodec::DEFAULT) {
                let s = s.expect("every summary sent is one the decoder accepts");
                if !s.is_final {
                    live_keys.push(s.key.x).unwrap();
                }
            }
        }
        input = rest;
    }
    assert_eq!(live_keys.as_slice(), &[0, 2, 3, 5]);
}

#[test]
fn an_empty_encoder_refuses_and_configure_starts_afresh() {
    let buf = || Buf {
        data: [0; 8192],
        len: 0,
    };
    let s = voxel(3);
    let mut enc = Enc::EMPTY;
    assert!(!enc.is_configured());
    assert_eq!(
        enc.evict(live(VoxelKey::new(1, 2, 3), &s, 7)),
        Err(SinkFull)
    );
    let mut out = buf();
    let r = enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
    assert_eq!((r.frames, out.len), (0, 0));
    assert_eq!(enc.send_header(&mut out), Ok(0));
    assert_eq!(enc.send_stats(&mut out), Ok(0));
    assert_eq!(out.len, 0);
    // A used encoder reconfigured in place writes exactly what a new one writes.
    let run = |enc: &mut Enc| {
        let mut out = buf();
        for i in 0..5 {
            enc.evict(live(VoxelKey::new(i, -i, 2 * i), &s, i as u32))
                .unwrap();
        }
        enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
        enc.send_stats(&mut out).unwrap();
        out
    };
    let fresh = run(&mut Enc::new(config(), EncoderSettings::new(1, 2)).unwrap());
    let mut reused = Enc::new(config(), EncoderSettings::new(9, 9)).unwrap();
    run(&mut reused);
    reused.evict(live(VoxelKey::new(9, 9, 9), &s, 99)).unwrap();
    reused
        .configure(config(), EncoderSettings::new(1, 2))
        .unwrap();
    assert_eq!((reused.queued(), reused.next_seq()), (0, 0));
    let again = run(&mut reused);
    assert_eq!(fresh.data[..fresh.len], again.data[..again.len]);
    // A configuration that does not fit leaves it without a session.
    let bad = SessionConfig { dim: 9, ..config() };
    assert!(reused.configure(bad, EncoderSettings::new(1, 2)).is_err());
    assert!(!reused.is_configured());
    assert_eq!(
        reused.evict(live(VoxelKey::new(1, 2, 3), &s, 7)),
        Err(SinkFull)
    );
}

#[test]
fn decoder_resyncs_after_garbage_and_counts_it() {
    let mut enc = Enc::new(config(), EncoderSettings::new(1, 2)).unwrap();
    let mut a = Buf {
        data: [0; 8192],
        len: 0,
    };
    enc.send_header(&mut a).unwrap();
    let first = a.len;
    enc.send_header(&mut a).unwrap();
    // Corrupt one byte in the first frame, feed byte by byte.
    a.data[first / 2] ^= 0x10;
    let mut dec = FrameDecoder::<256>::new();
    let (mut ok, mut bad) = (0, 0);
    for b in &a.data[..a.len] {
        match dec.feed(core::slice::from_ref(b)) {
            Feed::Frame { body, .. } => {
                assert_eq!(parse_body(body).unwrap().0.seq, 1);
                ok += 1;
            }
            Feed::Error { .. } => bad += 1,
            Feed::NeedMore => {}
        }
    }
    assert_eq!((ok, bad), (1, 1));
    // Overflow: a run longer than the buffer is refused, the next frame still decodes.
    let mut dec = FrameDecoder::<16>::new();
    assert!(matches!(dec.feed(&[1u8; 40]), Feed::NeedMore));
    assert!(matches!(
        dec.feed(&[0]),
        Feed::Error {
            error: FrameError::Overflow,
            ..
        }
    ));
    assert_eq!(dec.stats().overflows, 1);
}

#[test]
fn seq_tracker_counts_loss_duplicates_and_late_frames() {
    let mut t = SeqTracker::default();
    assert_eq!(t.accept(2), SeqVerdict::New); // 0, 1 lost
    assert_eq!(t.accept(3), SeqVerdict::New);
    assert_eq!(t.accept(3), SeqVerdict::Duplicate);
    assert_eq!(t.accept(7), SeqVerdict::New); // 4, 5, 6 lost
    assert_eq!(t.lost, 5);
    assert_eq!(t.accept(5), SeqVerdict::Late);
    assert_eq!(t.accept(5), SeqVerdict::Duplicate);
    assert_eq!(t.lost, 4);
    assert_eq!(t.accept(200), SeqVerdict::New);
    assert_eq!(t.accept(100), SeqVerdict::TooOld);
    assert_eq!(t.lost, 4 + 192);
    assert_eq!((t.received, t.duplicates, t.late, t.too_old), (5, 2, 1, 1));
}
