//! A session of stored codes end to end: the map's codes reach the receiver bit for bit (the same
//! statistics the map's own decode gives), a one-point summary sends no scatter, and hostile bytes are
//! refused, never a panic.

use crate::config::MapConfig;
use crate::frame::{live, EncoderSettings, Feed, FrameDecoder, FrameEncoder};
use crate::key::VoxelKey;
use crate::local_map::LocalMap;
use crate::obs::ObsStats;
use crate::quant::packed_len;
use crate::sink::{Evicted, EvictedStored, EvictionSink, SinkFull};
use crate::wire::{
    decode_summary, parse_body, DeltaBase, Message, SessionConfig, SummaryCodec, VoxelBatch,
};
extern crate std;
use std::boxed::Box;
use std::vec::Vec;

const D: usize = 16;
const P: usize = packed_len(D);
type Map = LocalMap<D, 64, P, 4>;
type Enc = FrameEncoder<D, 8192, 512>;

/// What a sink that takes codes sees, decoded by the map's unpacking.
#[derive(Default)]
struct Recorder(Vec<(VoxelKey, u32, ObsStats<D>)>);
impl EvictionSink<D> for Recorder {
    fn evict(&mut self, _: Evicted<'_, D>) -> Result<(), SinkFull> {
        panic!("a sink that takes codes is handed codes")
    }
    fn wants_stored(&self) -> bool {
        true
    }
    fn evict_stored(&mut self, v: EvictedStored<'_>) -> Result<(), SinkFull> {
        let mut obs = ObsStats::EMPTY;
        v.decode_into(&mut obs).expect("the map's codes decode");
        self.0.push((v.key, v.residency, obs));
        Ok(())
    }
}

/// A map holding voxels of one point and of many, some hot (not yet cooled) when it is flushed.
fn map_with_points() -> Box<Map> {
    let mut m = Box::new(Map::EMPTY);
    m.configure(MapConfig::default(), 50.0).unwrap();
    let mut none = |_: Evicted<'_, D>| Err(SinkFull);
    for i in 0..40u32 {
        let x = i as f32 * 0.5;
        let y: [f32; D] = core::array::from_fn(|d| ((i * 7 + d as u32) as f32 * 0.37).sin());
        let reps = if i % 3 == 0 { 1 } else { 1 + i % 5 };
        for r in 0..reps {
            m.add_point([x + r as f32 * 0.01, 0.1, 0.1], &y, &mut none)
                .unwrap();
        }
    }
    m
}

fn summaries(out: &[u8], codec: SummaryCodec) -> Vec<(crate::wire::Summary<D>, usize)> {
    let mut dec = FrameDecoder::<512>::new();
    let mut input = out;
    let mut got = Vec::new();
    while let Feed::Frame { body, rest } = dec.feed(input) {
        if let (_, Message::Voxels(b)) = parse_body(body).unwrap() {
            let (mut at, mut base) = (0, DeltaBase::default());
            for _ in 0..b.count {
                let from = at;
                let s = decode_summary::<D>(codec, &mut base, b.summaries, &mut at).unwrap();
                got.push((s, at - from));
            }
        }
        input = rest;
    }
    got
}

#[test]
fn stored_codes_reach_the_receiver_as_the_map_decodes_them() {
    let config = SessionConfig::new(&MapConfig::default(), D, SummaryCodec::STORED, 0);
    let mut enc = Enc::new(config, EncoderSettings::new(1, 2)).unwrap();
    let mut robot = map_with_points();
    let mut twin = map_with_points();
    let mut seen = Recorder::default();
    let n = robot.flush(&mut enc).unwrap();
    assert_eq!(twin.flush(&mut seen).unwrap(), n);
    assert_eq!(enc.stats().invalid, 0);
    let mut out = Out(Vec::new());
    enc.tick(&mut out, 1 << 20, core::iter::empty()).unwrap();
    let got = summaries(&out.0, SummaryCodec::STORED);
    assert_eq!(got.len(), n);
    let (mut ones, mut many) = (0, 0);
    for ((s, len), (key, residency, obs)) in got.iter().zip(&seen.0) {
        assert_eq!((s.key, s.residency, s.is_final), (*key, *residency, true));
        assert_eq!(&s.obs, obs, "bit for bit");
        let code_len = SummaryCodec::STORED.code_len_for(D, s.obs.count as u32);
        if s.obs.count == 1.0 {
            ones += 1;
            assert_eq!(
                code_len,
                2 + (D * 7).div_ceil(8),
                "no scatter for one point"
            );
        } else {
            many += 1;
            assert_eq!(code_len, 4 + P);
        }
        assert!(*len > code_len && *len <= code_len + 10);
    }
    assert!(
        ones > 0 && many > 0,
        "{ones} one-point voxels, {many} of more"
    );
}

#[test]
fn a_stored_session_takes_no_statistics_and_refuses_hostile_codes() {
    let config = SessionConfig::new(&MapConfig::default(), D, SummaryCodec::STORED, 0);
    let mut enc = Enc::new(config, EncoderSettings::new(1, 2)).unwrap();
    // Statistics handed as such have no codes to copy: counted invalid, not sent.
    let obs = ObsStats::<D> {
        count: 2.0,
        ..ObsStats::EMPTY
    };
    assert_eq!(enc.evict(live(VoxelKey::new(0, 0, 0), &obs, 1)), Ok(()));
    assert_eq!((enc.stats().invalid, enc.queued()), (1, 0));
    // A batch of good summaries, then every bit of it flipped in turn: refused or decoded valid, never
    // a panic.
    let mut robot = map_with_points();
    robot.flush(&mut enc).unwrap();
    let mut out = Out(Vec::new());
    enc.tick(&mut out, 1 << 20, core::iter::empty()).unwrap();
    let mut dec = FrameDecoder::<512>::new();
    let mut input = &out.0[..];
    let mut batch = None;
    while let Feed::Frame { body, rest } = dec.feed(input) {
        if let (_, Message::Voxels(b)) = parse_body(body).unwrap() {
            batch.get_or_insert((b.count, b.summaries.to_vec()));
        }
        input = rest;
    }
    let (count, bytes) = batch.expect("a frame of summaries");
    let good = VoxelBatch {
        count,
        summaries: &bytes,
    };
    assert!(good.iter::<D>(SummaryCodec::STORED).all(|s| s.is_ok()));
    let (mut refused, mut taken) = (0, 0);
    for bit in 0..bytes.len() * 8 {
        let mut bad = bytes.clone();
        bad[bit / 8] ^= 1 << (bit % 8);
        let batch = VoxelBatch {
            count,
            summaries: &bad,
        };
        for s in batch.iter::<D>(SummaryCodec::STORED) {
            match s {
                Ok(s) => {
                    assert!(s.obs.is_valid());
                    taken += 1;
                }
                Err(_) => refused += 1,
            }
        }
    }
    assert!(refused > 0 && taken > 0, "{refused} refused, {taken} taken");
}

/// The encoder's output, collected.
struct Out(Vec<u8>);
impl embedded_io::ErrorType for Out {
    type Error = embedded_io::ErrorKind;
}
impl embedded_io::Write for Out {
    fn write(&mut self, b: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// A map that forgets, in a session that forgets: stamped summaries carry the codes as of each voxel's last
/// change (a hot voxel cooled, faded by the clock rule, first), bit for bit what the map's decode gives.
#[cfg(feature = "forgetting")]
#[test]
fn stamped_stored_codes_carry_the_faded_codes_and_their_tick() {
    use crate::forget::{Fading, Forgetting};
    type Fmap = LocalMap<D, 64, P, 4, Fading>;
    let forgetting = Forgetting::new(20.0);
    let fill = || {
        let mut m = Box::new(Fmap::EMPTY);
        m.configure(MapConfig::default(), 50.0).unwrap();
        m.set_forgetting(forgetting).unwrap();
        let mut none = |_: Evicted<'_, D>| Err(SinkFull);
        for i in 0..30u32 {
            m.set_time(100 + 3 * i);
            let y: [f32; D] = core::array::from_fn(|d| ((i * 5 + d as u32) as f32 * 0.29).cos());
            for r in 0..1 + i % 3 {
                let x = (i % 17) as f32 * 0.5 + r as f32 * 0.01;
                m.add_point([x, 0.1, 0.1], &y, &mut none).unwrap();
            }
        }
        m
    };
    let config = SessionConfig::new(&MapConfig::default(), D, SummaryCodec::STORED, 0)
        .with_forgetting(forgetting);
    let mut enc = Enc::new(config, EncoderSettings::new(1, 2)).unwrap();
    let mut seen = Recorder::default();
    let mut times = Vec::new();
    let n = fill().flush(&mut enc).unwrap();
    assert_eq!(fill().flush(&mut seen).unwrap(), n);
    let mut twin = fill();
    twin.flush(&mut |v: Evicted<'_, D>| {
        times.push(v.time);
        Ok(())
    })
    .unwrap();
    let mut out = Out(Vec::new());
    enc.tick(&mut out, 1 << 20, core::iter::empty()).unwrap();
    let got = summaries(&out.0, SummaryCodec::STORED);
    assert_eq!(got.len(), n);
    for (((s, _), (key, _, obs)), time) in got.iter().zip(&seen.0).zip(&times) {
        assert_eq!(s.key, *key);
        assert_eq!(&s.obs, obs, "bit for bit");
        assert_eq!(s.time, Some(*time));
    }
    assert!(times.iter().any(|&t| t != times[0]), "stamps differ");
}
