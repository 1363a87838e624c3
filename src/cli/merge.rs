//! `scatterlab merge`: renders of disjoint sample ranges of one scene into the render of their
//! union, exactly. `path`'s random numbers are a function of (seed, pixel, sample index)
//! (glsl/path/trace.comp, `rng_init`), so `--samples 0..128` and `--samples 128..256` are
//! the two halves of `--samples 0..256`; what a merge needs besides each range's mean is what
//! its variance layer was estimated from, which the render records (`scatterlab.estimators`).
//!
//! The math, per pixel and channel and per estimator (camera paths, light paths), for inputs
//! i with N_i samples, mean m_i, variance of the mean v_i estimated from U_i independent units
//! (samples, or light-path batches): M2_i = v_i (U_i - 1) N_i is the input's weighted sum of
//! squared deviations of its units from its mean; the union's
//!   N = sum N_i,  m = sum N_i m_i / N,  M2 = sum M2_i + sum N_i (m_i - m)^2,  U = sum U_i,
//!   v = M2 / ((U - 1) N)
//! (Chan, Golub and LeVeque 1979, "Updating formulae and a pairwise algorithm for computing
//! sample variances", the pairwise update generalised to k weighted groups): the variance a
//! single render of the union computes, not the average of the inputs' variances that farm
//! tools take. In f64; the inputs' f32 sums differ from the union's only by summation order.
//!
//! `merge --csv` concatenates animation frame ranges' frames.csv (`animate --frame-range`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Result};

use super::args::check_output_path;
use super::MergeArgs;
use crate::output::{self, Image, Provenance, Staging};

/// Overrides a merge does not compare: the range itself (recorded as `samples`), and keys
/// compared through their own provenance fields (seed, size).
const RANGE_KEYS: [&str; 5] = ["render.spp", "render.first_sample", "render.seed", "render.width", "render.height"];

pub fn merge(a: MergeArgs) -> Result<()> {
    if a.csv {
        return merge_csv(&a);
    }
    check_output_path(&a.out, "merge output", &["exr"])?;
    check_not_an_input(&a.out, &a.inputs)?;
    let inputs = a.inputs.iter().map(|p| Input::read_header(p)).collect::<Result<Vec<_>>>()?;
    check_compatible(&inputs)?;
    let order = check_disjoint(&inputs)?;
    let estimators: Vec<String> = inputs[0].prov.estimators.iter().map(|(n, _)| n.clone()).collect();
    let (w, h) = (inputs[0].prov.width, inputs[0].prov.height);
    let several = estimators.len() > 1;
    // Each estimator's accumulated (N, sum N m, M2 parts) per value, in f64.
    let len = 3 * w as usize * h as usize;
    let mut merged: Vec<Merged> = estimators.iter().map(|_| Merged::new(len)).collect();
    for &i in &order {
        let input = &inputs[i];
        let names: Vec<(String, String)> = estimators.iter().map(|e| estimator_layers(e, several)).collect();
        let wanted: Vec<&str> = names.iter().flat_map(|(m, v)| [m.as_str(), v.as_str()]).collect();
        let layers = output::read_exr_layers(&input.path, &wanted).map_err(|e| anyhow!("{e}; nothing written"))?;
        for (e, pair) in layers.chunks_exact(2).enumerate() {
            let (mean, var) = (&pair[0], &pair[1]);
            for (img, what) in [(mean, "mean"), (var, "variance")] {
                if (img.width, img.height) != (w, h) {
                    bail!(
                        "{}: a layer of {}x{} pixels in an image recorded as {w}x{h}; the file is damaged; nothing \
                         written",
                        input.path.display(),
                        img.width,
                        img.height
                    );
                }
                if let Some(bad) = img.data.iter().position(|x| !x.is_finite() || (what == "variance" && *x < 0.0)) {
                    bail!(
                        "{}: {what} value {bad} is {}; not a render scatterlab wrote; nothing written",
                        input.path.display(),
                        img.data[bad]
                    );
                }
            }
            merged[e].fold(mean, var, input.count(), input.prov.estimators[e].1);
        }
    }
    // The union's image is the sum of its estimators' (they estimate disjoint sets of paths).
    let mut image = Image::new(w, h);
    let mut variance = Image::new(w, h);
    let finished: Vec<(Image, Image)> = merged.iter().map(|m| m.finish(w, h)).collect();
    for (m, v) in &finished {
        image.data.iter_mut().zip(&m.data).for_each(|(a, b)| *a += b);
        variance.data.iter_mut().zip(&v.data).for_each(|(a, b)| *a += b);
    }
    let total: u64 = inputs.iter().map(Input::count).sum();
    let mut count = Image::new(w, h);
    count.data.fill(total as f32);

    let header = merged_header(&inputs, &order, &merged)?;
    let mut layers: Vec<(&str, &Image)> = vec![("", &image), ("variance", &variance), ("samples", &count)];
    let layer_names: Vec<(String, String)> = estimators.iter().map(|e| estimator_layers(e, true)).collect();
    if several {
        for ((m, v), (mn, vn)) in finished.iter().zip(&layer_names) {
            layers.push((mn, m));
            layers.push((vn, v));
        }
    }
    let mut staging = Staging::new();
    staging.stage(&a.out, |tmp| output::write_exr_with_metadata(tmp, &layers, &header))?;
    staging.commit().map_err(|e| anyhow!("{e}; nothing was written"))?;
    if !a.quiet {
        let ranges: Vec<String> = order.iter().map(|&i| inputs[i].range_text()).collect();
        eprintln!(
            "merged {} renders ({}; {total} samples per pixel) into {}",
            inputs.len(),
            ranges.join(", "),
            a.out.display()
        );
    }
    Ok(())
}

/// The EXR layers (mean, variance of the mean) that hold estimator `name`: its own pair where
/// the image has `several` estimators, else the image's main layer and `variance`. One naming
/// for `render --out` and the merge.
pub(super) fn estimator_layers(name: &str, several: bool) -> (String, String) {
    if several {
        (name.to_string(), format!("{name}_variance"))
    } else {
        (String::new(), "variance".into())
    }
}

/// One input: its file and the provenance read from its header.
struct Input {
    path: PathBuf,
    prov: Provenance,
    /// The sample range, `[first, end)`.
    range: (u32, u32),
}

impl Input {
    fn read_header(path: &Path) -> Result<Input> {
        if !path.is_file() {
            bail!("{}: no such file; nothing written", path.display());
        }
        let pairs = output::read_exr_metadata(path).map_err(|e| anyhow!("{e}; nothing written"))?;
        let prov = Provenance::from_header(&pairs).map_err(|e| {
            anyhow!("{}: {e}: not a render written by scatterlab render; nothing written", path.display())
        })?;
        let Some(range) = prov.samples else {
            bail!(
                "{}: solver {} computes each pixel without samples (no scatterlab.samples attribute); only renders of \
                 solvers that sample pixels merge; nothing written",
                path.display(),
                prov.solver
            );
        };
        if prov.estimators.is_empty() {
            bail!(
                "{}: no scatterlab.estimators attribute, so its variance cannot be merged exactly (render it with this \
                 version); nothing written",
                path.display()
            );
        }
        Ok(Input { path: path.to_owned(), prov, range })
    }

    fn count(&self) -> u64 {
        (self.range.1 - self.range.0) as u64
    }

    fn range_text(&self) -> String {
        format!("{}..{}", self.range.0, self.range.1)
    }

    /// The overrides that change what is rendered (everything but the range, seed and size).
    fn knobs(&self) -> Vec<&str> {
        let mut k: Vec<&str> = self
            .prov
            .overrides
            .iter()
            .map(String::as_str)
            .filter(|o| !RANGE_KEYS.iter().any(|r| o.split_once('=').is_some_and(|(k, _)| k.trim() == *r)))
            .collect();
        k.sort_unstable();
        k
    }
}

/// The output must not replace an input that it is being read from.
fn check_not_an_input(out: &Path, inputs: &[PathBuf]) -> Result<()> {
    let canon = |p: &Path| std::fs::canonicalize(p).ok();
    if let Some(o) = canon(out) {
        if let Some(i) = inputs.iter().find(|i| canon(i).as_ref() == Some(&o)) {
            bail!("merge output {} is also an input ({}); write the merge to a new file", out.display(), i.display());
        }
    }
    Ok(())
}

/// Every input against the first: one line naming the two files and the field that differs.
fn check_compatible(inputs: &[Input]) -> Result<()> {
    let first = &inputs[0];
    for other in &inputs[1..] {
        let (a, b) = (&first.prov, &other.prov);
        let estimators = |p: &Provenance| p.estimators.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>().join(" ");
        let fields: [(&str, String, String); 7] = [
            ("engine", a.engine.clone(), b.engine.clone()),
            ("scene_hash", a.scene_hash.clone(), b.scene_hash.clone()),
            ("solver", a.solver.clone(), b.solver.clone()),
            ("seed", a.seed.to_string(), b.seed.to_string()),
            ("size", format!("{}x{}", a.width, a.height), format!("{}x{}", b.width, b.height)),
            ("overrides (solver knobs and scene keys)", first.knobs().join(" "), other.knobs().join(" ")),
            ("estimators", estimators(a), estimators(b)),
        ];
        for (field, va, vb) in fields {
            if va != vb {
                bail!(
                    "{} and {} differ in {field}: {va:?} against {vb:?}; only renders of one scene, engine, solver, \
                     knobs, size and seed merge; nothing written",
                    first.path.display(),
                    other.path.display()
                );
            }
        }
    }
    Ok(())
}

/// The inputs in sample order, after checking that no two ranges share a sample.
fn check_disjoint(inputs: &[Input]) -> Result<Vec<usize>> {
    let mut order: Vec<usize> = (0..inputs.len()).collect();
    order.sort_by_key(|&i| inputs[i].range);
    for pair in order.windows(2) {
        let (a, b) = (&inputs[pair[0]], &inputs[pair[1]]);
        if b.range.0 < a.range.1 {
            bail!(
                "{} ({}) and {} ({}) overlap in samples {}..{}; each sample may be merged once; nothing written",
                a.path.display(),
                a.range_text(),
                b.path.display(),
                b.range_text(),
                b.range.0,
                a.range.1.min(b.range.1)
            );
        }
    }
    Ok(order)
}

/// One estimator's ranges so far: per value, N, sum N_i m_i, sum M2_i and sum N_i m_i^2 (the
/// between-range term sum N_i (m_i - m)^2 = sum N_i m_i^2 - N m^2 is formed at the end from
/// these: in f64 over at most a few thousand ranges of f32 means, the cancellation stays
/// ~1e-16 relative to m^2, far below the f32 variance layer's own precision), and the units.
struct Merged {
    n: f64,
    units: u64,
    s1: Vec<f64>,
    s2: Vec<f64>,
    m2: Vec<f64>,
    /// Each input's (N_i, U_i), to judge whether a single render reproduces the merge.
    parts: Vec<(u64, u64)>,
}

impl Merged {
    fn new(len: usize) -> Merged {
        Merged { n: 0.0, units: 0, s1: vec![0.0; len], s2: vec![0.0; len], m2: vec![0.0; len], parts: Vec::new() }
    }

    fn fold(&mut self, mean: &Image, var: &Image, n: u64, units: u64) {
        let nf = n as f64;
        // An input of one unit has no estimate of its own spread (its variance layer is 0).
        let dof = units.saturating_sub(1) as f64;
        for i in 0..self.s1.len() {
            let m = mean.data[i] as f64;
            self.s1[i] += nf * m;
            self.s2[i] += nf * m * m;
            self.m2[i] += var.data[i] as f64 * dof * nf;
        }
        self.n += nf;
        self.units += units;
        self.parts.push((n, units));
    }

    fn finish(&self, w: u32, h: u32) -> (Image, Image) {
        let mut mean = Image::new(w, h);
        let mut var = Image::new(w, h);
        let dof = self.units.saturating_sub(1) as f64;
        for i in 0..self.s1.len() {
            let m = self.s1[i] / self.n;
            let between = (self.s2[i] - self.n * m * m).max(0.0);
            mean.data[i] = m as f32;
            var.data[i] = if dof > 0.0 { ((self.m2[i] + between) / (dof * self.n)) as f32 } else { 0.0 };
        }
        (mean, var)
    }
}

/// The merged image's provenance: the first input's, with the union's samples and units, the
/// ranges it was made of, and the one render that gives the same image.
fn merged_header(inputs: &[Input], order: &[usize], merged: &[Merged]) -> Result<Vec<(String, String)>> {
    let first = &inputs[order[0]];
    let last = &inputs[order[order.len() - 1]];
    let total: u64 = inputs.iter().map(Input::count).sum();
    let contiguous = (last.range.1 - first.range.0) as u64 == total;
    let mut prov = first.prov.clone();
    prov.spp = Some(total as u32);
    prov.samples = contiguous.then_some((first.range.0, last.range.1));
    prov.estimators = prov.estimators.iter().zip(merged).map(|((n, _), m)| (n.clone(), m.units)).collect();
    let mut overrides: Vec<String> = first.knobs().iter().map(|s| s.to_string()).collect();
    overrides.push(format!("render.seed={}", prov.seed));
    overrides.push(format!("render.width={}", prov.width));
    overrides.push(format!("render.height={}", prov.height));
    if contiguous {
        overrides.push(format!("render.first_sample={}", first.range.0));
        overrides.push(format!("render.spp={total}"));
    }
    prov.overrides = overrides;
    let mut header = prov.header_pairs();
    let ranges: Vec<String> =
        order.iter().map(|&i| format!("{} from {}", inputs[i].range_text(), inputs[i].path.display())).collect();
    header.push((format!("{}merged", output::KEY_PREFIX), ranges.join("\n")));
    header.push((format!("{}reproduce", output::KEY_PREFIX), reproduce(&prov, contiguous, merged)));
    Ok(header)
}

/// The `scatterlab render` command line whose image equals the merge (to float summation
/// order), or why there is none.
fn reproduce(prov: &Provenance, contiguous: bool, merged: &[Merged]) -> String {
    let Some((a, b)) = prov.samples.filter(|_| contiguous) else {
        return "none: the merged ranges are not contiguous, and one render takes one range".into();
    };
    let mut cmd = format!("scatterlab render {} --solver {} --samples {a}..{b}", prov.scene, prov.solver);
    for o in prov.overrides.iter().filter(|o| !o.starts_with("render.first_sample=") && !o.starts_with("render.spp=")) {
        cmd.push_str(&format!(" --set {o}"));
    }
    // Batched estimators (light paths): one render has the same batches only where every
    // input's batches hold the same number of rounds; it then needs as many batches.
    for (m, (name, units)) in merged.iter().zip(&prov.estimators) {
        if m.parts.iter().all(|&(n, u)| n == u) {
            continue; // one unit per sample: nothing to set
        }
        let size = m.parts[0].0 / m.parts[0].1.max(1);
        if m.parts.iter().all(|&(n, u)| u > 0 && n % u == 0 && n / u == size) {
            cmd.push_str(&format!(" --set {}.light_batches={units}", prov.solver));
        } else {
            return format!(
                "{cmd} (approximately: the {name} estimator's inputs have batches of different sizes, so one \
                 render's variance comes from other batches; its mean is the same)"
            );
        }
    }
    cmd
}

/// `merge --csv OUT.csv IN.csv...`: animation frame ranges' frames.csv, concatenated in frame
/// order after checking that they share one header, are of one sequence (their `sequence`
/// column), and that their frames neither overlap nor leave a gap.
fn merge_csv(a: &MergeArgs) -> Result<()> {
    check_output_path(&a.out, "merge output", &["csv"])?;
    check_not_an_input(&a.out, &a.inputs)?;
    let mut header: Option<(PathBuf, String)> = None;
    let mut frames: BTreeMap<u64, (PathBuf, String)> = BTreeMap::new();
    // The first row's file, solver and sequence digest: every row must be of that sequence.
    let mut sequence: Option<(PathBuf, String, String)> = None;
    for p in &a.inputs {
        let text = std::fs::read_to_string(p).map_err(|e| anyhow!("{}: {e}; nothing written", p.display()))?;
        let mut lines = text.lines();
        let head = lines.next().filter(|h| h.starts_with("frame,")).ok_or_else(|| {
            anyhow!(
                "{}: not a frames.csv (its first line does not begin with \"frame,\"); nothing written",
                p.display()
            )
        })?;
        match &header {
            None => header = Some((p.clone(), head.to_string())),
            Some((first, h)) if h != head => bail!(
                "{} and {} differ in their columns ({h:?} against {head:?}); nothing written",
                first.display(),
                p.display()
            ),
            Some(_) => {}
        }
        let column = |name: &str| head.split(',').position(|c| c == name);
        let (solver_at, sequence_at) = (column("solver"), column("sequence"));
        for (n, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
            // Frames of another solver, scene, --set or --orbit-light share the columns but not
            // the sequence: joined, they would read as one sequence's figures.
            if let Some(at) = sequence_at {
                let cells: Vec<&str> = line.split(',').collect();
                let cell = |i: Option<usize>| i.and_then(|i| cells.get(i)).map_or("", |c| c.trim()).to_string();
                let (solver, digest) = (cell(solver_at), cell(Some(at)));
                match &sequence {
                    None => sequence = Some((p.clone(), solver, digest)),
                    Some((first, first_solver, first_digest)) if *first_digest != digest => bail!(
                        "{} and {} are frames of different sequences ({}; the sequence column {first_digest} against \
                         {digest}: another solver, scene, --set, --orbit-light or engine build); nothing written",
                        first.display(),
                        p.display(),
                        if *first_solver != solver {
                            format!("solver {first_solver} against {solver}")
                        } else {
                            format!("both {solver}")
                        }
                    ),
                    Some(_) => {}
                }
            }
            let frame: u64 = line
                .split(',')
                .next()
                .and_then(|f| f.trim().parse().ok())
                .ok_or_else(|| anyhow!("{} line {}: no frame number; nothing written", p.display(), n + 2))?;
            if let Some((other, _)) = frames.insert(frame, (p.clone(), line.to_string())) {
                bail!("{} and {} both hold frame {frame}; nothing written", other.display(), p.display());
            }
        }
    }
    let (_, head) = header.ok_or_else(|| anyhow!("merge --csv: no input"))?;
    if let (Some((&lo, _)), Some((&hi, _))) = (frames.first_key_value(), frames.last_key_value()) {
        if let Some(gap) = (lo..=hi).find(|f| !frames.contains_key(f)) {
            bail!("frames {lo}..{} have a gap: frame {gap} is in no input; nothing written", hi + 1);
        }
    }
    let mut text = head + "\n";
    for (_, line) in frames.values() {
        text.push_str(line);
        text.push('\n');
    }
    let mut staging = Staging::new();
    staging.stage(&a.out, |tmp| {
        std::fs::write(tmp, &text).map_err(|source| output::OutputError::Io {
            path: tmp.to_owned(),
            action: "write",
            source,
        })
    })?;
    staging.commit().map_err(|e| anyhow!("{e}; nothing was written"))?;
    if !a.quiet {
        eprintln!("merged {} frames from {} files into {}", frames.len(), a.inputs.len(), a.out.display());
    }
    Ok(())
}
