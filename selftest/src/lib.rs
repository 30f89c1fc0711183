//! A deterministic synthetic room and depth sensor, for firmware self-tests and their host twin.
//!
//! Firmware has no camera in CI, yet it must run the real loop — sense, integrate, stream — and the host
//! must be able to recompute, bit for bit, what the device did. So the scene is generated *on the device*
//! by code both sides share: a furnished room (floor, walls, ceiling, a table, a cabinet, a chair), a
//! depth sensor on a circular trajectory (an 8×8 multizone ToF like the VL53L5CX, or a 64×64 subsampled
//! depth camera for 4,096-point frames), and per-point features drawn from a compiled-in codebook (one
//! random unit vector per category) plus noise.
//!
//! Why it is shaped so:
//! - **Random access, no state**: every number is a hash of (seed, frame, zone, component), so points can
//!   be generated in chunks of any size (a few kilobytes of RAM on the device) and the host twin needs no
//!   replay; nothing depends on call order.
//! - **f32 only, explicit libm**: the same inputs give the same bits on a Cortex-M4F and on a desktop.
//!   Only IEEE-exact operations (+ − × ÷ √, floor) are used (sin and cos by a short f32 polynomial), and a
//!   point's sensor-frame coordinates are `range × ray`, so no rotation round-off enters the input.
//! - **Same loop on both sides**: [`run`] drives the core's [`Mapper`](latentbki::Mapper) (the one integrate-and-stream loop
//!   every firmware uses) on the firmware and in the twin; a [`Probe`] brackets the map's work so the
//!   firmware can count instructions around exactly that.
//!
//! It is an application of the core, not part of it: its own crate, used by the QEMU firmware, the host
//! twin (`host-sim/tests/firmware_qemu.rs`) and host-sim's examples.
#![no_std]
#![deny(missing_docs)]
#![forbid(unsafe_code)]
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod codebook;
pub mod loopback;
mod run;
#[cfg(feature = "async")]
mod run_async;
mod scenarios;
mod scene;
mod shipped;

pub use codebook::*;
pub use run::*;
#[cfg(feature = "async")]
pub use run_async::run_async;
pub use scenarios::*;
pub use scene::*;
pub use shipped::*;

#[cfg(test)]
mod tests;
