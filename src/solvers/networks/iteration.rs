//! The network's iteration on the device (illumination networks 3.3): radiance moved one
//! particle further along every direction at once, batches of iterations with the
//! convergence test on the device, warm starts when a light moves.

use super::*;

/// Fewest iterations per submission; each writes its change and peak into its own slot of
/// the stats buffer, read once per submission (so the host waits at most once per 8).
pub const BATCH: u32 = 8;
/// Most iterations per submission: where an iteration takes less than
/// [`BATCH_TARGET_MS`] / [`BATCH`], batches grow toward that much GPU work (a GPU runs an
/// iteration of the default network in about a millisecond: a batch of 8 left it waiting for
/// the host between batches).
pub const BATCH_MAX: u32 = 64;
/// The GPU work a submission aims at, milliseconds (issue 42: 5-20 ms).
pub const BATCH_TARGET_MS: f64 = 12.0;
/// Words of the stats buffer: verdict, dispatches run, then two per slot.
pub(super) const STATS_WORDS: u64 = 2 + 2 * BATCH_MAX as u64;

/// How an iteration is judged ([`Illumination::solve`]; glsl/networks/iterate.comp's
/// `verdict` is the same rule in the same f32 arithmetic, so host and device agree bit for
/// bit): a negative or non-finite largest change or largest I is a fault; else converged where
/// the change is at most `tol` times the largest I (or nothing is lit).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    GoOn,
    Converged,
    Fault,
}

pub fn verdict(change: f32, peak: f32, tol: f32) -> Verdict {
    let bad = |x: f32| !x.is_finite() || x < 0.0;
    if bad(change) || bad(peak) {
        Verdict::Fault
    } else if peak <= 0.0 || change <= tol * peak {
        Verdict::Converged
    } else {
        Verdict::GoOn
    }
}

/// Whether the iteration reads the lights' scattered light from a table (glsl/networks/lit.comp)
/// rather than summing `units` light units on every link of every iteration: where there is
/// more than one unit (an environment is 16 of them by default). One unit costs a link two
/// reads either way. Not with `force_full` (`--model-all`): the iteration then sums the units
/// on every link, the general kernel the table is checked against.
pub fn tabulates_lit(units: u32, force_full: bool) -> bool {
    units > 1 && !force_full
}

/// In-scattering sums glsl/networks/inscatter.comp takes per particle each iteration for `d`
/// directions: one where the medium is isotropic (the same for every direction out), `d` where
/// it is anisotropic, none with `force_full` on an anisotropic medium (`--model-all`: the
/// iteration keeps the sum in each link, the general kernel the others are held to).
pub fn inscatter_outputs(anisotropic: bool, force_full: bool, d: u32) -> u32 {
    match (anisotropic, force_full) {
        (false, _) => 1,
        (true, false) => d,
        (true, true) => 0,
    }
}

/// inscatter.comp's `BLOCK`: directions one anisotropic invocation sums in a pass over its
/// particle's I.
const INSCATTER_BLOCK: u32 = 8;

/// What one submitted batch of iterations did ([`Illumination::batch`]).
pub(super) struct BatchRun {
    /// Per iteration that ran: its change relative to the largest I (NaN at a fault).
    pub(super) changes: Vec<f64>,
    /// The verdict that stopped the batch on the device, if one did.
    pub(super) stopped: Option<Verdict>,
}

/// The illumination network on the device, ready to iterate: the scene, particles, directions,
/// visibility network, phase matrix, direct light and the two radiance buffers (ping-pong).
/// It outlives a light's move: [`Illumination::set_lights`] recomputes the direct light and
/// keeps I, the paper's warm start (4: "we take the solution of the previous light position
/// as the initial value").
pub struct Illumination {
    pub(super) gs: GpuScene,
    pub(super) positions: Buffer,
    pub(super) dirs: Buffer,
    pub(super) visible: Buffer,
    pub(super) phase: Buffer,
    pub(super) direct: Buffer,
    /// Each particle's (1 - albedo) Le ([`Network::emitted`]) where the kernels model emission
    /// (glsl/networks/iterate.comp, gather.comp); None where they do not (bound: the scene's
    /// emission placeholder, never read).
    pub(super) emitted: Option<Buffer>,
    /// J[p][i], the emission arriving unscattered, and E[p][i], J scattered into each
    /// direction ([`EmissionModel::Marched`]: glsl/networks/arrive.comp), where the kernels
    /// model emission; None otherwise.
    pub(super) arriving: Option<(Buffer, Buffer)>,
    pub(super) emission: EmissionModel,
    pub(super) field: [Buffer; 2],
    /// Per iteration of a submission: the largest change of I and the largest I (f32 bits),
    /// after the verdict and the count of iterations run (a device record and its host copy).
    pub(super) stats: crate::solvers::parts::feedback::Feedback,
    /// Which of `field` holds the current I.
    pub(super) current: usize,
    pub(super) pipeline: crate::gpu::Pipeline,
    /// The in-scattering pass and its sums (glsl/networks/inscatter.comp; 16 N bytes for an
    /// isotropic medium, 16 N D for an anisotropic one, [`inscatter_outputs`]): the iteration
    /// then reads one sum per link instead of summing D values. None with `--model-all` on an
    /// anisotropic medium (the sum stays in the link).
    pub(super) inscatter: Option<(crate::gpu::Pipeline, Buffer)>,
    /// Where the lights are more than one unit: the table of their light scattered at each
    /// particle into each direction (16 N D bytes), summed once per light position
    /// (glsl/networks/lit.comp) and read by the iteration instead of summing the units.
    pub(super) lit: Option<(crate::gpu::Pipeline, Buffer)>,
    pub(super) push: IteratePush,
    pub(super) step: f32,
    /// Iterations the next batch submits (adapted to the measured iteration time).
    pub(super) batch: u32,
    /// The image's size and a particle's extinction cross-section sigma_t m (rgb, units^2).
    pub(super) size: [u32; 2],
    pub(super) sigma_m: Vec3,
    /// The scene's camera: the splats' order and screen tiles.
    pub(super) view: crate::scene::Camera,
    /// The kernels model every feature and take no shortcut (`--model-all`).
    pub(super) force_full: bool,
    /// Iterations run since the start (or the last light move).
    pub iterations: u32,
    /// Environment directions taken as direct units (`networks.single = view`), 0 where the
    /// environments are the network's sky.
    pub(super) env_dirs: u32,
    /// The last iteration's change of I against I's largest value (infinite before one ran).
    pub change: f64,
    /// Iterations whose change or peak came back negative or not finite.
    pub faults: u64,
}

/// How an iteration to a tolerance ended.
#[derive(Clone, Copy, Debug)]
pub struct Converged {
    pub iterations: u32,
    pub converged: bool,
    /// The last step's largest change of I against I's largest value.
    pub change: f64,
}

impl Illumination {
    /// Upload the scene, build the visibility network on the device, compute the direct light
    /// (transmittance step `step`, scene units) and start from I = 0. `force_full`: model every
    /// scene feature (the kernels' specialisation), as `--force-full` asks. `env_dirs` > 0: the
    /// environments are direct units of that many directions each and the sky is 0, so the
    /// network carries scattered light only (`networks.single = view`); 0: the environments
    /// are the sky (the paper's). An emissive medium's emission enters as
    /// [`EmissionModel::Marched`] (the default; [`Illumination::with_emission`] chooses).
    pub fn new(
        gpu: &Gpu,
        net: &Network,
        scene: &Scene,
        step: f32,
        force_full: bool,
        env_dirs: u32,
    ) -> Result<Illumination, SolverError> {
        Self::with_emission(gpu, net, scene, step, force_full, env_dirs, EmissionModel::Marched)
    }

    /// [`Illumination::new`] with the emission entering by `emission`.
    pub fn with_emission(
        gpu: &Gpu,
        net: &Network,
        scene: &Scene,
        step: f32,
        force_full: bool,
        env_dirs: u32,
        emission: EmissionModel,
    ) -> Result<Illumination, SolverError> {
        let n = net.particles.positions.len() as u32;
        let d = net.directions.len() as u32;
        let m = &scene.medium;
        let gs = GpuScene::upload(gpu, scene, force_full)?;
        let (positions, dirs) = net.upload(gpu)?;
        let visible = net.visibility_on(gpu, &positions, &dirs)?;
        let direct = gpu.buffer("networks direct light", net.direct_bytes(scene, env_dirs))?;
        net.direct(gpu, scene, &gs, &positions, step, env_dirs, &direct)?;
        let alpha = m.sigma_t.as_dvec3().map(|s| net.alpha(s)).as_vec3();
        let sky = if env_dirs > 0 { Vec3::ZERO } else { scene.environment_radiance() };
        let kind = gs.modelled.emission_kind();
        let emitted = if kind != 0 {
            let e: Vec<[f32; 4]> = net.emitted(scene).iter().map(|e| [e.x, e.y, e.z, 0.0]).collect();
            Some(gpu.buffer_with("networks emission", &e)?)
        } else {
            None
        };
        let phase = gpu.buffer_with("networks phase", &phase_matrix(&net.directions, m.g as f64).0)?;
        let arriving = if kind != 0 && emission == EmissionModel::Marched {
            Some(net.arriving(gpu, scene, &gs, &positions, &dirs, &phase, step)?)
        } else {
            None
        };
        let anisotropic = gs.modelled.anisotropic;
        let spec = [
            (crate::solvers::parts::gpu_scene::SPEC_EMISSION, crate::gpu::Spec::U32(kind)),
            (crate::solvers::parts::gpu_scene::SPEC_ANISOTROPIC, crate::gpu::Spec::Bool(anisotropic)),
        ];
        let units = unit_count(scene, env_dirs);
        let lit = if tabulates_lit(units, force_full) {
            Some((gpu.pipeline(&LIT, &[])?, gpu.buffer("networks lit table", 16 * n as u64 * d as u64)?))
        } else {
            None
        };
        let lit_table = lit.is_some();
        let outputs = inscatter_outputs(anisotropic, force_full, d);
        let inscatter = match outputs {
            0 => None,
            k => Some((
                gpu.pipeline(&INSCATTER, &[])?,
                gpu.buffer("networks in-scattering sums", 16 * n as u64 * k as u64)?,
            )),
        };
        let state = Illumination {
            inscatter,
            lit,
            phase,
            field: [
                gpu.buffer("networks radiance a", 16 * n as u64 * d as u64)?,
                gpu.buffer("networks radiance b", 16 * n as u64 * d as u64)?,
            ],
            stats: crate::solvers::parts::feedback::Feedback::new(gpu, "networks iteration stats", 4 * STATS_WORDS)?,
            batch: BATCH,
            current: 0,
            pipeline: gpu.pipeline(&ITERATE, &spec)?,
            push: IteratePush {
                alpha: [alpha.x, alpha.y, alpha.z, 0.0],
                sky: [sky.x, sky.y, sky.z, 0.0],
                particles: n,
                directions: d,
                units,
                slot: 0,
                check: 0,
                tol: 0.0,
                emission: emission.code(),
                lit: lit_table as u32,
                summed: (anisotropic && outputs > 0) as u32,
            },
            env_dirs,
            step,
            size: [scene.render.width, scene.render.height],
            sigma_m: m.sigma_t * net.particles.mass as f32,
            view: scene.camera,
            force_full,
            iterations: 0,
            change: f64::INFINITY,
            faults: 0,
            gs,
            positions,
            dirs,
            visible,
            direct,
            emitted,
            arriving,
            emission,
        };
        state.tabulate_lit(gpu)?;
        Ok(state)
    }

    /// Sum the lights' scattered light into the table, where there is one (after the direct
    /// light changed).
    fn tabulate_lit(&self, gpu: &Gpu) -> Result<(), SolverError> {
        let Some((pipeline, table)) = &self.lit else { return Ok(()) };
        let push = LitPush { particles: self.push.particles, directions: self.push.directions, units: self.push.units };
        let pass = Pass::new("networks.lit", QueueRole::Diffuse, pipeline)
            .read(0, &self.dirs)
            .read(1, &self.direct)
            .write(2, table)
            .read(3, &self.gs.block)
            .push(&push)
            .cover([self.push.particles, self.push.directions, 1]);
        let point = gpu.submit(QueueRole::Diffuse, &[pass], &[])?;
        gpu.wait(point)?;
        Ok(())
    }

    /// The particles' emission as the kernels bind it: the scene's emission placeholder where
    /// they do not model emission (EMISSION 0: never read).
    pub(super) fn emitted(&self) -> &Buffer {
        self.emitted.as_ref().unwrap_or(&self.gs.emission)
    }

    /// J as the gather binds it: the scene's emission placeholder without it (never read).
    pub(super) fn arriving(&self) -> &Buffer {
        self.arriving.as_ref().map_or(&self.gs.emission, |a| &a.0)
    }

    /// E, J scattered into each direction, as the iteration binds it (a placeholder without).
    pub(super) fn scattered_emission(&self) -> &Buffer {
        self.arriving.as_ref().map_or(&self.gs.emission, |a| &a.1)
    }

    /// The most device bytes an [`Illumination`] and its image hold at once: the scene,
    /// particles, directions and visibility network throughout; then the larger of the
    /// construction's buckets (freed once the network is built) and the iteration's state with
    /// the image's buffers.
    /// `view`: the view pass's bytes, where it runs after the splats (`networks.single =
    /// view`; 0 otherwise). `force_full`: the kernels model every feature, emission included
    /// (its per-particle array then, though the scene emits nothing).
    /// `emission`: how an emissive medium's emission enters (J and E, 32 N D bytes, where
    /// marched). `footprint`: the splats' width in particle radii (`networks.footprint`), which
    /// sets how many screen tiles list each particle ([`SplatTiles`]).
    pub fn device_bytes(
        net: &Network,
        scene: &Scene,
        force_full: bool,
        emission: EmissionModel,
        env_dirs: u32,
        view: u64,
        footprint: f32,
    ) -> u64 {
        let (n, d) = (net.particles.positions.len() as u64, net.directions.len() as u64);
        let modelled = crate::solvers::parts::gpu_scene::modelled(scene, force_full);
        let emitting = modelled.emission_kind() != 0;
        let emission_bytes = match (emitting, emission) {
            (false, _) => 0,
            (true, EmissionModel::Particles) => 16 * n,
            (true, EmissionModel::Marched) => 16 * n + 32 * n * d,
        };
        let base = crate::solvers::parts::gpu_scene::scene_bytes(scene) + 16 * n + 48 * d + 4 * n * d + emission_bytes;
        let state = 4 * d * d
            + net.direct_bytes(scene, env_dirs)
            + 2 * 16 * n * d
            + crate::solvers::parts::feedback::Feedback::bytes(4 * STATS_WORDS);
        let state = state
            + 16 * n * inscatter_outputs(modelled.anisotropic, force_full, d as u32) as u64
            + if tabulates_lit(unit_count(scene, env_dirs), force_full) { 16 * n * d } else { 0 };
        let size = [scene.render.width, scene.render.height];
        let tiles = SplatTiles::of(&scene.camera, size, net, footprint, None, force_full);
        let lists = 4 * tiles.starts.len() as u64 + 4 * tiles.items.len().max(1) as u64;
        let image = 16 * n + lists + 16 * size[0] as u64 * size[1] as u64;
        base + net.build_bytes().max(state + image.max(view))
    }

    /// The lights moved (same medium, same lights of the same kinds): recompute the direct
    /// light and the sky, keep I as the next iteration's start.
    pub fn set_lights(&mut self, gpu: &Gpu, net: &Network, scene: &Scene) -> Result<(), SolverError> {
        // The scene block (header and lights), rewritten in place: same size, same layout.
        let (header, lights) = crate::solvers::parts::gpu_scene::scene_block(scene);
        let mut bytes = bytemuck::bytes_of(&header).to_vec();
        bytes.extend_from_slice(bytemuck::cast_slice(&lights));
        if unit_count(scene, self.env_dirs) != self.push.units || bytes.len() as u64 != self.gs.block.size() {
            return Err(SolverError::Unsupported("networks: a warm start keeps the number of lights".to_string()));
        }
        gpu.write_buffer(&self.gs.block, 0, &bytes)?;
        net.direct(gpu, scene, &self.gs, &self.positions, self.step, self.env_dirs, &self.direct)?;
        self.tabulate_lit(gpu)?;
        let sky = if self.env_dirs > 0 { Vec3::ZERO } else { scene.environment_radiance() };
        self.push.sky = [sky.x, sky.y, sky.z, 0.0];
        self.iterations = 0;
        self.change = f64::INFINITY;
        Ok(())
    }

    /// `k` iterations, [`BATCH`] to a submission: for each, the largest change of I against
    /// the largest I, measured on the device (non-finite where a value went negative or not
    /// finite, which also counts a fault).
    pub fn step(&mut self, gpu: &Gpu, k: u32) -> Result<Vec<f64>, SolverError> {
        let mut changes = Vec::with_capacity(k as usize);
        let mut left = k;
        while left > 0 {
            let b = left.min(BATCH_MAX);
            let run = self.batch(gpu, b, None)?;
            left -= b;
            changes.extend(run.changes);
        }
        if let Some(c) = changes.last() {
            self.change = *c;
        }
        Ok(changes)
    }

    /// Submit `b` iterations as one batch and wait for it once. With `tol`, each iteration
    /// after the first judges the one before it on the device and the batch stops at the first
    /// that converged or faulted (the rest return at once); the iterations that ran are
    /// counted on the device.
    fn batch(&mut self, gpu: &Gpu, b: u32, tol: Option<f32>) -> Result<BatchRun, SolverError> {
        let d = self.push.directions;
        let mut passes = vec![self.stats.clear_pass(QueueRole::Diffuse)];
        for j in 0..b as usize {
            let (from, to) = ((self.current + j) % 2, (self.current + j + 1) % 2);
            let check = (tol.is_some() && j > 0) as u32;
            let push = IteratePush { slot: j as u32, check, tol: tol.unwrap_or(0.0), ..self.push };
            // The placeholder with `--model-all` on an anisotropic medium: the kernel never reads it.
            let sums = match &self.inscatter {
                Some((pipeline, sums)) => {
                    let outputs = if self.push.summed != 0 { d } else { 1 };
                    let push = InscatterPush { particles: self.push.particles, directions: d, check, outputs };
                    passes.push(
                        Pass::new("networks.inscatter", QueueRole::Diffuse, pipeline)
                            .read(0, &self.field[from])
                            .read(1, &self.phase)
                            .write(2, sums)
                            .read(3, self.stats.record())
                            .push(&push)
                            .cover([self.push.particles, outputs.div_ceil(INSCATTER_BLOCK), 1]),
                    );
                    sums
                }
                None => &self.gs.emission,
            };
            passes.push(
                Pass::new("networks.iterate", QueueRole::Diffuse, &self.pipeline)
                    .read(0, &self.visible)
                    .read(1, &self.dirs)
                    .read(2, &self.direct)
                    .read(3, &self.field[from])
                    .write(4, &self.field[to])
                    .read(5, &self.phase)
                    .read_write(6, self.stats.record())
                    .read(7, &self.gs.block)
                    .read(8, self.emitted())
                    .read(9, self.scattered_emission())
                    .read(10, sums)
                    .read(11, self.lit.as_ref().map_or(&self.gs.emission, |l| &l.1))
                    .push(&push)
                    .cover([self.push.particles, d, 1]),
            );
        }
        passes.push(self.stats.copy_pass(QueueRole::Diffuse));
        let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(point)?;
        let raw: Vec<u32> = self.stats.read_words(gpu)?;
        let ran = raw[1];
        let mut changes = Vec::with_capacity(ran as usize);
        let mut stopped = None;
        for j in 0..ran as usize {
            let (change, peak) = (f32::from_bits(raw[2 + 2 * j]), f32::from_bits(raw[3 + 2 * j]));
            let v = verdict(change, peak, tol.unwrap_or(0.0));
            changes.push(match v {
                Verdict::Fault => {
                    self.faults += 1;
                    f64::NAN
                }
                _ if peak > 0.0 => change as f64 / peak as f64,
                _ => 0.0,
            });
            if tol.is_some() && v != Verdict::GoOn {
                stopped = Some(v);
                break;
            }
        }
        // The device's count and the host's reading of the same words must agree: a batch
        // stops right after the iteration that converged (or at its end).
        let expected = changes.len() as u32;
        if tol.is_some() && ran != expected && !(stopped.is_none() && ran == b) {
            return Err(SolverError::Unsupported(format!(
                "networks: the device ran {ran} iterations of a batch of {b} but judged convergence after {expected}; \
                 please report this"
            )));
        }
        if raw[0] != 0 && stopped.is_none() {
            return Err(SolverError::Unsupported(format!(
                "networks: the device stopped a batch (verdict {}) that the host judges unfinished; please report this",
                raw[0]
            )));
        }
        self.current = (self.current + ran as usize) % 2;
        self.iterations += ran;
        if let Some(c) = changes.last() {
            self.change = *c;
        }
        Ok(BatchRun { changes, stopped })
    }

    /// The scene on the device (for the view pass of `networks.single = view`).
    pub fn scene(&self) -> &GpuScene {
        &self.gs
    }

    /// I [p][i] (rgb, w unused) as it stands.
    pub fn radiance(&self, gpu: &Gpu) -> Result<Vec<[f32; 4]>, SolverError> {
        Ok(gpu.read_buffer_as(&self.field[self.current])?)
    }

    /// Iterate until a step changes I by at most `tol` of its largest value, or `max` steps,
    /// reporting progress. Batches of iterations are submitted whole and stopped on the device
    /// at the first converged (or faulted) iteration, so the host waits once per batch and I
    /// is the converged iteration's, not a later one's; a batch is at least [`BATCH`]
    /// iterations and grows toward [`BATCH_TARGET_MS`] of GPU work. Stops at the first fault
    /// (a negative or non-finite value).
    pub fn solve(
        &mut self,
        gpu: &Gpu,
        tol: f64,
        max: u32,
        progress: &dyn Fn(crate::solvers::interface::Progress),
    ) -> Result<Converged, SolverError> {
        let mut earlier: Option<(f64, u64)> = None;
        while self.iterations < max {
            let b = self.batch.min(max - self.iterations);
            let started = std::time::Instant::now();
            let run = self.batch(gpu, b, Some(tol as f32))?;
            // The batch's time per iteration run sets the next batch's size.
            let per = started.elapsed().as_secs_f64() * 1e3 / run.changes.len().max(1) as f64;
            self.batch = ((BATCH_TARGET_MS / per.max(1e-3)) as u32).clamp(BATCH, BATCH_MAX);
            let it = self.iterations as u64;
            match run.stopped {
                Some(Verdict::Converged) => {
                    return Ok(Converged { iterations: self.iterations, converged: true, change: self.change })
                }
                Some(_) => break,
                None => {}
            }
            progress(crate::solvers::interface::Progress::converging(
                "networks iteration",
                it,
                self.change,
                tol,
                earlier,
                max as u64,
            ));
            if earlier.is_none() {
                earlier = Some((self.change, it));
            }
        }
        Ok(Converged { iterations: self.iterations, converged: false, change: self.change })
    }
}
