use super::*;
use latentbki::config::MapConfig;
use latentbki::frame::EncoderSettings;
use latentbki::key::to_map_frame;
use latentbki::mapper::{Mapper, Setup};
use latentbki::quant::packed_len;

#[test]
fn normal_has_unit_moments() {
    let n = 100_000u32;
    let (mut s, mut s2) = (0.0f64, 0.0f64);
    for i in 0..n {
        let v = f64::from(normal(hash(7, i)));
        s += v;
        s2 += v * v;
    }
    let mean = s / f64::from(n);
    let var = s2 / f64::from(n) - mean * mean;
    assert!(mean.abs() < 0.01, "mean {mean}");
    assert!((var - 1.0).abs() < 0.02, "variance {var}");
}

#[test]
fn codebook_is_unit_and_well_separated() {
    let cb = CategoryVectors::<64>::VECTORS;
    for (a, va) in cb.iter().enumerate() {
        let n: f32 = va.iter().map(|v| v * v).sum();
        assert!((n - 1.0).abs() < 1e-5, "norm² {n}");
        for vb in &cb[a + 1..] {
            let cos: f32 = va.iter().zip(vb).map(|(x, y)| x * y).sum();
            assert!(cos.abs() < 0.5, "cosine {cos}");
        }
        assert_eq!(CategoryVectors::<64>::classify(va), Some(a as u8));
    }
}

#[test]
fn rays_are_unit_and_span_the_field_of_view() {
    let s = DepthSensor::TOF_8X8;
    for z in 0..s.zones() {
        let r = s.ray(z);
        let n = libm::sqrtf(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
        assert!((n - 1.0).abs() < 1e-6);
        assert!(r[2] > 0.8);
    }
    // Zone 0 is top-left (x < 0, y < 0); the last is bottom-right.
    let (a, b) = (s.ray(0), s.ray(63));
    assert!(a[0] < 0.0 && a[1] < 0.0 && b[0] > 0.0 && b[1] > 0.0);
    assert!((a[0] + b[0]).abs() < 1e-7);
}

#[test]
fn cast_finds_floor_walls_and_furniture() {
    let r = Room::DEFAULT;
    assert_eq!(r.cast([2.0, 1.5, 1.0], [0.0, 0.0, -1.0]), (1.0, FLOOR));
    assert_eq!(r.cast([2.0, 1.5, 1.0], [0.0, 0.0, 1.0]), (1.5, CEILING));
    assert_eq!(r.cast([2.0, 2.5, 1.0], [-1.0, 0.0, 0.0]), (2.0, WALL));
    // Straight down onto the table top at 0.75 m.
    let (t, c) = r.cast([1.4, 0.8, 1.0], [0.0, 0.0, -1.0]);
    assert_eq!(c, 3);
    assert!((t - 0.25).abs() < 1e-6);
    // Towards +x at cabinet height: the cabinet front at x = 3.4.
    let (t, c) = r.cast([2.0, 0.7, 1.0], [1.0, 0.0, 0.0]);
    assert_eq!(c, 4);
    assert!((t - 1.4).abs() < 1e-6);
}

#[test]
fn observed_points_lie_on_the_surfaces() {
    let scene = Scene::new(DepthSensor::TOF_8X8, 3);
    let mut f = [0.0f32; 64];
    let mut seen = [0u32; CATEGORIES];
    for frame in 0..scene.frames_per_turn {
        let view = scene.view(frame);
        let pose = view.pose();
        for zone in 0..scene.sensor.zones() {
            let o = scene
                .observe(&view, frame, zone, &mut f)
                .expect("closed room: always a return");
            seen[usize::from(o.category)] += 1;
            // Back in the map frame, the point is on its surface to within the range noise (5σ).
            let p = to_map_frame(&pose, o.point);
            let d = match o.category {
                FLOOR => p[2].abs(),
                CEILING => (p[2] - 2.5).abs(),
                WALL => [p[0], 4.0 - p[0], p[1], 3.0 - p[1]]
                    .iter()
                    .fold(9.0f32, |m, v| m.min(v.abs())),
                _ => {
                    let b = scene
                        .room
                        .blocks
                        .iter()
                        .find(|b| b.category == o.category)
                        .unwrap();
                    (0..3)
                        .map(|i| (p[i] - b.lo[i]).abs().min((p[i] - b.hi[i]).abs()))
                        .fold(9.0f32, f32::min)
                }
            };
            assert!(
                d < 5.0 * scene.sensor.range_noise,
                "frame {frame} zone {zone}: {d} m off its {} surface",
                o.category
            );
            assert_eq!(CategoryVectors::<64>::classify(&f), Some(o.category));
        }
    }
    assert!(
        seen.iter().all(|&n| n > 0),
        "every category is seen: {seen:?}"
    );
}

#[test]
fn lidar_drives_through_the_room_and_down_the_corridor() {
    let sc = SELF_TEST.iter().find(|s| s.name == "lidar_f3").unwrap();
    let scene = sc.scene;
    let mut f = [0.0f32; 64];
    let (first, last) = (scene.view(0), scene.view(sc.frames - 1));
    assert!(
        first.origin[0] < 1.5 && last.origin[0] > 9.0,
        "{first:?} {last:?}"
    );
    for frame in [0, sc.frames / 2, sc.frames - 1] {
        let view = scene.view(frame);
        let pose = view.pose();
        let mut returns = 0;
        for zone in 0..scene.sensor.zones() {
            // Beams down the corridor's length may reach beyond the 8 m range.
            let Some(o) = scene.observe(&view, frame, zone, &mut f) else {
                continue;
            };
            returns += 1;
            let p = to_map_frame(&pose, o.point);
            assert!((p[2] - 0.3).abs() < 1e-4, "a level scan: {p:?}");
            assert_eq!(CategoryVectors::<64>::classify(&f), Some(o.category));
        }
        assert!(returns > 340, "frame {frame}: {returns} returns");
    }
    // In the corridor, the nearest wall is the corridor's (1.4 m wide).
    let view = scene.view(sc.frames - 10);
    let left = scene.room.cast(view.origin, [0.0, 1.0, 0.0]).0;
    let right = scene.room.cast(view.origin, [0.0, -1.0, 0.0]).0;
    assert!((left + right - 1.4).abs() < 1e-5);
}

#[test]
fn quantize_rounds_and_clamps() {
    let mut c = [0i8; 4];
    quantize(&[0.0124, -0.0126, 1.0, -1.0], 0.005, &mut c);
    assert_eq!(c, [2, -3, 127, -127]);
}

/// Collects the link's bytes.
struct Bytes(Vec<u8>);
impl embedded_io::ErrorType for Bytes {
    type Error = core::convert::Infallible;
}
impl embedded_io::Write for Bytes {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[test]
fn generation_is_deterministic_and_chunking_does_not_matter() {
    const P: usize = packed_len(16);
    type Small = Mapper<16, 600, P, 4096, 512>;
    let scene = Scene::new(DepthSensor::TOF_8X8, 9);
    let run = |chunk_points: usize| {
        let mut mapper = Box::new(Small::EMPTY);
        let setup = Setup::new(MapConfig::default(), 1.5, EncoderSettings::new(1, 1));
        mapper.configure(&setup).unwrap();
        let mut out = Bytes(Vec::new());
        let mut reports = Vec::new();
        for frame in 0..20 {
            reports.push(if chunk_points == 5 {
                let mut c = Box::new(Chunk5::ZERO);
                integrate_frame(&scene, frame, 0.0, &mut mapper, &mut c, &mut ())
            } else {
                let mut c = Box::new(Chunk64::ZERO);
                integrate_frame(&scene, frame, 0.0, &mut mapper, &mut c, &mut ())
            });
            mapper.tick(&mut out, 2048).unwrap();
        }
        let evicted = mapper.map().counters().evicted;
        mapper.drain(&mut out).unwrap();
        (out.0, reports, evicted)
    };
    let (a, ra, evicted) = run(5);
    let (b, rb, _) = run(64);
    assert_eq!(ra, rb);
    assert!(ra.iter().all(|r| r.points == 64), "{ra:?}");
    assert!(ra.iter().map(|r| r.integrated).sum::<u32>() > 600, "{ra:?}");
    assert!(evicted > 100, "the window and the pool evict: {evicted}");
    assert!(a.len() > 4000, "frames were sent: {} B", a.len());
    assert_eq!(a, b, "the same bytes on the link");
}

extern crate std;
type Chunk5 = Chunk<16, 5>;
type Chunk64 = Chunk<16, 64>;
use std::boxed::Box;
use std::vec::Vec;

/// The self-test's 8×8 ToF looks where the library's zone table (`latentbki::tof::VL53L5CX_8X8`, what a
/// firmware uses) says a VL53L5CX's zones look.
#[test]
fn the_tof_zones_are_the_library_table() {
    let table = latentbki::tof::VL53L5CX_8X8;
    let sensor = DepthSensor::TOF_8X8;
    assert_eq!(sensor.zones() as usize, table.rays_q14.len());
    for z in 0..sensor.zones() {
        let (a, b) = (sensor.ray(z), table.ray(z as usize).unwrap());
        for i in 0..3 {
            assert!((a[i] - b[i]).abs() < 1e-4, "zone {z}: {a:?} vs {b:?}");
        }
    }
}

/// `BOARD_FEATURES` names exactly the `latentbki` features this crate's `full` feature (the boards' build)
/// enables.
#[test]
fn board_features_are_what_full_enables() {
    let manifest = include_str!("../Cargo.toml");
    let line = manifest
        .lines()
        .find(|l| l.starts_with("full = "))
        .expect("a `full` feature");
    let enabled: Vec<&str> = line
        .split('"')
        .filter_map(|s| s.strip_prefix("latentbki/"))
        .collect();
    assert!(!enabled.is_empty(), "{line}");
    #[cfg(feature = "full")]
    assert_eq!(enabled, BOARD_FEATURES);
    #[cfg(not(feature = "full"))]
    assert!(BOARD_FEATURES.is_empty());
}

/// The maps' mean weights are those of the scene's feature space: every component of the features spreads
/// alike, so `MeanWeights::from_spreads` gives all ones on the finer grid.
#[test]
fn mean_weights_come_from_the_scenes_spreads() {
    const D: usize = 64;
    let scene = &TOF_ROOM;
    let (mut sum, mut sq, mut n) = ([0.0f64; D], [0.0f64; D], 0.0f64);
    let mut feature = [0.0f32; D];
    for frame in 0..48 {
        let view = scene.view(frame);
        for zone in 0..scene.sensor.zones() {
            if scene.observe(&view, frame, zone, &mut feature).is_some() {
                for i in 0..D {
                    sum[i] += f64::from(feature[i]);
                    sq[i] += f64::from(feature[i]).powi(2);
                }
                n += 1.0;
            }
        }
    }
    let spreads: [f32; D] =
        core::array::from_fn(|i| ((sq[i] / n - (sum[i] / n).powi(2)).sqrt()) as f32);
    let weights = latentbki::quant::MeanWeights::from_spreads(&spreads);
    assert_eq!(weights, latentbki::quant::MeanWeights::EQUAL, "{spreads:?}");
    #[cfg(feature = "full")]
    assert_eq!(SELF_TEST_MEAN_WEIGHTS, weights);
}
