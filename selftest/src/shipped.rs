//! What the boards ship, in one place: the `latentbki` features they link (this crate's `full`), how the
//! self-test's summaries go on the wire, and the weights its maps code their means with. The firmware and
//! its host twin read the same constants, so their streams stay equal; the demo prints [`BOARD_FEATURES`].

use latentbki::quant::MeanWeights;
use latentbki::wire::SummaryCodec;

/// The features of `latentbki` the boards link (this crate's `full` feature, which the boards enable; the
/// demo's robot uses exactly these), or none in the minimal build.
#[cfg(feature = "full")]
pub const BOARD_FEATURES: &[&str] = &["rice-codes", "mean-weights", "sparse-cooling"];
/// See above.
#[cfg(not(feature = "full"))]
pub const BOARD_FEATURES: &[&str] = &[];

/// How the self-test's summaries go on the wire: packed 6-bit means (`SummaryCodec::DEFAULT` but for its
/// 3 bits), 8 scatter blocks. Measured on the nine scenarios (`cargo run --release -p host-sim --example
/// firmware_accuracy -- thumbv7em --twin`: the base station against the f32 reference, RMS ‖Δμ‖/‖μ‖; with
/// [`SELF_TEST_MEAN_WEIGHTS`] unless said): packed 3-bit with all-ones weights 0.1126 (most of it the
/// wire's: 8-bit 0.0236), 5-bit 0.0286, **6-bit 0.0180** (982,706 stream bytes), Rice-coded means (the
/// demo's codec, `latentbki::wire::rice`) 0.0227 (854,372 B). Not Rice, though the boards link it: its
/// encoder picks each summary's steps by trial, and the 8×8 ToF evicts a voxel every second point, so on
/// the M4F it cost 17,044 instructions per ToF point against 8,128 with these codes (`boards/measure.sh`).
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
