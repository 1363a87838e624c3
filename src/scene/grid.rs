//! Density grids: loading Mitsuba 3 `.vol` and raw little-endian f32 files, and trilinear
//! sampling between voxel centres.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::{Grid, LoadOptions, SceneError};

/// The first four bytes of an OpenVDB file: its magic number 0x56444220 ("VDB" and a space),
/// little-endian.
const OPENVDB_MAGIC: [u8; 4] = [0x20, 0x42, 0x44, 0x56];

/// Whether the file at `path` starts with [`OPENVDB_MAGIC`].
fn is_openvdb(path: &Path) -> bool {
    let mut head = [0u8; 4];
    File::open(path).and_then(|mut f| f.read_exact(&mut head)).is_ok() && head == OPENVDB_MAGIC
}

/// Size of a Mitsuba 3 `.vol` header: "VOL", u8 version, i32 encoding, i32 x3 resolution,
/// i32 channels, f32 x6 bounding box.
pub(crate) const VOL_HEADER_BYTES: u64 = 48;

impl Grid {
    /// Voxel value at integer index `(i, j, k)`; indices past the last voxel clamp to it.
    pub fn at(&self, i: u32, j: u32, k: u32) -> f32 {
        let [nx, ny, nz] = self.dims;
        if nx == 0 || ny == 0 || nz == 0 {
            return 0.0;
        }
        let (i, j, k) = (u64::from(i.min(nx - 1)), u64::from(j.min(ny - 1)), u64::from(k.min(nz - 1)));
        // Checked: a hand-built Grid may have dims that do not match its data.
        let index = k
            .checked_mul(u64::from(ny))
            .and_then(|v| v.checked_add(j))
            .and_then(|v| v.checked_mul(u64::from(nx)))
            .and_then(|v| v.checked_add(i))
            .and_then(|v| usize::try_from(v).ok());
        let Some(index) = index else {
            return 0.0;
        };
        self.data.get(index).copied().unwrap_or(0.0)
    }

    /// Trilinear interpolation at `u` in [0, 1]^3 (the medium bounds mapped to the unit
    /// cube). Sample `i` sits at the voxel centre `(i + 0.5) / n`; between the outermost
    /// centres and the faces the value is clamped (constant), and `u` outside [0, 1] clamps
    /// to the face.
    pub fn sample(&self, u: Vec3) -> f32 {
        let [nx, ny, nz] = self.dims;
        if nx == 0 || ny == 0 || nz == 0 {
            return 0.0;
        }
        // Continuous voxel coordinate whose integer values are voxel centres.
        let axis = |u: f32, n: u32| -> (u32, u32, f32) {
            let x = (u * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
            // NaN clamps to NaN; treat it as the first centre.
            let x = if x.is_nan() { 0.0 } else { x };
            let i0 = (x.floor() as u32).min(n - 1);
            let i1 = (i0 + 1).min(n - 1);
            (i0, i1, x - i0 as f32)
        };
        let (i0, i1, tx) = axis(u.x, nx);
        let (j0, j1, ty) = axis(u.y, ny);
        let (k0, k1, tz) = axis(u.z, nz);
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(self.at(i0, j0, k0), self.at(i1, j0, k0), tx);
        let c10 = lerp(self.at(i0, j1, k0), self.at(i1, j1, k0), tx);
        let c01 = lerp(self.at(i0, j0, k1), self.at(i1, j0, k1), tx);
        let c11 = lerp(self.at(i0, j1, k1), self.at(i1, j1, k1), tx);
        lerp(lerp(c00, c10, ty), lerp(c01, c11, ty), tz)
    }

    /// Largest voxel value (0 for an empty grid).
    pub fn max_value(&self) -> f32 {
        self.data.iter().copied().fold(0.0, f32::max)
    }
}

/// Everything needed to read a grid and report problems with it.
pub(crate) struct GridRequest<'a> {
    pub scene_file: &'a Path,
    /// As written in the scene, for messages.
    pub file_as_written: &'a Path,
    /// Resolved against the scene's folder.
    pub resolved: PathBuf,
    /// `dims` from the scene, if given.
    pub dims: Option<[i64; 3]>,
    pub opts: &'a LoadOptions,
    /// What its values are, for messages: "density", "emission" or "temperature".
    pub what: &'static str,
    /// The scene field that names it (`medium.density`), for hints.
    pub key: &'a str,
}

impl GridRequest<'_> {
    fn err(&self, message: impl Into<String>) -> SceneError {
        SceneError::Grid {
            file: self.scene_file.to_path_buf(),
            field: format!("{}.file", self.key),
            grid: self.resolved.clone(),
            message: message.into(),
        }
    }
}

/// Open, check and read a grid (density, emission or temperature). The size is checked against the memory budget from
/// the header (or `dims`) before any voxel is read.
pub(crate) fn load_grid(req: &GridRequest) -> Result<Grid, SceneError> {
    let hint = if req.file_as_written.is_relative() {
        "; relative paths are resolved against the scene file's folder"
    } else {
        ""
    };
    let file = File::open(&req.resolved).map_err(|e| req.err(format!("cannot open grid file: {e}{hint}")))?;
    let file_len = file.metadata().map_err(|e| req.err(format!("cannot read grid file: {e}")))?.len();
    let mut reader = BufReader::with_capacity(1 << 16, file);

    // Mitsuba 3 .vol is recognised by its magic; anything else is raw f32 and needs dims.
    let mut magic = [0u8; 3];
    let is_vol = file_len >= 3 && {
        reader.read_exact(&mut magic).map_err(|e| req.err(format!("cannot read grid file: {e}")))?;
        &magic == b"VOL"
    };

    let (dims, data_offset) = if is_vol {
        let dims = read_vol_header(req, &mut reader, file_len)?;
        if let Some(given) = req.dims {
            if given.map(|d| d as u64) != dims.map(u64::from) || given.iter().any(|&d| d < 0) {
                return Err(req.err(format!(
                    "dims = [{}, {}, {}] disagrees with the .vol header ({}x{}x{}); remove dims (a .vol file carries \
                        its own size)",
                    given[0], given[1], given[2], dims[0], dims[1], dims[2]
                )));
            }
        }
        (dims, VOL_HEADER_BYTES)
    } else {
        let Some(given) = req.dims else {
            if file_len < VOL_HEADER_BYTES {
                return Err(req.err(format!(
                    "file is {} ({file_len} bytes): too short for a Mitsuba .vol header ({VOL_HEADER_BYTES} bytes) or \
                        any grid; the file is truncated or not a grid",
                    if file_len == 0 { "empty" } else { "truncated" }
                )));
            }
            if magic == OPENVDB_MAGIC[..3] && is_openvdb(&req.resolved) {
                return Err(req.err(format!(
                    "an OpenVDB file; read it with {} = {{ kind = \"vdb\", file = ..., grid = \"{}\" }}",
                    req.key, req.what
                )));
            }
            return Err(req.err(
                "not a Mitsuba .vol file (no 'VOL' magic) and no dims given; for a raw little-endian f32 grid add \
                    dims = [nx, ny, nz]",
            ));
        };
        let mut dims = [0u32; 3];
        for (axis, (&d, out)) in given.iter().zip(dims.iter_mut()).enumerate() {
            *out = u32::try_from(d).ok().filter(|&d| d > 0).ok_or_else(|| {
                req.err(format!("dims[{axis}] = {d} must be a positive voxel count (dims = [nx, ny, nz])"))
            })?;
        }
        (dims, 0)
    };

    // Budget before reading: the grid is held as f32 in memory.
    // Saturating: three u32 resolutions can overflow u64 (a hostile header must not panic).
    let voxels = dims.iter().fold(1u64, |acc, &d| acc.saturating_mul(u64::from(d)));
    let needed = voxels.saturating_mul(4);
    if needed > req.opts.memory_budget_bytes {
        return Err(SceneError::GridTooLarge {
            file: req.scene_file.to_path_buf(),
            field: format!("{}.file", req.key),
            grid: req.resolved.clone(),
            dims: dims.map(u64::from),
            needed_bytes: needed,
            budget_bytes: req.opts.memory_budget_bytes,
        });
    }

    let expected = data_offset.saturating_add(needed);
    if file_len != expected {
        let what = if is_vol {
            format!("a .vol of {}x{}x{} float32 voxels (48-byte header + data)", dims[0], dims[1], dims[2])
        } else {
            format!("a raw grid of dims = [{}, {}, {}] f32", dims[0], dims[1], dims[2])
        };
        let fix = if file_len < expected {
            "the file is truncated or dims are wrong"
        } else {
            "the file has extra bytes or dims are wrong"
        };
        return Err(req.err(format!("{what} needs {expected} bytes but the file has {file_len} bytes; {fix}")));
    }

    // Read the voxels in chunks (no second full-size copy) and check each one.
    let count = usize::try_from(voxels).map_err(|_| req.err("grid too large for this platform's address space"))?;
    let mut data = Vec::new();
    data.try_reserve_exact(count).map_err(|_| req.err(format!("cannot allocate {needed} bytes for the grid")))?;
    if !is_vol {
        // Raw files were only peeked at for the magic; start over.
        let file = File::open(&req.resolved).map_err(|e| req.err(format!("cannot open grid file: {e}")))?;
        reader = BufReader::with_capacity(1 << 16, file);
    }
    let mut chunk = vec![0u8; 1 << 16];
    while data.len() < count {
        let n = ((count - data.len()) * 4).min(chunk.len());
        reader.read_exact(&mut chunk[..n]).map_err(|e| req.err(format!("cannot read grid data: {e}")))?;
        data.extend(chunk[..n].chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])));
    }

    if let Some((index, &value)) = data.iter().enumerate().find(|(_, v)| !v.is_finite() || **v < 0.0) {
        let (nx, ny) = (dims[0] as usize, dims[1] as usize);
        let (i, j, k) = (index % nx, (index / nx) % ny, index / (nx * ny));
        return Err(req.err(format!(
            "voxel ({i}, {j}, {k}) (value #{index}, x fastest) is {value}; {} values must be finite and >= 0, fix the \
                grid",
            req.what
        )));
    }

    Ok(Grid { dims, data, file: req.resolved.clone() })
}

/// Check a `.vol` header (after the magic) and return its resolution.
fn read_vol_header(req: &GridRequest, reader: &mut impl Read, file_len: u64) -> Result<[u32; 3], SceneError> {
    if file_len < VOL_HEADER_BYTES {
        return Err(req.err(format!(
            "truncated .vol header: expected at least {VOL_HEADER_BYTES} bytes but the file has {file_len} bytes"
        )));
    }
    let mut rest = [0u8; (VOL_HEADER_BYTES - 3) as usize];
    reader.read_exact(&mut rest).map_err(|e| req.err(format!("cannot read .vol header: {e}")))?;
    let version = rest[0];
    let int = |offset: usize| i32::from_le_bytes([rest[offset], rest[offset + 1], rest[offset + 2], rest[offset + 3]]);
    let (encoding, xres, yres, zres, channels) = (int(1), int(5), int(9), int(13), int(17));
    if version != 3 {
        return Err(req.err(format!(
            "bad .vol header: version {version}, only version 3 (Mitsuba 3) is supported; re-export the grid"
        )));
    }
    if encoding != 1 {
        return Err(req.err(format!(
            "bad .vol header: encoding {encoding}, only encoding 1 (float32) is supported; convert the grid to float32"
        )));
    }
    if channels != 1 {
        return Err(req.err(format!(
            "bad .vol header: {channels} channels, only 1-channel {} grids are supported; export a single channel",
            req.what
        )));
    }
    let mut dims = [0u32; 3];
    for (axis, (&d, out)) in [xres, yres, zres].iter().zip(dims.iter_mut()).enumerate() {
        *out = u32::try_from(d).ok().filter(|&d| d > 0).ok_or_else(|| {
            req.err(format!("bad .vol header: resolution[{axis}] = {d}, must be a positive voxel count"))
        })?;
    }
    Ok(dims)
}

/// Bytes of a Mitsuba 3 `.vol` file (version 3, float32, one channel) for `data`, with the
/// bounding box `bbox_min`..`bbox_max` in the header. Used by tests and tools.
pub fn write_vol(dims: [u32; 3], data: &[f32], bbox_min: Vec3, bbox_max: Vec3) -> Vec<u8> {
    let mut out = Vec::with_capacity(VOL_HEADER_BYTES as usize + data.len() * 4);
    out.extend_from_slice(b"VOL");
    out.push(3);
    for v in [1i32, dims[0] as i32, dims[1] as i32, dims[2] as i32, 1] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in bbox_min.to_array().into_iter().chain(bbox_max.to_array()) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}
