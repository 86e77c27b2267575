//! Vocabulary every stage shares: the error type, order statistics, weighted sums of rows, lag
//! products of series, the vector kernels' register shuffles, sums on every core that do not
//! depend on the cores, the time-of-flight convention, the pixel grid and the vessel class codes.
//! Nothing here imports a stage.

pub mod buffers;
pub mod error;
pub mod geometry;
pub mod grid;
pub mod lags;
pub mod parallel;
pub mod rows;
pub mod simd;
pub mod stats;
pub mod units;
pub mod vessel;
