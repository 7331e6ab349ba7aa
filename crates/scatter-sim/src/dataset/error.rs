use std::path::PathBuf;

use thiserror::Error;

/// Every way reading or writing a dataset can fail; each message names the file.
#[derive(Debug, Error)]
pub enum DatasetError {
    /// The I/O error is part of the message, not a `source`: anyhow's report prints a
    /// source after the message, which printed it twice.
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: not an stcvae dataset (bad magic bytes)")]
    BadMagic { path: PathBuf },
    #[error(
        "{path}: dataset format version {found} is not supported (this build reads versions {} to {supported})",
        super::OLDEST_FORMAT_VERSION
    )]
    Version {
        path: PathBuf,
        found: u32,
        supported: u32,
    },
    #[error("{path}: corrupt header: {msg}")]
    Header { path: PathBuf, msg: String },
    #[error(
        "{path}: truncated or padded: the header promises {expected} bytes, the file has {found}"
    )]
    Truncated {
        path: PathBuf,
        expected: u64,
        found: u64,
    },
    #[error("{path}: checksum mismatch: the header or the rows are corrupt")]
    Checksum { path: PathBuf },
    #[error("{path}: row {row}: {msg}")]
    BadRow {
        path: PathBuf,
        row: u64,
        msg: String,
    },
    #[error("{path}: {msg}")]
    Other { path: PathBuf, msg: String },
    /// The caller's cancel flag stopped the work; its output is discarded.
    #[error("interrupted")]
    Interrupted,
}

impl DatasetError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            error: source,
        }
    }
}
