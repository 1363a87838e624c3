//! Errors of the output layer: each names the file and says what to do.

use std::path::PathBuf;

/// What went wrong writing or reading an image, metrics or report file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OutputError {
    /// A filesystem operation failed.
    #[error("cannot {action} '{}': {source}; check that the directory exists and is writable", path.display())]
    Io {
        /// File or directory involved.
        path: PathBuf,
        /// What was being done ("create", "rename into place", ...).
        action: &'static str,
        /// Underlying error.
        #[source]
        source: std::io::Error,
    },

    /// The EXR encoder or decoder failed.
    #[error("cannot {action} EXR file '{}': {source}; {}", path.display(), exr_hint(action))]
    Exr {
        /// File involved.
        path: PathBuf,
        /// "read" or "write".
        action: &'static str,
        /// Underlying error.
        #[source]
        source: ::exr::error::Error,
    },

    /// The PNG encoder failed.
    #[error("cannot write PNG file '{}': {source}; check the path and free disk space", path.display())]
    Png {
        /// File involved.
        path: PathBuf,
        /// Underlying error.
        #[source]
        source: ::image::ImageError,
    },

    /// The PNG encoder failed (a file with text chunks).
    #[error("cannot write PNG file '{}': {source}; check the path and free disk space", path.display())]
    PngEncode {
        /// File involved.
        path: PathBuf,
        /// Underlying error.
        #[source]
        source: ::png::EncodingError,
    },

    /// The PNG decoder failed.
    #[error("cannot read PNG file '{}': {source}; check that it is a PNG image", path.display())]
    PngDecode {
        /// File involved.
        path: PathBuf,
        /// Underlying error.
        #[source]
        source: ::png::DecodingError,
    },

    /// The file's format cannot express what the scene holds (the message names the field).
    #[error("cannot write '{}': {message}", path.display())]
    Unsupported {
        /// File that would have been written.
        path: PathBuf,
        /// What it cannot express, and what to do.
        message: String,
    },

    /// JSON serialisation failed.
    #[error("cannot write JSON file '{}': {source}; the value holds something JSON cannot represent", path.display())]
    Json {
        /// File involved.
        path: PathBuf,
        /// Underlying error.
        #[source]
        source: serde_json::Error,
    },

    /// An EXR file lacks the requested layer (or the R, G, B channels of it).
    #[error("EXR file '{}' has no {} (channels present: {available}); pick one of those layers or re-render", path.display(), layer_label(layer))]
    MissingLayer {
        /// File involved.
        path: PathBuf,
        /// Requested layer name ("" = main RGB layer).
        layer: String,
        /// Channel names found in the file, comma separated.
        available: String,
    },

    /// An image's buffer does not match its size, or it is empty.
    #[error("image for '{}' is invalid: {reason}; this is a bug in the code that built the image", path.display())]
    InvalidImage {
        /// File the image was to be written to.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },

    /// Two images that must have one size do not.
    #[error("{what}: image is {}x{} but the reference is {}x{}; render both at the same resolution", size.0, size.1, reference_size.0, reference_size.1)]
    SizeMismatch {
        /// Which comparison or file this is.
        what: String,
        /// Width and height of the image.
        size: (u32, u32),
        /// Width and height of the reference (or the first layer).
        reference_size: (u32, u32),
    },

    /// The reference image holds NaN or infinite pixels, so no error can be measured.
    #[error(
        "reference image has {count} non-finite (NaN/Inf) pixels; re-render or repair the reference before \
        comparing against it"
    )]
    NonFiniteReference {
        /// Number of pixels with a non-finite channel.
        count: u64,
    },
}

/// What to check after an EXR error: a read fails on a bad file, a write on the place.
fn exr_hint(action: &str) -> &'static str {
    if action == "read" {
        "check the path, and that the file is an uncorrupted OpenEXR image"
    } else {
        "check that the directory exists, is writable and has free space"
    }
}

impl OutputError {
    /// The same error naming `path`, the file the user asked for, where it named a temporary
    /// file written on the way there (the staging and atomic-write names are ours, not theirs).
    pub fn at(self, user_path: &std::path::Path) -> OutputError {
        let p = user_path.to_owned();
        match self {
            OutputError::Io { action, source, .. } => OutputError::Io { path: p, action, source },
            OutputError::Exr { action, source, .. } => OutputError::Exr { path: p, action, source },
            OutputError::Png { source, .. } => OutputError::Png { path: p, source },
            OutputError::PngEncode { source, .. } => OutputError::PngEncode { path: p, source },
            OutputError::Json { source, .. } => OutputError::Json { path: p, source },
            OutputError::InvalidImage { reason, .. } => OutputError::InvalidImage { path: p, reason },
            other => other,
        }
    }
}

fn layer_label(layer: &str) -> String {
    if layer.is_empty() {
        "main RGB layer (channels R, G, B)".to_owned()
    } else {
        format!("layer '{layer}' (channels {layer}.R, {layer}.G, {layer}.B)")
    }
}
