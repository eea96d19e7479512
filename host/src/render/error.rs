//! Typed errors of the renderer. Each message is one line that names the offending file or key.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// A scene file that does not parse or holds a value out of range.
    #[error("{}: {reason}", path.display())]
    Scene { path: PathBuf, reason: String },
    /// An image that cannot be read or written, or is not a usable image.
    #[error("{}: {reason}", path.display())]
    Image { path: PathBuf, reason: String },
    /// Two images that cannot be compared, or a parameter out of range.
    #[error("{0}")]
    Invalid(String),
    /// A material spec from the scene file.
    #[error(transparent)]
    Material(#[from] crate::brdf::BrdfError),
}

impl RenderError {
    pub(crate) fn scene(path: &Path, reason: impl Into<String>) -> Self {
        RenderError::Scene {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }

    pub(crate) fn image(path: &Path, reason: impl std::fmt::Display) -> Self {
        // Library errors (exr, png) may span lines; the CLI prints one.
        let reason = reason.to_string().split_whitespace().collect::<Vec<_>>().join(" ");
        RenderError::Image {
            path: path.to_path_buf(),
            reason,
        }
    }
}
