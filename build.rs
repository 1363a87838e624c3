//! The build's identity: a SHA-256 over every file the engine is built from (src/, the
//! committed SPIR-V in spirv/, Cargo.toml, Cargo.lock), as `SCATTERLAB_BUILD` (12 hex digits).
//! The version number alone does not change when the engine does: a cached `path` reference
//! keyed by it (bench's, the tests') would outlive a fix to the tracer, and two renders from
//! different trees would claim the same engine in their provenance.
//!
//! And the identity of what a `path` render is a function of, `SCATTERLAB_REFERENCE_BUILD`:
//! the same hash without the files `path` cannot reach, the other solvers' folders (a solver
//! never imports another: tests/registry_tests.rs holds that), the shared parts it does not
//! import (`SCATTERLAB_REFERENCE_PARTS` are those it does), the CLI and `measure` (above the
//! solvers), `main.rs`, and the SPIR-V folders of kernels `path` does not run
//! (`SCATTERLAB_REFERENCE_EXCLUDED_SPIRV`; tests/registry_tests.rs checks none holds one of
//! path's kernels and that the parts are all path imports). A kept `path` reference keyed by it
//! survives a change to `lbl` or the lattice, not one to the tracer, the scene code, the GPU
//! layer or a part it imports.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

/// SPIR-V folders whose kernels `path` never runs.
const REFERENCE_EXCLUDED_SPIRV: &[&str] =
    &["lattice", "marching", "networks", "ordinates", "sh_single", "wave_field", "view", "probe"];
/// Folders of `src/solvers/` that a `path` render runs code from: its own and the interface
/// (and of the shared parts, those of [`REFERENCE_PARTS`]). Every other folder there is another
/// solver's.
const REFERENCE_SOLVER_FOLDERS: &[&str] = &["path", "interface"];
/// The files of `src/solvers/parts/` that `path` imports, and what they import in turn
/// (tests/registry_tests.rs follows the imports and fails if one is missing).
const REFERENCE_PARTS: &[&str] = &["mod.rs", "gpu_scene.rs", "resumable.rs"];

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

/// 12 hex digits of a SHA-256 over `named` (relative name, file), in name order.
fn identity(named: &[(String, PathBuf)]) -> String {
    let mut h = Sha256::new();
    for (name, path) in named {
        let bytes = std::fs::read(path).unwrap_or_default();
        h.update((name.len() as u64).to_le_bytes());
        h.update(name.as_bytes());
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(&bytes);
    }
    h.finalize().iter().take(6).map(|b| format!("{b:02x}")).collect()
}

/// Whether the file `name` (relative to the root) can change what a `path` render gives.
fn reaches_path(name: &str) -> bool {
    let parts: Vec<&str> = name.split('/').collect();
    match parts.as_slice() {
        ["src", "cli" | "measure", ..] | ["src", "main.rs"] => false,
        ["src", "solvers", "parts", file] => REFERENCE_PARTS.contains(file),
        ["src", "solvers", "parts", _, _, ..] => false,
        ["src", "solvers", dir, _, ..] => REFERENCE_SOLVER_FOLDERS.contains(dir),
        ["spirv", dir, _, ..] => !REFERENCE_EXCLUDED_SPIRV.contains(dir),
        _ => true,
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
    println!("cargo:rustc-env=SCATTERLAB_BUILD={}", identity(&named));
    let reference: Vec<(String, PathBuf)> = named.into_iter().filter(|(n, _)| reaches_path(n)).collect();
    println!("cargo:rustc-env=SCATTERLAB_REFERENCE_BUILD={}", identity(&reference));
    println!("cargo:rustc-env=SCATTERLAB_REFERENCE_EXCLUDED_SPIRV={}", REFERENCE_EXCLUDED_SPIRV.join(","));
    println!("cargo:rustc-env=SCATTERLAB_REFERENCE_PARTS={}", REFERENCE_PARTS.join(","));
}
