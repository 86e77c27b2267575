//! The one error type of the science crate.

/// Why a pcuvd computation refused its input.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum Error {
    /// A parameter is out of its valid range (the message names it, its value and the rule).
    #[error("invalid {name}: {reason}")]
    InvalidParameter {
        /// The parameter, as the user knows it (e.g. "sampling frequency").
        name: String,
        /// What is wrong with it.
        reason: String,
    },
    /// Arrays whose shapes do not fit together.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// No Hadamard matrix of this order can be built.
    #[error(
        "no Hadamard matrix of order {0}: pcuvd builds orders 1, 2 and multiples of 4 reachable by Sylvester doubling and Paley I constructions (e.g. 4, 8, 12, 16, 20, 24, 28, 32)"
    )]
    HadamardOrder(usize),
    /// The data holds no flow a stage can analyse (noise alone, no vessel): a property of the
    /// recording, not a fault of the settings; a run notes it and keeps its other results.
    #[error("no flow to analyse: {0}")]
    NoFlow(String),
    /// NaN or infinite samples in input data.
    #[error("non-finite value in {0}")]
    NonFinite(String),
    /// A recording's samples could not be read from their file (the message names the file).
    #[error("{0}")]
    Read(String),
    /// The scratch file that holds finished windows' maps while a long recording's later segments
    /// are processed could not be written or read back (the message says why, e.g. a full disk).
    #[error("scratch file of the segments' maps (in the temporary folder, TMPDIR): {0}")]
    Scratch(String),
    /// A run's output could not be written as it went (the message names the file and why).
    #[error("writing the outputs: {0}")]
    Write(String),
}

/// Result of a pcuvd computation.
pub type Result<T> = std::result::Result<T, Error>;

/// Builds an [`Error::InvalidParameter`].
pub fn invalid(name: &str, reason: impl Into<String>) -> Error {
    Error::InvalidParameter {
        name: name.to_string(),
        reason: reason.into(),
    }
}

/// Checks that a physical quantity is finite and strictly positive.
pub fn require_positive(name: &str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(invalid(
            name,
            format!("must be finite and > 0, got {value:?}"),
        ))
    }
}

/// Checks that a quantity is finite and within `[lo, hi]` (in `unit`), naming it.
pub fn require_range(name: &str, value: f64, (lo, hi): (f64, f64), unit: &str) -> Result<()> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(invalid(
            name,
            format!("must be finite and within [{lo:e}, {hi:e}] {unit}, got {value:e} {unit}"),
        ))
    }
}
