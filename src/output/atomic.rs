//! Atomic file writes: write to a temporary sibling, rename over the final name on success.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::OutputError;

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Write `path` atomically: `write` receives a fresh temporary path in the same directory
/// and must create the complete file there; on success the temporary file is flushed to
/// disk and renamed to `path` (replacing any old file), on failure it is removed and the
/// error returned. Either way no partial file ever carries the name `path`.
pub fn write_atomically<F>(path: &Path, write: F) -> Result<(), OutputError>
where
    F: FnOnce(&Path) -> Result<(), OutputError>,
{
    let tmp = temp_sibling(path)?;
    let result = write(&tmp).and_then(|()| {
        // Flush the data before the rename makes it visible under the final name.
        fs::File::open(&tmp).and_then(|f| f.sync_all()).map_err(|source| OutputError::Io {
            path: tmp.clone(),
            action: "flush",
            source,
        })?;
        fs::rename(&tmp, path).map_err(|source| OutputError::Io {
            path: path.to_owned(),
            action: "rename temporary file into place as",
            source,
        })
    });
    if result.is_err() {
        // Best effort: the closure may not have created the file at all.
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// `dir/.name.<pid>.<n>.tmp`: hidden, unique within this process, same filesystem as `path`.
fn temp_sibling(path: &Path) -> Result<PathBuf, OutputError> {
    let name = path.file_name().ok_or_else(|| OutputError::Io {
        path: path.to_owned(),
        action: "write to",
        source: std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name"),
    })?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    };
    if !dir.is_dir() {
        return Err(OutputError::Io {
            path: dir,
            action: "write into directory",
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "directory does not exist"),
        });
    }
    let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp_name = format!(".{}.{}.{}.tmp", name.to_string_lossy(), std::process::id(), n);
    Ok(dir.join(tmp_name))
}
