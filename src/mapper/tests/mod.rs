//! Mapper: queue back-pressure, a failing link, a refused setup, its RAM constant, the window; the link
//! as a firmware runs it (`link`) and forgetting over it (`forget`).

use super::*;
use crate::config::{ConfigError, MapConfig};
use crate::frame::EncoderSettings;
use crate::frame::{Feed, FrameDecoder};
use crate::quant::packed_len;
use crate::wire::{parse_body, Message};
use crate::wire::{SummaryCodec, WireError};
use nalgebra::{Translation3, UnitQuaternion};

extern crate std;
use std::boxed::Box;
use std::vec::Vec;

const D: usize = 8;
/// A small queue (6 evicted voxels) so that draining needs several rounds of flush and send.
type Small = Mapper<D, 256, { packed_len(D) }, 160, 256>;

/// A link that collects bytes, or fails every write while `broken`.
struct Link {
    bytes: Vec<u8>,
    broken: bool,
}
impl embedded_io::ErrorType for Link {
    type Error = embedded_io::ErrorKind;
}
impl embedded_io::Write for Link {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        if self.broken {
            return Err(embedded_io::ErrorKind::BrokenPipe);
        }
        self.bytes.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

fn setup() -> Setup {
    Setup::new(MapConfig::DEFAULT, 1.0, EncoderSettings::new(2, 3))
}

/// 100 points on a 1 m strip beside `x` (within the 1 m window).
fn frame(mapper: &mut Small, x: f32) -> usize {
    let pose = Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity());
    let points: Vec<[f32; 3]> = (0..100)
        .map(|i| [0.01 * i as f32 - 0.5, 0.3, 0.02])
        .collect();
    let features: Vec<[f32; D]> = (0..100).map(|i| [i as f32 * 0.01; D]).collect();
    mapper.integrate(&pose, &points, &features)
}

/// (summaries, Σ point counts) in a byte stream.
fn decode(bytes: &[u8]) -> (usize, f32) {
    let mut decoder = FrameDecoder::<512>::default();
    let (mut summaries, mut points) = (0, 0.0);
    let mut rest = bytes;
    loop {
        match decoder.feed(rest) {
            Feed::NeedMore => break,
            Feed::Error { error, .. } => panic!("frame error {error:?}"),
            Feed::Frame { body, rest: r } => {
                if let Ok((_, Message::Voxels(batch))) = parse_body(body) {
                    for s in batch.iter::<D>(setup().codec) {
                        summaries += 1;
                        points += s.unwrap().obs.count;
                    }
                }
                rest = r;
            }
        }
    }
    (summaries, points)
}

#[test]
fn every_point_reaches_the_link_through_a_small_queue() {
    let mut mapper = Box::new(Small::EMPTY);
    mapper.configure(&setup()).unwrap();
    let mut link = Link {
        bytes: Vec::new(),
        broken: false,
    };
    let mut taken = 0;
    for f in 0..10 {
        taken += frame(&mut mapper, f as f32 * 0.5);
        mapper.tick(&mut link, 300).unwrap();
    }
    assert_eq!(taken, 1000);
    let held = mapper.map().len();
    assert!(held > 6, "more voxels than the queue holds: {held}");
    mapper.drain(&mut link).unwrap();
    assert!(mapper.map().is_empty());
    assert_eq!(mapper.encoder().queued(), 0);
    let (summaries, points) = decode(&link.bytes);
    assert_eq!(summaries as u32, mapper.map().counters().evicted);
    assert_eq!(points, 1000.0, "every point arrives exactly once");
}

#[test]
fn a_failing_link_loses_nothing() {
    let mut mapper = Box::new(Small::EMPTY);
    mapper.configure(&setup()).unwrap();
    let mut link = Link {
        bytes: Vec::new(),
        broken: true,
    };
    for f in 0..4 {
        frame(&mut mapper, f as f32 * 0.5);
        assert!(mapper.tick(&mut link, 300).is_err());
    }
    assert!(matches!(mapper.drain(&mut link), Err(DrainError::Write(_))));
    link.broken = false;
    mapper.drain(&mut link).unwrap();
    // Frames written while the link was broken are lost on the wire (the receiver counts them by
    // sequence number); every voxel the encoder did not get to write arrives.
    let (_, points) = decode(&link.bytes);
    assert!(points > 0.0 && points <= 400.0, "{points}");
    assert!(mapper.map().is_empty());
}

#[test]
fn a_refused_setup_sends_nothing() {
    let mut mapper = Box::new(Small::EMPTY);
    mapper.configure(&setup()).unwrap();
    let bad = Setup {
        window_radius: 0.0,
        ..setup()
    };
    assert_eq!(
        mapper.configure(&bad),
        Err(SetupError::Map(ConfigError::Window))
    );
    let mut link = Link {
        bytes: Vec::new(),
        broken: false,
    };
    frame(&mut mapper, 0.0);
    assert_eq!(mapper.tick(&mut link, 1000).unwrap().bytes, 0);
    assert_eq!(mapper.drain(&mut link), Err(DrainError::Stuck));
    assert!(link.bytes.is_empty());
    let no_codec = Setup {
        codec: SummaryCodec {
            mean_bits: 1,
            psi_blocks: 8,
            mean_bits_growth: 0,
            lead: 0,
            ..SummaryCodec::DEFAULT
        },
        ..setup()
    };
    assert_eq!(
        mapper.configure(&no_codec),
        Err(SetupError::Link(WireError::BadConfig))
    );
}

#[test]
fn ram_bytes_is_the_size_of_the_mapper() {
    use core::mem::size_of;
    assert_eq!(Small::RAM_BYTES, size_of::<Small>());
    type Big = Mapper<64, 1228, { packed_len(64) }, 4096, 512>;
    assert_eq!(Big::RAM_BYTES, size_of::<Big>());
    type Lidar = Mapper<64, 900, { packed_len(64) }, 2048, 256, 96>;
    assert_eq!(Lidar::RAM_BYTES, size_of::<Lidar>());
    type Odd = Mapper<13, 77, { packed_len(13) }, 333, 129, 5>;
    assert_eq!(Odd::RAM_BYTES, size_of::<Odd>());
    // One more hot entry costs its bytes (to the alignment: a 540-byte entry ends half-way through a
    // host's 8-byte word, where the compiler may pack a small field).
    type More = Mapper<64, 1228, { packed_len(64) }, 4096, 512, 33>;
    assert_eq!(More::RAM_BYTES, size_of::<More>());
    let one_more = Big::RAM_BYTES + LocalMap::<64, 1228, { packed_len(64) }>::BYTES_PER_HOT_VOXEL;
    assert!(More::RAM_BYTES.abs_diff(one_more) < core::mem::align_of::<Big>());
}

#[test]
fn the_queue_capacity_is_in_summaries() {
    let mut mapper = Box::new(Small::EMPTY);
    assert_eq!(mapper.queue_capacity(), 0);
    mapper.configure(&setup()).unwrap();
    let n = mapper.queue_capacity();
    assert!(n > 0);
    // Filling the map beyond the queue: exactly `n` evictions are queued before the queue refuses.
    for x in 0..40 {
        frame(&mut mapper, x as f32 * 3.0);
        if mapper.encoder().queued() == n {
            break;
        }
    }
    assert_eq!(mapper.encoder().queued(), n);
    assert!(mapper.encoder().stats().refused > 0);
}

#[test]
fn the_window_covers_the_sensor_range() {
    const W: f32 = MapConfig::DEFAULT.window_for_range(4.0);
    static S: Setup = Setup::new(
        MapConfig::DEFAULT,
        MapConfig::DEFAULT.window_for_range(4.0),
        EncoderSettings::new(1, 1),
    );
    assert!((W - 4.3).abs() < 1e-6);
    let mut mapper = Box::new(Small::EMPTY);
    mapper.configure(&S).unwrap();
    // Returns at the full range in every direction, from a sensor anywhere in its voxel: all taken.
    let mut frame = mapper.begin_frame(&Isometry3::from_parts(
        Translation3::new(0.099, -0.001, 0.05),
        UnitQuaternion::identity(),
    ));
    for i in 0..64 {
        let a = i as f32 * core::f32::consts::TAU / 64.0;
        let p = [4.0 * libm::cosf(a), 4.0 * libm::sinf(a), 0.0];
        assert_eq!(frame.add_point(p, &[0.5; D]), Ok(()), "{p:?}");
    }
}

mod link;

#[cfg(feature = "forgetting")]
mod forget;
