//! The one error type of the I/O crate: every message names the file, the field and the problem.

use std::path::PathBuf;

/// Why a file could not be read or written; its `Display` is one sentence that starts with the path.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The operating system refused to open, read, write or create a file or folder.
    #[error("{}: cannot {action}: {source}", path.display())]
    Io {
        /// The file, as given.
        path: PathBuf,
        /// What was attempted ("read", "write", "create").
        action: &'static str,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// The path names nothing.
    #[error("{}: does not exist", path.display())]
    NotFound {
        /// The path, as given.
        path: PathBuf,
    },
    /// The path names something that is not a regular file (a folder, a named pipe, a device, a
    /// broken or looping symbolic link).
    #[error("{}: is {what}, not a file", path.display())]
    NotAFile {
        /// The path, as given.
        path: PathBuf,
        /// What it is, e.g. "a folder" or "a named pipe (FIFO)".
        what: String,
    },
    /// The file is not in the expected format, or is damaged (truncated, corrupt, unparsable).
    #[error("{}: {problem}", path.display())]
    Malformed {
        /// The file, as given.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
    },
    /// A required variable, field or key is absent.
    #[error("{}: {container} has no {item}", path.display())]
    Missing {
        /// The file, as given.
        path: PathBuf,
        /// Where it was looked for, e.g. "variable 'param'" or "table \[probe\]".
        container: String,
        /// What is missing, e.g. "field 'fs'".
        item: String,
    },
    /// A variable, field or key is present but its value is unusable.
    #[error("{}: {field} {problem}", path.display())]
    Invalid {
        /// The file, as given.
        path: PathBuf,
        /// The variable, field or key, e.g. "param.fs" or "\[acquisition\].angles_deg".
        field: String,
        /// What is wrong, phrased to follow the field name ("must be > 0, got -1").
        problem: String,
    },
    /// The recording's parameters or shapes were refused by pcuvd's own checks.
    #[error("{}: {source}", path.display())]
    Recording {
        /// The file, as given.
        path: PathBuf,
        /// pcuvd's reason (kept verbatim).
        source: pcuvd::Error,
    },
}

impl IoError {
    /// The file the error is about.
    pub fn path(&self) -> &std::path::Path {
        match self {
            IoError::Io { path, .. }
            | IoError::NotFound { path }
            | IoError::NotAFile { path, .. }
            | IoError::Malformed { path, .. }
            | IoError::Missing { path, .. }
            | IoError::Invalid { path, .. }
            | IoError::Recording { path, .. } => path,
        }
    }

    /// An I/O failure while doing `action` ("read", "write"...) on `path`.
    pub fn io(path: &std::path::Path, action: &'static str, source: std::io::Error) -> Self {
        IoError::Io {
            path: path.to_path_buf(),
            action,
            source,
        }
    }

    pub(crate) fn malformed(path: &std::path::Path, problem: impl Into<String>) -> Self {
        IoError::Malformed {
            path: path.to_path_buf(),
            problem: problem.into(),
        }
    }

    pub(crate) fn missing(
        path: &std::path::Path,
        container: impl Into<String>,
        item: impl Into<String>,
    ) -> Self {
        IoError::Missing {
            path: path.to_path_buf(),
            container: container.into(),
            item: item.into(),
        }
    }

    pub(crate) fn invalid(
        path: &std::path::Path,
        field: impl Into<String>,
        problem: impl Into<String>,
    ) -> Self {
        IoError::Invalid {
            path: path.to_path_buf(),
            field: field.into(),
            problem: problem.into(),
        }
    }

    /// `value`, the number `field` of `path` holds, when it lies within `range` (in `unit`),
    /// as pcuvd's own parameters are checked ([`pcuvd::core::error::require_range`]); else its
    /// refusal: outside the range the number is in another unit (mm as m, MHz as Hz) or wrong.
    pub(crate) fn require_range(
        path: &std::path::Path,
        field: &str,
        value: f64,
        range: (f64, f64),
        unit: &str,
    ) -> Result<f64, IoError> {
        pcuvd::core::error::require_range(field, value, range, unit)
            .map(|()| value)
            .map_err(|refused| {
                let reason = match refused {
                    pcuvd::Error::InvalidParameter { reason, .. } => reason,
                    other => other.to_string(),
                };
                IoError::invalid(path, field, format!("{reason} (check the unit)"))
            })
    }
}

/// A foreign error's message on one line: its line breaks and the indentation after them become
/// single spaces (a parser's multi-line report would otherwise break the one-line message).
pub(crate) fn flat(e: impl std::fmt::Display) -> String {
    e.to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}
