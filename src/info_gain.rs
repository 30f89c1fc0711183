//! Information gain: how much a voxel's uncertainty would shrink if it were observed again, and the score of
//! a candidate view (where the robot should look next).
//!
//! **The measure.** A voxel's predictive is a Student-t per dimension with scale s² = (λ+1)/λ² · Ψ
//! ([`crate::inference`]). Its entropy is ½ ln s² plus a term of the degrees of freedom alone; the gain is
//! the expected drop of the ½ ln s² part (the log of the D-optimality of the authors' t_var, per dimension)
//! when the voxel receives kernel weight `w` more of observations. New observations are expected to have
//! the spread the voxel already predicts: kernel weight `w` of points adds E\[ΔΨ\] = w · Ψ/λ to the scatter
//! (the batch's own scatter plus its mean's offset from μ, §III-B's update, in expectation). Then
//!
//! ```text
//! s'²/s² = λ(λ+w+1) / ((λ+w)(λ+1))      (Ψ cancels)
//! gain(λ, w) = ½ ln[ (λ+w)(λ+1) / (λ(λ+w+1)) ]   nats per feature dimension
//! ```
//!
//! It depends on λ and w only: a voxel's spread Ψ scales its predictive, not how much a new look shrinks
//! it in ratio. It is positive for w > 0, grows with w (to ½ ln(1 + 1/λ) as w → ∞: even endless looks
//! leave the features' own spread), and falls as λ grows. A voxel with nothing in reach under a flat
//! prior (λ = 0) has an improper predictive whose entropy is infinite: λ is floored at
//! [`UNSEEN_LAMBDA`], a twentieth of a point, so such voxels gain most yet stay comparable. The
//! dimension-only entropy term (digamma of λ) is left out: it is common to all voxels of equal λ and small
//! beside the scale term once λ > 2. Multiply by D for the whole predictive's entropy.
//!
//! **The view score.** A candidate view is the set of voxels its rays are expected to hit, with a point
//! count each (e.g. ray-cast against the geometry known so far). Each hit spreads kernel weight to its
//! f³ neighbourhood exactly as integrating the points would; a target voxel t then receives
//! w_t = Σ_o k(o) · n(t+o) and the score is Σ_t gain(λ_t, w_t), with λ_t = λ₀ + the kernel-weighted count
//! the map already gathers there ([`gathered_count`]). No heap: the hits are a sorted slice, searched.

use crate::kernel::KernelLut;
use crate::key::VoxelKey;
use crate::obs::{GatherError, ObsLookup};

mod window;
use window::{Window, MAX_TARGETS};

/// The λ an unseen voxel under a flat prior is taken to have (see the module docs).
pub const UNSEEN_LAMBDA: f32 = 0.05;

/// Expected reduction, in nats per feature dimension, of the entropy (scale part) of a voxel's Student-t
/// predictive if it received kernel weight `w` of observations, given its current confidence `lambda`
/// (floored at [`UNSEEN_LAMBDA`]). 0 for `w ≤ 0` or NaN, and for an infinite `w` or `lambda`.
#[inline]
pub fn voxel_gain(lambda: f32, w: f32) -> f32 {
    if !(w > 0.0) {
        return 0.0;
    }
    let l = if lambda > UNSEEN_LAMBDA {
        lambda
    } else {
        UNSEEN_LAMBDA
    };
    let ratio = (l + w) * (l + 1.0) / (l * (l + w + 1.0));
    // About 1 or more, a normal number, for finite w and λ; an infinite one makes it NaN or ∞.
    if !(ratio < f32::INFINITY) {
        return 0.0;
    }
    0.5 * core::f32::consts::LN_2 * crate::f32math::log2_normal(ratio)
}

/// The kernel-weighted point count K a gather gives at `target` (its posterior's λ is λ₀ + K), reading
/// counts only.
pub fn gathered_count<const D: usize, const CAP: usize, M: ObsLookup<D> + ?Sized>(
    lut: &KernelLut<CAP>,
    map: &M,
    target: VoxelKey,
) -> Result<f32, GatherError> {
    if !lut.is_voxel_offset() {
        return Err(GatherError::SubVoxelKernel);
    }
    let mut k_sum = 0.0;
    for (&o, &k) in lut.offsets().iter().zip(lut.weights(0)) {
        k_sum += k * map.observed_count(target.offset(o));
    }
    Ok(k_sum)
}

/// Why a view cannot be scored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScoreError {
    /// The kernel table is in sub-voxel mode (see [`GatherError`]).
    SubVoxelKernel,
    /// The hits are not sorted by key without repeats.
    UnsortedHits,
    /// The filter is wider than f = 3 and the `wide-view-score` feature is off.
    WideFilter,
}

impl core::fmt::Display for ScoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::SubVoxelKernel => GatherError::SubVoxelKernel.fmt(f),
            Self::UnsortedHits => {
                f.write_str("view hits must be sorted by voxel key, without repeats")
            }
            Self::WideFilter => f.write_str(
                "view scores for filters wider than 3 need the `wide-view-score` feature",
            ),
        }
    }
}

impl core::error::Error for ScoreError {}

#[cfg(any(test, feature = "wide-view-score"))]
#[inline(never)] // one copy of the search in flash
fn count_at(hits: &[(VoxelKey, f32)], key: VoxelKey) -> f32 {
    hits.binary_search_by_key(&key, |h| h.0)
        .map_or(0.0, |i| hits[i].1)
}

fn check<const CAP: usize>(
    lut: &KernelLut<CAP>,
    hits: &[(VoxelKey, f32)],
) -> Result<(), ScoreError> {
    if !lut.is_voxel_offset() {
        return Err(ScoreError::SubVoxelKernel);
    }
    if hits.windows(2).any(|p| p[0].0 >= p[1].0) {
        return Err(ScoreError::UnsortedHits);
    }
    Ok(())
}

/// The information-gain score of a candidate view: Σ over every voxel the view's points would reach of
/// [`voxel_gain`]`(λ, w)` (module docs). `hits` are the voxels the view's points are expected to fall
/// in, with the number of points in each, sorted by key without repeats; `prior_lambda` is the map's λ₀.
///
/// Each target is counted once, from the first hit (in key order) in its neighbourhood. For f ≤ 3 each
/// hit's 5³ window (every source and map voxel its 27 targets can reach) is laid out on the stack: which
/// targets an earlier hit already counted is one OR of precomputed masks per earlier source, and map
/// counts are read once per window and carried over to the next hit's window where the two overlap
/// (consecutive hits are usually neighbours). Wider filters take the generic path (binary searches over
/// the hits). Either way the sums run in the kernel table's order, so the score is bit-identical to the
/// definition's, searched target by target (the tests compare the two on random maps and views).
pub fn view_score<const D: usize, const CAP: usize, M: ObsLookup<D> + ?Sized>(
    lut: &KernelLut<CAP>,
    map: &M,
    prior_lambda: f32,
    hits: &[(VoxelKey, f32)],
) -> Result<f32, ScoreError> {
    check(lut, hits)?;
    let offsets = lut.offsets();
    // f ≤ 3: every offset within ±1, at most 27 of them.
    if lut.reach() > 1 || offsets.len() > MAX_TARGETS {
        #[cfg(feature = "wide-view-score")]
        return generic(lut, map, prior_lambda, hits);
        #[cfg(not(feature = "wide-view-score"))]
        return Err(ScoreError::WideFilter);
    }
    let weights = lut.weights(0);
    // Each offset as a step between slots of the window; and bit a of reaches[q]: the voxel at x-major
    // position q around a hit is a source of its target a. (`black_box`: an opaque call in a loop keeps
    // LLVM from unrolling it, which on Cortex-M would spend flash on a once-per-view setup.)
    let mut steps = [0u8; MAX_TARGETS];
    let mut reaches = [0u32; 128];
    for (a, (t, oa)) in steps.iter_mut().zip(offsets).enumerate() {
        *t = window::step(*oa);
        for op in offsets {
            core::hint::black_box(());
            let d = |i: usize| i32::from(oa[i]) + i32::from(op[i]);
            reaches[window::x_major(d(0), d(1), d(2)) & 127] |= 1 << a;
        }
    }
    let steps = steps.get(..offsets.len()).unwrap_or(&[]);
    let mut win = Window::new();
    let mut score = 0.0;
    for &(hit, _) in hits {
        win.move_to(hits, hit);
        // Targets an earlier hit reaches were counted from it.
        let mut counted = 0u32;
        win.earlier(|q| counted |= reaches[q & 127]);
        let centre = win.centre_slot();
        for (a, &ra) in steps.iter().enumerate() {
            if counted & (1 << a) == 0 {
                let (w, k_sum) = win.sums(map, steps, weights, centre.wrapping_add(ra));
                score += gain(prior_lambda + k_sum, w);
            }
        }
    }
    Ok(score)
}

/// [`voxel_gain`], once in the code for both paths of [`view_score`] (flash on a microcontroller).
#[inline(never)]
fn gain(lambda: f32, w: f32) -> f32 {
    voxel_gain(lambda, w)
}

#[cfg(feature = "wide-view-score")]
/// [`view_score`] for filters wider than f = 3: per hit and offset, binary searches over the hits (stopping
/// at the first earlier hit that already counted the target) and one [`gathered_count`] per target.
fn generic<const D: usize, const CAP: usize, M: ObsLookup<D> + ?Sized>(
    lut: &KernelLut<CAP>,
    map: &M,
    prior_lambda: f32,
    hits: &[(VoxelKey, f32)],
) -> Result<f32, ScoreError> {
    let offsets = lut.offsets();
    let weights = lut.weights(0);
    let mut score = 0.0;
    for (i, &(hit, _)) in hits.iter().enumerate() {
        let earlier = hits.get(..i).unwrap_or(&[]);
        for &o in offsets {
            let target = hit.offset(o);
            let counted = offsets.iter().any(|&p| {
                let source = target.offset(p);
                source < hit && count_at(earlier, source) > 0.0
            });
            if counted {
                continue;
            }
            let mut w = 0.0;
            for (&p, &k) in offsets.iter().zip(weights) {
                let n = count_at(hits, target.offset(p));
                if n > 0.0 {
                    w += k * n;
                }
            }
            let lambda = prior_lambda
                + gathered_count(lut, map, target).map_err(|_| ScoreError::SubVoxelKernel)?;
            score += gain(lambda, w);
        }
    }
    Ok(score)
}

/// The score as the module docs define it, straight from the definition (every target's whole
/// neighbourhood searched from every hit that reaches it): the reference [`view_score`] is tested against.
#[cfg(test)]
fn view_score_brute<const D: usize, const CAP: usize, M: ObsLookup<D> + ?Sized>(
    lut: &KernelLut<CAP>,
    map: &M,
    prior_lambda: f32,
    hits: &[(VoxelKey, f32)],
) -> Result<f32, ScoreError> {
    if !lut.is_voxel_offset() {
        return Err(ScoreError::SubVoxelKernel);
    }
    if hits.windows(2).any(|p| p[0].0 >= p[1].0) {
        return Err(ScoreError::UnsortedHits);
    }
    let offsets = lut.offsets();
    let weights = lut.weights(0);
    let mut score = 0.0;
    for (i, &(hit, _)) in hits.iter().enumerate() {
        for &o in offsets {
            let target = hit.offset(o);
            // The hits reaching `target` are target + o′ (the kernel is symmetric); count the target from
            // the first of them only.
            let mut w = 0.0;
            let mut first = true;
            for (&p, &k) in offsets.iter().zip(weights) {
                let source = target.offset(p);
                let n = count_at(hits, source);
                if n > 0.0 {
                    first &= source >= hits[i].0;
                    w += k * n;
                }
            }
            if first {
                let lambda = prior_lambda
                    + gathered_count(lut, map, target).map_err(|_| ScoreError::SubVoxelKernel)?;
                score += voxel_gain(lambda, w);
            }
        }
    }
    Ok(score)
}

#[cfg(test)]
mod tests {
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
        // A small LCG: the same cases every run.
        let mut state = 0x2545_f491_u32;
        let mut next = move |m: u32| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) % m
        };
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
        let mut state = 0x9e37_79b9_u32;
        let mut next = move |m: u32| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) % m
        };
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
}
