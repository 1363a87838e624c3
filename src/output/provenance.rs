//! Provenance: what made an image, written into every output of a render (the JSON report,
//! EXR header attributes, PNG text chunks), so that a file found later says which scene, which
//! overrides, which solver, seed and engine produced it. pbrt-v4 writes render time and camera
//! into its EXRs and Mitsuba 3 its version; we add what those leave out: the `--set`
//! overrides and a digest of the scene's content.

use serde::Serialize;

/// What made an image. Every field is text a person can read back from the file.
#[derive(Clone, Debug, Serialize, PartialEq, Eq)]
pub struct Provenance {
    /// `scatterlab <version>`.
    pub engine: String,
    /// The scene file as given on the command line.
    pub scene: String,
    /// [`crate::scene::content_hash`]: SHA-256 of the scene text and its grid data.
    pub scene_hash: String,
    /// Every override as `key=value`, in the order given: `--set` pairs and the flags that
    /// stand for one (`--spp 64` is `render.spp=64`, `--max-depth 1` is `path.max_depth=1`).
    pub overrides: Vec<String>,
    pub solver: String,
    pub seed: u64,
    /// Samples per pixel, for solvers that sample pixels (`path`); absent for the others.
    pub spp: Option<u32>,
    pub width: u32,
    pub height: u32,
}

/// Prefix of every key this module writes into an image header.
pub const KEY_PREFIX: &str = "scatterlab.";

impl Provenance {
    /// `(key, value)` pairs for image headers: keys prefixed `scatterlab.`, overrides joined
    /// by newlines (a `--set` value never holds one: it is one command-line argument per line
    /// of a shell history), absent fields left out.
    pub fn header_pairs(&self) -> Vec<(String, String)> {
        let mut v = vec![
            ("engine", self.engine.clone()),
            ("scene", self.scene.clone()),
            ("scene_hash", self.scene_hash.clone()),
            ("overrides", self.overrides.join("\n")),
            ("solver", self.solver.clone()),
            ("seed", self.seed.to_string()),
            ("size", format!("{}x{}", self.width, self.height)),
        ];
        if let Some(spp) = self.spp {
            v.push(("spp", spp.to_string()));
        }
        v.into_iter().map(|(k, val)| (format!("{KEY_PREFIX}{k}"), val)).collect()
    }
}

/// The engine's name, version and build (the hash of the source it was built from), as recorded.
pub fn engine() -> String {
    format!("scatterlab {} (build {})", env!("CARGO_PKG_VERSION"), crate::BUILD)
}
