//! The base station: the `latentbki-station` crate (global map, SQLite store, exports, receiver glue), and
//! what decodes the map its viewer shows ([`phrases`]). Its commands (`base-station`, `map-info`,
//! `map-query`, `map-merge`) are in [`crate::cli::station`].

pub use latentbki_station::*;

pub mod phrases;
