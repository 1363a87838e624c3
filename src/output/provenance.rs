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
    /// The sample indices `[first, end)` of every pixel (`--samples A..B`; `--spp N` is
    /// `0..N`), for solvers that sample pixels.
    pub samples: Option<(u32, u32)>,
    /// The estimators behind the image and the units their variances come from
    /// ([`crate::solvers::Estimate`]): `("camera", 256)` is camera paths whose variance is that
    /// of 256 samples; `("light", 16)` light paths in 16 batches. Known after the render.
    pub estimators: Vec<(String, u64)>,
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
        if let Some((a, b)) = self.samples {
            v.push(("samples", format!("{a}..{b}")));
        }
        if !self.estimators.is_empty() {
            let e: Vec<String> = self.estimators.iter().map(|(n, u)| format!("{n}:{u}")).collect();
            v.push(("estimators", e.join(" ")));
        }
        v.into_iter().map(|(k, val)| (format!("{KEY_PREFIX}{k}"), val)).collect()
    }

    /// The provenance written by [`Provenance::header_pairs`], read back from an image's
    /// header; `Err` names the first key that is missing or unreadable. Keys it does not know
    /// (a merge's own) are left for the caller.
    pub fn from_header(pairs: &[(String, String)]) -> Result<Provenance, String> {
        let get = |k: &str| pairs.iter().find(|(key, _)| key.strip_prefix(KEY_PREFIX) == Some(k)).map(|(_, v)| v);
        let need = |k: &str| get(k).ok_or_else(|| format!("no {KEY_PREFIX}{k} attribute"));
        let bad = |k: &str, v: &str| format!("{KEY_PREFIX}{k} = {v:?} is not readable");
        let seed_text = need("seed")?;
        let seed = seed_text.parse().map_err(|_| bad("seed", seed_text))?;
        let size = need("size")?;
        let (width, height) = size
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
            .ok_or_else(|| bad("size", size))?;
        let spp = get("spp").map(|v| v.parse().map_err(|_| bad("spp", v))).transpose()?;
        let samples = get("samples").map(|v| parse_range(v).map_err(|_| bad("samples", v))).transpose()?;
        let estimators = match get("estimators") {
            None => Vec::new(),
            Some(v) => v
                .split_whitespace()
                .map(|e| e.split_once(':').and_then(|(n, u)| Some((n.to_string(), u.parse().ok()?))))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| bad("estimators", v))?,
        };
        let overrides = need("overrides")?;
        Ok(Provenance {
            engine: need("engine")?.clone(),
            scene: need("scene")?.clone(),
            scene_hash: need("scene_hash")?.clone(),
            overrides: overrides.lines().filter(|l| !l.is_empty()).map(str::to_string).collect(),
            solver: need("solver")?.clone(),
            seed,
            spp,
            samples,
            estimators,
            width,
            height,
        })
    }
}

/// `A..B` with A < B (sample indices A to B - 1), as `--samples` and the provenance write it.
pub fn parse_range(text: &str) -> Result<(u32, u32), String> {
    let (a, b) = text.trim().split_once("..").ok_or_else(|| format!("{text:?} is not a range A..B"))?;
    let num = |t: &str| {
        t.trim().parse::<u32>().map_err(|_| format!("{t:?} in {text:?} is not an integer in 0 ..= {}", u32::MAX))
    };
    let (a, b) = (num(a)?, num(b)?);
    if a >= b {
        return Err(format!("{text:?} is empty: the range A..B holds indices A to B - 1, so B must exceed A"));
    }
    Ok((a, b))
}

/// The engine's name, version and build (the hash of the source it was built from), as recorded.
pub fn engine() -> String {
    format!("scatterlab {} (build {})", env!("CARGO_PKG_VERSION"), crate::BUILD)
}
