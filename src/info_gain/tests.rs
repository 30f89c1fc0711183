//! The gain against hand-worked values and its monotonicity; the view score against its definition
//! (`view_score_brute`), bit for bit, on random maps and views and on walls and runs of hits.

use super::*;
use crate::config::MapConfig;
use crate::obs::ObsStats;

struct List<'a>(&'a [(VoxelKey, ObsStats<1>)]);
impl ObsLookup<1> for List<'_> {
    fn observed(&self, key: VoxelKey) -> Option<ObsStats<1>> {
        self.0.iter().find(|(k, _)| *k == key).map(|(_, s)| *s)
    }
}

fn seen(n: f32) -> ObsStats<1> {
    ObsStats {
        count: n,
        mean: [0.5],
        scatter: [0.1 * n],
    }
}

#[test]
fn hand_worked_gains() {
    // λ = 1, w = 1: ½ ln(2·2 / (1·3)) = ½ ln(4/3).
    assert!((voxel_gain(1.0, 1.0) - 0.5 * libm::logf(4.0 / 3.0)).abs() < 1e-6);
    // λ = 4, w = 2: ½ ln(6·5 / (4·7)).
    assert!((voxel_gain(4.0, 2.0) - 0.5 * libm::logf(30.0 / 28.0)).abs() < 1e-6);
    // Never seen (flat prior): the floor, λ = 0.05, w = 1: ½ ln(1.05·1.05 / (0.05·2.05)).
    let unseen = 0.5 * libm::logf(1.05 * 1.05 / (0.05 * 2.05));
    assert!((voxel_gain(0.0, 1.0) - unseen).abs() < 1e-5);
    // No weight, no gain; NaN or infinite weight or confidence, none either.
    assert_eq!(voxel_gain(3.0, 0.0), 0.0);
    assert_eq!(voxel_gain(3.0, f32::NAN), 0.0);
    assert_eq!(voxel_gain(3.0, f32::INFINITY), 0.0);
    assert_eq!(voxel_gain(f32::INFINITY, 2.0), 0.0);
}

#[test]
fn a_voxel_never_seen_gains_most_and_gain_falls_as_lambda_grows() {
    for w in [0.1f32, 0.5, 1.0, 4.0, 30.0] {
        let mut prev = voxel_gain(0.0, w);
        assert!(prev > 0.0);
        for lambda in [0.1f32, 0.5, 1.0, 2.0, 5.0, 20.0, 100.0, 1000.0] {
            let g = voxel_gain(lambda, w);
            assert!(g < prev, "w {w}: gain at λ {lambda} = {g} not below {prev}");
            assert!(g > 0.0);
            prev = g;
        }
    }
}

#[test]
fn gain_is_monotone_in_w_and_bounded() {
    for lambda in [0.0f32, 0.3, 1.0, 7.0, 60.0] {
        let mut prev = 0.0;
        for w in [0.01f32, 0.1, 0.4425, 1.0, 3.0, 10.0, 100.0] {
            let g = voxel_gain(lambda, w);
            assert!(g > prev, "λ {lambda}: gain at w {w} = {g} not above {prev}");
            prev = g;
        }
        let l = lambda.max(UNSEEN_LAMBDA);
        assert!(prev < 0.5 * libm::logf(1.0 + 1.0 / l) + 1e-6);
    }
}

#[test]
fn view_score_sums_each_reached_voxel_once() {
    let config = MapConfig::default(); // 0.1 m voxels, ℓ = 0.5, f = 3: 27 offsets
    let lut: KernelLut = KernelLut::new(&config).unwrap();
    let empty = List(&[]);
    // One hit of 2 points on an empty map: 27 targets, each gaining gain(0, 2·k(o)).
    let a = VoxelKey::new(0, 0, 0);
    let one = view_score(&lut, &empty, 0.0, &[(a, 2.0)]).unwrap();
    let by_hand: f32 = lut
        .weights(0)
        .iter()
        .map(|&k| voxel_gain(0.0, 2.0 * k))
        .sum();
    assert!((one - by_hand).abs() < 1e-4 * by_hand);
    // Two adjacent hits: targets in both neighbourhoods receive both weights, counted once.
    let b = VoxelKey::new(1, 0, 0);
    let two = view_score(&lut, &empty, 0.0, &[(a, 2.0), (b, 1.0)]).unwrap();
    let mut by_hand = 0.0;
    for x in -1..=2 {
        for y in -1..=1 {
            for z in -1..=1 {
                let w = 2.0 * lut.weight_at(0, x, y, z) + lut.weight_at(0, x - 1, y, z);
                by_hand += voxel_gain(0.0, w);
            }
        }
    }
    assert!((two - by_hand).abs() < 1e-4 * by_hand, "{two} vs {by_hand}");
    // A view of voxels the map has seen scores less, and less again the more it has seen.
    let seen_once = [(a, seen(1.0)), (b, seen(1.0))];
    let seen_often = [(a, seen(50.0)), (b, seen(50.0))];
    let s1 = view_score(&lut, &List(&seen_once), 0.0, &[(a, 2.0), (b, 1.0)]).unwrap();
    let s2 = view_score(&lut, &List(&seen_often), 0.0, &[(a, 2.0), (b, 1.0)]).unwrap();
    assert!(two > s1 && s1 > s2 && s2 > 0.0, "{two} > {s1} > {s2} > 0");
    // Unsorted or repeated hits are refused.
    assert_eq!(
        view_score(&lut, &empty, 0.0, &[(b, 1.0), (a, 1.0)]),
        Err(ScoreError::UnsortedHits)
    );
    assert_eq!(
        view_score(&lut, &empty, 0.0, &[(a, 1.0), (a, 1.0)]),
        Err(ScoreError::UnsortedHits)
    );
    assert_eq!(view_score(&lut, &empty, 0.0, &[]), Ok(0.0));
}

#[test]
fn view_score_equals_the_definition_on_random_maps_and_views() {
    use crate::config::{KernelMode, Prior};
    let mut next = lcg(0x2545_f491_u32);
    let prior = Prior {
        lambda: 0.0,
        mean: 0.0,
        psi: 0.0,
    };
    for f in [1u8, 3, 5] {
        let config = MapConfig::new(0.1, 0.5, f, prior, KernelMode::VoxelOffset).unwrap();
        let lut: KernelLut = KernelLut::new(&config).unwrap();
        for case in 0..40 {
            // Keys in a 7³ box (dense enough that neighbourhoods overlap), some far apart.
            let key = |next: &mut dyn FnMut(u32) -> u32| {
                let far = if next(8) == 0 { 100 } else { 0 };
                VoxelKey::new(
                    next(7) as i32 - 3 + far,
                    next(7) as i32 - 3,
                    next(7) as i32 - 3,
                )
            };
            let mut map = [(VoxelKey::default(), seen(0.0)); 60];
            for m in &mut map {
                *m = (key(&mut next), seen(next(40) as f32 * 0.25));
            }
            let mut hits = [(VoxelKey::default(), 0.0f32); 40];
            for h in &mut hits {
                // Mostly positive counts; some 0 or negative, which reach nothing.
                *h = (key(&mut next), next(12) as f32 * 0.5 - 1.0);
            }
            hits.sort_by_key(|h| h.0);
            let mut n = 0;
            for j in 0..hits.len() {
                if j == 0 || hits[j].0 != hits[n - 1].0 {
                    hits[n] = hits[j];
                    n += 1;
                }
            }
            let take = 1 + next(n as u32) as usize;
            let hits = &hits[..take];
            let lambda0 = [0.0, 0.5, 2.0][case % 3];
            let fast = match view_score(&lut, &List(&map), lambda0, hits) {
                Err(ScoreError::WideFilter) if f > 3 && !cfg!(feature = "wide-view-score") => {
                    continue
                }
                r => r.unwrap(),
            };
            let brute = view_score_brute(&lut, &List(&map), lambda0, hits).unwrap();
            assert_eq!(
                fast.to_bits(),
                brute.to_bits(),
                "f {f} case {case}: {fast} vs {brute}"
            );
            assert!(fast > 0.0 || hits.iter().all(|h| h.1 <= 0.0));
        }
    }
}

#[test]
fn view_score_equals_the_definition_on_walls_and_runs() {
    // Views like a camera's: planes and runs of neighbouring voxels (the window moves along z by 1 to 7
    // voxels, and to the next row), with gaps and some n ≤ 0.
    let mut next = lcg(0x9e37_79b9_u32);
    let lut: KernelLut = KernelLut::new(&MapConfig::default()).unwrap();
    for case in 0..30 {
        let mut map = [(VoxelKey::default(), seen(0.0)); 80];
        for m in &mut map {
            let k = VoxelKey::new(next(4) as i32, next(12) as i32 - 6, next(14) as i32 - 7);
            *m = (k, seen(next(20) as f32 * 0.5));
        }
        let mut hits = [(VoxelKey::default(), 0.0f32); 96];
        let mut n = 0;
        let (x0, gap) = (next(3) as i32, 1 + next(4) as i32);
        'fill: for x in x0..x0 + 1 + next(2) as i32 {
            for y in -4..4 {
                let mut z = -6 + next(3) as i32;
                while z < 6 {
                    if n == hits.len() {
                        break 'fill;
                    }
                    hits[n] = (VoxelKey::new(x, y, z), next(6) as f32 * 0.5 - 0.5);
                    n += 1;
                    z += if next(4) == 0 { gap } else { 1 };
                }
            }
        }
        let hits = &hits[..n];
        let fast = view_score(&lut, &List(&map), 0.5, hits).unwrap();
        let brute = view_score_brute(&lut, &List(&map), 0.5, hits).unwrap();
        assert_eq!(
            fast.to_bits(),
            brute.to_bits(),
            "case {case}: {fast} vs {brute}"
        );
    }
}

#[test]
fn gathered_count_is_the_posterior_lambda_above_the_prior() {
    let lut: KernelLut = KernelLut::new(&MapConfig::default()).unwrap();
    let a = VoxelKey::new(0, 0, 0);
    let map = [(a, seen(3.0)), (VoxelKey::new(1, 1, 0), seen(2.0))];
    let k = gathered_count(&lut, &List(&map), a).unwrap();
    let post = crate::obs::gather(&lut, &List(&map), a).unwrap();
    assert!((k - post.count).abs() < 1e-5);
    assert!((k - (3.0 + 2.0 * lut.weight_at(0, 1, 1, 0))).abs() < 1e-5);
}

#[test]
fn a_wall_view_reads_each_map_voxel_once() {
    // The board's candidate view: 8 rows (y) of 8 hits along z at one x. The window keeps the previous
    // row's planes, so each of the 5 × 12 × 12 voxels within ±2 of a hit is looked up once.
    struct Counting(core::cell::Cell<u32>);
    impl ObsLookup<1> for Counting {
        fn observed(&self, _: VoxelKey) -> Option<ObsStats<1>> {
            self.0.set(self.0.get() + 1);
            None
        }
    }
    let lut: KernelLut = KernelLut::new(&MapConfig::default()).unwrap();
    let mut hits = [(VoxelKey::default(), 1.0f32); 64];
    for (i, h) in hits.iter_mut().enumerate() {
        h.0 = VoxelKey::new(10, i as i32 / 8 - 4, i as i32 % 8 - 4);
    }
    let map = Counting(core::cell::Cell::new(0));
    let score = view_score(&lut, &map, 0.0, &hits).unwrap();
    assert_eq!(
        score.to_bits(),
        view_score_brute(&lut, &List(&[]), 0.0, &hits)
            .unwrap()
            .to_bits()
    );
    assert_eq!(map.0.get(), 5 * 12 * 12);
}

/// A small LCG drawing below `m`: the same cases every run.
fn lcg(mut state: u32) -> impl FnMut(u32) -> u32 {
    move |m| {
        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (state >> 8) % m
    }
}
