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

/// Outputs that appear together or not at all (an image, its PNG, its metrics JSON): each is
/// first written in full under a hidden staging name beside its final one; only when every
/// one is written does [`Staging::commit`] rename them into place. On any failure, or when
/// dropped uncommitted, nothing staged is left behind and nothing already placed stays.
#[derive(Debug, Default)]
pub struct Staging {
    /// (staging path, final path), in the order staged.
    staged: Vec<(PathBuf, PathBuf)>,
}

impl Staging {
    pub fn new() -> Staging {
        Staging::default()
    }

    /// Write `path`'s content (by `write`, given the staging path) under its staging name.
    pub fn stage<F>(&mut self, path: &Path, write: F) -> Result<(), OutputError>
    where
        F: FnOnce(&Path) -> Result<(), OutputError>,
    {
        let tmp = staging_path(path);
        self.staged.push((tmp.clone(), path.to_owned()));
        write(&tmp)
    }

    /// Rename every staged output into place; on a failure, remove what was placed and what
    /// is still staged, and return the error.
    pub fn commit(mut self) -> Result<(), OutputError> {
        let staged = std::mem::take(&mut self.staged);
        for (i, (tmp, fin)) in staged.iter().enumerate() {
            if let Err(source) = fs::rename(tmp, fin) {
                for (_, placed) in &staged[..i] {
                    let _ = fs::remove_file(placed);
                }
                for (left, _) in &staged[i..] {
                    let _ = fs::remove_file(left);
                }
                return Err(OutputError::Io {
                    path: fin.clone(),
                    action: "move the finished output into place as",
                    source,
                });
            }
        }
        Ok(())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        for (tmp, _) in &self.staged {
            let _ = fs::remove_file(tmp);
        }
    }
}

/// `dir/.name.partial.ext`: same directory (so the final rename is atomic), same extension
/// (so writers that look at it still work), hidden.
fn staging_path(p: &Path) -> PathBuf {
    let name = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = p.extension().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    p.with_file_name(format!(".{name}.partial.{ext}"))
}
