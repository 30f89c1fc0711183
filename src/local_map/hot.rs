//! The hot tier: the `H` voxels being observed now accumulate points in f32 (one Welford step per point,
//! no decoding). A voxel is quantized only when it cools — when another voxel needs its entry — so it is
//! re-encoded once per visit, not once per point or batch.

use super::{positive, Hot, LocalMap, CHANGED, REFERENCED};
use crate::forget::bring_forward;
use crate::forget::MapClock;
use crate::key::VoxelKey;
use crate::obs::{CodeSums, ObsStats, CODE_SUMS_MAX_COUNT};
use crate::quant::Cooling;

/// A hot voxel's new points: f32 features by Welford's update, int8 codes as exact integer sums (the
/// first point decides; a point of the other kind turns the sums into f32 statistics first).
#[derive(Clone, Copy, Debug)]
pub(super) enum Acc<const D: usize> {
    Float(ObsStats<D>),
    Codes(CodeSums<D>),
}

impl<const D: usize> Acc<D> {
    /// Points accumulated.
    pub(super) fn points(&self) -> f32 {
        f32::from_bits(self.points_bits())
    }

    /// The bits of [`Self::points`], in integer operations alone: what the link compares to tell a changed
    /// hot voxel (once per cooling; on an MCU without an FPU the f32 conversion and compare were two
    /// soft-float calls there: 6,788 `__aeabi_ui2f` + 6,788 `__aeabi_fcmpeq` in thumbv6m's ToF profile,
    /// none now). Bits compare as the f32 counts do: a count is never NaN or −0.
    #[inline]
    pub(super) fn points_bits(&self) -> u32 {
        match self {
            Self::Float(o) => o.count.to_bits(),
            Self::Codes(c) => exact_f32_bits(c.count),
        }
    }

    /// Add an f32 feature.
    #[inline]
    pub(super) fn add_f32(&mut self, y: &[f32; D], scale: f32) {
        match self {
            // What `clear` left is stale beyond the count: overwritten, not read.
            Self::Float(o) if o.is_empty() => o.set_point(y),
            Self::Float(o) => o.add_point(y),
            Self::Codes(_) => {
                self.make_float(scale);
                if let Self::Float(o) = self {
                    o.add_point(y);
                }
            }
        }
    }

    /// Add int8 codes of scale `scale` (checked by the caller).
    #[inline]
    pub(super) fn add_codes(&mut self, codes: &[i8; D], scale: f32) {
        match self {
            Self::Codes(c) if !c.is_full() => c.add(codes),
            Self::Float(o) if o.is_empty() => {
                let mut c = CodeSums::EMPTY;
                c.add(codes);
                *self = Self::Codes(c);
            }
            _ => {
                // f32 statistics (the voxel took an f32 feature first), or full sums (callers restart
                // those first): continue in f32.
                self.make_float(scale);
                if let Self::Float(o) = self {
                    o.add_point(&codes.map(|c| f32::from(c) * scale));
                }
            }
        }
    }

    /// Hold nothing, for the voxel's next visit, in place, by the count alone: every reader goes by it (an
    /// empty set is merged, decayed and cooled as nothing) and the first point overwrites the rest — the
    /// int8 sums' ([`CodeSums::clear`], [`CodeSums::add`]) as the f32 statistics' ([`ObsStats::set_point`]).
    /// (The sums were zeroed here, a `memclr` per new hot voxel; written over instead, with the DSP's
    /// `set_blocks` on the M4F: `boards/profile-scenario.sh 7`, int8 ToF, 34.00 → 32.16 M instructions;
    /// `4`, int8 depth frames, 17.87 → 17.65 M.)
    pub(super) fn clear(&mut self) {
        match self {
            Self::Codes(c) => c.clear(),
            Self::Float(o) => o.count = 0.0,
        }
    }

    /// Turn integer sums into f32 statistics. Out of line: rare (a voxel that takes both kinds, or fades),
    /// and each inlined copy kept a 516-byte temporary in its caller's frame (the forgetting build's stack
    /// went over 8 KiB by 80 B with one copy more).
    #[inline(never)]
    pub(super) fn make_float(&mut self, scale: f32) {
        if let Self::Codes(c) = self {
            *self = Self::Float(c.to_obs(scale));
        }
    }

    /// Merge what it holds into `obs`.
    #[inline]
    pub(super) fn merge_into(&self, obs: &mut ObsStats<D>, scale: f32) {
        match self {
            Self::Float(o) => obs.merge(o),
            Self::Codes(c) => obs.merge_codes(c, scale),
        }
    }

    /// Whether it holds nothing.
    pub(super) fn is_empty(&self) -> bool {
        match self {
            Self::Float(o) => !positive(o.count), // `o.is_empty()` without a float compare
            Self::Codes(c) => c.count == 0,
        }
    }
}

/// The bits of `n as f32` for `n` < 2⁹ — int8 sums hold at most [`CODE_SUMS_MAX_COUNT`] points — by integer
/// operations alone: n·2¹⁵ shifted up until its top bit is the f32's implicit one (at most 8 steps; no
/// `leading_zeros`, which thumbv6m and riscv32imac lack, and whose inline form cost riscv32imac's minimal
/// build 100 B of flash it does not have).
#[inline]
fn exact_f32_bits(n: u32) -> u32 {
    const _: () = assert!(CODE_SUMS_MAX_COUNT < 1 << 9);
    if n == 0 {
        return 0;
    }
    // m · 2^(e − 150), e the biased exponent, until 2²³ ≤ m < 2²⁴.
    let (mut m, mut e) = (n << 15, 135u32);
    while m < 1 << 23 {
        m <<= 1;
        e -= 1;
    }
    (e << 23) | (m & 0x7F_FFFF)
}

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    /// Merge hot entry `h` into its slot's codes (one decode, one exact merge, one encode) and mark the slot
    /// cold. The entry itself is left for the caller to reuse or remove.
    pub(super) fn cool(&mut self, h: usize) {
        let fixed = self.cooling() == Cooling::Fixed;
        let fine = !self.mean_weights().is_ones(); // the weights' grid (`reencode_fine`) for the fixed cooling too
        let Some(hot) = self.hot.get(h) else { return };
        let s = usize::from(hot.slot);
        let Some(slot) = self.slots.get_mut(s) else {
            return;
        };
        // Forgetting: the codes are as of their stamp, the hot statistics as of theirs (never earlier), so
        // the codes fade to the hot stamp before the exact merge ([`crate::forget::Stamped::merge`]).
        let older = self.clock.forgetting().is_some() && slot.stamp != hot.stamp;
        let weighed = self.mean_weights.has_shifts();
        match (&hot.acc, positive(slot.codes.count)) {
            // A first visit of f32 points: its codes are its hot statistics (no decode, no merge), unless
            // the mean is weighed first (below); on the weights' grid.
            // One point in a map that never forgets (no decay): its scatter is 0 (`set_point`), so no scatter
            // pass (a sparse sensor's usual cooling).
            (Acc::Float(o), false) if !weighed && !o.is_empty() => {
                // Not on an MCU without an FPU: its f32 cooling is soft float whatever, and flash is short.
                if crate::quant::HAS_FPU && o.count == 1.0 && self.clock.forgetting().is_none() {
                    self.mean_weights
                        .reencode_unscattered(&mut slot.codes, o, &mut self.dither)
                } else {
                    self.mean_weights
                        .reencode(&mut slot.codes, o, &mut self.dither)
                }
            }
            // A first visit of one int8 point where an FPU makes the f32 cooling fast (a sparse sensor's
            // usual cooling with int8 features): its mean straight from its codes, no merge, no scatter
            // pass (`QuantVoxel::encode_lone_codes_here`, the same codes bit for bit).
            #[cfg(all(feature = "sparse-cooling", not(latentbki_soft_float)))]
            (Acc::Codes(c), false) if !fixed && !weighed && c.count == 1 => {
                slot.codes.encode_lone_codes_here(
                    fine,
                    c,
                    self.int8_scale,
                    &mut self.scratch,
                    &mut self.dither,
                )
            }
            // int8 sums merge into the codes in fixed point where the map cools so (no FPU): no float
            // operation. Otherwise (or when the codes must fade first) they merge in f32 below.
            (Acc::Codes(c), _) if fixed && !older => {
                slot.codes
                    .merge_codes_fixed_here(c, &self.int8_fix, fine, &mut self.dither)
            }
            // A revisit of f32 points where an FPU makes the f32 cooling fast: decode, merge and the
            // encoder's maxima in one pass (`QuantVoxel::merge_here`, the same codes bit for bit). Left
            // out by `cfg` without an FPU (build.rs), not by `HAS_FPU`: even dead, the arm moved the
            // inliner's choices in this function and cost riscv32imac's minimal build 180 B of flash it
            // does not have. A sparse sensor's short path (feature `sparse-cooling`, ≈ 2 KB).
            #[cfg(all(feature = "sparse-cooling", not(latentbki_soft_float)))]
            (Acc::Float(o), true) if !older && !weighed => {
                slot.codes
                    .merge_here(fine, o, &mut self.scratch, &mut self.dither)
            }
            (acc, seen) if !acc.is_empty() => {
                if seen {
                    slot.codes.decode_into(&mut self.scratch);
                    bring_forward(&self.clock, &mut self.scratch, slot.stamp, hot.stamp);
                    self.mean_weights.apply(&mut self.scratch.mean, false);
                } else {
                    self.scratch = ObsStats::EMPTY;
                }
                acc.merge_into(&mut self.scratch, self.int8_scale);
                self.mean_weights.apply(&mut self.scratch.mean, true);
                self.mean_weights
                    .reencode(&mut slot.codes, &self.scratch, &mut self.dither);
            }
            _ => {}
        }
        if !hot.acc.is_empty() {
            slot.stamp = hot.stamp;
        }
        slot.hot = 0;
        slot.flags |= REFERENCED;
        if hot.acc.points_bits() != hot.live_sent {
            slot.flags |= CHANGED; // points the link has not streamed live yet
        }
        self.counters.cooled = self.counters.cooled.saturating_add(1);
        self.counters.slots_written = self.counters.slots_written.saturating_add(1);
    }

    /// Hot entry `h` holds as many int8 points as its sums can ([`crate::obs::CODE_SUMS_MAX_COUNT`]): merge
    /// them into the slot's codes and start afresh, the voxel staying hot.
    pub(super) fn restart_hot(&mut self, h: usize) {
        self.cool(h);
        let Some(e) = self.hot.get_mut(h) else { return };
        e.acc.clear();
        if let Some(slot) = self.slots.get_mut(usize::from(e.slot)) {
            slot.hot = h as u8 + 1;
        }
    }

    /// Whether hot entry `h` holds int8 sums that cannot take another point.
    #[inline]
    pub(super) fn hot_is_full(&self, h: usize) -> bool {
        matches!(self.hot.get(h), Some(Hot { acc: Acc::Codes(c), .. }) if c.is_full())
    }

    /// Drop hot entry `h` (its slot is being freed): the last entry moves into its place.
    pub(super) fn remove_hot(&mut self, h: usize) {
        let last = self.hot_len.saturating_sub(1);
        if h > last {
            return;
        }
        if h != last {
            let Some(&moved) = self.hot.get(last) else {
                return;
            };
            if let Some(e) = self.hot.get_mut(h) {
                *e = moved;
            }
            if let Some(slot) = self.slots.get_mut(usize::from(moved.slot)) {
                slot.hot = h as u8 + 1;
            }
        }
        self.hot_len = last;
        if self.last_hot >= self.hot_len {
            self.last_hot = 0;
        }
        if self.hot_hand >= self.hot_len {
            self.hot_hand = 0;
        }
    }

    /// A hot entry for slot `s` holding `key`: a free one, else the CLOCK choice among the hot, cooled.
    pub(super) fn make_hot(&mut self, s: usize, key: VoxelKey) -> usize {
        let h = if self.hot_len < H {
            self.hot_len += 1;
            self.hot_len - 1
        } else {
            let mut h = self.hot_hand;
            for _ in 0..2 * H + 1 {
                h = self.hot_hand;
                self.hot_hand = if h + 1 == H { 0 } else { h + 1 };
                match self.hot.get_mut(h) {
                    Some(e) if e.referenced => e.referenced = false,
                    _ => break,
                }
            }
            self.cool(h);
            h
        };
        let stamp = self.clock.now();
        if let Some(e) = self.hot.get_mut(h) {
            // Field by field: the entry's accumulator is cleared where it lies (see `Acc::clear`).
            e.acc.clear();
            e.key = key;
            e.slot = s as u16;
            e.referenced = true;
            e.live_sent = 0;
            e.stamp = stamp;
        }
        if let Some(slot) = self.slots.get_mut(s) {
            slot.hot = h as u8 + 1;
        }
        h
    }

    /// Whether hot entry `h` is as of the clock's tick ([`Self::hot_to_now`] would change nothing).
    #[cfg(latentbki_dsp)]
    #[inline(always)]
    pub(super) fn hot_is_now(&self, h: usize) -> bool {
        self.clock.forgetting().is_none()
            || self
                .hot
                .get(h)
                .is_some_and(|e| C::tick(e.stamp) == C::tick(self.clock.now()))
    }

    /// Bring hot entry `h` to the clock's tick before a point goes in (forgetting only; nothing in a map
    /// that never forgets): what it holds fades by its age, int8 sums turning into f32 statistics first
    /// (integer sums cannot be weighted). Once per voxel and tick, not per point.
    #[inline]
    pub(super) fn hot_to_now(&mut self, h: usize) {
        let Some(f) = self.clock.forgetting() else {
            return;
        };
        let now = self.clock.now();
        let scale = self.int8_scale;
        let Some(e) = self.hot.get_mut(h) else { return };
        let age = C::tick(now).saturating_sub(C::tick(e.stamp));
        if age == 0 {
            return;
        }
        if !e.acc.is_empty() {
            e.acc.make_float(scale);
            if let Acc::Float(o) = &mut e.acc {
                o.decay(f.factor(age));
            }
        }
        e.stamp = now;
    }
}

#[cfg(test)]
mod tests {
    use super::{exact_f32_bits, Acc};
    use crate::obs::{CodeSums, ObsStats};

    /// The integer conversion the link's change test uses is `n as f32` to the bit for every count int8
    /// sums can hold (and beyond); and `positive` is `> 0.0` on every non-NaN f32 a count could be.
    #[test]
    fn count_bits_are_the_float_ones() {
        for n in 0..1 << 9 {
            assert_eq!(exact_f32_bits(n), (n as f32).to_bits(), "{n}");
        }
        for x in [
            0.0f32,
            -0.0,
            1.0,
            0.5,
            1e-45,
            -1e-45,
            3.0e38,
            -7.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ] {
            assert_eq!(super::positive(x), x > 0.0, "{x}");
        }
        let mut c = Acc::<4>::Codes(CodeSums::EMPTY);
        for k in 0..200 {
            assert_eq!(c.points_bits(), (k as f32).to_bits());
            assert_eq!(c.points(), k as f32);
            c.add_codes(&[1, -2, 3, 127], 0.5);
        }
    }

    /// A reused f32 entry is reset by its count alone: its next points must give what a fresh entry gives
    /// (the stale mean and scatter never read), and an emptied one must merge and cool as nothing.
    #[test]
    fn a_cleared_entry_forgets_its_old_points() {
        const D: usize = 8;
        let y = |k: f32| core::array::from_fn::<f32, D, _>(|i| (i as f32 - 3.5) * k + 0.25 * k * k);
        let mut reused = Acc::<D>::Float(ObsStats::EMPTY);
        for k in [3.0, -7.5, 120.0] {
            reused.add_f32(&y(k), 1.0);
        }
        reused.clear();
        assert!(reused.is_empty() && reused.points() == 0.0);
        let mut merged = ObsStats::<D>::EMPTY;
        reused.merge_into(&mut merged, 1.0);
        assert_eq!(
            merged,
            ObsStats::EMPTY,
            "an emptied entry merges as nothing"
        );
        let mut fresh = Acc::<D>::Float(ObsStats::EMPTY);
        for k in [0.5, -2.0, 0.0, 9.0] {
            reused.add_f32(&y(k), 1.0);
            fresh.add_f32(&y(k), 1.0);
        }
        let (mut a, mut b) = (ObsStats::<D>::EMPTY, ObsStats::<D>::EMPTY);
        reused.merge_into(&mut a, 1.0);
        fresh.merge_into(&mut b, 1.0);
        assert_eq!(a, b);
        // The first point alone: what Welford's step makes of an empty set (n = 1, m = y, S = 0).
        let mut one = ObsStats::<D>::EMPTY;
        one.add_point(&y(-4.0));
        let mut set = ObsStats::<D> {
            count: 0.0,
            mean: [9.0; D],
            scatter: [5.0; D],
        };
        set.set_point(&y(-4.0));
        assert_eq!(set, one);
    }
}
