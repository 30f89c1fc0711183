//! Voxels built from fuzz bytes → FrameEncoder (as an eviction sink, with a byte budget) → bytes →
//! FrameDecoder: every voxel the encoder took arrives with its key, residency and λ exact; in a session
//! that forgets (bit 7 of the second byte), with its stamp exact too and any weight in (0, 2^24].
#![no_main]

use latentbki::frame::{EncoderSettings, Feed, FrameDecoder};
use latentbki::wire::{parse_body, Message, SessionConfig, SummaryCodec};
use latentbki::{
    frame::FrameEncoder, key::VoxelKey, obs::ObsStats, sink::Evicted, sink::EvictionSink, MapConfig,
};
use libfuzzer_sys::fuzz_target;

const D: usize = 8;

struct Buf(Vec<u8>);
impl embedded_io::ErrorType for Buf {
    type Error = core::convert::Infallible;
}
impl embedded_io::Write for Buf {
    fn write(&mut self, b: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let codec = SummaryCodec {
        mean_bits: 2 + data[0] % 7,
        psi_blocks: 1 + data[1] % D as u8,
        mean_bits_growth: data[0] / 7 % 4,
        // A lead band of 0..D−1 components (0 = none) with 0..=6 more bits.
        lead: data[1] / 16 % D as u8,
        lead_bits: data[0] / 28 % 7,
        // Rice-coded means and heads (a session extension byte).
        rice: (data[0] ^ data[1]) & 1 == 1,
    };
    let forgetting = (data[1] & 0x80 != 0)
        .then(|| latentbki::forget::Forgetting::new(1.0 + f32::from(data[0])))
        .flatten();
    let config = SessionConfig::new(&MapConfig::default(), D, codec, 0).with_forgetting(forgetting);
    let mut enc = FrameEncoder::<D, 2048, 256>::new(config, EncoderSettings::new(1, 1)).unwrap();
    let mut out = Buf(Vec::new());
    let mut sent = Vec::new();
    let f = |c: &[u8]| f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
    let record = 12 + 4 * (1 + 2 * D);
    for (i, c) in data[2..].chunks_exact(record).enumerate() {
        let key = VoxelKey::new(
            i32::from_le_bytes([c[0], c[1], c[2], c[3]]) >> 2,
            i32::from_le_bytes([c[4], c[5], c[6], c[7]]) >> 2,
            i32::from_le_bytes([c[8], c[9], c[10], c[11]]) >> 2,
        );
        let v = &c[12..];
        // Any bits for the count (mostly not a whole number in 1..=2^24: the encoder must drop those).
        let stats = ObsStats::<D> {
            count: f(v),
            mean: core::array::from_fn(|d| f(&v[4 + 4 * d..])),
            scatter: core::array::from_fn(|d| f(&v[4 + 4 * D + 4 * d..]).abs()),
        };
        let ok = stats.is_valid()
            && match forgetting {
                Some(_) => latentbki::wire::stamped_class(stats.count).is_some(),
                None => latentbki::wire::wire_count(stats.count).is_some(),
            };
        // Any tick (the key's first word).
        let time = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        if enc
            .evict(Evicted {
                key,
                obs: &stats,
                residency: i as u32,
                time,
            })
            .is_err()
        {
            enc.tick(&mut out, 700, core::iter::empty()).unwrap();
            continue;
        }
        if ok {
            sent.push((key, i as u32, stats.count, forgetting.map(|_| time)));
        }
    }
    while enc.queued() > 0 {
        enc.tick(&mut out, 700, core::iter::empty()).unwrap();
    }
    let mut dec = FrameDecoder::<256>::new();
    let mut got = Vec::new();
    let mut input = &out.0[..];
    loop {
        match dec.feed(input) {
            Feed::NeedMore => break,
            Feed::Error { error, .. } => panic!("clean stream refused: {error:?}"),
            Feed::Frame { body, rest } => {
                match parse_body(body).unwrap() {
                    (_, Message::Voxels(b)) => {
                        for s in b.iter::<D>(codec) {
                            let s = s.unwrap();
                            got.push((s.key, s.residency, s.obs.count, s.time));
                        }
                    }
                    (_, Message::Session(c)) => assert_eq!(c, config, "the half-life arrives"),
                    _ => {}
                }
                input = rest;
            }
        }
    }
    assert_eq!(got.len(), sent.len());
    for (a, b) in got.iter().zip(&sent) {
        assert_eq!(
            (a.0, a.1, a.2.to_bits(), a.3),
            (b.0, b.1, b.2.to_bits(), b.3)
        );
    }
});
