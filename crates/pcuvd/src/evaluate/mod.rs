//! Scores of an estimate against ground truth, each measure with its written definition.

pub mod metrics;
