//! The base station with its SQLite database behind it: frames built from fuzz bytes (voxels of any value,
//! so also clamped and refused ones), then damaged by fuzz-chosen bit flips, arrive in fuzz-sized chunks;
//! the station commits after every chunk. Never a panic, and the database always holds exactly the
//! in-memory map and sessions: nothing is written from a refused frame and nothing accepted is missed.
#![no_main]

use latentbki::frame::EncoderSettings;
use latentbki::wire::{SessionConfig, SummaryCodec};
use latentbki::{
    frame::FrameEncoder, key::VoxelKey, obs::ObsStats, sink::Evicted, sink::EvictionSink, MapConfig,
};
use latentbki_station::store::SqliteStore;
use latentbki_station::BaseStation;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

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
    let Some((&ctl, data)) = data.split_first() else {
        return;
    };
    let (voxels, flips) = data.split_at(data.len() / 2);
    let codec = SummaryCodec {
        mean_bits: 3,
        psi_blocks: 4,
        mean_bits_growth: 2,
        lead: 2,
        lead_bits: 3,
        rice: ctl & 0x80 != 0,
    };
    let config = SessionConfig::new(&MapConfig::default(), D, codec, 0);
    let settings = EncoderSettings::new(1 + u16::from(ctl % 3), 7);
    let mut enc = FrameEncoder::<D, 2048, 256>::new(config, settings).unwrap();
    let mut out = Buf(Vec::new());
    let f = |c: &[u8]| f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
    let record = 4 + 4 * (1 + 2 * D);
    for (i, c) in voxels.chunks_exact(record).enumerate() {
        // Few distinct keys, so contributions meet in the same voxels.
        let key = VoxelKey::new(
            i32::from(c[0] % 4),
            i32::from(c[1] % 4),
            i32::from(c[2] % 2),
        );
        let residency = u32::from(c[3] % 8);
        let v = &c[4..];
        // Any bits for the count (mostly not a whole number in 1..=2^24: the encoder must drop those).
        let stats = ObsStats::<D> {
            count: f(v),
            mean: core::array::from_fn(|d| f(&v[4 + 4 * d..])),
            scatter: core::array::from_fn(|d| f(&v[4 + 4 * D + 4 * d..]).abs()),
        };
        if enc
            .evict(Evicted {
                key,
                obs: &stats,
                residency,
                time: 0,
            })
            .is_err()
            || i % 3 == 2
        {
            enc.tick(&mut out, 300, core::iter::empty()).unwrap();
        }
    }
    while enc.queued() > 0 {
        enc.tick(&mut out, 300, core::iter::empty()).unwrap();
    }
    let mut bytes = out.0;
    for p in flips.chunks_exact(3) {
        if !bytes.is_empty() {
            let at = usize::from(u16::from_le_bytes([p[0], p[1]])) % bytes.len();
            bytes[at] ^= p[2];
        }
    }
    let mut store = SqliteStore::open(Path::new(":memory:")).unwrap();
    let mut base = BaseStation::<D>::open(&mut store).unwrap();
    for c in bytes.chunks(1 + usize::from(ctl) * 5) {
        base.receive(c);
        base.commit(&mut store).unwrap();
    }
    let back = BaseStation::<D>::open(&mut store).unwrap();
    assert!(
        back.map() == base.map(),
        "the database differs from the map"
    );
    assert_eq!(back.sessions(), base.sessions());
    assert_eq!(store.integrity_check().unwrap(), "ok");
});
