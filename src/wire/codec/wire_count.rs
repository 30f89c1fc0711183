//! A summary's weight as the wire carries it: its count, a whole number, read from the f32 count's bits
//! (integer operations alone: every eviction weighs its voxel by this, and on an MCU without an FPU the
//! float form, `count as u32` and `n as f32 == count`, was three soft-float calls an eviction).

use super::MAX_COUNT;

/// The count as the wire carries it, if it is a whole number in 1..=[`MAX_COUNT`]: what
/// `count as u32 … n as f32 == count` gives, for every f32 (the test `wire_count_is_the_float_test`).
pub fn wire_count(count: f32) -> Option<u32> {
    let bits = count.to_bits();
    // 1.m × 2^e with the sign clear and 0 ≤ e ≤ 24 (below 1, negative, NaN or infinite: none).
    let e = (bits >> 23).checked_sub(127).filter(|&e| e <= 24)?;
    let m = (bits & 0x7F_FFFF) | 0x80_0000;
    let n = if e <= 23 {
        // A whole number iff no bit of m is below 2^(23 − e).
        (m & ((1 << (23 - e)) - 1) == 0).then_some(m >> (23 - e))?
    } else {
        m << 1
    };
    (n <= MAX_COUNT).then_some(n)
}

#[cfg(test)]
mod tests {
    use super::{wire_count, MAX_COUNT};

    /// The float test `wire_count` replaced: whole numbers in 1..=MAX_COUNT.
    fn by_float(count: f32) -> Option<u32> {
        let n = count as u32;
        ((1..=MAX_COUNT).contains(&n) && n as f32 == count).then_some(n)
    }

    #[test]
    fn wire_count_is_the_float_test() {
        // Every count around every power of two and around the limit, their neighbouring bit patterns
        // (fractions just above and below a whole number), the special values, and pseudo-random bits.
        let check = |b: u32| {
            let c = f32::from_bits(b);
            assert_eq!(wire_count(c), by_float(c), "{c:e} ({b:#010x})");
        };
        for n in (0..=4096u32).chain((MAX_COUNT - 4096)..=(MAX_COUNT + 4096)) {
            let b = (n as f32).to_bits();
            [b, b.wrapping_sub(1), b + 1, b | 0x8000_0000]
                .into_iter()
                .for_each(check);
        }
        for e in 0..=40 {
            let b = 2f32.powi(e).to_bits();
            [b - 1, b, b + 1, b + 2].into_iter().for_each(check);
        }
        [
            0,
            0x8000_0000,
            f32::INFINITY.to_bits(),
            f32::NEG_INFINITY.to_bits(),
        ]
        .into_iter()
        .for_each(check);
        [
            f32::NAN.to_bits(),
            0x7F80_0001,
            0xFFC0_0000,
            1,
            f32::MAX.to_bits(),
        ]
        .into_iter()
        .for_each(check);
        let mut seed = 0x1234_5678u32;
        for _ in 0..2_000_000 {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            check(seed);
        }
        assert_eq!(wire_count(MAX_COUNT as f32), Some(MAX_COUNT));
        assert_eq!(wire_count(1.0), Some(1));
        assert_eq!(wire_count(0.5), None);
    }
}
