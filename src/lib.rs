//! # latentbki
//!
//! LatentBKI (open-vocabulary Bayesian kernel inference mapping) for microcontrollers: `no_std`, no heap,
//! single-precision only.
//!
//! Every voxel keeps a normal-inverse-Wishart posterior (confidence λ, mean μ, diagonal Ψ) over
//! PCA-compressed vision-language features. A batch of sensor points updates every voxel within the sparse
//! kernel's reach by the closed-form Bayesian kernel update; inference gives the expectation and
//! E-/D-optimality (of the authors' t_var or the Student-t covariance), [`sampling`] the sampling
//! uncertainty (the authors' procedure or the model's); decoding compares μ with text embeddings of any
//! words.
//!
//! The modules follow the data: [`config`] → [`kernel`] (sparse kernel and its lookup table) → [`key`]
//! (voxel keys, poses) → [`batch`] (validate, group, spread) → [`stats`] (the update) → [`inference`]
//! and [`sampling`] (uncertainty) → [`decode`] (open-vocabulary queries).
#![no_std]
#![deny(missing_docs)]
#![forbid(unsafe_code)]
// `!(x > 0.0)` is deliberate throughout: it is also true for NaN, which must be refused too.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Loops over a dimension index that address several parallel arrays read like the equations.
#![allow(clippy::needless_range_loop)]

pub mod batch;
pub mod config;
pub mod decode;
pub mod f32math;
pub mod frame;
pub mod inference;
pub mod kernel;
pub mod key;
pub mod local_map;
pub mod obs;
pub mod quant;
pub mod sampling;
pub mod sink;
pub mod stats;
pub mod synth;
pub mod wire;

pub use batch::{locate, spread, Rejection, RejectionCounts};
pub use config::{ConfigError, KernelMode, MapConfig, Prior, DEFAULT_DIM};
pub use decode::{Codebook, CodebookError, Pca};
pub use frame::{FrameDecoder, FrameEncoder, SeqTracker};
pub use inference::{Optimality, Spread};
pub use kernel::{sparse_kernel, KernelLut};
pub use key::{to_map_frame, VoxelKey};
pub use local_map::LocalMap;
pub use obs::{gather, gather_posterior, GatherError, ObsLookup, ObsStats};
pub use quant::packed_len;
pub use sampling::{Sampler, SamplingMode};
pub use sink::{Evicted, EvictionSink, SinkFull};
pub use stats::VoxelStats;
pub use wire::{SessionConfig, SummaryCodec};

/// Re-exported so users build poses with the same nalgebra the library uses.
pub use nalgebra;
/// Re-exported: the PRNG the library's tests and the host's simulations use.
pub use rand_xoshiro;
