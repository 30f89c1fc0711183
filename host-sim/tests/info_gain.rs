//! The view score on the host map and on the robot's `Mapper` is one function of the same statistics, and a
//! view scores less once it has been looked at.

use host_sim::obs_map::view_hits;
use host_sim::ObsMap;
use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use latentbki::{key::VoxelKey, packed_len, EncoderSettings, MapConfig, Mapper, Setup};

const D: usize = 8;
type Robot = Mapper<D, 4096, { packed_len(D) }, 4096, 512>;

/// A wall 1 m ahead: 400 points, features drawn around two classes.
fn wall(shift: f32) -> (Vec<[f32; 3]>, Vec<[f32; D]>) {
    let points: Vec<[f32; 3]> = (0..400)
        .map(|i| {
            [
                1.0,
                shift + (i % 20) as f32 * 0.025,
                (i / 20) as f32 * 0.025,
            ]
        })
        .collect();
    let features = (0..400)
        .map(|i| core::array::from_fn(|d| if (i + d) % 3 == 0 { 0.8 } else { 0.1 }))
        .collect();
    (points, features)
}

#[test]
fn host_map_and_mapper_score_a_view_alike_and_a_seen_view_scores_less() {
    let config = MapConfig::default();
    let pose = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), UnitQuaternion::identity());
    let mut host = ObsMap::<D>::new(config).unwrap();
    let setup = Setup::new(config, 4.0, EncoderSettings::new(1, 1));
    let mut robot: Box<Robot> = Box::new(Robot::EMPTY);
    robot.configure(&setup).unwrap();

    let (points, features) = wall(0.0);
    let (other, _) = wall(2.0);
    let before = host.view_score(&points);
    let hits = view_hits(&points, 1.0 / config.voxel_size());
    assert_eq!(robot.view_score(&hits).unwrap(), before, "empty maps agree");
    assert!(before > 0.0);

    host.integrate(&pose, &points, &features);
    robot.integrate(&pose, &points, &features);
    let after = host.view_score(&points);
    let on_robot = robot.view_score(&hits).unwrap();
    // The robot's map is quantized: its counts are exact, so λ (and the score) agree to f32 rounding.
    assert!(
        (on_robot - after).abs() <= 1e-4 * after,
        "{on_robot} vs {after}"
    );
    assert!(
        after < 0.5 * before,
        "a view already seen scores {after}, unseen {before}"
    );
    // A view of a wall never seen still scores as before.
    assert_eq!(host.view_score(&other), before);

    // Per voxel: a seen voxel gains less than an unseen one, more weight gains more.
    let seen = VoxelKey::from_position(points[0], 1.0 / config.voxel_size()).unwrap();
    let unseen = VoxelKey::new(100, 100, 100);
    assert!(host.voxel_gain(seen, 1.0) < host.voxel_gain(unseen, 1.0));
    assert!(host.voxel_gain(seen, 1.0) < host.voxel_gain(seen, 2.0));
}
