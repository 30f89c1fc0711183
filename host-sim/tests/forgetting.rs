//! Forgetting on the host map: off changes nothing whatever the clock says; on, a voxel reads as its
//! observations weighed γ^age (the core's stamped statistics); the changing house changes only furniture in
//! one room.

use host_sim::changing::changed;
use host_sim::sim::indoor::IndoorScene;
use host_sim::ObsMap;
use latentbki::nalgebra::Isometry3;
use latentbki::{forget::Forgetting, forget::Stamped, key::VoxelKey, obs::ObsLookup, MapConfig};

fn frame(t: usize) -> (Vec<[f32; 3]>, Vec<[f32; 2]>) {
    let points = (0..50)
        .map(|i| {
            [
                0.31 + (i % 5) as f32 * 0.1,
                0.12 + (i / 5) as f32 * 0.05,
                0.5,
            ]
        })
        .collect();
    let features = (0..50)
        .map(|i| {
            [
                (t % 3) as f32 + 0.1 * (i % 4) as f32,
                1.0 - 0.2 * (t % 2) as f32,
            ]
        })
        .collect();
    (points, features)
}

#[test]
fn off_by_default_the_clock_changes_nothing() {
    let config = MapConfig::default();
    let (mut a, mut b) = (
        ObsMap::<2>::new(config).unwrap(),
        ObsMap::<2>::new(config).unwrap(),
    );
    for t in 0..6 {
        let (p, f) = frame(t);
        b.set_time(100 * t as u32);
        a.integrate(&Isometry3::identity(), &p, &f);
        b.integrate(&Isometry3::identity(), &p, &f);
    }
    assert_eq!(a.posteriors_sorted(), b.posteriors_sorted());
}

#[test]
fn forgetting_reads_each_voxel_as_its_decayed_observations() {
    let config = MapConfig::default();
    let forgetting = Forgetting::new(3.0).unwrap();
    let mut map = ObsMap::<2>::new(config).unwrap();
    map.set_forgetting(Some(forgetting));
    // The same points, kept per voxel with the core's stamped statistics.
    let mut reference: std::collections::BTreeMap<VoxelKey, Stamped<2>> = Default::default();
    let ticks = [0u32, 1, 4, 9, 10, 17];
    for (i, &t) in ticks.iter().enumerate() {
        let (p, f) = frame(i);
        map.set_time(t);
        map.integrate(&Isometry3::identity(), &p, &f);
        for (q, y) in p.iter().zip(&f) {
            let k = VoxelKey::from_position(*q, 1.0 / config.voxel_size()).unwrap();
            reference
                .entry(k)
                .or_insert(Stamped::EMPTY)
                .add_point(&forgetting, t, y);
        }
    }
    map.set_time(25);
    for (k, v) in &reference {
        let want = v.at(&forgetting, 25);
        let got = map.observed(*k).unwrap();
        assert!((got.count - want.count).abs() <= 1e-6 * want.count, "{k:?}");
        assert_eq!(got.mean, want.mean);
        assert_eq!(
            map.observed_count(*k),
            got.count,
            "counts read alone decay alike"
        );
        for d in 0..2 {
            assert!((got.scatter[d] - want.scatter[d]).abs() <= 1e-5 * want.scatter[d].max(1.0));
        }
        // Stored as of the last change (tick ≤ 17), read 8+ ticks later: decayed on reading.
        let stored = map.observed_voxels().find(|(q, _)| q == k).unwrap().1.count;
        assert!(got.count < 0.2 * stored, "{} vs stored {stored}", got.count);
    }
    // Gathered posteriors use the decayed statistics: λ is below the undecayed map's.
    let mut plain = ObsMap::<2>::new(config).unwrap();
    for i in 0..ticks.len() {
        let (p, f) = frame(i);
        plain.integrate(&Isometry3::identity(), &p, &f);
    }
    let (k, _) = reference.iter().next().unwrap();
    assert!(map.posterior(*k).lambda < plain.posterior(*k).lambda);
}

#[test]
fn the_change_swaps_furniture_classes_in_one_room_only() {
    let before = IndoorScene::generate(1);
    let after = changed(&before, 0);
    let r = before.rooms[0];
    let mut swapped = 0;
    for (a, b) in before.boxes.iter().zip(&after.boxes) {
        assert_eq!((a.min, a.max), (b.min, b.max), "geometry unchanged");
        if a.class != b.class {
            swapped += 1;
            assert!(a.class >= 5 && b.class >= 5, "only furniture");
            let c = [(a.min[0] + a.max[0]) / 2.0, (a.min[1] + a.max[1]) / 2.0];
            assert!(
                (0..2).all(|i| c[i] > r.min[i] && c[i] < r.max[i]),
                "only room 0"
            );
        }
    }
    assert!(swapped > 0);
}
