//! Evaluation: the paper's experiments on simulated sequences — methods side by side, metrics,
//! sparsification, figures.
//!
//! [`experiment`] runs the protocol (80 % integrated, 20 % held out, every method on the same input),
//! [`methods`] holds the compared mappers, [`metrics`] the confusion matrix, [`per_class`] the per-class IoU table, [`sparsification`] the
//! uncertainty analysis, [`figures`] the PNGs, and [`scenes`] the two default experiments the CLI runs.

pub mod cli;
pub mod experiment;
pub mod figures;
pub mod methods;
pub mod metrics;
pub mod per_class;
pub mod scenes;
pub mod sparsification;
