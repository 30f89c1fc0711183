//! The reference map's grouping and spreading equal a brute-force evaluation of the paper: for every voxel,
//! k̄, ȳ, S̄ summed over every point of the batch with the kernel of the point-to-voxel offset distance,
//! in f64. Random poses, points near and far from the origin, several batches, f = 1, 3, 5.

use host_sim::ReferenceMap;
use latentbki::kernel::sparse_kernel;
use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use latentbki::{key::to_map_frame, key::VoxelKey, KernelMode, MapConfig, Prior};
use proptest::prelude::*;
use std::collections::BTreeMap;

const D: usize = 4;
type Exact = BTreeMap<VoxelKey, (f64, [f64; D], [f64; D])>;
type Batch = (Isometry3<f32>, Vec<([f32; 3], [f32; D])>);

fn brute_force(config: &MapConfig, batches: &[Batch]) -> Exact {
    let vs = config.voxel_size();
    let r = config.reach();
    let prior = config.prior();
    let mut map = Exact::new();
    for (pose, points) in batches {
        let mut targets: BTreeMap<VoxelKey, Vec<(f64, [f64; D])>> = BTreeMap::new();
        for (p, y) in points {
            let key = VoxelKey::from_position(to_map_frame(pose, *p), 1.0 / vs).unwrap();
            for dz in -r..=r {
                for dy in -r..=r {
                    for dx in -r..=r {
                        let d = ((dx * dx + dy * dy + dz * dz) as f32).sqrt() * vs;
                        let k = sparse_kernel(d, config.kernel_length()) as f64;
                        if k > 0.0 {
                            let t = VoxelKey::new(key.x + dx, key.y + dy, key.z + dz);
                            targets.entry(t).or_default().push((k, y.map(f64::from)));
                        }
                    }
                }
            }
        }
        for (t, obs) in targets {
            let k_bar: f64 = obs.iter().map(|(k, _)| k).sum();
            let y_bar: [f64; D] =
                core::array::from_fn(|d| obs.iter().map(|(k, y)| k * y[d]).sum::<f64>() / k_bar);
            let s_bar: [f64; D] = core::array::from_fn(|d| {
                obs.iter().map(|(k, y)| k * (y[d] - y_bar[d]).powi(2)).sum()
            });
            let v = map.entry(t).or_insert((
                prior.lambda as f64,
                [prior.mean as f64; D],
                [prior.psi as f64; D],
            ));
            let l1 = v.0 + k_bar;
            for d in 0..D {
                v.2[d] += s_bar[d] + v.0 * k_bar / l1 * (y_bar[d] - v.1[d]).powi(2);
                v.1[d] = (v.0 * v.1[d] + k_bar * y_bar[d]) / l1;
            }
            v.0 = l1;
        }
    }
    map
}

fn point() -> impl Strategy<Value = ([f32; 3], [f32; D])> {
    (
        proptest::array::uniform3(-0.4f32..0.4),
        proptest::array::uniform4(-2.0f32..2.0),
    )
}

fn pose() -> impl Strategy<Value = Isometry3<f32>> {
    (proptest::array::uniform3(-1.0f32..1.0), -3.0f32..3.0).prop_map(|(t, yaw)| {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn reference_map_equals_brute_force(
        far in prop_oneof![Just(0.0f32), Just(450.0f32)],
        filter in prop_oneof![Just(1u8), Just(3), Just(5)],
        batches in proptest::collection::vec((pose(), proptest::collection::vec(point(), 0..40)), 1..4),
    ) {
        let config = MapConfig::new(0.1, 0.5, filter, Prior::default(), KernelMode::VoxelOffset).unwrap();
        let batches: Vec<Batch> = batches.into_iter().map(|(pose, pts)| {
            (pose, pts.into_iter().map(|(p, y)| ([p[0] + far, p[1] - far, p[2]], y)).collect())
        }).collect();
        let mut map = ReferenceMap::<D>::new(config).unwrap();
        for (pose, pts) in &batches {
            let (p, y): (Vec<_>, Vec<_>) = pts.iter().cloned().unzip();
            map.integrate(pose, &p, &y);
        }
        let exact = brute_force(&config, &batches);
        prop_assert_eq!(map.len(), exact.len());
        for (key, (l, m, s)) in &exact {
            let v = map.get(key).expect("voxel present");
            prop_assert!((v.lambda as f64 - l).abs() <= 1e-5 * (l + 1.0));
            for d in 0..D {
                prop_assert!((v.mean[d] as f64 - m[d]).abs() <= 1e-5 * 2.0 * 4.0, "mean {} vs {}", v.mean[d], m[d]);
                prop_assert!((v.psi[d] as f64 - s[d]).abs() <= 1e-5 * (s[d] + 4.0 * l), "psi {} vs {}", v.psi[d], s[d]);
            }
        }
    }
}
