//! JSON reports (metrics, bench results), written atomically.

use std::io::Write;
use std::path::Path;

use serde::Serialize;

use super::{write_atomically, OutputError};

/// Write `value` as pretty-printed JSON (with a trailing newline) to `path`, atomically.
pub fn write_json<T: Serialize + ?Sized>(path: &Path, value: &T) -> Result<(), OutputError> {
    let mut text =
        serde_json::to_vec_pretty(value).map_err(|source| OutputError::Json { path: path.to_owned(), source })?;
    text.push(b'\n');
    write_text(path, &text)
}

/// Write bytes (CSV, SVG, JSON) to `path` atomically.
pub fn write_text(path: &Path, text: impl AsRef<[u8]>) -> Result<(), OutputError> {
    write_atomically(path, |tmp| {
        std::fs::File::create(tmp).and_then(|mut f| f.write_all(text.as_ref())).map_err(|source| OutputError::Io {
            path: tmp.to_owned(),
            action: "write",
            source,
        })
    })
}
