//! host-sim: the desktop twin of the robot. It runs the same `latentbki` core as the firmware: the f32
//! reference map, recorded-data integration and (later) the simulator and base station.
#![forbid(unsafe_code)]

pub mod base_station;
pub mod bench;
pub mod changing;
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
pub mod view_bench;

pub use latentbki_station::{obs_map, png_io, ObsMap};
pub use reference_map::ReferenceMap;
