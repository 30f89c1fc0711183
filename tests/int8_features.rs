//! int8 features: the map built from codes c of scale s equals the map built from the f32 features s · c,
//! to f32 rounding — in the robot's map, in what it evicts, and in what a base station decodes from the
//! wire; the scale travels in the session header; bad codes and bad scales are counted, never stored.

use latentbki::frame::{Feed, FrameDecoder};
use latentbki::nalgebra::{Isometry3, Translation3};
use latentbki::wire::{parse_body, Message, Summary};
use latentbki::{
    batch::Rejection, key::VoxelKey, local_map::LocalMap, obs::ObsStats, packed_len,
    quant::Cooling, sink::Evicted, sink::SinkFull, wire::SessionConfig, EncoderSettings, MapConfig,
    Mapper, Setup,
};

const D: usize = 16;
const P: usize = packed_len(D);
const SCALE: f32 = 0.0123;

/// Deterministic points in a few voxels (at most 24: all stay hot until flushed) with codes spread over
/// the whole range, a constant offset per dimension (features far from zero relative to their spread).
fn points(n: usize, voxels: u32) -> (Vec<[f32; 3]>, Vec<[i8; D]>) {
    let mut s = 0x1234_5678u32;
    let mut r = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        s
    };
    let mut pts = Vec::new();
    let mut codes = Vec::new();
    for i in 0..n {
        let v = (r() % voxels) as f32;
        pts.push([0.05 + 0.1 * v, 0.05 + 0.01 * (i % 5) as f32, 0.05]);
        codes.push(core::array::from_fn(|d| {
            let spread = (r() % 61) as i32 - 30;
            (spread + 3 * d as i32 - 20).clamp(-127, 127) as i8
        }));
    }
    (pts, codes)
}

#[derive(Default)]
struct Collect(Vec<(VoxelKey, ObsStats<D>)>);
impl latentbki::sink::EvictionSink<D> for Collect {
    fn evict(&mut self, v: Evicted<'_, D>) -> Result<(), SinkFull> {
        self.0.push((v.key, *v.obs));
        Ok(())
    }
}

fn assert_close(a: &ObsStats<D>, b: &ObsStats<D>, what: &str) {
    assert_eq!(a.count, b.count, "{what}: count");
    // f32 rounding: Welford's running mean and the integer sums round differently, each by a few ulps of
    // the largest value involved.
    let m_tol = 127.0 * SCALE * 1e-5;
    for d in 0..D {
        assert!(
            (a.mean[d] - b.mean[d]).abs() <= m_tol,
            "{what}: mean[{d}] {} vs {}",
            a.mean[d],
            b.mean[d]
        );
        let s_tol = 1e-4 * a.scatter[d].abs().max(b.scatter[d].abs()) + 1e-9;
        assert!(
            (a.scatter[d] - b.scatter[d]).abs() <= s_tol,
            "{what}: scatter[{d}] {} vs {}",
            a.scatter[d],
            b.scatter[d]
        );
    }
}

#[test]
fn int8_map_equals_the_dequantized_f32_map() {
    let (pts, codes) = points(3000, 24);
    let feats: Vec<[f32; D]> = codes
        .iter()
        .map(|c| c.map(|v| f32::from(v) * SCALE))
        .collect();
    let mut a = Box::new(LocalMap::<D, 64, P>::EMPTY);
    let mut b = Box::new(LocalMap::<D, 64, P>::EMPTY);
    a.configure(MapConfig::default(), 3.0).unwrap();
    b.configure(MapConfig::default(), 3.0).unwrap();
    a.set_int8_scale(SCALE).unwrap();
    let (mut sa, mut sb) = (Collect::default(), Collect::default());
    let pose = Isometry3::identity();
    assert_eq!(a.add_points_i8(&pose, &pts, &codes, &mut sa), 3000);
    assert_eq!(b.add_points(&pose, &pts, &feats, &mut sb), 3000);
    // While observed (hot): the same statistics, and the same posteriors.
    for (key, obs) in a.iter().map(|v| (v.key, v.obs)) {
        assert_close(&obs, &b.get(key).unwrap(), "held");
        let (pa, pb) = (a.posterior(key), b.posterior(key));
        for d in 0..D {
            assert!((pa.mean[d] - pb.mean[d]).abs() <= 1e-5);
        }
    }
    a.flush(&mut sa).unwrap();
    b.flush(&mut sb).unwrap();
    assert_eq!(sa.0.len(), 24);
    for ((ka, oa), (kb, ob)) in sa.0.iter().zip(&sb.0) {
        assert_eq!(ka, kb);
        assert_close(oa, ob, "evicted");
    }
}

type Robot = Mapper<D, 256, P, 4096, 512>;

fn setup(int8: bool) -> Setup {
    let s = Setup::new(MapConfig::default(), 3.0, EncoderSettings::new(3, 9));
    if int8 {
        s.with_int8_features(SCALE)
    } else {
        s
    }
}

/// What a base station decodes from a byte stream: the session header, then every summary.
fn receive(bytes: &[u8]) -> (Option<SessionConfig>, Vec<Summary<D>>) {
    let mut decoder = FrameDecoder::<512>::default();
    let (mut session, mut out) = (None, Vec::new());
    let mut rest = bytes;
    loop {
        match decoder.feed(rest) {
            Feed::NeedMore => break,
            Feed::Error { error, .. } => panic!("frame error {error:?}"),
            Feed::Frame { body, rest: r } => {
                match parse_body(body) {
                    Ok((_, Message::Session(c))) => session = Some(c),
                    Ok((_, Message::Voxels(batch))) => {
                        out.extend(batch.iter::<D>(setup(false).codec).map(|s| s.unwrap()))
                    }
                    _ => {}
                }
                rest = r;
            }
        }
    }
    (session, out)
}

#[test]
fn the_base_station_decodes_the_same_map_and_the_scale() {
    let (pts, codes) = points(2000, 20);
    let feats: Vec<[f32; D]> = codes
        .iter()
        .map(|c| c.map(|v| f32::from(v) * SCALE))
        .collect();
    let pose = Isometry3::from_parts(Translation3::new(0.5, 0.0, 0.0), Default::default());
    let run = |int8: bool| {
        let mut robot = Box::new(Robot::EMPTY);
        robot.configure(&setup(int8)).unwrap();
        let taken = if int8 {
            robot.integrate_i8(&pose, &pts, &codes)
        } else {
            robot.integrate(&pose, &pts, &feats)
        };
        assert_eq!(taken, pts.len());
        let mut buf = vec![0u8; 1 << 16];
        let mut out: &mut [u8] = &mut buf;
        robot.drain(&mut out).unwrap();
        let sent = (1 << 16) - out.len();
        receive(&buf[..sent])
    };
    let (sa, a) = run(true);
    let (sb, b) = run(false);
    assert_eq!(sa.unwrap().int8_scale, SCALE, "the scale is in the header");
    assert_eq!(sb.unwrap().int8_scale, 0.0);
    assert_eq!(a.len(), 20);
    assert_eq!(a.len(), b.len());
    // The wire codes are a deterministic function of the statistics: equal inputs to f32 rounding give
    // the same codes but where a value sits on a rounding boundary, one code step apart.
    let mut differing = 0;
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(
            (x.key, x.residency, x.obs.count),
            (y.key, y.residency, y.obs.count)
        );
        if x.obs != y.obs {
            differing += 1;
        }
    }
    assert!(
        differing <= 1,
        "{differing} of {} summaries differ",
        a.len()
    );
}

#[test]
fn bad_codes_and_scales_are_counted_never_stored() {
    let mut map = Box::new(LocalMap::<D, 64, P>::EMPTY);
    map.configure(MapConfig::default(), 3.0).unwrap();
    let mut sink = Collect::default();
    let ok = [5i8; D];
    let p = [0.05, 0.05, 0.05];
    // No scale yet.
    assert_eq!(
        map.add_point_i8(p, &ok, &mut sink),
        Err(Rejection::FeatureScale)
    );
    for bad in [f32::NAN, 0.0, -1.0, f32::INFINITY, 1e6] {
        assert!(map.set_int8_scale(bad).is_err(), "{bad}");
        assert_eq!(
            map.add_point_i8(p, &ok, &mut sink),
            Err(Rejection::FeatureScale)
        );
    }
    map.set_int8_scale(0.5).unwrap();
    let mut bad = ok;
    bad[3] = i8::MIN;
    assert_eq!(
        map.add_point_i8(p, &bad, &mut sink),
        Err(Rejection::CodeOutOfRange)
    );
    assert_eq!(map.add_point_i8(p, &ok, &mut sink), Ok(()));
    let r = map.rejections();
    assert_eq!((r.feature_scale, r.code_out_of_range, r.total()), (6, 1, 7));
    assert_eq!(map.counters().points, 1);
    assert_eq!(map.len(), 1);
    assert_eq!(map.get(map.iter().next().unwrap().key).unwrap().count, 1.0);
    // A mapper refuses a bad scale in its setup.
    let mut robot = Box::new(Robot::EMPTY);
    assert!(robot
        .configure(&setup(false).with_int8_features(f32::NAN))
        .is_err());
    // f32 and int8 points mix in one voxel: the same statistics as all in f32.
    map.add_point([0.05, 0.05, 0.05], &[2.5; D], &mut sink)
        .unwrap();
    map.add_point_i8(p, &[5; D], &mut sink).unwrap();
    let got = map.get(VoxelKey::new(0, 0, 0)).unwrap();
    assert_eq!(got.count, 3.0);
    assert!((got.mean[0] - 2.5).abs() < 1e-6 && got.scatter[0].abs() < 1e-5);
}

#[test]
fn a_long_visit_merges_its_sums_every_255_points_and_counts_each_point_once() {
    let (_, codes) = points(1000, 1);
    // A hosted build links both cooling methods (a bare-metal one only its target's) and cools in f32
    // unless told otherwise; each method keeps the statistics within a code step of the exact ones.
    assert_eq!(Cooling::NATIVE, Cooling::Float);
    let mut held = Vec::new();
    for cooling in [Cooling::Float, Cooling::Fixed] {
        let mut map = Box::new(LocalMap::<D, 64, P>::EMPTY);
        map.configure(MapConfig::default(), 3.0).unwrap();
        assert_eq!(map.cooling(), Cooling::NATIVE);
        map.set_cooling(cooling).unwrap();
        map.set_int8_scale(SCALE).unwrap();
        let mut sink = Collect::default();
        for c in &codes {
            map.add_point_i8([0.05, 0.05, 0.05], c, &mut sink).unwrap();
        }
        assert_eq!(
            map.counters().cooled,
            3,
            "{cooling:?}: merged at 255, 510 and 765 points"
        );
        let got = map.get(VoxelKey::new(0, 0, 0)).unwrap();
        assert_eq!(got.count, 1000.0);
        // Against the exact mean and scatter (f64): within one step of the stored 7-bit mean codes (scale
        // max |μ| · 1.25 / 63) and of the scatter's minifloat codes (≤ 2^−PSI_STEPS_LOG2 of the value).
        let max_mean = (0..D)
            .map(|d| (got.mean[d] as f64).abs())
            .fold(0.0, f64::max);
        let step = max_mean * 1.25 / 63.0 * 1.05;
        let psi_step = 1.0 / f64::from(1u32 << latentbki::quant::PSI_STEPS_LOG2);
        for d in 0..D {
            let ys: Vec<f64> = codes
                .iter()
                .map(|c| f64::from(c[d]) * f64::from(SCALE))
                .collect();
            let m = ys.iter().sum::<f64>() / 1000.0;
            let s: f64 = ys.iter().map(|y| (y - m) * (y - m)).sum();
            assert!(
                (f64::from(got.mean[d]) - m).abs() <= step,
                "{cooling:?}: mean[{d}]"
            );
            assert!(
                (f64::from(got.scatter[d]) / s - 1.0).abs() < psi_step,
                "{cooling:?}: scatter[{d}]"
            );
        }
        held.push(got);
    }
    // The last cooling's sums differ by less than a code step here: the same codes.
    assert_eq!(held[0].count, held[1].count);
}

#[test]
fn the_cooling_method_is_the_one_chosen() {
    // 24 voxels through 4 hot entries: hundreds of coolings of int8 sums into earlier codes.
    let (pts, codes) = points(3000, 24);
    let pose = Isometry3::identity();
    let evicted = |cooling| {
        let mut map = Box::new(LocalMap::<D, 64, P, 4>::EMPTY);
        map.configure(MapConfig::default(), 3.0).unwrap();
        map.set_cooling(cooling).unwrap();
        map.set_int8_scale(SCALE).unwrap();
        let mut sink = Collect::default();
        assert_eq!(map.add_points_i8(&pose, &pts, &codes, &mut sink), 3000);
        assert!(map.counters().cooled > 500, "{}", map.counters().cooled);
        map.flush(&mut sink).unwrap();
        sink.0
    };
    let (float, fixed) = (evicted(Cooling::Float), evicted(Cooling::Fixed));
    assert_eq!(float.len(), 24);
    // The same voxels and counts; the codes round differently (the fixed-point merge matches the f32 one
    // to the rounding of the last code step), so some voxel's statistics differ.
    for ((ka, a), (kb, b)) in float.iter().zip(&fixed) {
        assert_eq!((ka, a.count), (kb, b.count));
    }
    assert!(float
        .iter()
        .zip(&fixed)
        .any(|((_, a), (_, b))| (a.mean, a.scatter) != (b.mean, b.scatter)));
}

#[test]
fn integer_millimetre_points_reach_the_same_voxels() {
    let (pts, codes) = points(2000, 20);
    let pose = Isometry3::from_parts(
        Translation3::new(0.5, -0.2, 0.1),
        latentbki::nalgebra::UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
    );
    // The points as a sensor in millimetres reports them (0.05 m from the faces: away from rounding).
    let pts_mm: Vec<[i32; 3]> = pts
        .iter()
        .map(|p| p.map(|v| (v * 1000.0).round() as i32))
        .collect();
    let run = |mm: bool| {
        let mut robot = Box::new(Robot::EMPTY);
        robot.configure(&setup(true)).unwrap();
        let mut frame = robot.begin_frame(&pose);
        let taken = if mm {
            frame.add_points_mm_i8(&pts_mm, &codes)
        } else {
            frame.add_points_i8(&pts, &codes)
        };
        assert_eq!(taken, pts.len());
        let mut voxels: Vec<_> = robot.map().iter().map(|v| (v.key, v.obs)).collect();
        voxels.sort_by_key(|v| v.0);
        voxels
    };
    let (a, b) = (run(true), run(false));
    assert_eq!(a.len(), b.len());
    let same = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| x.0 == y.0 && x.1.count == y.1.count)
        .count();
    assert!(same * 100 >= a.len() * 95, "{same} of {} voxels", a.len());
    // Refusals are counted: a coordinate beyond ±32.7 m, a pose fixed point cannot hold, unpaired.
    let mut robot = Box::new(Robot::EMPTY);
    robot.configure(&setup(true)).unwrap();
    let mut frame = robot.begin_frame(&pose);
    assert_eq!(
        frame.add_point_mm_i8([40_000, 0, 0], &codes[0]),
        Err(Rejection::KeyOutOfRange)
    );
    assert_eq!(frame.add_points_mm_i8(&pts_mm[..3], &codes[..2]), 2);
    let far = Isometry3::translation(1e7, 0.0, 0.0);
    let mut frame = robot.begin_frame(&far);
    assert_eq!(
        frame.add_point_mm_i8([0, 0, 0], &codes[0]),
        Err(Rejection::NonFinitePosition)
    );
    let r = robot.map().rejections();
    assert_eq!(
        (r.key_out_of_range, r.unpaired, r.non_finite_position),
        (1, 1, 1)
    );
}

#[test]
fn the_code_check_finds_minus_128_at_every_position_and_nothing_else() {
    use latentbki::obs::code_in_range;
    // Every byte value at every position of a 4-code word and of the tail (D = 7: one word and three).
    for pos in 0..7 {
        for v in i8::MIN..=i8::MAX {
            let mut codes = [-127i8, 127, 0, 1, -1, 64, -64];
            codes[pos] = v;
            assert_eq!(code_in_range(&codes), v != i8::MIN, "code {v} at {pos}");
        }
    }
    // Neighbouring bytes cannot mask or fake one (0x7F and 0x80 next to each other, all 0x80).
    assert!(!code_in_range(&[127i8, -128, 127, 127]));
    assert!(!code_in_range(&[i8::MIN; 8]));
    assert!(code_in_range(&[-127i8, 127, -127, 127, -1, 0, 1, -127]));
}
