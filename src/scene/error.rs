//! Scene errors: every variant displays as one line that names the scene file and the field,
//! says what is wrong and what to do about it.

use std::path::PathBuf;

/// Why a scene could not be loaded. `Display` is always a single line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneError {
    /// The scene file itself could not be read.
    #[error("{}: cannot read scene file: {source}", .file.display())]
    Read {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The text is not valid TOML.
    #[error("{}:{line}:{column}: malformed TOML: {message}", .file.display())]
    Syntax { file: PathBuf, line: usize, column: usize, message: String },

    /// A key the format does not know (a typo, or a key from another kind of light/camera).
    #[error("{}{}: unknown key `{key}`; {expected} (unknown keys are errors, not ignored)",
        .file.display(), line_suffix(*.line))]
    UnknownKey {
        file: PathBuf,
        /// Full dotted path, e.g. `medium.albdo` or `light[1].intensty`.
        key: String,
        /// Line in the scene file, when the key could be located there.
        line: Option<usize>,
        /// What the section accepts, e.g. "expected one of `bounds`, `sigma_t`, ...".
        expected: String,
    },

    /// A required key is absent.
    #[error("{}: missing required key `{key}`; {hint}", .file.display())]
    MissingKey { file: PathBuf, key: String, hint: String },

    /// A key is present but its value is wrong (type, range, or inconsistent with another key).
    #[error("{}: {field}: {message}", .file.display())]
    Invalid { file: PathBuf, field: String, message: String },

    /// A `--set key=value` override could not be applied.
    #[error("{}: override `{key}`: {message}", .file.display())]
    Override { file: PathBuf, key: String, message: String },

    /// A grid file (density, emission or temperature) is missing, truncated, or holds
    /// something we cannot use. `field`: the scene key naming it (`medium.emission.file`).
    #[error("{}: {field} `{}`: {message}", .file.display(), .grid.display())]
    Grid { file: PathBuf, field: String, grid: PathBuf, message: String },

    /// A grid would not fit the memory budget (checked before reading it). `field`: the scene
    /// key naming it.
    #[error("{}: {field} `{}`: grid {}x{}x{} needs {} of f32 data but the memory budget is {}; resample \
        the grid or raise --memory-budget",
        .file.display(), .grid.display(), .dims[0], .dims[1], .dims[2], human_bytes(*.needed_bytes), human_bytes(*.budget_bytes))]
    GridTooLarge { file: PathBuf, field: String, grid: PathBuf, dims: [u64; 3], needed_bytes: u64, budget_bytes: u64 },
}

impl SceneError {
    /// The dotted field this error is about, where there is one.
    pub fn field(&self) -> Option<&str> {
        match self {
            SceneError::UnknownKey { key, .. }
            | SceneError::MissingKey { key, .. }
            | SceneError::Override { key, .. } => Some(key),
            SceneError::Invalid { field, .. } => Some(field),
            SceneError::Grid { field, .. } | SceneError::GridTooLarge { field, .. } => Some(field),
            SceneError::Read { .. } | SceneError::Syntax { .. } => None,
        }
    }
}

fn line_suffix(line: Option<usize>) -> String {
    line.map(|l| format!(":{l}")).unwrap_or_default()
}

/// `1536` -> "1.5 KiB"; exact byte count kept for small sizes.
pub(crate) fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["KiB", "MiB", "GiB", "TiB", "PiB"];
    if bytes < 1024 {
        return format!("{bytes} B");
    }
    let mut value = bytes as f64 / 1024.0;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.1} {} ({bytes} bytes)", UNITS[unit])
}

/// Collapse any multi-line text (toml's messages can span lines) into one line.
pub(crate) fn one_line(text: &str) -> String {
    let parts: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    parts.join("; ")
}
