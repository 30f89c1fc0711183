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
//! ## A robot in ten lines
//!
//! [`Mapper`] is the entry point on a robot: it owns the on-device [`local_map::LocalMap`] and the
//! [`frame::FrameEncoder`]
//! that streams evicted voxels to a base station, is configured once from a `const` [`Setup`] and lives in
//! a `static` (it is all zero until configured, so it costs no flash). Per sensor frame: the pose, the
//! points and their features in, then a byte-budgeted [`Mapper::tick`] into any [`embedded_io::Write`]
//! (a UART, or here a buffer); [`Mapper::drain`] sends everything at the end.
//!
//! ```
//! use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
//! use latentbki::{mapper_type, EncoderSettings, MapConfig, Setup};
//! use static_cell::ConstStaticCell;
//!
//! const D: usize = 64; // feature dimension (PCA-compressed)
//! // 1,024 voxels; a 4 KiB queue of evicted voxels; frames of at most 512 bytes on the wire.
//! type Robot = mapper_type!(D, 1024, 4096, 512); // = Mapper<D, 1024, { packed_len(D) }, 4096, 512>
//!
//! // Robot 1, session 7 (a fresh number per boot), a window of 2 m around the sensor.
//! static SETUP: Setup = Setup::new(MapConfig::DEFAULT, 2.0, EncoderSettings::new(1, 7));
//! static MAPPER: ConstStaticCell<Robot> = ConstStaticCell::new(Robot::EMPTY);
//!
//! let mapper = MAPPER.take();
//! mapper.configure(&SETUP).expect("a valid setup");
//!
//! // One sensor frame: 64 points on a wall 1 m ahead, each with its feature.
//! let pose = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.3), UnitQuaternion::identity());
//! let points: [[f32; 3]; 64] = core::array::from_fn(|i| [1.0, (i % 8) as f32 * 0.05, (i / 8) as f32 * 0.05]);
//! let features = [[0.125f32; D]; 64];
//! let taken = mapper.integrate(&pose, &points, &features);
//!
//! let mut link = [0u8; 4096];
//! let mut out: &mut [u8] = &mut link;
//! mapper.tick(&mut out, 2048).expect("room in the buffer"); // session header (nothing evicted yet)
//! mapper.drain(&mut out).expect("room in the buffer"); // every voxel, then link statistics
//! let sent = 4096 - out.len();
//!
//! assert_eq!(taken, 64);
//! assert_eq!(mapper.map().len(), 0);
//! assert_eq!(mapper.encoder().stats().bytes_sent as usize, sent);
//! assert!(mapper.encoder().stats().evicted_sent > 0);
//! ```
//!
//! `examples/robot.rs` is the same loop as a program to copy. The base station side reads the bytes with
//! [`receiver::Receiver`].
//!
//! ## Modules
//!
//! They follow the data: [`config`] → [`kernel`] (sparse kernel and its lookup table) → [`key`]
//! (voxel keys, poses; [`fixed_pose`]: integer sensor points without float; [`tof`]: a multizone ToF's zone
//! rays as a fixed-point table) → [`batch`] (validating a
//! point) → [`obs`] (what a voxel observed — in f32, or as exact integer sums of int8 codes — and gathering
//! posteriors through the kernel; [`forget`]: letting old observations fade) → [`stats`] (the posterior
//! update) → [`inference`]
//! and [`sampling`] (uncertainty; [`info_gain`]: where to look next) →
//! [`decode`] (open-vocabulary queries; [`classes`]: a closed-set segmenter's scores as features the base
//! station decodes). On the robot: [`quant`] (compact voxels) → [`local_map`] →
//! [`sink`] (evictions) → [`wire`] (messages and summaries) → [`frame`] (framing, encoder, decoder,
//! acknowledgements) → [`mapper`] (all of it as one value; the firmware author's guide is
//! `docs/firmware.md`); at the other end of the link, [`receiver`] (the acceptance rules and
//! acknowledgements). [`f32math`] holds the single-precision elementary functions the
//! device path uses.
#![no_std]
#![deny(missing_docs)]
#![deny(unsafe_code)]
// `!(x > 0.0)` is deliberate throughout: it is also true for NaN, which must be refused too.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Loops over a dimension index that address several parallel arrays read like the equations.
#![allow(clippy::needless_range_loop)]

pub mod batch;
pub mod classes;
pub mod config;
pub mod decode;
pub mod f32math;
pub mod fixed_pose;
pub mod forget;
pub mod frame;
pub mod inference;
pub mod info_gain;
pub mod kernel;
pub mod key;
pub mod local_map;
pub mod mapper;
pub mod obs;
pub mod quant;
pub mod receiver;
pub mod sampling;
pub mod sink;
pub mod stats;
pub mod tof;
pub mod wire;

// ----- The front door: what a firmware author names. Everything else lives in the module that owns it
// (`key::VoxelKey`, `local_map::LocalMap`, `frame::FrameDecoder`, `decode::Codebook` …).
pub use batch::{Rejection, RejectionCounts};
pub use classes::{ClassPrototypes, MixError};
pub use config::{ConfigError, KernelMode, MapConfig, Prior};
pub use frame::{EncoderSettings, TickError, TickReport};
pub use key::KeyError;
pub use mapper::{DrainError, DrainReport, Mapper, SensorFrame, Setup, SetupError};
pub use quant::packed_len;
pub use wire::WireError;

/// `docs/firmware.md` (the firmware author's guide), compiled so its examples run as doc tests.
#[cfg(doctest)]
#[doc = include_str!("../docs/firmware.md")]
pub struct FirmwareGuide;

/// Re-exported so users build poses with the same nalgebra the library uses.
pub use nalgebra;
