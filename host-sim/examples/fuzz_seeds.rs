//! Writes the committed seed corpus of the fuzz targets (`host-sim/fuzz/seeds/<target>/`), so a short CI
//! run starts from inputs that reach deep: whole sessions (header, voxel frames with live and final
//! summaries, link statistics) rather than the few hundred bytes a fuzzer grows from nothing in 30 s.
//! Each seed is laid out as its target reads its input (see `host-sim/fuzz/fuzz_targets/`).
//! Run: `cargo run --release -p host-sim --example fuzz_seeds` (deterministic: same files every run).

use latentbki::frame::EncoderSettings;
use latentbki::wire::{SessionConfig, SummaryCodec};
use latentbki::{
    frame::FrameEncoder, key::VoxelKey, obs::ObsStats, sink::Evicted, sink::EvictionSink, MapConfig,
};
use std::path::Path;

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

/// A small deterministic generator (SplitMix64).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [-1, 1).
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 23) as f32 - 1.0
    }
}

/// Valid observation statistics: a whole count, finite means, non-negative scatter.
fn stats<const D: usize>(rng: &mut Rng) -> ObsStats<D> {
    let count = 1.0 + (rng.next() % 200) as f32;
    ObsStats {
        count,
        mean: core::array::from_fn(|_| rng.unit()),
        scatter: core::array::from_fn(|_| count * (0.01 + rng.unit().abs())),
    }
}

fn put_stats<const D: usize>(out: &mut Vec<u8>, s: &ObsStats<D>) {
    out.extend(s.count.to_le_bytes());
    for v in s.mean.iter().chain(&s.scatter) {
        out.extend(v.to_le_bytes());
    }
}

/// `base_station_db`: control byte, then `n` voxel records (key bytes, residency byte, n, m, S), then as
/// many bytes of bit flips (all zero: no damage, or a few real flips).
fn base_station_db(rng: &mut Rng, ctl: u8, n: usize, flips: usize) -> Vec<u8> {
    const D: usize = 8;
    let mut voxels = Vec::new();
    for i in 0..n {
        voxels.extend([
            (i % 4) as u8,
            (i / 4 % 4) as u8,
            (i / 16 % 2) as u8,
            (i % 8) as u8,
        ]);
        put_stats(&mut voxels, &stats::<D>(rng));
    }
    let mut damage = vec![0u8; voxels.len()];
    for f in damage.chunks_exact_mut(3).take(flips) {
        f.copy_from_slice(&[rng.next() as u8, rng.next() as u8, 1 << (rng.next() % 8)]);
    }
    let mut out = vec![ctl];
    out.extend(voxels);
    out.extend(damage);
    out
}

/// `roundtrip`: two codec bytes (bit 7 of the second: a session that forgets), then `n` records (three
/// i32 key words, n, m, S; a forgetting session's weights faded to fractions).
fn roundtrip(rng: &mut Rng, n: usize, forgets: bool) -> Vec<u8> {
    const D: usize = 8;
    let mut out = vec![6, 3 | if forgets { 0x80 } else { 0 }];
    for i in 0..n as i32 {
        for k in [i * 4, (i / 3) * 4 - 8, 12] {
            out.extend(k.to_le_bytes());
        }
        let mut s = stats::<D>(rng);
        if forgets {
            s.decay(0.37);
        }
        put_stats(&mut out, &s);
    }
    out
}

/// `map_integrate`: batches of a translation then 16 points (xyz, D = 4 features) along a street.
fn map_integrate(rng: &mut Rng, batches: usize) -> Vec<u8> {
    let mut out = Vec::new();
    for b in 0..batches {
        for t in [b as f32 * 0.5, 0.0, 0.0] {
            out.extend(t.to_le_bytes());
        }
        for _ in 0..16 {
            let p = [2.0 * rng.unit(), 2.0 * rng.unit(), 0.5 * rng.unit()];
            for v in p
                .iter()
                .chain(&[rng.unit(), rng.unit(), rng.unit(), rng.unit()])
            {
                out.extend(v.to_le_bytes());
            }
        }
    }
    out
}

/// `frame_decoder`: a chunk size, then a robot's whole session as it goes over the link (D = 64, the
/// decoder target parses every summary with each of its codecs).
fn frame_decoder(
    rng: &mut Rng,
    chunk: u8,
    n: usize,
    forgets: bool,
    codec: SummaryCodec,
) -> Vec<u8> {
    use host_sim::sim::vocab::D;
    let forgetting = forgets.then(|| latentbki::forget::Forgetting::new(40.0).unwrap());
    let config = SessionConfig::new(&MapConfig::default(), D, codec, 0).with_forgetting(forgetting);
    let mut enc = FrameEncoder::<D, 4096, 512>::new(config, EncoderSettings::new(4, 8)).unwrap();
    let mut out = Buf(Vec::new());
    let mut live = Vec::new();
    for i in 0..n {
        let key = VoxelKey::new(i as i32 % 7, i as i32 / 7, 1);
        let mut obs = stats::<D>(rng);
        // A forgetting session's voxels: faded weights, stamped with their tick.
        let time = if forgets { 1000 + 3 * i as u32 } else { 0 };
        if forgets {
            obs.decay(0.61);
        }
        if i % 3 == 0 {
            live.push((key, obs));
        } else if enc
            .evict(Evicted {
                key,
                obs: &obs,
                residency: i as u32,
                time,
            })
            .is_err()
        {
            enc.tick(&mut out, 600, core::iter::empty()).unwrap();
        }
        if i % 5 == 4 {
            let live_now = live.iter().map(|(key, obs)| Evicted {
                key: *key,
                obs,
                residency: 0,
                time,
            });
            enc.tick(&mut out, 600, live_now).unwrap();
        }
    }
    while enc.queued() > 0 {
        enc.tick(&mut out, 600, core::iter::empty()).unwrap();
    }
    enc.send_stats(&mut out).unwrap();
    let mut seed = vec![chunk];
    seed.extend(out.0);
    seed
}

/// `frame_decoder`, a session of stored codes (`SummaryCodec::STORED`): a local map's voxels — one-point
/// and many-point, some hot when flushed — evicted into the encoder as their codes (statistics have none
/// to copy), in frames of 600 bytes.
fn frame_decoder_stored(rng: &mut Rng, chunk: u8, n: usize) -> Vec<u8> {
    use host_sim::sim::vocab::D;
    use latentbki::local_map::LocalMap;
    use latentbki::quant::packed_len;
    let config = SessionConfig::new(&MapConfig::default(), D, SummaryCodec::STORED, 0);
    let mut enc = FrameEncoder::<D, 8192, 512>::new(config, EncoderSettings::new(4, 8)).unwrap();
    let mut map = Box::new(LocalMap::<D, 256, { packed_len(D) }, 8>::EMPTY);
    map.configure(MapConfig::default(), 100.0).unwrap();
    for i in 0..n {
        let y = stats::<D>(rng).mean;
        for r in 0..1 + i % 4 {
            let p = [i as f32 * 0.5 + r as f32 * 0.01, 0.2, 0.2];
            map.add_point(p, &y, &mut enc).unwrap();
        }
    }
    map.flush(&mut enc).unwrap();
    let mut out = Buf(Vec::new());
    while enc.queued() > 0 {
        enc.tick(&mut out, 600, core::iter::empty()).unwrap();
    }
    enc.send_stats(&mut out).unwrap();
    let mut seed = vec![chunk];
    seed.extend(out.0);
    seed
}

/// The robot's back channel: a chunk size, then acknowledgements of its session (robot 1, session 2, the
/// fuzz target's), one of another robot, one with a flipped byte, and line noise between them.
fn ack_reader(rng: &mut Rng, chunk: u8, n: u32) -> Vec<u8> {
    use latentbki::frame::Ack;
    let mut out = vec![chunk];
    let mut buf = [0u8; 64];
    for i in 0..n {
        let robot = if i % 5 == 3 { 9 } else { 1 };
        let ack = Ack {
            version: latentbki::wire::PROTOCOL_VERSION,
            robot,
            session: 2,
            highest: i,
            received: (rng.next() | 1) & ((1u64 << (i.min(63) + 1)) - 1),
        };
        let Some(len) = ack.encode(&mut buf) else {
            continue;
        };
        let start = out.len();
        out.extend_from_slice(&buf[..len]);
        if i % 7 == 6 {
            let at = start + 1 + (rng.next() as usize) % (len - 2);
            out[at] ^= 0x20;
        }
        if i % 4 == 2 {
            out.extend((0..3).map(|_| rng.next() as u8));
        }
    }
    out
}

/// The fuzz target's Rice-coded lead band: 8 components, psi in 2 blocks.
const RICE_LEAD: SummaryCodec = SummaryCodec {
    mean_bits: 3,
    psi_blocks: 2,
    mean_bits_growth: 3,
    lead: 8,
    lead_bits: 3,
    rice: true,
};

fn main() -> std::io::Result<()> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds");
    let mut rng = Rng(0x5EED);
    let seeds: Vec<(&str, &str, Vec<u8>)> = vec![
        (
            "base_station_db",
            "session-whole",
            base_station_db(&mut rng, 12, 40, 0),
        ),
        (
            "base_station_db",
            "session-bytewise",
            base_station_db(&mut rng, 0, 24, 0),
        ),
        (
            "base_station_db",
            "session-damaged",
            base_station_db(&mut rng, 40, 40, 6),
        ),
        ("roundtrip", "forty-voxels", roundtrip(&mut rng, 40, false)),
        ("map_integrate", "street", map_integrate(&mut rng, 12)),
        (
            "frame_decoder",
            "session-whole",
            frame_decoder(&mut rng, 255, 60, false, SummaryCodec::DEFAULT),
        ),
        (
            "frame_decoder",
            "session-chunked",
            frame_decoder(&mut rng, 7, 30, false, SummaryCodec::DEFAULT),
        ),
        ("ack_reader", "acks-whole", ack_reader(&mut rng, 255, 24)),
        ("ack_reader", "acks-bytewise", ack_reader(&mut rng, 1, 12)),
        // Forgetting (stamped summaries, the half-life in the header): last, so the seeds above keep
        // their bytes.
        (
            "roundtrip",
            "forty-voxels-forgetting",
            roundtrip(&mut rng, 40, true),
        ),
        (
            "frame_decoder",
            "session-forgetting",
            frame_decoder(&mut rng, 255, 40, true, SummaryCodec::DEFAULT),
        ),
        // A Rice session with a lead band (the demo's codec; the target's Rice lead-band codec), so the
        // rest step's predictor (protocol 5) is reached from the first input.
        (
            "frame_decoder",
            "session-rice-lead",
            frame_decoder(&mut rng, 255, 40, false, RICE_LEAD),
        ),
        // A session of stored codes (the boards' codec), whole and in chunks.
        (
            "frame_decoder",
            "session-stored",
            frame_decoder_stored(&mut rng, 255, 30),
        ),
        (
            "frame_decoder",
            "session-stored-chunked",
            frame_decoder_stored(&mut rng, 13, 12),
        ),
    ];
    for (target, name, bytes) in seeds {
        std::fs::create_dir_all(dir.join(target))?;
        let path = dir.join(target).join(name);
        std::fs::write(&path, &bytes)?;
        println!("{} ({} bytes)", path.display(), bytes.len());
    }
    Ok(())
}
