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
    // About 1 or more, a normal number, for finite w and λ; an infinite one makes it NaN or ∞. Every
    // factor is positive, so the ratio's bits order as it does: below ∞'s bits is finite (an integer
    // compare on the bits `log2_normal` reads anyway, shorter on the device than a float one).
    if ratio.to_bits() >= f32::INFINITY.to_bits() {
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
#[non_exhaustive]
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

#[cfg(feature = "wide-view-score")]
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
    if !lut.is_voxel_offset() {
        return Err(ScoreError::SubVoxelKernel);
    }
    let offsets = lut.offsets();
    // f ≤ 3: every offset within ±1, at most 27 of them.
    if lut.reach() > 1 || offsets.len() > MAX_TARGETS {
        #[cfg(feature = "wide-view-score")]
        return check(lut, hits).and_then(|()| generic(lut, map, prior_lambda, hits));
        #[cfg(not(feature = "wide-view-score"))]
        return Err(ScoreError::WideFilter);
    }
    let weights = lut.weights(0);
    // Each offset as a step between slots of the window, beside its weight; and bit a of reaches[q]: the
    // voxel at x-major position q around a hit is a source of its target a. (`black_box`: an opaque call
    // in a loop keeps LLVM from unrolling it, which on Cortex-M would spend flash on a once-per-view
    // setup.)
    // (u32, not u16: no padding, so the array starts as one memclr, not 27 pairs of stores: flash.)
    let mut kernel = [(0u32, 0.0f32); MAX_TARGETS];
    let mut reaches = [0u32; 128];
    for (a, ((t, oa), &k)) in kernel.iter_mut().zip(offsets).zip(weights).enumerate() {
        *t = (u32::from(window::step(*oa)), k);
        for op in offsets {
            core::hint::black_box(());
            let d = |i: usize| i32::from(oa[i]) + i32::from(op[i]);
            reaches[window::x_major(d(0), d(1), d(2)) & 127] |= 1 << a;
        }
    }
    // (Weights as many as offsets: the table's; none would score nothing, as zero weights would.)
    let kernel = kernel
        .get(..offsets.len().min(weights.len()))
        .unwrap_or(&[]);
    let mut win = Window::new();
    let mut score = 0.0;
    for (i, &(hit, _)) in hits.iter().enumerate() {
        // Sorted without repeats (checked here, not in a pass of its own: flash).
        if i > 0 && hits[i - 1].0 >= hit {
            return Err(ScoreError::UnsortedHits);
        }
        win.move_to(hits, hit);
        // Targets an earlier hit reaches were counted from it.
        let mut counted = 0u32;
        win.earlier(|q| counted |= reaches[q & 127]);
        let centre = win.centre_slot();
        for (a, &(ra, _)) in kernel.iter().enumerate() {
            if counted & (1 << a) == 0 {
                let (w, k_sum) = win.sums(map, kernel, centre.wrapping_add(ra as u16));
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
mod tests;
