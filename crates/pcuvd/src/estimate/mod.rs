//! From per-angle image series to velocities: SVD clutter filtering, autocorrelation Doppler,
//! the pixels that hold flow, the vector solve (LS and IRLS), vector dealiasing and the
//! partial-volume correction.

pub mod clutter;
pub mod dealias;
pub mod doppler;
mod leading_eigen;
pub mod masks;
pub mod partial_volume;
pub mod projections;
pub mod vector;
