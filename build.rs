//! The build's identity: a SHA-256 over every file the engine is built from (src/, the
//! committed SPIR-V in spirv/, Cargo.toml, Cargo.lock), as `SCATTERLAB_BUILD` (12 hex digits).
//! The version number alone does not change when the engine does: a cached `path` reference
//! keyed by it (bench's, the tests') would outlive a fix to the tracer, and two renders from
//! different trees would claim the same engine in their provenance.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            files(&p, out);
        } else {
            out.push(p);
        }
    }
}

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let mut list = Vec::new();
    for dir in ["src", "spirv"] {
        // A directory: cargo reruns the script when any file under it changes.
        println!("cargo:rerun-if-changed={dir}");
        files(&root.join(dir), &mut list);
    }
    for f in ["Cargo.toml", "Cargo.lock", "build.rs"] {
        println!("cargo:rerun-if-changed={f}");
        list.push(root.join(f));
    }
    // Sorted by path relative to the root: the same tree gives the same identity anywhere.
    let mut named: Vec<(String, PathBuf)> = list
        .into_iter()
        .map(|p| (p.strip_prefix(&root).unwrap_or(&p).to_string_lossy().replace('\\', "/"), p))
        .collect();
    named.sort();
    let mut h = Sha256::new();
    for (name, path) in &named {
        let bytes = std::fs::read(path).unwrap_or_default();
        h.update((name.len() as u64).to_le_bytes());
        h.update(name.as_bytes());
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(&bytes);
    }
    let id: String = h.finalize().iter().take(6).map(|b| format!("{b:02x}")).collect();
    println!("cargo:rustc-env=SCATTERLAB_BUILD={id}");
}
