//! Typed errors of the BRDF layer. Each message is one line that names the offending spec or file.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum BrdfError {
    /// A material or warp spec string that does not parse.
    #[error("bad material spec '{spec}': {reason}")]
    Spec { spec: String, reason: String },
    /// A file that cannot be opened, read or written.
    #[error("{}: {err}", path.display())]
    Io { path: PathBuf, err: std::io::Error },
    /// A file that was read but is not what it claims to be (size, header, fields).
    #[error("{}: {reason}", path.display())]
    Format { path: PathBuf, reason: String },
    /// Measurement-grid data that does not fit together.
    #[error("measurement grid: {0}")]
    Grid(String),
    /// `nbrdf:NAME` with a name that is not bundled.
    #[error("no bundled nbrdf material '{name}' ({count} are bundled, e.g. 'alum-bronze'; or give a PATH.json)")]
    UnknownNbrdf { name: String, count: usize },
}

impl BrdfError {
    pub(crate) fn spec(spec: &str, reason: impl Into<String>) -> Self {
        BrdfError::Spec {
            spec: spec.to_string(),
            reason: reason.into(),
        }
    }

    pub(crate) fn format(path: &std::path::Path, reason: impl Into<String>) -> Self {
        BrdfError::Format {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }

    pub(crate) fn io(path: &std::path::Path, err: std::io::Error) -> Self {
        BrdfError::Io {
            path: path.to_path_buf(),
            err,
        }
    }
}
