//! What the boards ship, in one place: the `latentbki` features they link (this crate's `full`), how the
//! self-test's summaries go on the wire, and the weights its maps code their means with. The firmware and
//! its host twin read the same constants, so their streams stay equal; the demo prints [`BOARD_FEATURES`].

use latentbki::quant::MeanWeights;
use latentbki::wire::SummaryCodec;

/// The features of `latentbki` the boards link (this crate's `full` feature, which the boards enable; the
/// demo's robot uses exactly these), or none in the minimal build.
#[cfg(feature = "full")]
pub const BOARD_FEATURES: &[&str] = &[
    "rice-codes",
    "mean-weights",
    "sparse-cooling",
    "stored-codes",
];
/// See above.
#[cfg(not(feature = "full"))]
pub const BOARD_FEATURES: &[&str] = &[];

/// How the self-test's summaries go on the wire: the map's own codes, verbatim ([`SummaryCodec::STORED`]):
/// an eviction copies the voxel's bytes, with no decode and no float, so the base station's map is the
/// robot's (its μ error the robot map's) at ≈ 100 B per summary. Why: the 8×8 ToF evicts a voxel every
/// second point, and a summary codec decodes and codes each one again — on the M4F 8,128 instructions per
/// ToF point with the packed 6-bit means used before, 17,044 with Rice codes (`boards/measure.sh`), tens
/// of thousands in soft float on thumbv6m and riscv32imac. Before, measured on the nine scenarios (`cargo
/// run --release -p host-sim --example firmware_accuracy -- thumbv7em --twin`: the base station against
/// the f32 reference, RMS ‖Δμ‖/‖μ‖, with [`SELF_TEST_MEAN_WEIGHTS`]): packed 6-bit 0.0180 (982,706 stream
/// bytes), 5-bit 0.0286, Rice-coded means 0.0227 (854,372 B). With stored codes: 0.0129 (thumbv6m,
/// riscv32imac 0.0190), 1,375,102 stream bytes, ToF 8×8 4,756 instructions per point on the M4F, 20,788 on
/// thumbv6m, 14,048 on riscv32imac (docs/numbers.md, "Stored-code summaries"). The minimal build (no
/// `full`, so no `stored-codes`) keeps the packed 6-bit means.
#[cfg(feature = "full")]
pub const SELF_TEST_CODEC: SummaryCodec = SummaryCodec::STORED;
/// See above.
#[cfg(not(feature = "full"))]
pub const SELF_TEST_CODEC: SummaryCodec = SummaryCodec {
    mean_bits: 6,
    ..SummaryCodec::DEFAULT
};

/// Weights of the self-test maps' mean codes: [`MeanWeights::from_spreads`] of the scene's features, whose
/// 64 components spread alike (a codebook sign of ±1/8 plus noise 0.1 each), so [`MeanWeights::EQUAL`]: all
/// ones on the finer grid (with Rice summaries 0.0299 → 0.0227, see [`SELF_TEST_CODEC`]). Without
/// `mean-weights` (the minimal build) [`MeanWeights::ONES`].
#[cfg(feature = "full")]
pub const SELF_TEST_MEAN_WEIGHTS: MeanWeights = MeanWeights::EQUAL;
/// See above.
#[cfg(not(feature = "full"))]
pub const SELF_TEST_MEAN_WEIGHTS: MeanWeights = MeanWeights::ONES;
