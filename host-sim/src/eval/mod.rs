//! Evaluation: the paper's experiments on simulated sequences — methods side by side, metrics,
//! sparsification, figures.
//!
//! [`experiment`] is the protocol (80 % integrated, 20 % held out, every method on the same input);
//! [`runner`] runs every method and the sparsity sweep ([`sweep`]) on a pool of worker threads;
//! [`methods`] holds the compared mappers, [`metrics`] the confusion matrix, [`tables`] the results and
//! per-class IoU tables, [`sparsification`] the uncertainty analysis, [`figures`] the PNGs, and
//! [`scenes`] the two default experiments the CLI runs (`scene_report` runs one end to end).

pub mod experiment;
pub mod figures;
pub mod methods;
pub mod metrics;
pub mod runner;
pub mod scale_search;
mod scene_report;
pub mod scenes;
pub mod sparsification;
pub mod sweep;
pub mod tables;
