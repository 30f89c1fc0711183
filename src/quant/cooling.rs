//! How a hot voxel's int8 sums cool into its compact codes: Chan's merge in f32, or the same merge in
//! integers ([`super::Int8Fix`]). Which is cheaper depends on the target, so each target links one.

/// The method a local map cools int8 sums with ([`crate::local_map::LocalMap::set_cooling`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Cooling {
    /// Decode, merge and re-encode in f32: the fewest instructions where floats run on an FPU.
    Float,
    /// The integer merge of `quant::fixed`: no float operation, where floats are library calls.
    Fixed,
}

/// A hosted build (not bare metal): it links both methods, so a host twin can compute what any board does.
const HOSTED: bool = cfg!(not(target_os = "none"));

impl Cooling {
    /// This target's method and every map's default. Why: an FPU (hosted, `eabihf` Arm, RISC-V F) merges in
    /// f32 in fewer instructions (M4F: ≈ 4,000 per cooling vs ≈ 10,000 in integers); without one (thumbv6m,
    /// riscv32imac) the f32 merge is soft-float library calls and the integer one is 2× cheaper per point.
    pub const NATIVE: Self = if HOSTED || cfg!(any(target_abi = "eabihf", target_feature = "f")) {
        Self::Float
    } else {
        Self::Fixed
    };

    /// Whether the fixed-point cooling has its path for a few points into a voxel of many (feature
    /// `sparse-cooling`; without it those merges take the general integer merge, to the same codes' meaning).
    pub const SPARSE: bool = cfg!(feature = "sparse-cooling");

    /// Whether this build has the method's code: a bare-metal build links only [`Self::NATIVE`] (flash),
    /// a hosted one both.
    pub const fn is_built(self) -> bool {
        HOSTED || self as u8 == Self::NATIVE as u8
    }
}
