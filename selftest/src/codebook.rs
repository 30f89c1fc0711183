//! The compiled-in category codebook: one random unit vector per category, from a hash (same bits on
//! every target).

#[allow(unused_imports)]
use crate::*;

/// Number of categories in the room (and vectors in the codebook).
pub const CATEGORIES: usize = 6;

/// Category names, by index.
pub const CATEGORY_NAMES: [&str; CATEGORIES] =
    ["floor", "wall", "ceiling", "table", "cabinet", "chair"];

pub(crate) const FLOOR: u8 = 0;
pub(crate) const WALL: u8 = 1;
pub(crate) const CEILING: u8 = 2;

/// Seed of the compiled-in codebook.
pub const CODEBOOK_SEED: u32 = 0xC0DE_B00C;

/// One 32-bit hash step (murmur3's finaliser over a multiply-add mix): well mixed, cheap, deterministic.
#[inline]
pub const fn hash(a: u32, b: u32) -> u32 {
    let mut h = a.wrapping_mul(0x9E37_79B1) ^ b.wrapping_mul(0x85EB_CA77).rotate_left(13);
    h ^= h >> 16;
    h = h.wrapping_mul(0x85EB_CA6B);
    h ^= h >> 13;
    h = h.wrapping_mul(0xC2B2_AE35);
    h ^ (h >> 16)
}

/// An approximately standard normal number from one hash: the sum of its four bytes (Irwin–Hall, n = 4),
/// centred and scaled to unit variance.
#[inline]
pub fn normal(h: u32) -> f32 {
    let s = (h & 0xFF) + (h >> 8 & 0xFF) + (h >> 16 & 0xFF) + (h >> 24);
    // Mean 4 · 127.5 = 510; variance 4 · (256² − 1) / 12 = 21,845, σ = 147.80.
    (s as f32 - 510.0) * (1.0 / 147.800_54)
}

/// 1/√D by Newton's method, usable in `const` context.
const fn inv_sqrt(d: usize) -> f32 {
    let x = d as f32;
    let mut y = 1.0 / x;
    let mut i = 0;
    while i < 40 {
        y = y * (1.5 - 0.5 * x * y * y);
        i += 1;
    }
    y
}

/// The codebook: one vector per category, components ±1/√D with hashed signs (unit length; two
/// categories have cosine ≈ N(0, 1/D), so they are well apart at D = 64).
pub const fn codebook<const D: usize>(seed: u32) -> [[f32; D]; CATEGORIES] {
    let v = inv_sqrt(D);
    let mut out = [[0.0f32; D]; CATEGORIES];
    let mut c = 0;
    while c < CATEGORIES {
        let mut i = 0;
        while i < D {
            let h = hash(hash(seed, c as u32), i as u32);
            out[c][i] = if h & 1 == 0 { v } else { -v };
            i += 1;
        }
        c += 1;
    }
    out
}

/// The compiled-in codebook at dimension `D` (a `'static` table in flash).
pub struct CategoryVectors<const D: usize>;

impl<const D: usize> CategoryVectors<D> {
    /// The vectors, by category.
    pub const VECTORS: [[f32; D]; CATEGORIES] = codebook::<D>(CODEBOOK_SEED);

    /// The category whose vector has the largest cosine with `feature` (`None` for a zero vector).
    pub fn classify(feature: &[f32; D]) -> Option<u8> {
        let norm2: f32 = feature.iter().map(|v| v * v).sum();
        if !(norm2 > 0.0) {
            return None;
        }
        let mut best = (0u8, f32::NEG_INFINITY);
        for (c, v) in Self::VECTORS.iter().enumerate() {
            let dot: f32 = v.iter().zip(feature).map(|(a, b)| a * b).sum();
            if dot > best.1 {
                best = (c as u8, dot);
            }
        }
        Some(best.0)
    }
}
