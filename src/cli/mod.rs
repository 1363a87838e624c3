//! The command line: parse raw arguments (clap), validate them into a ready-to-run request,
//! run it, and turn any error into one line on stderr and a non-zero exit code.

mod animate;
mod args;
mod commands;
mod merge;
mod render;
mod view;

use std::path::PathBuf;

use clap::builder::{PossibleValue, PossibleValuesParser};
use clap::{Args, Parser, Subcommand};

use crate::solvers::{self, Schedule};

/// `--solver`'s values: every registered solver, each with what it is for (`--help` lists them).
fn solver_names() -> PossibleValuesParser {
    PossibleValuesParser::new(solvers::SOLVERS.iter().map(|s| PossibleValue::new(s.name()).help(s.about())))
}

/// `--exposure`: the range `render.exposure` takes (a NaN wrote a black PNG with exit 0).
fn exposure_stops(text: &str) -> Result<f32, String> {
    match text.trim().parse::<f32>() {
        Ok(e) if e.is_finite() && e.abs() <= 64.0 => Ok(e),
        Ok(_) => Err("out of range; use -64 ..= 64 stops".into()),
        Err(e) => Err(format!("{e}; give stops as a number, -64 ..= 64")),
    }
}

/// `--solver`'s default: the registry's reference solver (the ground truth).
fn default_solver() -> String {
    solvers::reference().name().into()
}

#[derive(Parser, Debug)]
#[command(
    name = "scatterlab",
    version,
    about = "Multiple scattering in participating media on any Vulkan device, headless."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Args, Debug, Clone)]
pub struct GpuArgs {
    /// Device index, name substring, `uuid:GPU-...` (a unique prefix will do) or `auto`
    /// (SCATTERLAB_DEVICE, else the GPU in CUDA_VISIBLE_DEVICES, SLURM_STEP_GPUS or
    /// SLURM_JOB_GPUS: docs/cluster.md); see `scatterlab devices`; env SCATTERLAB_DEVICE.
    #[arg(long, global = true)]
    pub device: Option<String>,
    /// Enable the Khronos validation layer (synchronization validation included); env SCATTERLAB_VALIDATE=1.
    /// Any validation error makes the command fail.
    #[arg(long, global = true)]
    pub validate: bool,
    /// Queue mapping for concurrency experiments: auto (the strongest the device offers),
    /// shared (one queue for every role), same-family (two queues of one compute family),
    /// separate-families (two compute families); copies use a transfer-only family where there is
    /// one, except when shared. One line of error where the device cannot. Env SCATTERLAB_QUEUES.
    #[arg(long, global = true, value_parser = clap::builder::PossibleValuesParser::new(crate::gpu::QueueChoice::NAMES))]
    pub queues: Option<String>,
    /// Build every pipeline afresh: neither load nor save the persistent pipeline cache
    /// ($SCATTERLAB_CACHE_DIR, else $XDG_CACHE_HOME/scatterlab, else ~/.cache/scatterlab; one
    /// file per device and driver). SCATTERLAB_CACHE_DIR=off does the same.
    #[arg(long, global = true)]
    pub no_cache: bool,
}

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Scene file (TOML).
    pub scene: PathBuf,
    /// The solver shown first (keys 1-8 switch, in registry order).
    #[arg(long, value_parser = solver_names(), default_value_t = default_solver())]
    pub solver: String,
    /// Override a scene key or set a solver knob, as `render --set`. Repeatable.
    #[arg(long, value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// The window's size in pixels (default: the scene's render.width x render.height); the
    /// render follows the window's size when it is resized.
    #[arg(long, value_name = "WxH")]
    pub size: Option<String>,
    /// Samples per pixel a frame adds for solvers that sample pixels (path), up to the scene's
    /// render.spp.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=65536))]
    pub batch: u32,
    /// Replay input events from FILE: one per line, `FRAME ACTION ARGS` (drag-left DX DY,
    /// drag-right DX DY, wheel LINES, key NAME, resize W H, close, minimise, restore), applied
    /// before frame FRAME (frames minimised count, without a render).
    #[arg(long, value_name = "FILE")]
    pub script: Option<PathBuf>,
    /// Stop after this many frames have been shown.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000_000))]
    pub frames: Option<u32>,
    /// Save the last frame (`--frames`) as this PNG, read back from the image presented, and an
    /// EXR of the linear image beside it (same name, .exr; path's variance as a layer), both
    /// with the `--set`s that make `scatterlab render` draw the same view; S in the window
    /// saves numbered pairs beside it.
    #[arg(long, value_name = "PNG")]
    pub screenshot: Option<PathBuf>,
    /// No per-session lines on stderr (the summary on stdout stays).
    #[arg(long)]
    pub quiet: bool,
    #[command(flatten)]
    pub gpu: GpuArgs,
}

#[derive(Args, Debug)]
pub struct AnimateArgs {
    /// Scene file (TOML): its first light (point or directional) orbits.
    pub scene: PathBuf,
    /// The solver: one that keeps its solution from frame to frame.
    #[arg(long, value_parser = solver_names())]
    pub solver: String,
    /// Degrees the light turns per frame.
    #[arg(long, value_name = "DEG", default_value_t = 5.0, allow_negative_numbers = true)]
    pub orbit_light: f64,
    /// Frames (the first iterates from zero to the solver's tolerance).
    #[arg(long, default_value_t = 24, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub frames: u32,
    /// Render frames A to B - 1 of the sequence only (for a job array: one range per task); the
    /// range's first frame iterates from zero, as frame 0 does. Its frames.csv holds its rows;
    /// `scatterlab merge --csv` concatenates the ranges' files.
    #[arg(long, value_name = "A..B", conflicts_with = "frames")]
    pub frame_range: Option<String>,
    /// Directory for frame-NNNN.exr and frames.csv (created if missing).
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Also write each frame as a tone-mapped PNG (the scene's render.exposure).
    #[arg(long)]
    pub png: bool,
    /// Skip the converged reference of every frame (no relL2 column; half the work or less).
    #[arg(long)]
    pub no_reference: bool,
    /// Override a scene key or set a solver knob, as `render --set` (the per-frame iterations:
    /// the solver's `iterations_per_frame` knob where it has one). Repeatable.
    #[arg(long, value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// No progress bar and no per-frame lines.
    #[arg(long)]
    pub quiet: bool,
    /// Where stderr is not a terminal (a CI log, a batch job's output file): a plain progress
    /// line within a frame at most every SECONDS (the first after SECONDS; the per-frame lines
    /// come regardless). 0: every update.
    #[arg(long, value_name = "SECONDS", default_value_t = 30.0, value_parser = non_negative_seconds)]
    pub progress_every: f64,
    #[command(flatten)]
    pub gpu: GpuArgs,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Render a scene to EXR or PFM (linear) and/or PNG (tone-mapped), with a JSON report.
    Render(RenderArgs),
    /// Render a sequence in which the first light orbits the medium (about +y through its
    /// centre), each frame warm started from the previous frame's solution, for solvers that
    /// keep one: the frames and frames.csv (per frame: time, iterations, relL2 and energy ratio
    /// against the same frame iterated to the tolerance).
    Animate(AnimateArgs),
    /// A live window on the scene (winit, Vulkan presentation): left-drag orbits the camera
    /// about the medium, the wheel zooms, right- or shift-drag orbits the first light, keys 1-8
    /// switch solver (registry order), + and - change exposure, R resets, S saves a screenshot,
    /// D measures the solver against a path accumulation beside it, Esc quits. path accumulates
    /// progressively; lbl, networks and dom start a light move from their last solution (a budget
    /// `<solver>.iterations_per_frame` converges over frames); the others render again.
    View(ViewArgs),
    /// Merge renders of disjoint sample ranges (`render --samples A..B`) of one scene into the
    /// render of their union: the sample-weighted mean and the exact pooled variance, checked
    /// from the inputs' provenance. `--csv`: animation frame ranges' frames.csv, concatenated.
    Merge(MergeArgs),
    /// Compare two EXR images: relL2 (and without the images' noise where they carry variance
    /// layers), relMSE, RMSE, energy ratio, max error, NaN/Inf count.
    Compare(CompareArgs),
    /// List Vulkan devices, their queue families and the queue-role mapping scatterlab would use.
    Devices {
        #[command(flatten)]
        gpu: GpuArgs,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Error against time for every solver's quality ladder on each scene, against a cached
    /// `path` reference: CSV, JSON and an SVG plot per scene (log-log, Pareto front marked).
    Bench {
        /// Scene files.
        #[arg(required_unless_present = "replot")]
        scenes: Vec<PathBuf>,
        /// No rendering: redraw the SVG plots of an earlier run from its bench.json in DIR,
        /// beside it (a plot of this version from results measured before); with several DIRs
        /// (one Slurm task per scene: tools/slurm/bench.sbatch), combine their runs into one
        /// bench.json, bench.csv and plots in --out. Runs combined must share the engine build,
        /// device, --repeats, --quick/--points and --ref-spp, and no scene.
        #[arg(long, value_name = "DIR", num_args = 1.., conflicts_with_all = ["scenes", "quick", "points", "throughput"])]
        replot: Vec<PathBuf>,
        /// Solvers to bench (comma-separated; default: every solver).
        #[arg(long, value_delimiter = ',', value_parser = solver_names())]
        solvers: Vec<String>,
        /// Output directory (created if missing; default `bench`). With `--replot` of one DIR
        /// the plots go beside its bench.json unless this is given.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Samples per pixel of the `path` reference.
        #[arg(long, default_value_t = 4096)]
        ref_spp: u32,
        /// Renders per point, at most: the first is reported apart as the cold start (pipelines
        /// built; on a GPU, clocks still low), the rest are warm and stop once two agree within
        /// 5%; times are the warm renders' medians, with their spread. 1: the cold render alone.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=100))]
        repeats: u32,
        /// The cheap end of each ladder only (its three cheapest rungs).
        #[arg(long, conflicts_with = "points")]
        quick: bool,
        /// Which rungs of each solver's ladder to run, numbered from 1 at the cheap end:
        /// `2`, `1,3-5` (`scatterlab knobs` and bench.json's `ladders` list them).
        #[arg(long, value_name = "LIST")]
        points: Option<String>,
        /// Also print the throughput table (samples/s, path segments/s, lattice voxel-updates/s, GB/s).
        #[arg(long)]
        throughput: bool,
        /// Override scene keys for every scene (render.width=64, ...).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Where references are cached.
        #[arg(long, default_value = ".scatterlab-cache")]
        cache: PathBuf,
        #[command(flatten)]
        gpu: GpuArgs,
    },
    /// Every solver at the extremes (albedo, optical thickness, g, point-light placement):
    /// finite, non-negative, never brighter than the lossless bound, exact where an exact
    /// answer is cheap. Prints a pass/fail table, writes CSV and JSON, fails on any failure.
    Stability {
        /// Solvers to sweep (comma-separated; default: every solver).
        #[arg(long, value_delimiter = ',', value_parser = solver_names())]
        solvers: Vec<String>,
        /// Also run the cases marked slow (optical thickness 1e3 and 1e4).
        #[arg(long)]
        slow: bool,
        /// Directory for stability.csv and stability.json (created if missing).
        #[arg(long, default_value = "stability")]
        out: PathBuf,
        #[command(flatten)]
        gpu: GpuArgs,
    },
    /// Write the equivalent Mitsuba 3 scene (XML, plus a .vol grid beside it) to check any
    /// result with Mitsuba: `scatterlab export --mitsuba SCENE OUT.xml`.
    Export(ExportArgs),
    /// Scene tools.
    Scene {
        #[command(subcommand)]
        command: SceneCommand,
    },
    /// Characterise a Vulkan device for scattering workloads: its memory bandwidth, every
    /// solver's headline workload (time, throughput, share of the bandwidth) and the queue
    /// concurrency under every mapping it offers; report.json, report.md and a Perfetto trace
    /// per mapping in --out. `--compare A.json B.json` prints two reports side by side.
    Report {
        /// Output directory (created if missing).
        #[arg(long, required_unless_present = "compare")]
        out: Option<PathBuf>,
        /// Small sizes (CI; minutes on lavapipe) instead of the seeds' headline sizes.
        #[arg(long)]
        quick: bool,
        /// Where the scenes are (the repository's scenes/).
        #[arg(long, default_value = "scenes")]
        scenes: PathBuf,
        /// Two report.json files: print their figures side by side (ratio B / A).
        #[arg(long, num_args = 2, value_names = ["A", "B"], conflicts_with_all = ["out", "quick"])]
        compare: Option<Vec<PathBuf>>,
        #[command(flatten)]
        gpu: GpuArgs,
    },
    /// Every knob of every solver (or of one): default, range and meaning, as `--set
    /// solver.knob=value` takes them.
    Knobs {
        /// Only this solver's knobs.
        #[arg(value_parser = solver_names())]
        solver: Option<String>,
        /// Print the Markdown reference (docs/knobs.md) instead of text.
        #[arg(long)]
        markdown: bool,
    },
}

#[derive(Subcommand, Debug)]
pub enum SceneCommand {
    /// What physics a scene requires and the device memory each solver would allocate.
    Info {
        /// Scene file (TOML, format v1: docs/scene-format.md).
        scene: PathBuf,
        /// Override scene keys (`medium.albedo=0.5`) or set solver knobs for the memory
        /// estimate (`lbl.grid=128`).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
}

fn non_negative_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!("{s:?} is not a number of seconds >= 0")),
    }
}

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Scene file (TOML, format v1: docs/scene-format.md).
    pub scene: PathBuf,
    /// The solver (`scatterlab knobs` lists each one's knobs).
    #[arg(long, default_value_t = default_solver(), value_parser = solver_names())]
    pub solver: String,
    /// Samples per pixel of Monte Carlo solvers (the same as `--set render.spp=N`).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Render sample indices A to B - 1 of every pixel (`--spp N` is `0..N`): the same samples
    /// as those of a render of 0..B, so renders of disjoint ranges merge into the render of
    /// their union (`scatterlab merge`). The same as `--set render.first_sample=A --set
    /// render.spp=B-A`.
    #[arg(long, value_name = "A..B", conflicts_with = "spp")]
    pub samples: Option<String>,
    /// Scattering events per path (1 = single scattering): `--set <solver>.max_depth=N`
    /// for a solver with that knob (`path`).
    #[arg(long)]
    pub max_depth: Option<u32>,
    /// Seed of every random choice (overrides render.seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override a scene key (`medium.albedo=0.5`; lights by index from 0:
    /// `light.0.intensity=[5, 5, 5]`; docs/scene-format.md) or set a solver knob
    /// (`path.max_depth=1`, `single.step=0.01`). Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// The image, in the format its extension names: `.exr` (linear RGB f32, provenance in the
    /// header; `path` adds a `variance` layer: the variance of each pixel's mean), `.png`
    /// (tone-mapped 8-bit, `--exposure`), `.pfm` (linear RGB f32).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also a tone-mapped 8-bit PNG (provenance in its text chunks).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// PNG exposure in stops (default: the scene's render.exposure, else 0), -64 to 64.
    #[arg(long, allow_negative_numbers = true, value_parser = exposure_stops)]
    pub exposure: Option<f32>,
    /// Metrics and provenance as JSON (device, driver, queue mapping, settings, pass times).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Model every feature (chromatic tracking, HG phase) even where the scene needs none.
    #[arg(long)]
    pub model_all: bool,
    /// Overlap the work of the two queue roles (concurrent) or not: `--set <solver>.schedule=`
    /// for a solver with concurrent work (`lbl`).
    #[arg(long, value_enum)]
    pub schedule: Option<Schedule>,
    /// Run both schedules and print the sequential/concurrent time ratio (the image written
    /// is the concurrent one); for a solver with a `schedule` knob.
    #[arg(long)]
    pub compare_schedules: bool,
    /// Renders per schedule under `--compare-schedules` (interleaved; default 3): the gain is
    /// reported with the run-to-run spread of the spans, and as a gain only when it exceeds
    /// twice that.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub repeats: Option<u32>,
    /// Deterministic order of floating-point accumulation (bit-identical images):
    /// `--set <solver>.deterministic=true` for a solver with that knob (`lbl`, where it is the
    /// default; `--set lbl.deterministic=false` asks for float atomics).
    #[arg(long)]
    pub deterministic: bool,
    /// Per-queue GPU timeline as Chrome-trace/Perfetto JSON (open in ui.perfetto.dev).
    #[arg(long)]
    pub trace: Option<PathBuf>,
    /// Largest grid, in bytes, a scene may load (suffixes K, M, G: 512M, 4G).
    #[arg(long, default_value = "4G")]
    pub memory_budget: String,
    /// No progress bar or summary.
    #[arg(long, short)]
    pub quiet: bool,
    /// Where stderr is not a terminal (a CI log, a batch job's output file), where no progress
    /// bar is drawn: a plain progress line at most every SECONDS (the first after SECONDS), so
    /// a long render is not silent there. 0: every update.
    #[arg(long, value_name = "SECONDS", default_value_t = 30.0, value_parser = non_negative_seconds)]
    pub progress_every: f64,
    #[command(flatten)]
    pub gpu: GpuArgs,
}

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// Scene file (TOML, format v1: docs/scene-format.md).
    pub scene: PathBuf,
    /// The Mitsuba 3 XML to write; a heterogeneous medium's grid goes beside it as
    /// NAME.sigma_t.vol.
    pub out: PathBuf,
    /// Export for Mitsuba 3 (volpath, medium, emitters, sensor; grids as .vol). The only
    /// format for now, and required: `export --mitsuba SCENE OUT.xml` or
    /// `export SCENE --mitsuba OUT.xml`.
    #[arg(long)]
    pub mitsuba: bool,
    /// Override a scene key (`medium.albedo=0.5`, `light.0.position=[0, 1, 0]`), as for
    /// `render`. Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

#[derive(Args, Debug)]
pub struct MergeArgs {
    /// The merged EXR (or CSV with `--csv`); it must not exist as one of the inputs.
    pub out: PathBuf,
    /// The renders to merge (EXR from `scatterlab render --out`), or frames.csv files.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Concatenate `animate --frame-range` frames.csv files instead: one header, frames in
    /// order, none twice and none missing.
    #[arg(long)]
    pub csv: bool,
    /// No summary line.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Args, Debug)]
pub struct CompareArgs {
    /// The image to judge.
    pub a: PathBuf,
    /// The reference.
    pub b: PathBuf,
    /// Write a false-colour per-pixel relative-error PNG.
    #[arg(long)]
    pub error_png: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Parse `std::env::args`, run, and return the process exit code.
pub fn main() -> i32 {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    match commands::run(cli) {
        Ok(()) => 0,
        Err(e) => {
            // One line. The library's errors already carry their cause in their own text, so
            // print the top-level message only (`{:#}` would repeat the cause).
            let msg = format!("{e}").replace('\n', " ");
            eprintln!("error: {msg}");
            1
        }
    }
}
