//! Robot = base station, with forgetting: the robot's `Mapper` (the `Fading` clock, a half-life) maps the
//! changing house, one tick per frame, and streams over the link into the base station; the base station's
//! statistics, decayed by the same clock rule, gather to the posteriors the robot's own statistics give —
//! argmax equal on ≥ 99.9 % of the voxels, λ equal to f32 rounding.

use host_sim::changing::changed;
use host_sim::demo_radio::CODEC;
use host_sim::eval::experiment::{decoding, ExperimentSettings};
use host_sim::sim::indoor::{self, IndoorRun, IndoorScene};
use host_sim::sim::mix_all;
use host_sim::sim::sensor::DepthCamera;
use host_sim::sim::vocab::TextEmbeddings;
use host_sim::ObsMap;
use latentbki::forget::{Fading, Forgetting, Stamped};
use latentbki::key::VoxelKey;
use latentbki::sink::Evicted;
use latentbki::{packed_len, EncoderSettings, Mapper, Setup};
use latentbki_station::BaseStation;
use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::BTreeMap;

use host_sim::sim::vocab::D;
type Robot = Mapper<D, 4096, { packed_len(D) }, 32_768, 1024, 32, Fading>;

#[test]
fn decayed_statistics_at_the_base_station_equal_the_robots() {
    let (layout, seed) = (1, 7);
    let before = IndoorScene::generate(layout);
    let after = changed(&before, 0);
    let camera = IndoorRun {
        layout_seed: layout,
        seed,
        sensor: indoor::IndoorSensor::Camera(DepthCamera {
            pixels_per_frame: 600,
            ..DepthCamera::default()
        }),
        ..IndoorRun::default()
    };
    let first = indoor::sequence(&before, &camera);
    let config = first.config;
    let loop_frames = first.frames.len();
    let second = indoor::sequence(
        &after,
        &IndoorRun {
            seed: mix_all(&[seed, 2]),
            ..camera
        },
    );
    let train = indoor::sequence(
        &IndoorScene::generate(mix_all(&[layout, 0x7EA1])),
        &IndoorRun {
            seed: mix_all(&[seed, 0x7EA1]),
            ..camera
        },
    );
    let dec = decoding(
        &TextEmbeddings::builtin(),
        &train,
        &ExperimentSettings {
            seed,
            ..ExperimentSettings::default()
        },
    )
    .unwrap();

    // Half a loop's half-life: by the end the first loop weighs a few per cent.
    let forgetting = Forgetting::new(loop_frames as f32 / 2.0).unwrap();
    // The demo's codec with 4-bit means: the changing house's thin frames leave many voxels near a tie
    // between two classes, where 3-bit means flip the argmax (99.87 % with forgetting; 99.66 % on the same
    // run whose half-life is 10⁹ frames — the codec, not the clock). λ is exact either way.
    let setup = Setup {
        codec: latentbki::wire::SummaryCodec {
            mean_bits: 4,
            ..CODEC
        },
        ..Setup::new(config, 2.5, EncoderSettings::new(1, 1))
    }
    .with_forgetting(Some(forgetting));
    let mut robot = Box::new(Robot::EMPTY);
    robot.configure(&setup).unwrap();
    let mut tapped: BTreeMap<VoxelKey, Stamped<D>> = BTreeMap::new();
    let mut tap = |e: &Evicted<'_, D>| {
        let v = Stamped {
            obs: *e.obs,
            time: e.time,
        };
        tapped
            .entry(e.key)
            .or_insert(Stamped::EMPTY)
            .merge(&forgetting, &v);
    };
    let mut buf = vec![0u8; 64 << 20];
    let mut link: &mut [u8] = &mut buf;
    let frames = first.frames.iter().chain(&second.frames);
    let mut now = 0;
    for (t, f) in frames.enumerate() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(mix_all(&[seed, t as u64, 0xC4A]));
        let features = dec
            .encoder
            .encode_compressed(&f.points, t as u32, &dec.projected, &mut rng);
        let sensor: Vec<[f32; 3]> = f
            .points
            .iter()
            .map(|p| {
                let q = f.pose.inverse_transform_point(&p.position.into());
                [q.x, q.y, q.z]
            })
            .collect();
        now = t as u32;
        robot.set_time(now);
        robot.integrate_tapped(&f.pose, &sensor, &features, &mut tap);
        robot.tick(&mut link, usize::MAX).unwrap();
    }
    robot.drain_tapped(&mut link, &mut tap).unwrap();
    assert_eq!(robot.encoder().stats().invalid, 0);
    let sent = (64 << 20) - link.len();
    let link = &buf[..sent];

    // The robot's own statistics, every voxel it observed, decayed by the clock rule.
    let mut ours = ObsMap::<D>::new(config).unwrap();
    ours.set_forgetting(Some(forgetting));
    ours.set_time(now);
    for (k, v) in &tapped {
        ours.set_stamped(*k, &v.obs, v.time);
    }
    // The base station's, from the bytes.
    let mut base = BaseStation::<D>::adopting();
    base.receive(link);
    assert_eq!(base.stats().refused.invalid_voxel, 0);
    let mut map = base.into_map().expect("a session");
    assert_eq!(
        map.forgetting(),
        Some(forgetting),
        "the half-life in the header"
    );
    assert_eq!(map.time(), now, "the clock: the latest stamp");
    map.set_time(now);

    let theirs: BTreeMap<VoxelKey, _> = map.posteriors().into_iter().collect();
    let label = |m: &[f32; D]| dec.decoder.argmax(m).map(|(c, _)| c);
    let (mut n, mut agree, mut worst_lambda) = (0usize, 0usize, 0f32);
    ours.for_each_posterior(|k, r| {
        n += 1;
        let Some(b) = theirs.get(&k) else { return };
        agree += usize::from(label(&b.mean) == label(&r.mean));
        worst_lambda = worst_lambda.max((b.lambda - r.lambda).abs() / r.lambda);
    });
    let agreement = agree as f64 / n as f64;
    println!(
        "forgetting over the link: {n} voxels, argmax agreement {:.2} %, largest relative λ difference {worst_lambda:.1e}",
        100.0 * agreement
    );
    assert!(n > 5_000, "{n} voxels");
    assert_eq!(theirs.len(), n, "the base station answers the same voxels");
    assert!(agreement >= 0.999, "{agreement}");
    assert!(worst_lambda <= 1e-5, "{worst_lambda}");
    // Forgetting did something: the first loop's voxels faded.
    let faded = tapped
        .values()
        .filter(|v| v.at(&forgetting, now).count < 0.1 * v.obs.count);
    assert!(faded.count() > 100);
}
