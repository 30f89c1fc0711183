//! The exploration run's pieces: the house is drivable, the explorers' fast score is the map's view score,
//! and a short run of each explorer stays within its budget and learns.

use host_sim::explore::world::{footprint, World};
use host_sim::explore::{mean_curve, run, Explorer, Planner, Sample, Truth, UTILITY_OFFSET_M};
use host_sim::sim::indoor::{self, IndoorRun, IndoorScene};
use host_sim::sim::mix_all;
use host_sim::sim::vocab::TextEmbeddings;
use host_sim::ObsMap;
use latentbki::kernel::KernelLut;
use latentbki::nalgebra::Isometry3;

#[test]
fn every_room_is_reachable_and_the_fast_score_is_the_maps() {
    let scene = IndoorScene::generate(1);
    let config = indoor::sequence(&scene, &IndoorRun::default()).config;
    let world = World::new(scene.clone(), &config, 3072).unwrap();
    let start = world.nearest_free(scene.room_centre(0)).unwrap();
    let (dist, _) = world.distances(start);
    for r in 0..4 {
        let c = world.nearest_free(scene.room_centre(r)).unwrap();
        assert!(dist[c].is_finite(), "room {r} unreachable");
    }
    assert!(
        world.views.len() > 500,
        "{} candidate views",
        world.views.len()
    );

    // The dense slots the explorers score by name the same voxels as the footprints' keys.
    let key_of: std::collections::HashMap<u32, _> =
        world.slots.iter().map(|(&k, &s)| (s, k)).collect();
    assert_eq!(key_of.len(), world.slots.len(), "two voxels share a slot");
    for (_, fp) in &world.views {
        assert_eq!(fp.slot_weights.len(), fp.weights.len());
        for (&(s, ws), &(k, w)) in fp.slot_weights.iter().zip(&fp.weights) {
            assert_eq!((key_of[&s], ws), (k, w));
        }
        let hits: Vec<_> = fp.hit_slots.iter().map(|s| key_of[s]).collect();
        assert_eq!(hits, fp.hits);
    }

    // After one real frame, the footprint's Σ gain(λ, w) equals ObsMap::view_score on the same points.
    let lut: KernelLut = KernelLut::new(&config).unwrap();
    let mut map = ObsMap::<2>::new(config).unwrap();
    let (view, _) = world.views[world.views.len() / 2];
    let points = world.predicted(view);
    let half: Vec<[f32; 3]> = points.iter().step_by(2).copied().collect();
    let feats = vec![[0.5f32, -0.5]; half.len()];
    map.integrate(&Isometry3::identity(), &half, &feats);
    let fp = footprint(&lut, &points, 1.0);
    let fast: f32 = fp.weights.iter().map(|&(k, w)| map.voxel_gain(k, w)).sum();
    let exact = map.view_score(&points);
    assert!(
        (fast - exact).abs() <= 1e-4 * exact,
        "footprint {fast} vs view_score {exact}"
    );
}

/// House 1's decoding, ground truth and world (seed 5's training loop).
fn house_one() -> (
    World,
    host_sim::eval::experiment::Decoding,
    Truth,
    latentbki::MapConfig,
) {
    let scene = IndoorScene::generate(1);
    let train = indoor::sequence(
        &IndoorScene::generate(mix_all(&[1, 0x7EA1])),
        &IndoorRun {
            seed: 5,
            ..IndoorRun::default()
        },
    );
    let config = train.config;
    let dec = host_sim::eval::experiment::decoding(
        &TextEmbeddings::builtin(),
        &train,
        &host_sim::eval::experiment::ExperimentSettings::default(),
    )
    .unwrap();
    let truth = Truth::from_loop(&scene, &config);
    let world = World::new(scene, &config, 3072).unwrap();
    (world, dec, truth, config)
}

fn explorer(planner: Planner, horizon: usize, budget: f32) -> Explorer {
    Explorer {
        planner,
        seed: 1,
        budget,
        utility_offset: UTILITY_OFFSET_M,
        discount: 0.0,
        horizon,
        replan: false,
        rooms: false,
        surface_only: false,
    }
}

#[test]
fn short_runs_stay_in_budget_and_learn() {
    let (world, dec, truth, config) = house_one();
    let explorers = [
        explorer(Planner::InformationGain, 1, 5.0),
        explorer(Planner::InformationGain, 2, 5.0),
        Explorer {
            discount: 0.2,
            replan: true,
            ..explorer(Planner::InformationGain, 1, 5.0)
        },
        Explorer {
            rooms: true,
            surface_only: true,
            ..explorer(Planner::InformationGain, 1, 5.0)
        },
        explorer(Planner::Random, 1, 5.0),
        explorer(Planner::NearestFrontier, 1, 5.0),
    ];
    for e in &explorers {
        let name = format!("{e:?}");
        let samples = run(&world, &dec, &truth, &config, e).unwrap();
        assert!(samples.len() >= 3, "{name}: {} samples", samples.len());
        assert!(samples.windows(2).all(|w| w[0].distance <= w[1].distance));
        let last = samples.last().unwrap();
        assert!(last.distance <= 5.0 + 1e-3, "{name}: {} m", last.distance);
        assert!(last.accuracy > samples[0].accuracy, "{name}");
    }
}

#[test]
fn information_gain_single_views_and_tours_beat_random_choice() {
    // 12 m in house 1: both information-gain planners know more of the house than random choice does.
    let (world, dec, truth, config) = house_one();
    let final_accuracy = |e: Explorer| {
        run(&world, &dec, &truth, &config, &e)
            .unwrap()
            .last()
            .unwrap()
            .accuracy
    };
    let random = final_accuracy(explorer(Planner::Random, 1, 12.0));
    for horizon in [1, 2] {
        let ig = final_accuracy(explorer(Planner::InformationGain, horizon, 12.0));
        assert!(
            ig > random + 0.05,
            "horizon {horizon}: information gain {ig:.3}, random {random:.3}"
        );
    }
}

#[test]
fn the_mean_curve_holds_the_last_value_within_each_distance() {
    let s = |distance: f32, accuracy: f64| Sample {
        distance,
        accuracy,
        miou: 0.0,
        frames: 0,
    };
    let runs = vec![
        vec![s(0.0, 0.1), s(1.0, 0.5), s(3.0, 0.9)],
        vec![s(0.0, 0.3), s(2.0, 0.7)],
    ];
    let c = mean_curve(&runs, &[0.0, 1.0, 2.5, 3.0], |x| x.accuracy);
    let want = [0.2, 0.4, 0.6, 0.8];
    for (a, b) in c.iter().zip(want) {
        assert!((a - b).abs() < 1e-12, "{c:?}");
    }
}

#[test]
fn the_utility_prefers_more_gain_and_less_driving() {
    use host_sim::explore::utility;
    for discount in [0.0, 0.2] {
        let u = |score, path| utility(score, path, UTILITY_OFFSET_M, discount);
        // The same drive: the view that would teach more wins; the same gain: the nearer view wins.
        assert!(u(200.0, 2.0) > u(100.0, 2.0), "discount {discount}");
        assert!(u(100.0, 1.0) > u(100.0, 6.0), "discount {discount}");
        // A view next to the robot is not free (offset), and enough gain is worth a drive.
        assert!(u(400.0, 5.0) > u(100.0, 0.0), "discount {discount}");
        assert!(u(100.0, 0.0).is_finite());
    }
    // The rate: twice the gain is worth exactly the drive that doubles path + offset (1 m → 2 m + offset).
    let r = |score, path| utility(score, path, UTILITY_OFFSET_M, 0.0);
    assert!((r(200.0, UTILITY_OFFSET_M + 2.0) - r(100.0, 1.0)).abs() < 1e-4);
}
