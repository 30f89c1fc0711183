//! What a hot voxel observed from int8 features, in exact integers: the point count n and per dimension Σc
//! and Σc² of the codes. Why its own module: it is the per-point work of an int8 point (one integer add and
//! one multiply-add per dimension), and how the sums lie in memory depends on the target — plain arrays,
//! or on a Cortex-M4/M7 the lanes its DSP instructions update (`dsp.rs`); readers see the same values
//! through [`CodeSums::dims`] either way.

use super::ObsStats;

/// Largest int8 feature code magnitude: codes are −127..=127 (−128 is refused, so the code range is
/// symmetric and a code's negation is a code).
pub const CODE_MAX: i8 = 127;

/// Points one [`CodeSums`] may hold: up to it, n·Σc² and (Σc)² stay below 2³¹ (255² · 127² · 255 <
/// 1.1·10⁹), so the scatter's numerator is formed in i32 — no 64-bit arithmetic, which a Cortex-M0 or an
/// RV32 does in library calls — and |Σc| ≤ 32,385 fits 16 bits (the 16-bit lanes of `src/obs/dsp.rs`). A voxel
/// observed longer cools (one merge per 255 points).
pub const CODE_SUMS_MAX_COUNT: u32 = 255;

/// What was observed in one voxel from int8 features (y = scale · c), in exact integers: the point count n
/// and per dimension Σc and Σc² of the codes ([`Self::sum`], [`Self::square`], [`Self::dims`]).
///
/// Why integers: an accelerator hands the map int8 codes, and a microcontroller without an FPU adds an
/// integer in one instruction where a float costs a library call. Integer sums are exact, so the raw form
/// S = Σc² − (Σc)²/n cannot cancel (the failure of raw f32 sums that [`ObsStats`] avoids with Welford's
/// update): it is formed once, exactly, when the sums are turned into [`ObsStats`] ([`Self::to_obs`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CodeSums<const D: usize> {
    /// n: points added (at most [`CODE_SUMS_MAX_COUNT`]).
    pub count: u32,
    store: Store<D>,
}

#[cfg(latentbki_dsp)]
use super::dsp::Lanes as Store;

/// Σc and Σc² as two arrays (targets without the DSP instructions).
#[cfg(not(latentbki_dsp))]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Store<const D: usize> {
    sum: [i32; D],
    squares: [u32; D],
}

#[cfg(not(latentbki_dsp))]
impl<const D: usize> Store<D> {
    const EMPTY: Self = Self {
        sum: [0; D],
        squares: [0; D],
    };

    /// Add one point's codes: two integer additions and a multiply per dimension. Returns whether every
    /// code is in range, as the DSP store does; here the caller has checked ([`CodeSums::add_checked`]).
    #[inline]
    fn add(&mut self, codes: &[i8; D]) -> bool {
        // Wrapping only so that no overflow check is linked: with n ≤ 255 nothing can wrap. Two dimensions
        // at a time, each pair of sums read and written together (`ldm`/`stm` on v6-M).
        let mut sums = self.sum.chunks_exact_mut(2);
        let mut squares = self.squares.chunks_exact_mut(2);
        let mut pairs = codes.chunks_exact(2);
        for ((s, q), c) in (&mut sums).zip(&mut squares).zip(&mut pairs) {
            if let ([s0, s1], [q0, q1], &[c0, c1]) = (s, q, c) {
                let (c0, c1) = (i32::from(c0), i32::from(c1));
                let (a0, a1) = (*s0, *s1);
                (*s0, *s1) = (a0.wrapping_add(c0), a1.wrapping_add(c1));
                let (b0, b1) = (*q0, *q1);
                (*q0, *q1) = (
                    b0.wrapping_add(c0.wrapping_mul(c0) as u32),
                    b1.wrapping_add(c1.wrapping_mul(c1) as u32),
                );
            }
        }
        let rest = sums
            .into_remainder()
            .iter_mut()
            .zip(squares.into_remainder());
        for ((s, q), &c) in rest.zip(pairs.remainder()) {
            let c = i32::from(c);
            *s = s.wrapping_add(c);
            *q = q.wrapping_add(c.wrapping_mul(c) as u32);
        }
        true
    }

    /// One point's codes as the sums of a set of one (what [`Self::add`] gives an empty store), written
    /// over whatever the store held: no clearing first, no reading.
    #[cfg(feature = "sparse-cooling")]
    #[inline]
    fn set(&mut self, codes: &[i8; D]) {
        for ((s, q), &c) in self.sum.iter_mut().zip(&mut self.squares).zip(codes) {
            let c = i32::from(c);
            *s = c;
            *q = c.wrapping_mul(c) as u32;
        }
    }

    #[inline]
    fn sum(&self, i: usize) -> i32 {
        self.sum.get(i).copied().unwrap_or(0)
    }

    #[inline]
    fn square(&self, i: usize) -> u32 {
        self.squares.get(i).copied().unwrap_or(0)
    }

    #[inline]
    fn dims(&self) -> impl Iterator<Item = (i32, u32)> + '_ {
        self.sum.iter().copied().zip(self.squares.iter().copied())
    }

    #[inline(always)]
    fn for_each_dim(&self, mut f: impl FnMut(usize, i32, u32)) {
        for (i, (&s, &q)) in self.sum.iter().zip(&self.squares).enumerate() {
            f(i, s, q);
        }
    }
}

impl<const D: usize> CodeSums<D> {
    /// No point.
    pub const EMPTY: Self = Self {
        count: 0,
        store: Store::EMPTY,
    };

    /// Whether it can take another point ([`CODE_SUMS_MAX_COUNT`]).
    #[inline]
    pub fn is_full(&self) -> bool {
        self.count >= CODE_SUMS_MAX_COUNT
    }

    /// Add one point's codes (callers check [`code_in_range`](super::code_in_range) and [`Self::is_full`]): an integer addition
    /// and a multiply-add per dimension. The first point (count 0) is written over whatever the sums
    /// held: a set of count 0 holds nothing whatever its sums say ([`Self::clear`]).
    #[inline]
    pub fn add(&mut self, codes: &[i8; D]) {
        #[cfg(any(latentbki_dsp, feature = "sparse-cooling"))]
        if self.count == 0 {
            self.store.set(codes);
            self.count = 1;
            return;
        }
        self.count = self.count.wrapping_add(1);
        #[cfg(latentbki_dsp)]
        let _checked_by_the_caller = self.store.add_outlined(codes);
        #[cfg(not(latentbki_dsp))]
        let _checked_by_the_caller = self.store.add(codes);
    }

    /// Hold nothing, in place: by the count alone where the first point is written over the sums
    /// ([`Self::add`]; every reader goes by the count: [`Self::to_obs`] of none is empty, merges of none
    /// change nothing), so a hot entry reused for another voxel is not cleared first (a 384–512-byte
    /// `memclr` per new hot voxel: ≈ 300 instructions on a Cortex-M4F). A minimal build without the DSP
    /// store (`default-features = false`: riscv32imac's has no flash for the writing loop) zeroes them.
    #[inline]
    pub fn clear(&mut self) {
        #[cfg(any(latentbki_dsp, feature = "sparse-cooling"))]
        {
            self.count = 0;
        }
        #[cfg(not(any(latentbki_dsp, feature = "sparse-cooling")))]
        {
            *self = Self::EMPTY;
        }
    }

    /// Add one point's codes if every one is in range ([`code_in_range`](super::code_in_range); callers check
    /// [`Self::is_full`]); `false`, and nothing changed, if one is not. On a Cortex-M4/M7 the check rides
    /// on the additions' loads (`src/obs/dsp.rs`); elsewhere it runs first.
    #[inline(always)]
    pub fn add_checked(&mut self, codes: &[i8; D]) -> bool {
        if self.count == 0 {
            // The first point (never the map's per-point path: a voxel's first point takes its general
            // path): the stale sums zeroed, then checked and added as any point.
            self.store = Store::EMPTY;
        }
        #[cfg(not(latentbki_dsp))]
        if !super::code_in_range(codes) {
            return false;
        }
        if !self.store.add(codes) {
            #[cfg(latentbki_dsp)]
            self.store.undo(codes);
            return false;
        }
        self.count = self.count.wrapping_add(1);
        true
    }

    /// Σc of dimension `i` (0 beyond `D`).
    #[inline]
    pub fn sum(&self, i: usize) -> i32 {
        self.store.sum(i)
    }

    /// Σc² of dimension `i` (0 beyond `D`).
    #[inline]
    pub fn square(&self, i: usize) -> u32 {
        self.store.square(i)
    }

    /// `f(i, Σc, Σc²)` for every dimension i, in order: [`Self::dims`] as a loop, which reads a DSP
    /// block's words once for its four dimensions (the iterator's state costs the M4F's cooling ≈ 20
    /// instructions a point).
    #[inline(always)]
    pub fn for_each_dim(&self, f: impl FnMut(usize, i32, u32)) {
        self.store.for_each_dim(f)
    }

    /// (Σc, Σc²) of every dimension, in order.
    #[inline]
    pub fn dims(&self) -> impl Iterator<Item = (i32, u32)> + '_ {
        self.store.dims()
    }

    /// The same observations as f32 statistics of y = scale · c: m = scale · Σc / n,
    /// S = scale² · (n Σc² − (Σc)²) / n with the numerator exact in i32 (rounded once to f32).
    pub fn to_obs(&self, scale: f32) -> ObsStats<D> {
        let mut out = ObsStats::EMPTY;
        self.write_obs(scale, &mut out);
        out
    }

    /// [`Self::to_obs`] into existing statistics (no 516-byte temporary on the device stack).
    pub fn write_obs(&self, scale: f32, out: &mut ObsStats<D>) {
        if self.count == 0 {
            *out = ObsStats::EMPTY;
            return;
        }
        let n = self.count as f32;
        let inv_n = 1.0 / n;
        let scale2_over_n = scale * scale * inv_n;
        out.count = n;
        self.for_each_dim(|i, sum, sq| {
            if let (Some(m), Some(s)) = (out.mean.get_mut(i), out.scatter.get_mut(i)) {
                *m = scale * (sum as f32 * inv_n);
                *s = scatter_numerator(self.count, sum, sq) as f32 * scale2_over_n;
            }
        });
    }
}

/// n·Σc² − (Σc)² = n·S in code units, exact: with n ≤ [`CODE_SUMS_MAX_COUNT`] both terms are below 2³¹
/// (wrapping arithmetic only so that no overflow check is linked; it cannot wrap). Never negative.
#[inline(always)]
pub(crate) fn scatter_numerator(n: u32, sum: i32, squares: u32) -> u32 {
    n.wrapping_mul(squares)
        .wrapping_sub(sum.wrapping_mul(sum) as u32)
}

#[cfg(test)]
mod tests {
    use super::super::code_in_range;
    use super::*;

    /// Codes of a small xorshift generator, −128 included.
    fn codes<const D: usize>(state: &mut u32) -> [i8; D] {
        core::array::from_fn(|_| {
            *state ^= *state << 13;
            *state ^= *state >> 17;
            *state ^= *state << 5;
            (*state >> 24) as u8 as i8
        })
    }

    /// The sums against their definition (i64 sums of the codes, in order), after every point, checked
    /// and unchecked, for a size the DSP lanes cover in whole blocks and one they do not.
    fn sums_equal_the_definition<const D: usize>() {
        let mut state = 0x9E37_79B9;
        let mut sums = CodeSums::<D>::EMPTY;
        let mut want = ([0i64; D], [0i64; D]);
        let mut taken = 0;
        for p in 0..CODE_SUMS_MAX_COUNT * 2 {
            let mut c = codes::<D>(&mut state);
            // Mostly in range; every fifth point keeps its −128s (if it drew any).
            if p % 5 != 0 {
                c = c.map(|v| v.max(-CODE_MAX));
            }
            let ok = code_in_range(&c);
            let before = sums;
            if p % 3 == 0 {
                if !ok {
                    continue; // `add` is for checked codes
                }
                sums.add(&c);
            } else {
                assert_eq!(sums.add_checked(&c), ok);
                if !ok {
                    assert_eq!(sums, before, "a refused point changed the sums");
                    continue;
                }
            }
            for (i, &v) in c.iter().enumerate() {
                want.0[i] += i64::from(v);
                want.1[i] += i64::from(v) * i64::from(v);
            }
            taken += 1;
            assert_eq!(sums.count, taken);
            for i in 0..D {
                assert_eq!(i64::from(sums.sum(i)), want.0[i], "Σc, dimension {i}");
                assert_eq!(i64::from(sums.square(i)), want.1[i], "Σc², dimension {i}");
            }
            let dims: ([i64; D], [i64; D]) = (
                core::array::from_fn(|i| i64::from(sums.dims().nth(i).unwrap().0)),
                core::array::from_fn(|i| i64::from(sums.dims().nth(i).unwrap().1)),
            );
            assert_eq!(dims, want);
            assert_eq!(sums.dims().count(), D);
            if sums.is_full() {
                break;
            }
        }
        assert!(
            sums.is_full(),
            "the test never filled the sums ({taken} points)"
        );
        assert_eq!((sums.sum(D), sums.square(D)), (0, 0));
    }

    #[test]
    fn sums_are_the_codes_sums() {
        sums_equal_the_definition::<64>();
        sums_equal_the_definition::<7>();
    }

    /// Sums cleared by their count and used again hold what fresh sums hold after the same points (the
    /// first point written over the stale sums), by `add` and by `add_checked`; an out-of-range first
    /// point is refused and leaves the sums empty.
    #[test]
    fn cleared_sums_forget_their_old_points() {
        const D: usize = 9;
        let mut state = 77u32;
        let mut reused = CodeSums::<D>::EMPTY;
        for round in 0..40 {
            for _ in 0..(round % 5 + 3) {
                let c = codes::<D>(&mut state).map(|c| c.max(-127));
                reused.add(&c);
            }
            reused.clear();
            assert_eq!(reused.count, 0);
            if round % 2 == 1 {
                assert!(!reused.add_checked(&[i8::MIN; D]));
                assert_eq!(reused.count, 0, "a refused first point leaves nothing");
            }
            // The definition: Σc and Σc² of the new points alone.
            let mut want = [(0i32, 0u32); D];
            let n = round % 4 + 1;
            for p in 0..n {
                let c = codes::<D>(&mut state).map(|c| c.max(-127));
                for (w, &c) in want.iter_mut().zip(&c) {
                    let c = i32::from(c);
                    *w = (w.0 + c, w.1 + (c * c) as u32);
                }
                if (round / 2 + p) % 2 == 0 {
                    reused.add(&c);
                } else {
                    assert!(reused.add_checked(&c));
                }
            }
            assert_eq!(reused.count, n);
            let got: [(i32, u32); D] = core::array::from_fn(|i| (reused.sum(i), reused.square(i)));
            assert_eq!(got, want, "round {round}");
        }
    }

    #[test]
    fn extreme_codes_fill_without_wrapping() {
        for v in [CODE_MAX, -CODE_MAX] {
            let mut sums = CodeSums::<8>::EMPTY;
            while !sums.is_full() {
                assert!(sums.add_checked(&[v; 8]));
            }
            let n = CODE_SUMS_MAX_COUNT as i32;
            assert_eq!(sums.sum(3), n * i32::from(v));
            assert_eq!(sums.square(5), (n * 127 * 127) as u32);
            assert_eq!(
                scatter_numerator(sums.count, sums.sum(0), sums.square(0)),
                0
            );
            let obs = sums.to_obs(0.5);
            assert!((obs.mean[7] - 0.5 * f32::from(v)).abs() < 1e-4);
            assert_eq!(obs.scatter[7], 0.0);
        }
    }
}
