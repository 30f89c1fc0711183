//! The base station: the `latentbki-station` crate (global map, SQLite store, exports, receiver glue),
//! and the `base-station`, `map-info` and `map-query` commands built on it.

pub use latentbki_station::*;

pub mod cli;
