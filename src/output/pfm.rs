//! Portable float maps (`.pfm`): linear f32 RGB with no compression and no metadata, the
//! format pbrt-v4 and many image tools read. Paul Debevec's layout: the header `PF`, the size,
//! and a scale whose sign gives the byte order (negative: little-endian); rows bottom to top.

use std::path::Path;

use super::png::check_writable;
use super::{write_atomically, Image, OutputError};

/// Write `image` as a little-endian PFM, atomically.
pub fn write_pfm(path: &Path, image: &Image) -> Result<(), OutputError> {
    check_writable(path, image)?;
    let (w, h) = (image.width as usize, image.height as usize);
    let mut bytes = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
    bytes.reserve(12 * w * h);
    for row in (0..h).rev() {
        for v in &image.data[3 * w * row..3 * w * (row + 1)] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    write_atomically(path, |tmp| {
        std::fs::write(tmp, &bytes).map_err(|source| OutputError::Io { path: path.to_owned(), action: "write", source })
    })
}

/// Read a PFM written by [`write_pfm`] (RGB, either byte order).
pub fn read_pfm(path: &Path) -> Result<Image, OutputError> {
    let bad = |reason: &str| OutputError::InvalidImage { path: path.to_owned(), reason: reason.to_owned() };
    let bytes =
        std::fs::read(path).map_err(|source| OutputError::Io { path: path.to_owned(), action: "read", source })?;
    // Three whitespace-terminated header tokens after the magic: width, height, scale.
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 {
        while at < bytes.len() && bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        let start = at;
        while at < bytes.len() && !bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        if start == at {
            return Err(bad("truncated PFM header"));
        }
        fields.push(String::from_utf8_lossy(&bytes[start..at]).into_owned());
    }
    at += 1; // the single whitespace byte that ends the header
    if fields[0] != "PF" {
        return Err(bad("not an RGB PFM (header is not PF)"));
    }
    let parse = |s: &str| s.parse::<usize>().map_err(|_| bad("PFM size is not an integer"));
    let (w, h) = (parse(&fields[1])?, parse(&fields[2])?);
    let scale: f32 = fields[3].parse().map_err(|_| bad("PFM scale is not a number"))?;
    let data = bytes.get(at..at + 12 * w * h).ok_or_else(|| bad("PFM data shorter than its size"))?;
    let value = |c: &[u8]| {
        let b = [c[0], c[1], c[2], c[3]];
        if scale < 0.0 {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        }
    };
    let mut out = vec![0.0f32; 3 * w * h];
    for (i, c) in data.chunks_exact(4).enumerate() {
        let (row, col) = (i / (3 * w), i % (3 * w));
        out[3 * w * (h - 1 - row) + col] = value(c);
    }
    Ok(Image { width: w as u32, height: h as u32, data: out })
}
