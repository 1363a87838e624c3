//! `scatterlab view`: a live window (winit, presented through `gpu::Presenter`) on a scene, where
//! the camera orbits, the first light orbits and the solver changes, each change rendered
//! again. `path` accumulates progressively (a batch of samples per frame, from a fresh seed per
//! batch, reset on any change); the other solvers render once per change. A scripted session
//! (`--script`, `--frames`, `--screenshot`) replays input without a hand on the mouse, for
//! tests and demos. Nothing here knows a solver.
//!
//! Solvers that keep a solution (lbl, networks) re-solve from it after a light move; with
//! their `iterations_per_frame` knob set, a frame runs that many iterations and the frames
//! after it go on from there until the tolerance, so the window shows the image converging.
//! Key D runs a `path` accumulation beside the solver shown and measures the solver's image
//! against it (relL2, with path's noise removed, and the energy ratio) as it converges.
//!
//! The linear image is tone-mapped on the device by the PNG writer's operator
//! (glsl/view/tonemap.comp, `gpu::Presenter::show`) and copied into the swapchain image: the
//! window shows what `render --png` writes when the window is the render's size (the same bytes
//! but where the device's float arithmetic rounds a value across an 8-bit step: at most 1).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use glam::{Quat, Vec3};
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, ModifiersState, NamedKey};
use winit::window::{Window, WindowId};

use super::args::{check_validation, gpu_options, parse_sets};
use super::ViewArgs;
use crate::gpu::{surface_extensions, Gpu, Presenter, Shown};
use crate::measure::animate;
use crate::output::{self, Image};
use crate::scene::{is_scene_key, Light, LoadOptions, Scene};
use crate::solvers::{self, Animation, RenderRequest, Settings, Solver};

/// The one line a session without a display gets.
pub const NO_DISPLAY: &str = "no display: set DISPLAY or WAYLAND_DISPLAY; `scatterlab render` works headless";

/// Radians the camera turns per pixel of a left drag.
const ORBIT_PER_PIXEL: f32 = 0.01;
/// Degrees the first light turns per pixel of a right (or shift) drag.
const LIGHT_DEG_PER_PIXEL: f64 = 0.5;
/// The camera's distance to its target scales by this per wheel line (in: < 1).
const ZOOM_PER_LINE: f32 = 0.9;
/// Exposure steps of + and - (stops).
const EXPOSURE_STEP: f32 = 0.5;

/// One input event of a `--script` file: `FRAME ACTION ARGS...`, applied before frame FRAME
/// (counted from 0) is drawn.
#[derive(Clone, Debug, PartialEq)]
pub enum Scripted {
    /// `drag-left DX DY`: orbit the camera as a left drag of (DX, DY) pixels would.
    DragCamera(f32, f32),
    /// `drag-right DX DY`: orbit the first light (DX pixels; DY is ignored).
    DragLight(f32, f32),
    /// `wheel LINES`: zoom (positive: in).
    Wheel(f32),
    /// `key NAME`: a key press (`1`-`8`, `+`, `-`, `r`, `s`, `d`, `escape`).
    Key(String),
    /// `resize W H`: ask the window for W x H pixels.
    Resize(u32, u32),
    /// `close`: the window's close button (what the window manager sends).
    Close,
    /// `minimise` / `restore`: the window iconified (and unmapped, which is all an X server
    /// without a window manager does) and back.
    Minimise(bool),
}

/// Parse a `--script` file: one event per line, `#` comments and blank lines ignored.
pub fn parse_script(text: &str, path: &Path) -> Result<Vec<(u32, Scripted)>> {
    let mut events = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let at = |what: &str| anyhow!("{}:{}: {what} (`{line}`)", path.display(), n + 1);
        let words: Vec<&str> = line.split_whitespace().collect();
        let frame: u32 = words[0].parse().map_err(|_| at("the first word is the frame number"))?;
        let num = |i: usize| -> Result<f32> {
            let w = words.get(i).ok_or_else(|| at("a number is missing"))?;
            w.parse::<f32>().ok().filter(|v| v.is_finite()).ok_or_else(|| at(&format!("{w:?} is not a number")))
        };
        let event = match words.get(1).copied() {
            Some("drag-left") => Scripted::DragCamera(num(2)?, num(3)?),
            Some("drag-right") => Scripted::DragLight(num(2)?, num(3)?),
            Some("wheel") => Scripted::Wheel(num(2)?),
            Some("key") => Scripted::Key(words.get(2).ok_or_else(|| at("key needs a name"))?.to_lowercase()),
            Some("close") => Scripted::Close,
            Some("minimise" | "minimize") => Scripted::Minimise(true),
            Some("restore") => Scripted::Minimise(false),
            Some("resize") => {
                let (w, h) = (num(2)?, num(3)?);
                if !(1.0..=16384.0).contains(&w) || !(1.0..=16384.0).contains(&h) {
                    return Err(at("resize takes two sizes of 1-16384 pixels"));
                }
                Scripted::Resize(w as u32, h as u32)
            }
            _ => {
                return Err(at(
                    "the action is one of drag-left, drag-right, wheel, key, resize, close, minimise, restore",
                ))
            }
        };
        if words.len() > expected_words(&event) {
            return Err(at("too many words"));
        }
        events.push((frame, event));
    }
    events.sort_by_key(|(f, _)| *f);
    Ok(events)
}

fn expected_words(e: &Scripted) -> usize {
    match e {
        Scripted::DragCamera(..) | Scripted::DragLight(..) | Scripted::Resize(..) => 4,
        Scripted::Wheel(_) | Scripted::Key(_) => 3,
        Scripted::Close | Scripted::Minimise(_) => 2,
    }
}

/// `scene`'s camera turned about the medium's centre: `yaw` about +y, then `pitch` about the
/// camera's right axis (kept short of the poles).
pub fn orbit_camera(scene: &Scene, yaw: f32, pitch: f32) -> Scene {
    let mut s = scene.clone();
    let center = (scene.medium.bounds_min + scene.medium.bounds_max) * 0.5;
    let c = &mut s.camera;
    let (right, _, forward) = c.basis();
    // Stop 5 degrees short of looking straight up or down (the basis degenerates there).
    let elevation = forward.y.clamp(-1.0, 1.0).asin();
    let limit = 85f32.to_radians();
    let pitch = (elevation - pitch).clamp(-limit, limit) - elevation;
    let q = Quat::from_axis_angle(Vec3::Y, yaw) * Quat::from_axis_angle(right, -pitch);
    c.origin = center + q * (c.origin - center);
    c.target = center + q * (c.target - center);
    c.up = q * c.up;
    s
}

/// `scene`'s camera moved toward its target by `lines` wheel lines.
pub fn zoom_camera(scene: &Scene, lines: f32) -> Scene {
    let mut s = scene.clone();
    let c = &mut s.camera;
    c.origin = c.target + (c.origin - c.target) * ZOOM_PER_LINE.powf(lines);
    s
}

/// A vector as a TOML array without spaces (one word in a `--set`; f32's shortest exact form).
fn vec3(v: Vec3) -> String {
    format!("[{:?},{:?},{:?}]", v.x, v.y, v.z)
}

/// The `--set` overrides that make `scatterlab render` draw `scene`'s view: camera, first light,
/// size and exposure.
pub fn view_sets(scene: &Scene, exposure: f32) -> Vec<(String, String)> {
    let c = &scene.camera;
    let mut sets = vec![
        ("camera.origin".to_string(), vec3(c.origin)),
        ("camera.target".into(), vec3(c.target)),
        ("camera.up".into(), vec3(c.up)),
        ("render.width".into(), scene.render.width.to_string()),
        ("render.height".into(), scene.render.height.to_string()),
        ("render.exposure".into(), format!("{exposure:?}")),
    ];
    match scene.lights.first() {
        Some(Light::Point { position, .. }) => sets.push(("light.0.position".into(), vec3(*position))),
        Some(Light::Directional { direction, .. }) => sets.push(("light.0.direction".into(), vec3(*direction))),
        _ => {}
    }
    sets
}

/// Per solver used: renders, frames shown, host and GPU time of the renders, and for solvers
/// that iterate, the iterations of renders from zero (cold) and from the last solution (warm).
#[derive(Default)]
struct Used {
    renders: u32,
    frames: u32,
    wall_ms: f64,
    gpu_ms: f64,
    spp: u32,
    cold: (u32, u64),
    warm: (u32, u64),
    /// Said once: a change the warm start cannot follow.
    restart_said: bool,
    /// Said once: an iterative solver without a warm start solves every change from zero.
    cold_said: bool,
    /// The last measure of its image against the `path` accumulation (key D).
    vs_path: Option<Measured>,
    /// The last render's convergence (solvers that iterate).
    last: Option<solvers::Convergence>,
    /// Renders that stopped at the per-frame iteration budget short of the tolerance.
    budget_stops: u32,
}

/// Samples per pixel at which the comparison's `path` accumulation stops (the measure goes on
/// against it as the solver's image converges).
const COMPARE_SPP_MAX: u32 = 65536;

/// Frames a solver under a per-frame iteration budget may take to reach its tolerance after a
/// change before the view stops asking (and says so).
const CONVERGING_FRAMES_MAX: u32 = 1000;

/// A progressive accumulation: the mean of `spp` samples per pixel and, where the batches carry
/// one, the variance of that mean.
struct Accumulated {
    image: Image,
    variance: Option<Image>,
    spp: u32,
}

impl Accumulated {
    /// Fold in a batch's mean of `b` samples per pixel (independent of the samples so far):
    /// the means weighted by their samples, and the variance of the mean of the union
    /// (n^2 v_a + b^2 v_b) / (n + b)^2.
    fn add(&mut self, image: Image, variance: Option<Image>, b: u32) {
        if self.spp == 0 {
            (self.image, self.variance, self.spp) = (image, variance, b);
            return;
        }
        let (n, bf) = (self.spp as f64, b as f64);
        let t = n + bf;
        for (acc, v) in self.image.data.iter_mut().zip(&image.data) {
            *acc = ((*acc as f64 * n + *v as f64 * bf) / t) as f32;
        }
        self.variance = match (self.variance.take(), variance) {
            (Some(mut va), Some(vb)) => {
                for (acc, v) in va.data.iter_mut().zip(&vb.data) {
                    *acc = ((n * n * *acc as f64 + bf * bf * *v as f64) / (t * t)) as f32;
                }
                Some(va)
            }
            _ => None,
        };
        self.spp += b;
    }

    /// [`Accumulated::add`] into `slot`, which holds nothing before the first batch.
    fn fold(slot: &mut Option<Accumulated>, image: Image, variance: Option<Image>, b: u32) {
        match slot {
            Some(a) => a.add(image, variance, b),
            None => *slot = Some(Accumulated { image, variance, spp: b }),
        }
    }
}

/// The solver's image against the `path` accumulation beside it.
#[derive(Clone, Copy, Debug)]
struct Measured {
    rel_l2: f64,
    /// relL2 with both images' noise removed (`output::noise_floor`).
    corrected: Option<f64>,
    energy_ratio: f64,
    spp: u32,
}

impl Measured {
    fn line(&self) -> String {
        format!(
            "relL2 {:.4}{} and energy ratio {:.4} against path at {} spp",
            self.rel_l2,
            self.corrected.map_or(String::new(), |c| format!(" ({c:.4} with the noise removed)")),
            self.energy_ratio,
            self.spp
        )
    }
}

/// Key D's `path` accumulation, for the view (camera, lights, size) it was made for.
struct Comparison {
    key: String,
    acc: Option<Accumulated>,
    /// Said once: D with path itself shown.
    path_said: bool,
}

impl Used {
    fn iterations(&self) -> String {
        let mean = |(n, sum): (u32, u64)| if n > 0 { sum as f64 / n as f64 } else { 0.0 };
        match (self.cold.0, self.warm.0) {
            (0, 0) => String::new(),
            (_, 0) => format!(", {:.0} iterations from zero", mean(self.cold)),
            _ => format!(
                ", {:.0} iterations from zero and {:.0} warm started ({} renders{})",
                mean(self.cold),
                mean(self.warm),
                self.warm.0,
                if self.budget_stops > 0 {
                    format!(", {} stopped at the per-frame budget", self.budget_stops)
                } else {
                    String::new()
                }
            ),
        }
    }
}

/// What the window and the device are, once the event loop has started.
struct Live {
    // Dropped in this order: the presenter (its surface) before the device and the window.
    presenter: Presenter,
    gpu: Gpu,
    window: Window,
}

struct App<'a> {
    args: &'a ViewArgs,
    /// The scene as loaded (R resets to it) and as the view has moved it.
    base: Scene,
    scene: Scene,
    solver: &'static dyn Solver,
    /// Every solver's `--set` knobs; each render gets its own solver's ([`own_knobs`]).
    knob_sets: Vec<(String, String)>,
    exposure: f32,
    live: Option<Live>,
    script: Vec<(u32, Scripted)>,
    frame: u32,
    /// The linear image shown, with the variance of its mean where the solver gives one, and
    /// (path) the samples per pixel it averages (0 for the other solvers, and after a change).
    shown: Option<Accumulated>,
    /// Something changed since the image was rendered.
    dirty: bool,
    /// The solver shown stopped at its per-frame iteration budget short of its tolerance: the
    /// next frames go on from its solution (counted, up to [`CONVERGING_FRAMES_MAX`]).
    converging: Option<u32>,
    /// Key D: a `path` accumulation beside the solver, and its measure.
    compare: Option<Comparison>,
    /// The warm-started sequence of the solver shown (those that keep a solution: lbl,
    /// networks), and the view it was made for (solver, camera, size): a move of the light
    /// renders its next frame from the last solution; any other change starts a new one.
    anim: Option<(String, Box<dyn Animation>)>,
    /// The render warnings printed so far.
    said: std::collections::HashSet<String>,
    drag: Option<(MouseButton, PhysicalPosition<f64>)>,
    cursor: PhysicalPosition<f64>,
    modifiers: ModifiersState,
    screenshot_now: bool,
    screenshots: u32,
    /// Esc or the close button: the loop ends, and no frame after it is drawn.
    closing: bool,
    /// Minimised or hidden (a script's `minimise`, or the window system saying it is occluded):
    /// nothing is rendered or presented until it is back.
    hidden: bool,
    used: BTreeMap<&'static str, Used>,
    started: Instant,
    error: Option<anyhow::Error>,
}

pub fn view(a: ViewArgs) -> Result<()> {
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        bail!(NO_DISPLAY);
    }
    let solver = solvers::find(&a.solver)?;
    let sets = parse_sets(&a.set)?;
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = sets.into_iter().partition(|(k, _)| is_scene_key(k));
    // Knobs of any solver: the keys switch between them.
    solvers::check_settings(&Settings::new(&knob_sets), solvers::SOLVERS)?;
    let mut scene = Scene::load(&a.scene, &scene_sets, &LoadOptions::default())?;
    if let Some(size) = &a.size {
        let (w, h) = parse_size(size)?;
        (scene.render.width, scene.render.height) = (w, h);
    }
    if let Some(why) = solver.scene_refusal(&scene) {
        bail!("{}: {why}", a.scene.display());
    }
    let script = match &a.script {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("--script {}", p.display()))?;
            parse_script(&text, p)?
        }
        None => Vec::new(),
    };
    if let Some(p) = &a.screenshot {
        super::args::check_output_path(p, "--screenshot", &["png"])?;
    }
    let event_loop = event_loop()?;
    let mut app = App {
        args: &a,
        base: scene.clone(),
        exposure: scene.render.exposure,
        scene,
        solver,
        knob_sets,
        live: None,
        script,
        frame: 0,
        shown: None,
        dirty: true,
        converging: None,
        compare: None,
        anim: None,
        said: Default::default(),
        drag: None,
        cursor: PhysicalPosition::new(0.0, 0.0),
        modifiers: ModifiersState::empty(),
        screenshot_now: false,
        screenshots: 0,
        closing: false,
        hidden: false,
        used: BTreeMap::new(),
        started: Instant::now(),
        error: None,
    };
    event_loop.run_app(&mut app).map_err(|e| anyhow!("the window's event loop failed: {e}"))?;
    if let Some(Live { presenter, gpu, window }) = app.live.take() {
        // The swapchain and surface go first, so that what the layer says of their destruction
        // is counted; then the device, then the window.
        drop(presenter);
        app.anim = None;
        check_validation(&gpu)?;
        let log = gpu.validation_log();
        let validating = gpu.validation_enabled();
        let before = log.errors.load(Ordering::SeqCst);
        drop(gpu);
        drop(window);
        // The device is destroyed with the last handle on it: a handle still held (a buffer, a
        // pipeline kept past the session) keeps it, and the log's last other holder, alive.
        if Arc::strong_count(&log) > 1 {
            bail!("the device outlived the window: a handle on it was never released (a leak; please report it)");
        }
        if validating {
            // The layer names every object left on a device it sees destroyed, one error each.
            let left = log.errors.load(Ordering::SeqCst) - before;
            if left > 0 {
                let first = log.first_errors.lock().map(|v| v.first().cloned().unwrap_or_default()).unwrap_or_default();
                bail!("{left} Vulkan object(s) were left on the device at exit (a leak; please report it): {first}");
            }
            if !a.quiet {
                eprintln!("view: device closed with no Vulkan object left on it (the validation layer's count)");
            }
        }
    }
    if let Some(e) = app.error {
        return Err(e);
    }
    for (name, u) in &app.used {
        let per = |x: f64| if u.renders > 0 { x / u.renders as f64 } else { 0.0 };
        println!(
            "view: {name}: {} frames, {} renders{}, {:.1} ms wall and {:.2} ms GPU per render{}",
            u.frames,
            u.renders,
            if u.spp > 0 { format!(" ({} spp)", u.spp) } else { String::new() },
            per(u.wall_ms),
            per(u.gpu_ms),
            u.iterations()
        );
        if let Some(m) = u.vs_path {
            println!("view: {name}: {}", m.line());
        }
    }
    // Quoted for a shell: the arrays' brackets are glob characters.
    let sets: Vec<String> =
        view_sets(&app.scene, app.exposure).iter().map(|(k, v)| format!("--set '{k}={v}'")).collect();
    println!(
        "view: the last view as a render: scatterlab render {} --solver {} {}",
        a.scene.display(),
        app.solver.name(),
        sets.join(" ")
    );
    Ok(())
}

/// The seed of the progressive batch that starts at sample `spp`: each batch its own, so that
/// batches are independent samples of one image.
fn batch_seed(seed: u64, spp: u32) -> u64 {
    seed.wrapping_add((spp as u64).wrapping_mul(0x9e37_79b9))
}

/// The knobs of `sets` that belong to `solver` (`<name>.` keys): the view's `--set`s may name
/// every solver's, a render takes only its own.
fn own_knobs(sets: &[(String, String)], solver: &dyn Solver) -> Settings {
    let prefix = format!("{}.", solver.name());
    let own: Vec<(String, String)> = sets.iter().filter(|(k, _)| k.starts_with(&prefix)).cloned().collect();
    Settings::new(&own)
}

/// winit's event loop, or one line. winit 0.30 panics where the X server answers its first
/// queries with an I/O error (an X server still starting: "Failed to query XRandR extension");
/// that panic is caught and said as the display's error, never shown as a panic.
fn event_loop() -> Result<EventLoop<()>> {
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let made = std::panic::catch_unwind(EventLoop::new);
    std::panic::set_hook(hook);
    match made {
        Ok(Ok(el)) => Ok(el),
        Ok(Err(e)) => Err(anyhow!("{NO_DISPLAY} ({e})")),
        Err(p) => {
            let why = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "the windowing library failed".into());
            Err(anyhow!(
                "the display does not answer as a window system should: {why}; check DISPLAY or WAYLAND_DISPLAY"
            ))
        }
    }
}

/// `WxH` in pixels.
fn parse_size(s: &str) -> Result<(u32, u32)> {
    let bad = || anyhow!("--size {s}: give WIDTHxHEIGHT in pixels, each 1-16384 (e.g. 512x512)");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

impl App<'_> {
    /// Samples per pixel the image shown averages (path).
    fn spp(&self) -> u32 {
        self.shown.as_ref().map_or(0, |a| a.spp)
    }

    fn open(&mut self, el: &ActiveEventLoop) -> Result<()> {
        let size = PhysicalSize::new(self.scene.render.width, self.scene.render.height);
        let attrs = Window::default_attributes().with_title(self.title()).with_inner_size(size).with_resizable(true);
        let window = el.create_window(attrs).map_err(|e| anyhow!("{NO_DISPLAY} (cannot open a window: {e})"))?;
        let display = window.display_handle().map_err(|e| anyhow!("the window's display: {e}"))?.as_raw();
        let handle = window.window_handle().map_err(|e| anyhow!("the window's handle: {e}"))?.as_raw();
        let mut opts = gpu_options(&self.args.gpu);
        opts.presentation = Some(surface_extensions(display)?);
        let gpu = Gpu::new(&opts)?;
        let inner = window.inner_size();
        let presenter = Presenter::new(&gpu, display, handle, [inner.width, inner.height])?;
        if !self.args.quiet {
            let info = gpu.info();
            eprintln!(
                "view: device {} ({}), presenting {} on queue family {}{}",
                info.name,
                info.device_type,
                presenter.format(),
                presenter.family(),
                if presenter.reads_back() { "" } else { " (screenshots from the uploaded bytes)" }
            );
        }
        self.live = Some(Live { presenter, gpu, window });
        Ok(())
    }

    fn title(&self) -> String {
        let u = self.used.get(self.solver.name());
        let (ms, gpu) = u.map_or((0.0, 0.0), |u| {
            if u.renders == 0 {
                (0.0, 0.0)
            } else {
                (u.wall_ms / u.renders as f64, u.gpu_ms / u.renders as f64)
            }
        });
        let fps = if self.frame > 0 { self.frame as f64 / self.started.elapsed().as_secs_f64() } else { 0.0 };
        let spp = if self.solver.samples_pixels() { format!(", {} spp", self.spp()) } else { String::new() };
        let iterating = match (u.and_then(|u| u.last), self.converging) {
            (Some(c), Some(_)) => format!(", {} iterations (change {:.1e}, converging)", c.iterations, c.final_change),
            (Some(c), None) => format!(", {} iterations (change {:.1e})", c.iterations, c.final_change),
            (None, _) => String::new(),
        };
        let vs = match (&self.compare, u.and_then(|u| u.vs_path)) {
            (Some(_), Some(m)) => format!(
                ", vs path {} spp: relL2 {:.3}{}, energy {:.3}",
                m.spp,
                m.rel_l2,
                m.corrected.map_or(String::new(), |c| format!(" ({c:.3} less noise)")),
                m.energy_ratio
            ),
            _ => String::new(),
        };
        format!(
            "scatterlab view: {} - {fps:.1} frames/s, {ms:.0} ms a render ({gpu:.1} ms GPU){spp}{iterating}{vs}, exposure {:+.1}",
            self.solver.name(),
            self.exposure
        )
    }

    /// Apply one input: a change of view, light or solver marks the image stale.
    fn apply(&mut self, event: &Scripted, el: &ActiveEventLoop) -> Result<()> {
        match event {
            Scripted::DragCamera(dx, dy) => {
                self.scene = orbit_camera(&self.scene, -dx * ORBIT_PER_PIXEL, -dy * ORBIT_PER_PIXEL);
                self.dirty = true;
            }
            Scripted::DragLight(dx, _) => {
                if matches!(self.scene.lights.first(), Some(Light::Point { .. } | Light::Directional { .. })) {
                    self.scene =
                        animate::orbit(&self.scene, *dx as f64 * LIGHT_DEG_PER_PIXEL).map_err(|e| anyhow!(e))?;
                    self.dirty = true;
                }
            }
            Scripted::Wheel(lines) => {
                self.scene = zoom_camera(&self.scene, *lines);
                self.dirty = true;
            }
            Scripted::Close => {
                self.closing = true;
                el.exit();
            }
            Scripted::Minimise(m) => {
                self.hidden = *m;
                if let Some(l) = &self.live {
                    if *m {
                        l.window.set_minimized(true);
                        l.window.set_visible(false);
                    } else {
                        l.window.set_visible(true);
                        l.window.set_minimized(false);
                    }
                }
            }
            Scripted::Resize(w, h) => {
                if let Some(l) = &self.live {
                    let _ = l.window.request_inner_size(PhysicalSize::new(*w, *h));
                }
            }
            Scripted::Key(k) => match k.as_str() {
                "escape" => {
                    self.closing = true;
                    el.exit();
                }
                "+" | "=" => self.exposure += EXPOSURE_STEP,
                "-" => self.exposure -= EXPOSURE_STEP,
                "r" => {
                    let size = (self.scene.render.width, self.scene.render.height);
                    self.scene = self.base.clone();
                    (self.scene.render.width, self.scene.render.height) = size;
                    self.exposure = self.base.render.exposure;
                    self.dirty = true;
                }
                "s" => self.screenshot_now = true,
                "d" => {
                    self.compare = match self.compare.take() {
                        Some(_) => None,
                        None => Some(Comparison { key: String::new(), acc: None, path_said: false }),
                    };
                    for u in self.used.values_mut() {
                        u.vs_path = None;
                    }
                }
                d if d.len() == 1 && d.as_bytes()[0].is_ascii_digit() => {
                    let i = (d.as_bytes()[0] - b'1') as usize;
                    if let Some(&next) = solvers::SOLVERS.get(i) {
                        self.switch(next);
                    }
                }
                _ => {}
            },
        }
        Ok(())
    }

    /// Switch to `next`, or say once why it cannot draw this scene.
    fn switch(&mut self, next: &'static dyn Solver) {
        if next.name() == self.solver.name() {
            return;
        }
        if let Some(why) = next.scene_refusal(&self.scene) {
            eprintln!("view: {}: {why}; staying with {}", next.name(), self.solver.name());
            return;
        }
        self.solver = next;
        self.dirty = true;
    }

    /// Render what the view needs now: a fresh image after a change, (path) one more batch, or
    /// (a solver under a per-frame iteration budget) more iterations from its last solution;
    /// then the comparison's batch where D is on.
    fn render_step(&mut self, extent: [u32; 2]) -> Result<()> {
        self.solver_step(extent)?;
        self.compare_step()
    }

    fn solver_step(&mut self, extent: [u32; 2]) -> Result<()> {
        let live = self.live.as_ref().expect("open");
        let size_changed = self.shown.as_ref().is_some_and(|a| [a.image.width, a.image.height] != extent);
        let progressive = self.solver.samples_pixels();
        let target = self.base.render.spp.max(1);
        let more = progressive && self.spp() < target;
        if !(self.dirty || size_changed || more || self.converging.is_some()) {
            return Ok(());
        }
        let changed = self.dirty || size_changed;
        if changed {
            if let Some(a) = self.shown.as_mut() {
                a.spp = 0;
            }
            self.converging = None;
        }
        let spp = self.spp();
        (self.scene.render.width, self.scene.render.height) = (extent[0], extent[1]);
        let mut s = self.scene.clone();
        let batch = if progressive { self.args.batch.min(target - spp).max(1) } else { 0 };
        if progressive {
            // Each batch its own seed: independent samples, averaged below.
            s.render.spp = batch;
            s.render.seed = batch_seed(self.base.render.seed, spp);
        }
        let started = Instant::now();
        let settings = own_knobs(&self.knob_sets, self.solver);
        let req = RenderRequest { scene: &s, settings: &settings, force_full: false, progress: &|_| {} };
        let name = self.solver.name();
        let fail = |e: solvers::SolverError| anyhow!("{name}: {e}");
        // A per-frame iteration budget where the user set the solver's knob for it.
        let budget_key = format!("{name}.iterations_per_frame");
        let budgeted = self.knob_sets.iter().any(|(k, _)| *k == budget_key);
        // Warm starts follow the light; the camera, the size and the solver are the sequence's.
        let key = format!("{name}|{:?}|{}x{}", s.camera, s.render.width, s.render.height);
        let warm = self.anim.as_ref().is_some_and(|(k, _)| *k == key);
        if !warm && !progressive {
            let had = self.anim.as_ref().is_some_and(|(k, _)| k.starts_with(&format!("{name}|")));
            self.anim = None;
            self.anim = self.solver.animation(&req, !budgeted).map_err(fail)?.map(|a| (key, a));
            let u = self.used.entry(name).or_default();
            if had && self.anim.is_some() && !u.restart_said && !self.args.quiet {
                eprintln!("view: {name} starts again from zero when the camera or the size changes (its warm start follows the light)");
                u.restart_said = true;
            }
        }
        let out = match &mut self.anim {
            Some((_, a)) if !progressive => a.frame(&live.gpu, &s, &|_| {}).map_err(fail)?,
            _ => self.solver.render(&live.gpu, &req).map_err(fail)?,
        };
        let nonfinite = out.image.nan_inf_count();
        if nonfinite > 0 {
            bail!(
                "solver {} produced {nonfinite} NaN/Inf values (this is a bug: please report the scene)",
                self.solver.name()
            );
        }
        let quiet = self.args.quiet;
        let has_anim = self.anim.is_some();
        let u = self.used.entry(name).or_default();
        u.renders += 1;
        u.wall_ms += started.elapsed().as_secs_f64() * 1e3;
        u.gpu_ms += out.report.gpu_ms;
        if !progressive && !has_anim && u.renders > 1 && !u.cold_said && !quiet {
            // Once: lbl, networks and dom carry their solution to the next frame, the others do not.
            eprintln!("view: {name} keeps no solution between frames: every change renders again from scratch");
            u.cold_said = true;
        }
        if let Some(c) = out.report.stats.convergence {
            u.last = Some(c);
            let slot = if warm { &mut u.warm } else { &mut u.cold };
            *slot = (slot.0 + 1, slot.1 + c.iterations);
            // Under a budget, short of the tolerance: the next frames go on from here.
            let stopped = budgeted && has_anim && !c.converged;
            if stopped {
                u.budget_stops += 1;
            }
            self.converging = match (stopped, self.converging) {
                (false, _) => None,
                (true, Some(n)) if n + 1 >= CONVERGING_FRAMES_MAX => {
                    eprintln!(
                        "view: {name} did not reach its tolerance in {CONVERGING_FRAMES_MAX} frames of {budget_key}; \
                         showing the last (change {:.1e} against {:.1e})",
                        c.final_change, c.tolerance
                    );
                    None
                }
                (true, n) => Some(n.map_or(1, |n| n + 1)),
            };
        }
        // A fresh image (not a batch added to path's): its warnings, once each (the same render
        // again, after a light move, says the same). A frame stopped at its iteration budget
        // says so in every warning; the title shows the convergence instead.
        if spp == 0 && !(budgeted && warm) {
            for w in &out.report.warnings {
                if self.said.insert(w.clone()) {
                    eprintln!("warning: {w}");
                }
            }
        }
        // The other solvers' images replace the last (0 samples: `add` keeps none of it).
        Accumulated::fold(&mut self.shown, out.image, out.variance, batch);
        if progressive {
            u.spp = spp + batch;
        }
        self.dirty = false;
        Ok(())
    }

    /// Key D: one more `path` batch beside the solver shown (started again when the view
    /// changes), and the solver's image measured against the accumulation.
    fn compare_step(&mut self) -> Result<()> {
        let Some(cmp) = self.compare.as_mut() else { return Ok(()) };
        let Some(shown) = self.shown.as_ref() else { return Ok(()) };
        let image = &shown.image;
        if self.solver.samples_pixels() {
            if !cmp.path_said && !self.args.quiet {
                eprintln!("view: D measures the solver shown against path; path is shown (keys 1-8 switch)");
                cmp.path_said = true;
            }
            return Ok(());
        }
        let s = &self.scene;
        let key = format!("{:?}|{:?}|{}x{}", s.camera, s.lights, image.width, image.height);
        if cmp.key != key {
            (cmp.key, cmp.acc) = (key, None);
        }
        let spp = cmp.acc.as_ref().map_or(0, |a| a.spp);
        if spp < COMPARE_SPP_MAX {
            let path = solvers::reference();
            let mut ps = s.clone();
            ps.render.spp = self.args.batch.min(COMPARE_SPP_MAX - spp);
            // Seeds of their own, apart from those of a `path` shown in the window.
            ps.render.seed = batch_seed(self.base.render.seed ^ 0x5ca7_7e51, spp);
            let settings = own_knobs(&self.knob_sets, path);
            let req = RenderRequest { scene: &ps, settings: &settings, force_full: false, progress: &|_| {} };
            let live = self.live.as_ref().expect("open");
            let out = path.render(&live.gpu, &req).map_err(|e| anyhow!("{} (key D's comparison): {e}", path.name()))?;
            Accumulated::fold(&mut cmp.acc, out.image, out.variance, ps.render.spp);
        }
        let acc = cmp.acc.as_ref().expect("a batch");
        let m = output::compare(image, &acc.image)?;
        let floor = output::metrics::noise_floor(image, &acc.image, shown.variance.as_ref(), acc.variance.as_ref())?;
        let measured = Measured {
            rel_l2: m.rel_l2,
            corrected: floor.rel_l2_corrected,
            energy_ratio: m.energy_ratio,
            spp: acc.spp,
        };
        self.used.entry(self.solver.name()).or_default().vs_path = Some(measured);
        Ok(())
    }

    /// One frame: scripted input, a render step, the image shown, a screenshot if asked.
    fn draw(&mut self, el: &ActiveEventLoop) -> Result<()> {
        let due: Vec<Scripted> = self.script.iter().filter(|(f, _)| *f == self.frame).map(|(_, e)| e.clone()).collect();
        for e in &due {
            self.apply(e, el)?;
        }
        if self.closing {
            // Closed before this frame: nothing more is rendered, shown or saved.
            return Ok(());
        }
        if self.hidden {
            // Minimised: no render and no present. A script's frames go on counting, so that
            // its `restore` comes; without one the loop waits for the window to come back.
            if !self.script.is_empty() {
                self.frame += 1;
            }
            return Ok(());
        }
        let extent = self.live.as_ref().expect("open").presenter.extent();
        if extent[0] == 0 || extent[1] == 0 {
            // Minimised: nothing to draw into.
            return Ok(());
        }
        self.render_step(extent)?;
        let image = &self.shown.as_ref().expect("rendered").image;
        if [image.width, image.height] != extent {
            return Ok(());
        }
        let last = self.args.frames.is_some_and(|n| self.frame + 1 >= n);
        let read = self.screenshot_now || (last && self.args.screenshot.is_some());
        let live = self.live.as_mut().expect("open");
        match live.presenter.show(&image.data, self.exposure, read)? {
            Shown::OutOfDate => {
                let size = live.window.inner_size();
                live.presenter.resize([size.width, size.height])?;
                return Ok(());
            }
            Shown::Presented(pixels) => {
                if let Some(pixels) = pixels {
                    self.save_screenshot(&pixels, extent)?;
                }
            }
        }
        self.used.entry(self.solver.name()).or_default().frames += 1;
        self.frame += 1;
        let title = self.title();
        let live = self.live.as_ref().expect("open");
        live.window.set_title(&title);
        if last {
            el.exit();
        }
        Ok(())
    }

    /// The frame shown as a PNG (the bytes presented) and beside it an EXR of the linear image
    /// (with the variance of path's mean as a layer), both carrying the `--set`s that make
    /// `scatterlab render` draw the same view; staged and then renamed together, so that an
    /// error leaves neither.
    fn save_screenshot(&mut self, rgb8: &[u8], extent: [u32; 2]) -> Result<()> {
        let path: PathBuf = match (&self.args.screenshot, self.screenshot_now) {
            (Some(p), false) => p.clone(),
            (Some(p), true) => {
                self.screenshots += 1;
                let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or("screenshot");
                p.with_file_name(format!("{stem}-{}.png", self.screenshots))
            }
            (None, _) => {
                self.screenshots += 1;
                PathBuf::from(format!("scatterlab-view-{}.png", self.screenshots))
            }
        };
        self.screenshot_now = false;
        let exr = path.with_extension("exr");
        let sets: Vec<String> =
            view_sets(&self.scene, self.exposure).iter().map(|(k, v)| format!("--set {k}={v}")).collect();
        let mut text = vec![
            ("scatterlab.engine".to_string(), output::engine()),
            ("scatterlab.view.scene".into(), self.args.scene.display().to_string()),
            ("scatterlab.view.solver".into(), self.solver.name().to_string()),
            ("scatterlab.view.sets".into(), sets.join(" ")),
            ("scatterlab.view.spp".into(), self.spp().to_string()),
            ("scatterlab.tonemap".into(), output::TONEMAP_DESCRIPTION.into()),
        ];
        if let Some(c) = self.used.get(self.solver.name()).and_then(|u| u.last) {
            text.push((
                "scatterlab.view.iterations".into(),
                format!(
                    "{} ({}, change {:.3e})",
                    c.iterations,
                    if c.converged { "converged" } else { "converging" },
                    c.final_change
                ),
            ));
        }
        let shown = self.shown.as_ref().expect("shown");
        let mut layers: Vec<(&str, &Image)> = vec![("", &shown.image)];
        if let Some(v) = &shown.variance {
            layers.push(("variance", v));
        }
        let mut staging = output::Staging::new();
        staging.stage(&path, |tmp| output::write_rgb8_png(tmp, extent[0], extent[1], rgb8, &text))?;
        staging.stage(&exr, |tmp| output::write_exr_with_metadata(tmp, &layers, &text))?;
        staging.commit().map_err(|e| anyhow!("--screenshot {}: {e}", path.display()))?;
        if !self.args.quiet {
            eprintln!("view: screenshot {} and {}", path.display(), exr.display());
        }
        Ok(())
    }

    fn fail(&mut self, el: &ActiveEventLoop, e: anyhow::Error) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        el.exit();
    }

    /// Whether the next frame has work: a stale image, path still accumulating, a script or a
    /// frame count still to run (and a window that is not minimised).
    fn busy(&self) -> bool {
        // Minimised: nothing can be drawn until the window is restored (its Resized event).
        if self.live.as_ref().is_some_and(|l| l.presenter.extent().contains(&0)) {
            return false;
        }
        if self.hidden {
            // Only a script's frames tick while hidden (to reach its `restore`).
            return self.script.iter().any(|(f, _)| *f >= self.frame);
        }
        self.dirty
            || (self.solver.samples_pixels() && self.spp() < self.base.render.spp.max(1))
            || self.args.frames.is_some()
            || self.script.iter().any(|(f, _)| *f >= self.frame)
            || self.screenshot_now
            || self.converging.is_some()
            || self.compare.as_ref().is_some_and(|c| c.acc.as_ref().map_or(true, |a| a.spp < COMPARE_SPP_MAX))
    }
}

impl ApplicationHandler for App<'_> {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.live.is_none() {
            if let Err(e) = self.open(el) {
                self.fail(el, e);
            }
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let result = match event {
            WindowEvent::CloseRequested => self.apply(&Scripted::Close, el),
            WindowEvent::Resized(size) => match self.live.as_mut() {
                Some(l) => l.presenter.resize([size.width, size.height]).map_err(anyhow::Error::from),
                None => Ok(()),
            },
            WindowEvent::RedrawRequested => {
                if self.live.is_some() {
                    self.draw(el)
                } else {
                    Ok(())
                }
            }
            WindowEvent::Occluded(hidden) => {
                self.hidden = hidden;
                Ok(())
            }
            WindowEvent::ModifiersChanged(m) => {
                self.modifiers = m.state();
                Ok(())
            }
            WindowEvent::MouseInput { state, button, .. } => {
                self.drag = (state == ElementState::Pressed).then_some((button, self.cursor));
                Ok(())
            }
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = position;
                match self.drag {
                    Some((button, from)) => {
                        let (dx, dy) = ((position.x - from.x) as f32, (position.y - from.y) as f32);
                        self.drag = Some((button, position));
                        let light = button == MouseButton::Right || self.modifiers.shift_key();
                        let e = if light { Scripted::DragLight(dx, dy) } else { Scripted::DragCamera(dx, dy) };
                        self.apply(&e, el)
                    }
                    None => Ok(()),
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => (p.y / 40.0) as f32,
                };
                self.apply(&Scripted::Wheel(lines), el)
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                let name = match &event.logical_key {
                    Key::Named(NamedKey::Escape) => Some("escape".to_string()),
                    Key::Character(c) => Some(c.to_lowercase()),
                    _ => None,
                };
                match name {
                    Some(n) => self.apply(&Scripted::Key(n), el),
                    None => Ok(()),
                }
            }
            _ => Ok(()),
        };
        if let Err(e) = result {
            self.fail(el, e);
        }
    }

    fn about_to_wait(&mut self, el: &ActiveEventLoop) {
        match &self.live {
            Some(l) if self.busy() => {
                el.set_control_flow(ControlFlow::Poll);
                l.window.request_redraw();
            }
            _ => el.set_control_flow(ControlFlow::Wait),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_script_parses_and_names_its_line_when_it_does_not() {
        let p = Path::new("s.txt");
        let text =
            "# a session\n2 drag-left 10 -5\n0 key 2\n1 wheel 1.5\n3 resize 65 33\n4 minimise\n5 restore\n6 close\n";
        let ev = parse_script(text, p).unwrap();
        assert_eq!(
            ev,
            vec![
                (0, Scripted::Key("2".into())),
                (1, Scripted::Wheel(1.5)),
                (2, Scripted::DragCamera(10.0, -5.0)),
                (3, Scripted::Resize(65, 33)),
                (4, Scripted::Minimise(true)),
                (5, Scripted::Minimise(false)),
                (6, Scripted::Close),
            ]
        );
        for bad in ["x key 1", "1 jump", "1 wheel", "1 wheel nan", "1 resize 0 10", "1 key 1 2", "1 close now"] {
            let e = parse_script(bad, p).unwrap_err().to_string();
            assert!(e.starts_with("s.txt:1: "), "{bad}: {e}");
        }
    }

    #[test]
    fn the_camera_orbits_about_the_medium_and_keeps_its_distance() {
        let s = crate::scene::Scene::load(
            Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/homogeneous-sphere.toml")),
            &[],
            &LoadOptions::default(),
        )
        .unwrap();
        let center = (s.medium.bounds_min + s.medium.bounds_max) * 0.5;
        let d0 = (s.camera.origin - center).length();
        let o = orbit_camera(&s, 0.7, 0.3);
        assert!(((o.camera.origin - center).length() - d0).abs() < 1e-4 * d0);
        assert!((o.camera.origin - s.camera.origin).length() > 0.1);
        // A full turn of yaw returns the camera.
        let back = orbit_camera(&s, std::f32::consts::TAU, 0.0);
        assert!((back.camera.origin - s.camera.origin).length() < 1e-4 * d0);
        // Pitch stops short of the pole.
        let top = orbit_camera(&s, 0.0, -10.0);
        let (_, _, f) = top.camera.basis();
        assert!(f.y.abs() < 86f32.to_radians().sin(), "{f}");
        let z = zoom_camera(&s, 1.0);
        assert!(
            ((z.camera.origin - z.camera.target).length() / (s.camera.origin - s.camera.target).length() - 0.9).abs()
                < 1e-5
        );
    }
}
