#[cfg(feature = "sparse-cooling")]
use super::sparse::SPARSE_MAX_NEW;
use super::*;
use crate::obs::ObsStats;

extern crate std;

const D: usize = 16;
const P: usize = super::super::packed_len(D);
const S: f32 = 0.0123;

struct Rng(u32);
impl Rng {
    fn next(&mut self) -> u32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 17;
        self.0 ^= self.0 << 5;
        self.0
    }
    /// Codes around a per-dimension offset.
    fn sums(&mut self, n: u32, offset: i32) -> CodeSums<D> {
        let mut c = CodeSums::EMPTY;
        for _ in 0..n {
            let codes: [i8; D] = core::array::from_fn(|d| {
                let spread = (self.next() % 41) as i32 - 20;
                (spread + offset + 5 * d as i32 - 40).clamp(-127, 127) as i8
            });
            c.add(&codes);
        }
        c
    }
}

/// The f32 cooling the fixed-point merges are held to: the codes decoded, merged with the sums (scale
/// [`S`]) and re-encoded on the grid (`fine`); returns the merged statistics and the codes.
fn float_cooling(
    old: &QuantVoxel<D, P>,
    sums: &CodeSums<D>,
    fine: bool,
    dither: &mut Dither,
) -> (ObsStats<D>, QuantVoxel<D, P>) {
    let mut want = old.decode();
    want.merge(&sums.to_obs(S));
    let float = if fine {
        old.reencode_fine(&want, dither)
    } else {
        old.reencode(&want, dither)
    };
    (want, float)
}

#[test]
fn the_reciprocal_table_is_the_division() {
    for k in 0..300u32 {
        assert_eq!(recip(k), u32::MAX / k.max(1), "{k}");
        if let Some(&r) = RECIPS.get(k as usize) {
            assert_eq!(r, u32::MAX / k.max(1), "{k}");
        }
    }
}

#[test]
fn the_halves_multiply_is_the_64_bit_product() {
    let mut rng = Rng(0x1357_9BDF);
    let edges = [0, 1, 0xFFFF, 0x1_0000, 0x8000_0000, u32::MAX - 1, u32::MAX];
    for &a in &edges {
        for &b in &edges {
            assert_eq!(mul32_halves(a, b), u64::from(a) * u64::from(b), "{a} {b}");
        }
    }
    for _ in 0..100_000 {
        let (a, b) = (rng.next(), rng.next());
        assert_eq!(mul32_halves(a, b), u64::from(a) * u64::from(b), "{a} {b}");
        let s = a as i32 / 2;
        assert_eq!(mul32s(s, b), i64::from(s) * i64::from(b));
    }
}

#[test]
fn the_32_bit_shift_and_leading_zeros_match_the_64_bit_ones() {
    let mut rng = Rng(0x2468_ACE0);
    for i in 0..100_000u32 {
        let p = (u64::from(rng.next()) << 32 | u64::from(rng.next())) >> (i % 64);
        for s in [0, 1, 17, 31, 32, 33, 47, 51, 63] {
            let want = (p >> s).min(u64::from(u32::MAX)) as u32;
            assert_eq!(shr_sat32(p, s), want, "{p} >> {s}");
        }
        let v = rng.next() >> (i % 33).min(31) >> u32::from(i % 33 == 32);
        assert_eq!(lz_halving(v), v.leading_zeros(), "{v}");
    }
    assert_eq!(lz_halving(0), 32);
}

#[test]
fn integer_helpers_match_f32() {
    for v in [1.0f32, 3.0, 255.0, 1000.0, 16_777_215.0] {
        assert_eq!(count_of(v.to_bits()), v as u32);
        assert_eq!(f32_bits(v as u32, 0), v.to_bits());
    }
    assert_eq!(count_of(0.0f32.to_bits()), 0);
    assert_eq!(f32_bits(0, 5), 0);
    assert_eq!(f32_bits(3, -2), 0.75f32.to_bits());
    assert_eq!(f32_bits(1, 200), f32::MAX.to_bits());
    assert_eq!(shift(5, -1), 3);
    assert_eq!(shift(1, 70), 1 << 30);
    let fix = Int8Fix::new(S);
    // σ = 0.5 (an f16 exactly) is 0.5/S steps.
    let steps = fix.steps_of(f16::from_f32(0.5));
    let want = 0.5 / S * (1 << MEAN_FRAC) as f32;
    assert!((steps as f32 - want).abs() <= 1.0, "{steps} vs {want}");
}

/// The fixed-point cooling gives what the f32 path gives, to the last code step's rounding: first visits
/// and merges into codes of earlier visits, many voxels.
#[test]
fn fixed_cooling_matches_the_f32_path() {
    // Both grids: `reencode`'s and the weighed map's finer one (`reencode_fine`).
    for fine in [false, true] {
        fixed_cooling_matches_the_f32_path_on(fine);
    }
}

fn fixed_cooling_matches_the_f32_path_on(fine: bool) {
    let fix = Int8Fix::new(S);
    let mut rng = Rng(0x2468_ACE1);
    let (mut df, mut dx) = (Dither::new(9), Dither::new(9));
    let (mut worst_mu, mut worst_psi) = (0.0f32, 0.0f32);
    for trial in 0..400 {
        let old_n = [0, 1, 3, 40, 1000][trial % 5];
        let offset = (rng.next() % 120) as i32 - 60;
        let old_obs = if old_n == 0 {
            ObsStats::EMPTY
        } else {
            rng.sums(old_n.min(255), offset).to_obs(S)
        };
        let mut old_obs = old_obs;
        old_obs.count = old_n as f32;
        let old = if fine {
            QuantVoxel::<D, P>::EMPTY.reencode_fine(&old_obs, &mut Dither::new(3))
        } else {
            QuantVoxel::<D, P>::encode(&old_obs, &mut Dither::new(3))
        };
        let (n1, shift_by) = (1 + rng.next() % 255, (rng.next() % 21) as i32 - 10);
        let sums = rng.sums(n1, offset + shift_by);

        let (want, float) = float_cooling(&old, &sums, fine, &mut df);
        let float_scale = float.mu_scale;
        let float = float.decode();
        let fixed = old.merge_codes_fixed(&sums, &fix, fine, &mut dx);
        // The same grid: the same scale kept or chosen (or the next f16 up, from the rounding of max|m|).
        let up = fixed.mu_scale.to_bits().abs_diff(float_scale.to_bits());
        assert!(
            up <= 1,
            "trial {trial} (fine {fine}): scale {} vs {}",
            fixed.mu_scale,
            float_scale
        );
        let fixed = fixed.decode();

        assert_eq!(fixed.count, float.count, "trial {trial}");
        let headroom = if fine {
            super::super::FINE_HEADROOM
        } else {
            1.25
        };
        let step = want.mean.iter().fold(0.0f32, |a, m| a.max(m.abs())) * headroom / 63.0;
        for d in 0..D {
            // Each within ~one code step of the exact merge (stochastic rounding lands on a neighbour).
            let e = (fixed.mean[d] - want.mean[d]).abs() / step;
            worst_mu = worst_mu.max(e);
            assert!(
                e <= 1.3,
                "trial {trial} mean[{d}]: {} vs {}",
                fixed.mean[d],
                want.mean[d]
            );
            if want.scatter[d] > want.scatter.iter().fold(0.0f32, |a, &b| a.max(b)) * 1e-2 {
                let r = fixed.scatter[d] / want.scatter[d];
                worst_psi = worst_psi.max((r - 1.0).abs());
                // Within one scatter code step (the widest: mantissa 1 → 1 + 2^−L), with a little slack.
                let wide = 1.0 + 1.0 / (1u32 << super::super::PSI_STEPS_LOG2) as f32;
                assert!(
                    r > 0.975 / wide && r < 1.025 * wide,
                    "trial {trial} scatter[{d}]: {r}"
                );
            }
        }
    }
    std::println!(
        "fine grid {fine}: worst mean error {worst_mu:.2} steps, worst scatter ratio off by {worst_psi:.2}"
    );
}

/// A voxel cooled hundreds of times (a few points per visit) keeps its mean and scatter no worse than the
/// f32 path: no drift from the integer rounding.
#[test]
fn many_coolings_do_not_drift() {
    let fix = Int8Fix::new(S);
    let mut rng = Rng(77);
    let mut dither = Dither::new(5);
    let mut code = QuantVoxel::<D, P>::EMPTY;
    let mut truth = ObsStats::<D>::EMPTY;
    let mut float = QuantVoxel::<D, P>::EMPTY;
    for _ in 0..600 {
        let n1 = 1 + rng.next() % 4;
        let sums = rng.sums(n1, 30);
        truth.merge(&sums.to_obs(S));
        code = code.merge_codes_fixed(&sums, &fix, false, &mut dither);
        let mut f = float.decode();
        f.merge(&sums.to_obs(S));
        float = float.reencode(&f, &mut dither);
    }
    let rel = |q: &QuantVoxel<D, P>| {
        let b = q.decode();
        let e: f32 = (0..D)
            .map(|d| (b.mean[d] - truth.mean[d]).powi(2))
            .sum::<f32>()
            .sqrt();
        e / truth.mean.iter().map(|m| m * m).sum::<f32>().sqrt()
    };
    std::println!(
        "after 600 coolings: mean error fixed {:.4}, f32 path {:.4}",
        rel(&code),
        rel(&float)
    );
    let back = code.decode();
    assert_eq!(back.count, truth.count);
    // Stochastic rounding at every cooling is a random walk of the stored mean (the f32 path's too): the
    // integer path walks no farther.
    let (fixed, in_f32) = (rel(&code), rel(&float));
    assert!(
        fixed <= (1.25 * in_f32).max(0.02),
        "mean drifted: {fixed} (f32 path {in_f32})"
    );
    // The scatter random-walks too (its codes are 19 % steps): RMS of ln(stored/exact) over the dimensions
    // no larger than the f32 path's, give or take.
    let fb = float.decode();
    let walk = |b: &ObsStats<D>| {
        let sq: f32 = (0..D)
            .map(|d| libm::logf(b.scatter[d] / truth.scatter[d]).powi(2))
            .sum();
        libm::sqrtf(sq / D as f32)
    };
    let (fixed, in_f32) = (walk(&back), walk(&fb));
    std::println!("scatter walk: fixed {fixed:.3}, f32 path {in_f32:.3}");
    assert!(
        fixed <= 1.5 * in_f32 + 0.05,
        "scatter drifted: {fixed} (f32 path {in_f32})"
    );
}

/// A first visit of one point (the lone-point step of the merge): count 1, scatter exactly 0, each mean
/// within one code step of the point's value and unbiased over the dither.
#[test]
fn a_lone_first_point_codes_its_value() {
    let fix = Int8Fix::new(S);
    let mut rng = Rng(0x0BAD_5EED);
    let mut dither = Dither::new(17);
    for trial in 0..60 {
        let offset = (rng.next() % 120) as i32 - 60;
        let sums = rng.sums(1, offset);
        let y = sums.to_obs(S);
        // 200 draws: the mean of a stochastic rounding has a spread ≤ 0.5/√200 ≈ 0.035 steps.
        let (mut sum, runs) = ([0.0f64; D], 200);
        let mut step = 0.0f32;
        for _ in 0..runs {
            let q = QuantVoxel::<D, P>::EMPTY.merge_codes_fixed(&sums, &fix, false, &mut dither);
            step = q.mu_scale.to_f32();
            let back = q.decode();
            assert_eq!(back.count, 1.0, "trial {trial}");
            assert!(back.scatter.iter().all(|&s| s == 0.0), "trial {trial}");
            for d in 0..D {
                assert!(
                    (back.mean[d] - y.mean[d]).abs() <= step * 1.001,
                    "trial {trial} mean[{d}]"
                );
                sum[d] += f64::from(back.mean[d]);
            }
        }
        for d in 0..D {
            let bias = (sum[d] / runs as f64 - f64::from(y.mean[d])).abs() / f64::from(step);
            assert!(bias < 0.2, "trial {trial} mean[{d}]: bias {bias} steps");
        }
    }
}

/// The sparse path alone (a few points into a voxel of many, the scanning LiDAR's cooling): taken for most
/// such merges, and within one code step of the exact merge, mean and scatter; its codes decode as the
/// f32 path's do (same scale kept, same count).
#[cfg(feature = "sparse-cooling")]
#[test]
fn sparse_merges_match_the_exact_merge() {
    let fix = Int8Fix::new(S);
    let mut rng = Rng(0x5A5A_0F0F);
    let mut dither = Dither::new(21);
    let (mut taken, trials) = (0, 3000);
    let (mut worst_mu, mut worst_psi) = (0.0f32, 0.0f32);
    for trial in 0..trials {
        let n0 = [2, 5, 16, 40, 255, 3000, 100_000][trial % 7];
        let offset = (rng.next() % 120) as i32 - 60;
        let mut old_obs = rng.sums(n0.min(255), offset).to_obs(S);
        old_obs.count = n0 as f32;
        let old = QuantVoxel::<D, P>::encode(&old_obs, &mut Dither::new(trial as u32 + 1));
        let n1 = 1 + rng.next() % SPARSE_MAX_NEW;
        let shift_by = (rng.next() % 11) as i32 - 5;
        let sums = rng.sums(n1, offset + shift_by);
        let n = n0 + n1;
        let sigma = fix.steps_of(old.mu_scale);
        let before = dither.clone().next();
        let Some(got) = old.merge_sparse(
            &sums,
            &ScatterUnits::new(&fix, n0, n),
            n0,
            sigma,
            false,
            &mut dither,
        ) else {
            assert_eq!(
                dither.clone().next(),
                before,
                "a refused merge used the dither"
            );
            continue;
        };
        taken += 1;
        assert_eq!(got.mu_scale, old.mu_scale, "trial {trial}");
        let mut want = old.decode();
        want.merge(&sums.to_obs(S));
        let back = got.decode();
        assert_eq!(back.count, want.count, "trial {trial}");
        let step = old.mu_scale.to_f32();
        let top = want.scatter.iter().fold(0.0f32, |a, &b| a.max(b));
        for d in 0..D {
            // Dithered: one of the two codes around the exact value.
            let e = (back.mean[d] - want.mean[d]).abs() / step;
            worst_mu = worst_mu.max(e);
            assert!(e < 1.0 + 1e-3, "trial {trial} mean[{d}]: {e} steps");
            // Scatters above the codes' floor (the base) within one key step (25 % at most).
            if want.scatter[d] > top / 128.0 {
                let r = back.scatter[d] / want.scatter[d];
                worst_psi = worst_psi.max((r - 1.0).abs());
                assert!(r > 1.0 / 1.2501 && r < 1.2501, "trial {trial} scatter[{d}]: {r} n1 {n1} want {} got {} old {} top {top} oldmean {} step {step} sum {} sq {}", want.scatter[d], back.scatter[d], old.decode().scatter[d], old.decode().mean[d], sums.sum(d), sums.square(d));
            }
        }
    }
    std::println!(
        "sparse path: {taken} of {trials} merges, worst mean error {worst_mu:.3} steps, scatter off by {worst_psi:.3}"
    );
    assert!(
        taken * 10 > trials * 8,
        "the sparse path took only {taken} of {trials}"
    );
}

/// A voxel fed one or two points at a time for thousands of coolings (a LiDAR revisiting it): the sparse
/// path's mean and scatter stay unbiased — mean no farther from the exact statistics than the f32 path's,
/// the scatter within its code step on average.
#[test]
fn sparse_merges_do_not_drift() {
    let fix = Int8Fix::new(S);
    let mut rng = Rng(4242);
    let mut dither = Dither::new(8);
    let (mut code, mut float) = (QuantVoxel::<D, P>::EMPTY, QuantVoxel::<D, P>::EMPTY);
    let mut truth = ObsStats::<D>::EMPTY;
    for _ in 0..3000 {
        let n1 = 1 + rng.next() % 2;
        let sums = rng.sums(n1, 10);
        truth.merge(&sums.to_obs(S));
        code = code.merge_codes_fixed(&sums, &fix, false, &mut dither);
        let mut f = float.decode();
        f.merge(&sums.to_obs(S));
        float = float.reencode(&f, &mut dither);
    }
    let rel = |q: &QuantVoxel<D, P>| {
        let b = q.decode();
        let e: f32 = (0..D)
            .map(|d| (b.mean[d] - truth.mean[d]).powi(2))
            .sum::<f32>()
            .sqrt();
        e / truth.mean.iter().map(|m| m * m).sum::<f32>().sqrt()
    };
    let log_ratio = |q: &QuantVoxel<D, P>| {
        let b = q.decode();
        (0..D)
            .map(|d| libm::logf(b.scatter[d] / truth.scatter[d]))
            .sum::<f32>()
            / D as f32
    };
    let (mean_fixed, mean_f32) = (rel(&code), rel(&float));
    let (bias_fixed, bias_f32) = (log_ratio(&code), log_ratio(&float));
    std::println!(
        "after 3000 sparse coolings: mean error fixed {mean_fixed:.4}, f32 path {mean_f32:.4}; scatter bias (mean ln ratio) fixed {bias_fixed:.3}, f32 path {bias_f32:.3}"
    );
    assert_eq!(code.decode().count, truth.count);
    assert!(
        mean_fixed <= (1.25 * mean_f32).max(0.02),
        "mean drifted: {mean_fixed} (f32 path {mean_f32})"
    );
    assert!(
        bias_fixed.abs() < 0.1,
        "scatter drifted: mean ln ratio {bias_fixed}"
    );
}

/// The lone-point short path (a first visit of one point) codes what the general merge codes, bit for bit,
/// and leaves the dither stream where it leaves it: on both grids, for codes at the ends of their range
/// and all zero.
#[cfg(feature = "sparse-cooling")]
#[test]
fn a_lone_point_takes_the_short_path_to_the_general_merges_codes() {
    let fix = Int8Fix::new(S);
    let mut rng = Rng(0x007E_571D);
    let mut short_taken = 0;
    for trial in 0..2000u32 {
        let sums = match trial {
            0 => CodeSums::EMPTY,
            1 => {
                let mut c = CodeSums::EMPTY;
                c.add(&[0; D]);
                c
            }
            2 | 3 => {
                let mut c = CodeSums::EMPTY;
                c.add(&core::array::from_fn(|d| {
                    if (d + trial as usize).is_multiple_of(2) {
                        127
                    } else {
                        -127
                    }
                }));
                c
            }
            _ => {
                let offset = (rng.next() % 200) as i32 - 100;
                rng.sums(1, offset)
            }
        };
        let fine = trial % 2 == 1;
        let (mut d_short, mut d_general) = (Dither::new(trial + 1), Dither::new(trial + 1));
        let empty = QuantVoxel::<D, P>::EMPTY;
        let short = empty.merge_codes_fixed(&sums, &fix, fine, &mut d_short);
        let general = empty.merge_general(&sums, &fix, fine, &mut d_general);
        assert_eq!(short, general, "trial {trial}");
        assert_eq!(
            d_short.next(),
            d_general.next(),
            "trial {trial}: the dither"
        );
        if sums.count == 1 {
            short_taken += usize::from(
                QuantVoxel::<D, P>::encode_lone(&sums, &fix, fine, &mut Dither::new(1)).is_some(),
            );
        }
    }
    assert!(
        short_taken >= 1998,
        "the short path took {short_taken} of 1999 lone points"
    );
}

/// The eight-at-a-time unpacking and packing of the sparse path read and write the layout the code-at-a-time
/// reader and writer do (whole groups of eight and a last partial one), and round-trip.
#[cfg(feature = "sparse-cooling")]
#[test]
fn codes_unpack_and_pack_eight_at_a_time_as_one_at_a_time() {
    fn check<const W: usize>(rng: &mut Rng, dims: usize) {
        let len = (dims * W).div_ceil(8);
        let mut data = [0u8; 64];
        let data = &mut data[..len];
        for b in data.iter_mut() {
            *b = rng.next() as u8;
        }
        // Bits past the last code are 0 in a packed section.
        if !(dims * W).is_multiple_of(8) {
            data[len - 1] &= (1u8 << ((dims * W) % 8)) - 1;
        }
        let mut codes = [0u8; 80];
        unpack_codes::<W>(data, &mut codes[..dims]);
        let mut r = CodeReader::new(data);
        for (i, &c) in codes[..dims].iter().enumerate() {
            assert_eq!(u32::from(c), r.next(W as u32), "W {W} dims {dims} code {i}");
        }
        let mut back = [0u8; 64];
        pack_codes::<W>(&codes[..dims], &mut back[..len]);
        assert_eq!(&back[..len], &*data, "W {W} dims {dims}");
    }
    let mut rng = Rng(0x000C_0DE5);
    for dims in [1, 7, 8, 13, 16, 64, 67] {
        for _ in 0..50 {
            check::<{ MU_BITS as usize }>(&mut rng, dims);
            check::<{ super::super::PSI_BITS as usize }>(&mut rng, dims);
        }
    }
}

/// The loop-invariant shift of the sparse merge is the per-value one it replaced, capped at 2³⁰, for every
/// shift up to 31.
#[cfg(feature = "sparse-cooling")]
#[test]
fn the_fixed_shift_is_the_saturating_shift() {
    let mut rng = Rng(0x5417_F7ED);
    for s in -40..=31 {
        let shift = Shift::new(s);
        for v in [0, 1, 2, 0xFFFF, 0x8000_0000, u32::MAX]
            .into_iter()
            .chain((0..200).map(|_| rng.next() >> (rng.next() % 32)))
        {
            assert_eq!(shift.apply(v), shl_sat(v, s).min(1 << 30), "v {v} s {s}");
        }
    }
}

/// Codes of one point for the single-point tests: around an offset, at the ends of the range (±127, −128),
/// tiny (a scale of a few hundredths of a step), or all zero.
#[cfg(feature = "sparse-cooling")]
fn point_codes(rng: &mut Rng, kind: u32) -> [i8; D] {
    let offset = (rng.next() % 200) as i32 - 100;
    core::array::from_fn(|d| match kind {
        0 => ((rng.next() % 41) as i32 - 20 + offset + 3 * d as i32 - 24).clamp(-127, 127) as i8,
        1 => [127, -128, -127, 0][(rng.next() % 4) as usize],
        2 => (rng.next() % 3) as i8 - 1,
        3 => 0,
        4 => [127, -128][(rng.next() % 2) as usize],
        _ => (rng.next() % 256) as u8 as i8,
    })
}

/// A voxel of at most [`super::small::SMALL_MAX_OLD`] points — above all one point revisited by a few (the
/// ToF's usual cooling after a first visit), also none, a few or 255 — merged with 1 to 255 points takes
/// the small-voxel path, which holds to the f32 path with the general merge's bounds (scale within one f16
/// step, mean within 1.3 code steps, scatter within one key step) on both grids, over codes at the ends of
/// the range, tiny and zero codes, fresh and kept scales; and uses the dither stream as the general merge
/// does. The general merge's errors on the same merges are printed beside its.
#[cfg(feature = "sparse-cooling")]
#[test]
fn small_voxel_merges_match_the_f32_path() {
    use super::small::{SMALL_MAX_NEW, SMALL_MAX_OLD};
    let fix = Int8Fix::new(S);
    let mut rng = Rng(0x51_6E_61_E5);
    let trials = 6000u32;
    for fine in [false, true] {
        let (mut worst_mu, mut worst_psi) = (0.0f32, 0.0f32);
        let (mut general_mu, mut general_psi) = (0.0f32, 0.0f32);
        let (mut df, mut dx) = (Dither::new(31), Dither::new(31));
        let mut checked_psi = 0;
        for trial in 0..trials {
            // Half the trials one old point, the rest 0 to 255.
            let n0 = if trial % 2 == 0 {
                1
            } else {
                [0, 2, 3, 17, SMALL_MAX_OLD][(trial as usize / 2) % 5]
            };
            let first = point_codes(&mut rng, trial % 6);
            let mut old_sums = CodeSums::EMPTY;
            for j in 0..n0 {
                if j == 0 {
                    old_sums.add(&first);
                } else {
                    // Around the first point, by a few codes.
                    old_sums.add(&core::array::from_fn(|d| {
                        (i32::from(first[d]) + (rng.next() % 7) as i32 - 3).clamp(-128, 127) as i8
                    }));
                }
            }
            // As the map makes it (its first cooling) or from f32 statistics.
            let old = if trial % 4 == 3 {
                let mut obs = old_sums.to_obs(S);
                obs.count = n0 as f32;
                QuantVoxel::<D, P>::encode(&obs, &mut Dither::new(trial + 1))
            } else {
                QuantVoxel::<D, P>::EMPTY.merge_codes_fixed(
                    &old_sums,
                    &fix,
                    fine,
                    &mut Dither::new(trial + 1),
                )
            };
            // Mostly a few points (the ToF's usual revisit), every third up to a full CodeSums.
            let n1 = 1 + rng.next() % if trial % 3 == 0 { SMALL_MAX_NEW } else { 8 };
            let mut sums = CodeSums::EMPTY;
            let near = trial % 7 < 3;
            for _ in 0..n1 {
                let codes: [i8; D] = if near {
                    // Close to the first point (a fraction of a code step apart, or the same point).
                    let spread = rng.next() % 4;
                    core::array::from_fn(|d| {
                        (i32::from(first[d]) + (rng.next() % (2 * spread + 1)) as i32
                            - spread as i32)
                            .clamp(-128, 127) as i8
                    })
                } else {
                    let kind = rng.next() % 6;
                    point_codes(&mut rng, kind)
                };
                sums.add(&codes);
            }
            let mut dg = dx.clone();
            let got = old
                .merge_small::<true>(&sums, &fix, n0, fine, &mut dx)
                .unwrap_or_else(|| panic!("trial {trial}: not taken"));
            let general = old.merge_general(&sums, &fix, fine, &mut dg);
            assert_eq!(dx.clone().next(), dg.next(), "trial {trial}: the dither");
            // The dispatch takes it (where neither the lone point's nor the sparse path does).
            let mut dd = Dither::new(trial);
            let sparse = n0 >= 2
                && n1 <= SPARSE_MAX_NEW
                && old
                    .merge_sparse(
                        &sums,
                        &ScatterUnits::new(&fix, n0, n0 + n1),
                        n0,
                        fix.steps_of(old.mu_scale),
                        fine,
                        &mut dd.clone(),
                    )
                    .is_some();
            if !sparse && (n0, n1) != (0, 1) {
                assert_eq!(
                    old.merge_codes_fixed(&sums, &fix, fine, &mut dd.clone()),
                    old.merge_small::<true>(&sums, &fix, n0, fine, &mut dd)
                        .unwrap(),
                );
            }

            let (want, float) = float_cooling(&old, &sums, fine, &mut df);
            let up = got.mu_scale.to_bits().abs_diff(float.mu_scale.to_bits());
            assert!(
                up <= 1,
                "trial {trial} (fine {fine}): scale {} vs {}",
                got.mu_scale,
                float.mu_scale
            );
            assert_eq!(got.decode().count, want.count, "trial {trial}");
            // A code step: the larger of the f32 path's scale and a fresh one's (the test above).
            let headroom = if fine {
                super::super::FINE_HEADROOM
            } else {
                1.25
            };
            let max_mean = want.mean.iter().fold(0.0f32, |a, m| a.max(m.abs()));
            let step = (max_mean * headroom / 63.0).max(float.mu_scale.to_f32());
            let top = want.scatter.iter().fold(0.0f32, |a, &b| a.max(b));
            let wide = 1.0 + 1.0 / (1u32 << super::super::PSI_STEPS_LOG2) as f32;
            // The general merge's errors for comparison only: its per-voxel scatter units are too coarse for
            // the tiniest scatters (a pair of near-zero points: ≈ 1 % of S), which this path keeps.
            for (q, is_single, worst) in [
                (&got, true, (&mut worst_mu, &mut worst_psi)),
                (&general, false, (&mut general_mu, &mut general_psi)),
            ] {
                let back = q.decode();
                for d in 0..D {
                    if step == 0.0 {
                        assert_eq!(back.mean[d], 0.0, "trial {trial} mean[{d}]");
                    } else {
                        let e = (back.mean[d] - want.mean[d]).abs() / step;
                        *worst.0 = worst.0.max(e);
                    }
                    if want.scatter[d] > top * 1e-2 {
                        let r = back.scatter[d] / want.scatter[d];
                        *worst.1 = worst.1.max((r - 1.0).abs());
                        checked_psi += usize::from(is_single);
                        assert!(
                            !is_single || (r > 0.975 / wide && r < 1.025 * wide),
                            "trial {trial} scatter[{d}]: {r} (want {}, n1 {n1})",
                            want.scatter[d]
                        );
                    } else if top == 0.0 {
                        assert_eq!(back.scatter[d], 0.0, "trial {trial} scatter[{d}]");
                    }
                }
            }
            assert!(
                worst_mu <= 1.3,
                "trial {trial}: mean off by {worst_mu} steps (n1 {n1}, general {general_mu}, step {step}, scale {} vs {}; old {:?}; got {:?} want {:?})",
                got.mu_scale, float.mu_scale, old.mu_scale, &got.decode().mean[..4], &want.mean[..4]
            );
        }
        std::println!(
            "small-voxel path (fine {fine}): worst mean error {worst_mu:.3} steps (general merge {general_mu:.3}), scatter off by {worst_psi:.3} (general {general_psi:.3}) over {checked_psi} scatters"
        );
        assert!(checked_psi > 10_000);
    }
}

/// The small-voxel path's fused form (a voxel of at most one point merged with one: each scatter computed
/// where its codes are made, the largest from y's extremes) gives the codes of its separate scatter pass,
/// bit for bit, and draws the same dither (its Ψ codes without the f32 bit pattern, on every merge it
/// takes: as the separate pass's); and the table's leading zeros are `top16`'s.
#[cfg(feature = "sparse-cooling")]
#[test]
fn the_fused_small_merge_is_the_unfused_one() {
    let mut rng = Rng(0x0F_05_ED_01);
    for v in (1..1 << 20).chain((0..200_000).map(|_| rng.next().max(1))) {
        assert_eq!(super::small::top16_by_table(v), top16(v), "{v}");
    }
    let fix = Int8Fix::new(S);
    let mut taken = 0;
    for trial in 0..20_000u32 {
        let fine = trial % 2 == 0;
        let n0 = [1, 1, 1, 0, 2, 1, 0, 5, 40, 255][(trial % 10) as usize];
        let first = point_codes(&mut rng, trial % 6);
        let mut old_sums = CodeSums::EMPTY;
        for j in 0..n0 {
            old_sums.add(&if j == 0 {
                first
            } else {
                point_codes(&mut rng, 0)
            });
        }
        let old = QuantVoxel::<D, P>::EMPTY.merge_codes_fixed(
            &old_sums,
            &fix,
            fine,
            &mut Dither::new(trial + 1),
        );
        let n1 = match trial % 7 {
            0 => 2,
            1 => 1 + rng.next() % 255,
            _ => 1,
        };
        let mut sums = CodeSums::EMPTY;
        for _ in 0..n1 {
            let spread = rng.next() % 4;
            let kind = rng.next() % 6;
            let codes: [i8; D] = if trial % 3 == 0 {
                point_codes(&mut rng, kind)
            } else {
                core::array::from_fn(|d| {
                    (i32::from(first[d]) + (rng.next() % (2 * spread + 1)) as i32 - spread as i32)
                        .clamp(-128, 127) as i8
                })
            };
            sums.add(&codes);
        }
        let (mut a, mut b) = (Dither::new(trial | 1), Dither::new(trial | 1));
        let fused = old.merge_small::<true>(&sums, &fix, n0, fine, &mut a);
        let unfused = old.merge_small::<false>(&sums, &fix, n0, fine, &mut b);
        assert_eq!(fused, unfused, "trial {trial}");
        assert_eq!(a.next(), b.next(), "trial {trial}: the dither");
        taken += usize::from(fused.is_some());
    }
    assert!(taken > 15_000, "{taken}");
}

/// The rounded shift saturates where a count of leading zeros says it must (what it tested before): p · 2^sh
/// saturated at 2³⁰ once a bit reaches bit 30, rounded to nearest when shifting right.
#[test]
fn the_shift_saturates_as_by_leading_zeros() {
    let by_zeros = |p: u32, sh: i32| -> u32 {
        if p == 0 {
            0
        } else if sh >= 0 {
            if sh >= 30 || p.leading_zeros() < 2 + sh as u32 {
                1 << 30
            } else {
                p << sh
            }
        } else if sh <= -32 {
            0
        } else {
            (p >> (-sh - 1)).div_ceil(2)
        }
    };
    let mut rng = Rng(0x0BAD_5EED);
    for sh in -40..=40 {
        let edges = (0..32).flat_map(|b| [1u32 << b, (1u32 << b) - 1, (1u32 << b) + 1]);
        for p in edges.chain((0..300).map(|_| rng.next() >> (rng.next() % 32))) {
            assert_eq!(shift(p, sh), by_zeros(p, sh), "p {p} sh {sh}");
        }
    }
}
