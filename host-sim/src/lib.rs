//! host-sim: the desktop twin of the robot. It runs the same `latentbki` core as the firmware: the
//! simulator (scenes, sensors, a simulated vision-language encoder), the paper's evaluation, the f32
//! reference map, exploration, the demo's radio and the base station's commands.
//!
//! Every command lives in [`cli`], the top floor; the modules below it are the library the commands are
//! built from, and none of them imports [`cli`].
#![forbid(unsafe_code)]

pub mod base_station;
pub mod bench;
pub mod changing;
pub mod cli;
pub mod cli_args;
pub mod demo_radio;
pub mod eval;
pub mod explore;
pub mod feature_space;
pub mod las_frame;
pub mod link;
pub mod npy_io;
pub mod reference_map;
pub mod sim;
#[cfg(feature = "encoder")]
pub mod text_encoder;

pub use latentbki_station::{obs_map, png_io, ObsMap};
pub use reference_map::ReferenceMap;
