//! Atomic file writes: write to a temporary sibling, move it over the final name on success
//! (`tempfile`'s `NamedTempFile`: unique names, removed when dropped, `persist` renames).
//! Errors name the file the user asked for, never the temporary one.

use std::fs;
use std::path::{Path, PathBuf};

use tempfile::NamedTempFile;

use super::OutputError;

/// Write `path` atomically: `write` receives the path of a fresh temporary file in the same
/// directory and must write the complete file there; on success it is flushed to disk and
/// renamed to `path` (replacing any old file), on failure it is removed and the error
/// returned. Either way no partial file ever carries the name `path`.
pub fn write_atomically<F>(path: &Path, write: F) -> Result<(), OutputError>
where
    F: FnOnce(&Path) -> Result<(), OutputError>,
{
    let tmp = temp_beside(path, "tmp")?;
    write(tmp.path()).map_err(|e| e.at(path))?;
    flush(tmp.path()).map_err(|e| e.at(path))?;
    tmp.persist(path).map(drop).map_err(|e| OutputError::Io {
        path: path.to_owned(),
        action: "move the finished file into place as",
        source: without_temp_path(e.error),
    })
}

/// A hidden temporary file beside `path` (same filesystem, so the final rename is atomic),
/// `.name.XXXXXX.suffix`.
fn temp_beside(path: &Path, suffix: &str) -> Result<NamedTempFile, OutputError> {
    let io = |source| OutputError::Io { path: path.to_owned(), action: "write", source };
    let name = path
        .file_name()
        .ok_or_else(|| io(std::io::Error::new(std::io::ErrorKind::InvalidInput, "the path has no file name")))?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    };
    if !dir.is_dir() {
        return Err(OutputError::Io {
            path: path.to_owned(),
            action: "write",
            source: std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("directory {} does not exist", dir.display()),
            ),
        });
    }
    let (prefix, suffix) = (format!(".{}.", name.to_string_lossy()), format!(".{suffix}"));
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(&suffix);
    // An output is the user's file, not a secret: created as File::create would (0666 less the
    // umask), not with tempfile's private 0600 (images and reports came out unreadable to the
    // group and to a web server).
    #[cfg(unix)]
    builder.permissions(<fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(0o666));
    builder.tempfile_in(&dir).map_err(|e| io(without_temp_path(e)))
}

/// tempfile's errors append the temporary file's path ("... at path \"/d/.x.exr.Ab12.tmp\"");
/// the message names the user's path instead, so keep only the OS error's own text.
fn without_temp_path(e: std::io::Error) -> std::io::Error {
    let text = e.to_string();
    let os = text.split(" at path ").next().unwrap_or(&text).to_string();
    std::io::Error::new(e.kind(), os)
}

/// The data on disk before the rename makes it visible under the final name.
fn flush(p: &Path) -> Result<(), OutputError> {
    fs::File::open(p).and_then(|f| f.sync_all()).map_err(|source| OutputError::Io {
        path: p.to_owned(),
        action: "flush",
        source,
    })
}

/// Outputs that appear together or not at all (an image, its PNG, its metrics JSON): each is
/// first written in full under a hidden staging name beside its final one; only when every
/// one is written does [`Staging::commit`] move them into place. On any failure, or when
/// dropped uncommitted, nothing staged is left behind and nothing already placed stays.
#[derive(Debug, Default)]
pub struct Staging {
    /// (staged file, final path), in the order staged.
    staged: Vec<(NamedTempFile, PathBuf)>,
}

impl Staging {
    pub fn new() -> Staging {
        Staging::default()
    }

    /// Write `path`'s content (by `write`, given the staging path, which keeps `path`'s
    /// extension for writers that look at it) under its staging name.
    pub fn stage<F>(&mut self, path: &Path, write: F) -> Result<(), OutputError>
    where
        F: FnOnce(&Path) -> Result<(), OutputError>,
    {
        let ext = path.extension().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let tmp = temp_beside(path, &format!("partial.{ext}"))?;
        write(tmp.path()).map_err(|e| e.at(path))?;
        self.staged.push((tmp, path.to_owned()));
        Ok(())
    }

    /// Move every staged output into place; on a failure, remove what was placed (what is
    /// still staged is removed as its temporary file drops), and return the error.
    pub fn commit(mut self) -> Result<(), OutputError> {
        let staged = std::mem::take(&mut self.staged);
        let mut placed: Vec<PathBuf> = Vec::new();
        for (tmp, fin) in staged {
            if let Err(e) = tmp.persist(&fin) {
                for p in &placed {
                    let _ = fs::remove_file(p);
                }
                return Err(OutputError::Io {
                    path: fin,
                    action: "move the finished output into place as",
                    source: without_temp_path(e.error),
                });
            }
            placed.push(fin);
        }
        Ok(())
    }
}
