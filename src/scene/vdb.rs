//! OpenVDB density grids (`density = { kind = "vdb", file = "cloud.vdb", grid = "density" }`),
//! read with the `vdb-rs` crate (pure Rust, plus its vendored Blosc) into the same dense grid
//! as a `.vol`.
//!
//! The grid's active voxels and tiles are copied into a dense array over their index-space
//! bounding box; inactive voxels take the value 0 (a density grid's background; a grid whose
//! background is not 0 is rare and would read as 0 outside its active set). Voxel (i, j, k) of
//! the box becomes sample (i - min.x, j - min.y, k - min.z) of the dense grid, which spans the
//! medium's bounds like any grid (`docs/scene-format.md`): the file's own transform (voxel size,
//! origin) is not used, as a `.vol` header's bounding box is not.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use super::error::human_bytes;
use super::{Grid, LoadOptions, SceneError};

/// What `load_vdb` needs to read a grid and report on it.
pub(crate) struct VdbRequest<'a> {
    pub scene_file: &'a Path,
    /// Resolved against the scene's folder.
    pub resolved: PathBuf,
    /// As written in the scene, for the hint about relative paths.
    pub file_as_written: &'a Path,
    /// The grid's name in the file.
    pub grid: &'a str,
    pub opts: &'a LoadOptions,
    /// What its values are, for messages: "density", "emission" or "temperature".
    pub what: &'static str,
    /// The scene field that names it (`medium.density`), for hints.
    pub key: &'a str,
    /// The index-space box the dense grid spans: its first voxel and size. None: the grid's own
    /// active voxels' bounding box. A medium's emission or temperature grid from an OpenVDB file
    /// is read over its density grid's box, so their voxels coincide (voxels outside it, where
    /// nothing absorbs, are dropped).
    pub region: Option<([i64; 3], [u32; 3])>,
}

impl VdbRequest<'_> {
    fn err(&self, message: impl Into<String>) -> SceneError {
        SceneError::Grid {
            file: self.scene_file.to_path_buf(),
            field: format!("{}.file", self.key),
            grid: self.resolved.clone(),
            message: message.into(),
        }
    }
}

/// vdb-rs's error, said so a user can act on it: its I/O errors display as a bare "IoError".
fn why(e: &vdb_rs::ParseError) -> String {
    match e {
        vdb_rs::ParseError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            "it ends early: the file is truncated".into()
        }
        vdb_rs::ParseError::IoError(io) => format!("{io}; the file may be damaged"),
        other => format!("{other}; the file may be damaged or from a newer OpenVDB"),
    }
}

thread_local! {
    /// Set while [`quietly`] runs a parse on this thread: its panics are caught and reported as
    /// the one error line, so the panic hook prints nothing for them.
    static QUIET: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// `f` behind `catch_unwind`, its panic message kept from stderr (a damaged file gave the
/// reader's "thread 'main' panicked at ..." before our error line). The hook is wrapped once
/// for the process, and stays silent only on this thread while `f` runs: other threads' panics
/// print as before.
fn quietly<R>(f: impl FnOnce() -> R + std::panic::UnwindSafe) -> std::thread::Result<R> {
    static WRAP: std::sync::Once = std::sync::Once::new();
    WRAP.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET.with(|q| q.get()) {
                previous(info)
            }
        }));
    });
    QUIET.with(|q| q.set(true));
    let result = std::panic::catch_unwind(f);
    QUIET.with(|q| q.set(false));
    result
}

/// One active value: a voxel, or a tile of `edge`^3 voxels from its `min` corner.
struct Active {
    min: [i64; 3],
    edge: i64,
    value: f32,
}

/// Read float grid `req.grid` of an OpenVDB file into a dense [`Grid`], and the index of its
/// first voxel.
pub(crate) fn load_vdb(req: &VdbRequest) -> Result<(Grid, [i64; 3]), SceneError> {
    let hint = if req.file_as_written.is_relative() {
        "; relative paths are resolved against the scene file's folder"
    } else {
        ""
    };
    let file = File::open(&req.resolved).map_err(|e| req.err(format!("cannot open OpenVDB file: {e}{hint}")))?;
    // vdb-rs indexes its node maps without checking them: a damaged file must be an error, not
    // a panic, so the parse runs behind catch_unwind (its panic message is kept for the line).
    let name = req.grid.to_owned();
    let (what, key) = (req.what, req.key.to_owned());
    let parsed = quietly(move || -> Result<Result<Vec<Active>, String>, String> {
        let mut reader = vdb_rs::VdbReader::new(BufReader::new(file))
            .map_err(|e| format!("not a readable OpenVDB file ({})", why(&e)))?;
        let Some(descriptor) = reader.grid_descriptors.get(&name) else {
            let mut names = reader.available_grids();
            names.sort();
            return Ok(Err(format!(
                "has no grid named {name:?}; its grids are {}; set {key}.grid to one of them",
                names.iter().map(|n| format!("{n:?}")).collect::<Vec<_>>().join(", ")
            )));
        };
        if !descriptor.grid_type.contains("float") {
            return Ok(Err(format!(
                "grid {name:?} holds {} values, not float: a {what} grid is a FloatGrid",
                descriptor.grid_type
            )));
        }
        let grid = reader.read_grid::<f32>(&name).map_err(|e| format!("cannot read grid {name:?} ({})", why(&e)))?;
        Ok(Ok(grid
            .iter()
            .map(|(c, value, level)| Active {
                min: [c.x as i64, c.y as i64, c.z as i64],
                edge: level.scale() as i64,
                value,
            })
            .collect()))
    });
    let active = match parsed {
        Ok(Ok(Ok(active))) => active,
        Ok(Ok(Err(message))) | Ok(Err(message)) => return Err(req.err(message)),
        Err(panic) => {
            let why = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown".into());
            return Err(req.err(format!("a damaged or unsupported OpenVDB file (the reader failed: {why})")));
        }
    };
    if active.is_empty() && req.region.is_none() {
        return Err(req.err(format!("grid {:?} has no active voxels: the medium would be empty", req.grid)));
    }
    for a in &active {
        if !(a.value.is_finite() && a.value >= 0.0) {
            return Err(req.err(format!(
                "grid {:?} has the value {} at voxel ({}, {}, {}); {} values must be finite and >= 0",
                req.grid, a.value, a.min[0], a.min[1], a.min[2], req.what
            )));
        }
    }
    let mut lo = [i64::MAX; 3];
    let mut hi = [i64::MIN; 3];
    match req.region {
        Some((first, dims)) => {
            lo = first;
            hi = [0, 1, 2].map(|a| first[a] + dims[a] as i64 - 1);
        }
        None => {
            for a in &active {
                for axis in 0..3 {
                    lo[axis] = lo[axis].min(a.min[axis]);
                    hi[axis] = hi[axis].max(a.min[axis] + a.edge - 1);
                }
            }
        }
    }
    let dims_wide = [hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1];
    let voxels = dims_wide.iter().map(|&d| d as u128).product::<u128>();
    let needed = voxels.saturating_mul(4);
    if needed > u128::from(req.opts.memory_budget_bytes) || dims_wide.iter().any(|&d| d > i64::from(u32::MAX)) {
        return Err(req.err(format!(
            "grid {:?} spans {} x {} x {} voxels, {} as a dense f32 grid, past the memory budget of {}; crop or \
                resample it, or raise --memory-budget",
            req.grid,
            dims_wide[0],
            dims_wide[1],
            dims_wide[2],
            human_bytes(u64::try_from(needed).unwrap_or(u64::MAX)),
            human_bytes(req.opts.memory_budget_bytes)
        )));
    }
    let dims = [dims_wide[0] as u32, dims_wide[1] as u32, dims_wide[2] as u32];
    let (nx, ny) = (dims_wide[0] as usize, dims_wide[1] as usize);
    let mut data = vec![0f32; voxels as usize];
    for a in &active {
        // Clipped to the box (only a given region can cut a voxel or tile off).
        let from = [0, 1, 2].map(|x| a.min[x].max(lo[x]));
        let to = [0, 1, 2].map(|x| (a.min[x] + a.edge - 1).min(hi[x]));
        if (0..3).any(|x| from[x] > to[x]) {
            continue;
        }
        for k in from[2]..=to[2] {
            for j in from[1]..=to[1] {
                let row = ((k - lo[2]) as usize * ny + (j - lo[1]) as usize) * nx;
                let (x0, x1) = ((from[0] - lo[0]) as usize, (to[0] - lo[0]) as usize);
                data[row + x0..=row + x1].fill(a.value);
            }
        }
    }
    Ok((Grid { dims, data, file: req.resolved.clone() }, lo))
}
