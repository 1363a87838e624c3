//! Solver `lbl`: photon marching plus Lattice-Boltzmann diffusion (thesis ch. 4), with tracing
//! and diffusion on separate queue roles synchronised by timeline semaphores.
//!
//! Per round n (thesis Fig. 4.1): `march(n)` advances every light ray by `k` steps on the
//! `trace` role, writing deposits into the Ray History Buffer, while `diffuse(n-1)` runs
//! lattice iterations on the `diffuse` role; then `transfer(n)` (alone: it reads the history
//! and writes the lattice) adds the round's deposits to the lattice. After the last round the
//! lattice iterates until the relative change at sparse probe voxels falls under `tol` (of the
//! field with its geometric tail extrapolated, `lbl.extrapolate`), and the view pass marches
//! camera rays: exact single scattering (as `single`) plus the multiply scattered light
//! gathered from the lattice's time-integrated field (thesis 4.6.2). The deposits are the
//! power scattered out of the light beams (the once-scattered source); what they send straight
//! to the camera is the single-scattering term, and the lattice carries the rest, so no energy
//! is counted twice. An emitting medium's emission enters the lattice too, as an isotropic
//! volume source beside the deposits ([`lattice::emission`]), while the view pass adds what it
//! emits along the camera ray: the lattice carries only the emitted light that scatters.
//!
//! Built from shared parts (`crate::solvers::parts`): [`marching`] (raymaps, marching,
//! transfer), [`lattice`] (the lattice, injection, convergence), [`view`] (the view pass) and,
//! for `warm_start=wavefront`, [`wave_field`]. This file holds the round graph
//! ([`plan`]), the knobs and the bookkeeping. Knobs: `scatterlab knobs lbl`.

use serde::Serialize;

use crate::gpu::{DeviceInfo, Gpu, Kernel, QueueRole, SyncPoint};
use crate::scene::{Scene, MAX_MATERIALS};

use crate::solvers::interface::Progress;
use crate::solvers::interface::{
    Animation, Convergence, Figure, Headline, Knob, Knobs, Range, RenderOutput, RenderReport, RenderRequest, Rung,
    Schedule, Solver, SolverError, Stats, Variant,
};
use crate::solvers::parts::gpu_scene::{self, GpuScene};
use crate::solvers::parts::lattice::{
    self, check_block, Diffuser, EnergyBook, Injector, Lattice, LatticeGeom, LatticeParams,
};
use crate::solvers::parts::marching::{self, MarchSettings, Marcher};
use crate::solvers::parts::view::{self, MsVolume, ViewSettings};
use crate::solvers::parts::wave_field::{self, wave_volume, WaveSettings};

pub struct Lbl;

impl Solver for Lbl {
    fn name(&self) -> &'static str {
        "lbl"
    }

    fn about(&self) -> &'static str {
        "photon marching + Lattice-Boltzmann diffusion on concurrent queues (thesis ch. 4)"
    }

    fn knobs(&self) -> Vec<Knob> {
        let mut k = vec![
            Knob::derived(
                "grid",
                "from the medium's reduced optical length T along its longest side (the densest part's sigma_t (1 - \
                 albedo g) times the side): 64 where T >= 16, 32 where T < 10, 40-56 between (voxels of reduced optical \
                 thickness at least 0.25, within 32..=64); raised until the thinnest side spans 2 voxels, within 128^3 \
                 voxels",
                Range::int(2, 512),
                "lattice voxels along the medium's longest side",
            ),
            Knob::fixed(
                "lattice",
                "d3q6",
                Range::Choice(&["d3q6", "d3q18"]),
                "d3q6: 6 axial links (thesis 4.5); d3q18: Geist's 18 links (section 2.2.3)",
            ),
            Knob::derived(
                "block",
                "8 where the device's shared memory and workgroup size allow it, else 4, else 2",
                Range::Choice(&["2", "4", "8"]),
                "block edge in voxels (a power of two for the workgroup reduction); d3q6 at 8 needs 16 KiB of shared \
                 memory and 512 invocations, d3q18 40 KiB",
            ),
            Knob::derived(
                "block_steps",
                "the block edge",
                Range::int(1, 64),
                "lattice steps per dispatch inside a block (1: the global lattice)",
            ),
            Knob::fixed(
                "iters_per_round",
                "8",
                Range::int(1, 1 << 20),
                "lattice steps run while one round of marching runs (thesis Fig. 4.1)",
            ),
            Knob::fixed(
                "tol",
                "1e-4",
                // At least 1e-12: the test runs in f32, where 1e-300 was 0 (20000 iterations, then
                // "did not converge, tolerance 0.0e0"); f32's step at 1 is 1.2e-7 anyway.
                Range::Real { min: 1e-12, max: 1.0, min_open: false, max_open: true },
                "convergence: largest relative change per iteration at the probe voxels (of the extrapolated field \
                 with lbl.extrapolate)",
            ),
            Knob::fixed("max_iters", "20000", Range::int(1, 1 << 26), "lattice iterations at most"),
            Knob::derived(
                "iterations_per_frame",
                "to the tolerance (lbl.tol)",
                Range::int(1, 1 << 26),
                "scatterlab animate: lattice iterations of each frame after the first, from the previous frame's \
                 field (d3q6)",
            ),
            Knob::fixed(
                "extrapolate",
                "true",
                Range::Bool,
                "add the iteration's geometric tail (the last increments times r / (1 - r), r their decay) and test \
                 convergence on the extrapolated field (docs/lbl.md); false: stop on the plain field's change",
            ),
            Knob::fixed(
                "deterministic",
                "true",
                Range::Bool,
                "fixed-point transfer (integer atomics, rounded without bias): the same image bit for bit on every run; \
                 false: float atomics where the device offers them, whose order of adds moves the last bits",
            ),
            Knob::fixed(
                "schedule",
                "concurrent",
                Range::Choice(&["concurrent", "sequential"]),
                "concurrent: marching of round n overlaps diffusion of round n-1; sequential: no overlap",
            ),
            Knob::fixed(
                "warm_start",
                "none",
                Range::Choice(&["none", "wavefront"]),
                "start the lattice from the wavefront field (its knobs as wavefront_*; d3q6 only)",
            ),
            Knob::fixed(
                "escape",
                "box",
                Range::Choice(&["none", "box", "all"]),
                "d3q6: scatter toward vacuum with the voxel's first-flight escape probability instead of 1/6, at the \
                 box's faces (box), also toward zero-density voxels (all: too much on voxelised curves), or nowhere",
            ),
            Knob::fixed(
                "drift",
                "true",
                Range::Bool,
                "d3q6 with lbl.escape: light a link carries parallel to an open face drifts out through it, 0.167 per \
                 voxel of path (the mean over the link's cone of directions; docs/lbl.md); false: it stays until it scatters",
            ),
            Knob::derived(
                "near_light",
                "3, or 1.5 mean free paths at the light where fewer, where the scene's only light is a point light inside the medium (without lbl.cascade or lbl.warm_start), else 0",
                Range::non_negative(),
                "radius in voxels of the ball about a point light inside the medium whose once-scattered light is \
                 lumped into the light (its image scaled by 1 / (1 - k), k the share of the light's power scattered \
                 there) instead of injected, where its six axial beams draw a \"+\" (docs/lbl.md); 0: off",
            ),
            Knob::fixed(
                "inject",
                "auto",
                Range::Choice(&["auto", "forward", "directed", "isotropic"]),
                "anisotropic media: carry the share g of once-scattered light on along its light ray until it collides \
                 at the reduced extinction, emitting the rest isotropically (forward), inject it with its first moment \
                 g on the lattice's axial links (directed), or emit it isotropically (the thesis); auto: forward where \
                 no medium has g < 0 and no object refracts, else directed unless a point light is inside the medium",
            ),
            Knob::fixed(
                "flux",
                "auto",
                Range::Choice(&["auto", "two_term", "lobe", "off"]),
                "anisotropic media: integrate the lattice's net flux E too and scatter the field toward the camera as \
                 an HG lobe about E (lobe) or by the two-term expansion phi / 4pi + 3 g E.w / 4pi (two_term); off: \
                 the fluence alone, isotropically; auto: two_term unless a point light is inside the medium",
            ),
            Knob::fixed(
                "cascade",
                "0",
                Range::int(0, 6),
                "coarse levels of a cascadic start (d3q6): solve on grids 2^L, ..., 2 times coarser, prolong, then the \
                 fine lattice; saved 7-34% of a plain lattice's time at grid 64, but turns the tail extrapolation off \
                 on the seeded levels (docs/lbl.md); loses the round overlap and the energy book (0: cold start)",
            ),
        ];
        k.push(Knob::fixed(
            "refraction",
            "true",
            Range::Bool,
            "with a refractive [[object]] (ior != 1): light rays and camera rays refract at its surface with the \
             Fresnel split; false renders its boundary as index-matched (what refraction changes)",
        ));
        k.extend(marching::knobs());
        k.extend(wave_field::knobs().into_iter().map(|k| k.prefixed("wavefront_").only_with("warm_start=wavefront")));
        k.extend(view::knobs().into_iter().map(|k| k.prefixed("view_")));
        k
    }

    /// lbl renders [[object]] meshes: the lattice over the mesh's voxelised occupancy, light
    /// and camera rays refracted at the surface (glsl/marching/march.comp, glsl/view/march.comp).
    fn renders_meshes(&self) -> bool {
        true
    }

    /// Objects of several materials: each lattice voxel takes the material it holds most of,
    /// whose extinction, albedo, g and boundary reflectance the lattice kernels read
    /// (glsl/include/lattice.glsl MATS); the marching and the view march follow each ray into
    /// each object with its material.
    fn renders_materials(&self) -> bool {
        true
    }

    /// An emitting medium: the view march adds the emission along the camera ray (the
    /// zero-scattering term, glsl/view/march.comp), and the lattice carries the emitted light
    /// the medium scatters. Each voxel's emission enters the lattice as an isotropic volume
    /// source beside the once-scattered deposits, 4 pi Le lambda^2 kappa_a / l per voxel (the
    /// power 4 pi sigma_a Le lambda^3 in the form that balances the lattice's own absorption:
    /// src/solvers/parts/lattice/emission.rs), so its fluence holds the emitted light,
    /// uncollided and scattered, and the view march's sigma_s phi / 4 pi gathers it once per
    /// scattering toward the camera. A scene lit by its emission alone marches no light rays.
    /// The lattice's limits apply to it as to the lights' light (docs/lbl.md, "Emission").
    fn renders_emission(&self) -> bool {
        true
    }

    fn kernels(&self) -> Vec<Kernel> {
        let mut k = marching::kernels();
        k.extend([lattice::DIFFUSE, lattice::REDUCE, lattice::CHECK, lattice::INJECT, view::MARCH, view::SHADOW]);
        k.extend(wave_field::kernels());
        k.push(crate::solvers::parts::feedback::COPY);
        k
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let k = req.knobs(self)?;
        let set = LblSettings::parse(&k, req.scene)?;
        k.finish()?;
        Ok(self.render_with(gpu, req.scene, req.force_full, &k, &set, req.progress)?.0)
    }

    fn animation(&self, req: &RenderRequest, converge: bool) -> Result<Option<Box<dyn Animation>>, SolverError> {
        let knobs = req.knobs(self)?;
        let mut set = LblSettings::parse(&knobs, req.scene)?;
        knobs.finish()?;
        if set.lattice != Lattice::D3q6 {
            return Err(knobs.invalid("lattice", "animate starts each frame from the last on the d3q6 lattice only"));
        }
        if set.near_light > 0.0 {
            if knobs.is_set("near_light") {
                return Err(knobs.invalid(
                    "near_light",
                    "a frame started from the previous frame's field cannot lump the near ball; set lbl.near_light=0",
                ));
            }
            // Derived: off for the whole sequence, so every frame is the same method.
            set.near_light = 0.0;
        }
        Ok(Some(Box::new(LblAnimation { knobs, set, converge, lights: None })))
    }

    fn preflight(&self, scene: &Scene, knobs: &Knobs) -> Result<Vec<String>, SolverError> {
        let set = LblSettings::parse(knobs, scene)?;
        // Where nothing scatters the lattice carries nothing: its grid's trust does not apply.
        let grid = set.geom.trust(scene, set.grid, &lattice::LBL_GRID).warning().filter(|_| scene.scatters());
        Ok(grid
            .into_iter()
            .chain(view::ViewTrust::of(scene, &set.view).warning(self.name()))
            .chain(near_light_trust(scene, &set))
            .collect())
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let set = LblSettings::parse(knobs, scene)?;
        if !scene.scatters() {
            // No field where nothing scatters (render_unscattered): the scene and the view.
            return Ok(gpu_scene::scene_bytes(scene) + view::device_bytes(scene, &set.view));
        }
        let geom = set.geom;
        let chromatic = gpu_scene::modelled(scene, false).chromatic;
        let p = lattice_params(scene, &set, &geom, LblSettings::channels(scene, chromatic));
        // The raymaps are cheap on the host: count the rays exactly (misses are dropped).
        let m = &set.march;
        let rays = marching::ray_count(scene, &geom, m.rays, m.env_lights, m.step, scene.render.seed).0;
        // A warm start's wave field lives only while the lattice is seeded; it counts at peak.
        let warm = set.warm_start.map_or(0, |w| w.device_bytes(scene, chromatic, &geom));
        // The forward population: its history beside the rays', its sums, and the view's copy
        // of the lattice's field with the forward field appended.
        let forward = if set.forward {
            rays * m.k as u64 * 16 + 2 * 4 * p.nch as u64 * geom.voxels() * 4 + p.irradiance_floats() * 4
        } else {
            0
        };
        Ok(gpu_scene::scene_bytes(scene)
            + forward
            + m.device_bytes(&geom, rays, p.nch, p.directed, true)
            + p.diffuser_bytes()
            + p.injector_bytes()
            + lattice::LatticeMaterials::bytes(
                geom.voxels(),
                scene.object.as_ref().is_some_and(|o| o.several_materials()),
            )
            + warm
            + view::device_bytes(scene, &set.view))
    }

    /// The thesis's headline (ch. 4): a 128^3 lattice and a 1024^2 image at 8 fps.
    fn headline(&self, quick: bool) -> Option<Headline> {
        Some(if quick {
            Headline::new(
                "lbl cloud 16^3, 64^2",
                "cloud.toml",
                &[("render.width", "64"), ("render.height", "64"), ("lbl.grid", "16"), ("lbl.rays", "4096")],
                "",
            )
        } else {
            Headline::new(
                "lbl cloud 128^3, 1024^2",
                "cloud.toml",
                &[("render.width", "1024"), ("render.height", "1024"), ("lbl.grid", "128")],
                "thesis ch. 4: a 128^3 lattice and a 1024^2 image at 8 fps (GTX 580, 2011)",
            )
        })
    }

    /// Marching on the trace role beside the lattice on the diffuse role.
    fn concurrency(&self, quick: bool) -> Option<Headline> {
        let (grid, size) = if quick { ("16", "64") } else { ("64", "256") };
        Some(Headline::new(
            format!("lbl homogeneous sphere {grid}^3, {size}^2"),
            "homogeneous-sphere.toml",
            &[("render.width", size), ("render.height", size), ("lbl.grid", grid), ("lbl.rays", "16384")],
            "",
        ))
    }

    fn ladder(&self, _scene: &Scene) -> Vec<Rung> {
        [16u32, 24, 32, 48, 64].iter().map(|g| Rung::one("lbl.grid", g)).collect()
    }

    fn stability(&self) -> Vec<Variant> {
        // 16384 rays per light (the default is 65536): at 4096 the forward population of the
        // g 0.99 case (14 environment beams, few rays per voxel) drew single pixels 30% above
        // the furnace bound (max 1.304 against 1; mean 0.761 as at 65536), at 8192 0.956, at
        // 16384 0.913, at 65536 0.83 (docs/lbl.md, "the forward population").
        vec![Variant::new(
            "",
            &[("lbl.grid", "16"), ("lbl.rays", "16384"), ("lbl.view_env_dirs", "16"), ("lbl.max_iters", "4000")],
        )]
    }

    fn summary(&self, report: &RenderReport) -> Vec<String> {
        let Some(l) = report.detail::<LblStats>() else { return Vec::new() };
        if !l.field {
            return vec![
                "lbl: nothing scatters (sigma_s 0 in every channel and material): no lattice run, the image is the \
                 view's camera-ray march"
                    .into(),
                format!("lbl: {}", l.view_trust.line()),
            ];
        }
        let d = l.lattice.dims;
        vec![
            format!(
                "lbl: {}x{}x{} {} lattice, {} channel(s){}, {} rays, {} rounds, {} iterations ({})",
                d[0],
                d[1],
                d[2],
                l.lattice_kind.name(),
                l.channels,
                if l.channels == 1 { " (grey medium and lights)" } else { "" },
                l.rays,
                l.rounds,
                l.iterations,
                match (l.converged, l.tail) {
                    (false, _) => "NOT converged".to_string(),
                    (true, None) => "converged".to_string(),
                    (true, Some(t)) => format!("converged; tail extrapolated: {:.1}% of the fluence", 100.0 * t.share),
                }
            ),
            format!("lbl: {}", l.trust.line()),
            format!("lbl: {}", l.view_trust.line()),
        ]
    }
}

impl Lbl {
    /// lbl where nothing scatters (sigma_s 0 in every channel and material): no light marched,
    /// no lattice. The view scatters the lattice's field toward the camera by sigma_s and the
    /// direct light by sigma_s too, so with the lattice the image is the view's camera-ray march
    /// alone (the unscattered emission, the background through the medium); without it the same
    /// march gives the same image. An absorbing emitter of optical diameter 40 ran the lattice
    /// for 1.3 s at the default grid to carry nothing. Nothing is carried to a next frame.
    fn render_unscattered(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        gs: &GpuScene,
        k: &Knobs,
        set: &LblSettings,
    ) -> Result<(RenderOutput, Carried), SolverError> {
        let view = view::march(gpu, scene, gs, &set.view, None)?;
        let mut report =
            RenderReport::finish(gpu, self, k, gs.modelled.clone(), gs.bytes + view.device_bytes, Stats::new(()));
        let geom = set.geom;
        let nch = LblSettings::channels(scene, gs.modelled.chromatic);
        let params = lattice_params(scene, set, &geom, nch);
        let ls = LblStats {
            deterministic: set.deterministic || !gpu.info().float_atomics,
            view_dispatches: view.dispatches,
            ..LblStats::of_settings(scene, set, nch, params.directed)
        };
        report.warnings.extend(ls.view_trust.warning(self.name()));
        report.zeroed_nonfinite(view.nonfinite_pixels);
        let mut stats = Stats::new(ls);
        stats.convergence =
            Some(Convergence { iterations: 0, converged: true, final_change: 0.0, tolerance: set.tol as f64 });
        stats.faults = view.nonfinite_pixels as u64;
        report.stats = stats;
        Ok((RenderOutput { image: view.image, variance: None, report, estimates: Vec::new() }, (Vec::new(), None)))
    }

    /// A render with parsed settings; also returns the lattice's time-integrated field (the
    /// irradiance buffer, [c V + v]) for the next frame of an animation to start from.
    fn render_with(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        force_full: bool,
        k: &Knobs,
        set: &LblSettings,
        progress: &dyn Fn(Progress),
    ) -> Result<(RenderOutput, Carried), SolverError> {
        let mut gs = GpuScene::upload_with(gpu, scene, force_full, crate::solvers::parts::gpu_scene::MAJORANT_CELL)?;
        // Refraction turned off: the marching and view kernels are specialised without it (both
        // read the modelled set), and the report says the boundary was taken as index-matched.
        gs.modelled.refractive &= set.view.refraction;
        if !scene.scatters() {
            return self.render_unscattered(gpu, scene, &gs, k, set);
        }
        let lat = run_lattice(gpu, scene, &gs, set, progress)?;
        let g = &lat.stats.lattice;
        let ms = MsVolume {
            energy: &lat.irradiance_buffer,
            dims: g.dims,
            channels: lat.stats.channels,
            origin: g.origin,
            lambda: g.lambda,
            flux: if lat.stats.flux { set.flux } else { view::FluxUse::None },
            window: None,
            forward: lat.stats.forward,
        };
        let mut view = view::march(gpu, scene, &gs, &set.view, Some(&ms))?;
        if let Some(n) = &lat.stats.near_light {
            // The near ball's light, lumped into the light: 1 / (1 - k) times the image
            // (NearLight).
            for px in view.image.data.chunks_exact_mut(3) {
                for (p, k) in px.iter_mut().zip(n.k) {
                    *p = (*p as f64 / (1.0 - k)) as f32;
                }
            }
        }
        let bytes = gs.bytes + view.device_bytes + lat.stats.device_bytes;
        let mut report = RenderReport::finish(gpu, self, k, gs.modelled.clone(), bytes, Stats::new(()));
        let mut ls = lat.stats;
        ls.diffuse_ms = report.passes.iter().filter(|p| p.name == "lattice.diffuse").map(|p| p.duration_ms()).sum();
        ls.view_dispatches = view.dispatches;
        // A sequence's frame stopped at its budget stops short by design.
        if !ls.converged && !set.budgeted {
            // Where the marching rounds' lattice steps took every one lbl.max_iters allows, no
            // convergence test ran: there is no change to give.
            let change = if ls.final_change > 0.0 {
                format!("relative change {:.2e} per iteration", ls.final_change)
            } else {
                "the marching rounds' steps (lbl.iters_per_round) used them all, none tested".to_string()
            };
            report.warnings.push(format!(
                "lbl: the lattice did not converge in {} iterations ({change}, tolerance {:.1e}); raise lbl.max_iters \
                 or lbl.tol",
                ls.iterations, set.tol
            ));
        }
        report.warnings.extend(ls.trust.warning());
        report.warnings.extend(ls.view_trust.warning(self.name()));
        report.warnings.extend(near_light_trust(scene, set));
        report.zeroed_nonfinite(view.nonfinite_pixels);
        let mut stats = Stats::new(ls.clone());
        stats.convergence = Some(Convergence {
            iterations: ls.iterations as u64,
            converged: ls.converged,
            final_change: ls.final_change,
            tolerance: set.tol as f64,
        });
        stats.faults = view.nonfinite_pixels as u64;
        if ls.diffuse_ms > 0.0 {
            let ups = ls.lattice.voxels() as f64 * ls.iterations as f64 / (ls.diffuse_ms * 1e-3);
            // Per voxel-update at least: 6 links read and written, 1 irradiance
            // read-modify-write, 1 density read, 4 bytes each, per channel.
            let bytes = (ls.channels as f64 * (6.0 * 2.0 + 2.0) + 1.0) * 4.0;
            stats.throughput = vec![
                Figure { figure: "lattice voxel-updates/s".into(), value: ups, unit: "1/s".into() },
                Figure { figure: "lattice effective bandwidth".into(), value: ups * bytes / 1e9, unit: "GB/s".into() },
            ];
        }
        report.stats = stats;
        Ok((
            RenderOutput { image: view.image, variance: None, report, estimates: Vec::new() },
            (lat.irradiance, lat.source),
        ))
    }
}

/// What a frame hands the next ([`LblAnimation`]): the lattice's time-integrated field and the
/// source it injected ([`LatticeResult::source`]).
type Carried = (Vec<f32>, Option<Vec<f32>>);

/// An `lbl` sequence: every frame marches its light anew; after the first, the lattice starts
/// from the previous frame's field (the wavefront paper's initial guess, section 1.1, with
/// the last frame as the guess) and runs `lbl.iterations_per_frame` steps, or to the
/// tolerance. The lattice integrates every link's outgoing value as well (`LatticeParams::links`),
/// so the next frame's guess is its exact time-integrated state, plus (from the third frame)
/// the source the frame injected. A frame whose lights are the last frame's (`scatterlab view`
/// going on after a budgeted frame) runs to the tolerance: before the links were carried, the
/// guess was made from the fluence and flux, and budgeted frames of one light stalled at that
/// projection's error (the sphere at grid 16, 8 iterations a frame: the change stayed at 2.4e-2
/// per iteration for 7 frames).
struct LblAnimation {
    knobs: Knobs,
    set: LblSettings,
    converge: bool,
    lights: Option<Vec<crate::scene::Light>>,
}

impl Animation for LblAnimation {
    fn frame(&mut self, gpu: &Gpu, scene: &Scene, progress: &dyn Fn(Progress)) -> Result<RenderOutput, SolverError> {
        // The previous field moves into this frame's settings (not copied with them).
        let previous = self.set.previous.take();
        let previous_source = self.set.previous_source.take();
        let mut set = LblSettings { previous, previous_source, ..self.set.clone() };
        let moved = self.lights.as_ref() != Some(&scene.lights);
        if set.previous.is_some() {
            // Later frames: no cascade (the previous field is the guess).
            set.cascade = 0;
            if let (false, Some(k), true) = (self.converge, set.iterations_per_frame, moved) {
                set.max_iters = k;
                set.budgeted = true;
            }
        }
        set.keep_source = true;
        let (out, (field, source)) = Lbl.render_with(gpu, scene, false, &self.knobs, &set, progress)?;
        // Nothing carried where nothing scatters (render_unscattered): no lattice to start from.
        self.set.previous = Some(field).filter(|f| !f.is_empty());
        self.set.previous_source = source;
        self.lights = Some(scene.lights.clone());
        Ok(out)
    }
}

/// One step of the round graph.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    March(u32),
    Transfer(u32),
    Diffuse(u32),
}

/// A submission of the plan: its role, what it runs, and the earlier submissions (by index)
/// it waits on. Indices always point backwards: the host-order rule by construction.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Planned {
    pub role: QueueRole,
    pub step: Step,
    pub waits: Vec<usize>,
}

/// The round graph for `rounds` marching rounds (thesis Fig. 4.1). Both schedules contain the
/// same steps on the same roles; `Sequential` only adds a wait of every diffusion on the
/// marching of the same round, removing the overlap.
pub fn plan(rounds: u32, schedule: Schedule) -> Vec<Planned> {
    let mut p: Vec<Planned> = Vec::new();
    if rounds == 0 {
        return p;
    }
    p.push(Planned { role: QueueRole::Trace, step: Step::March(0), waits: vec![] });
    p.push(Planned { role: QueueRole::Diffuse, step: Step::Transfer(0), waits: vec![0] });
    let mut transfer_prev = 1;
    for n in 1..rounds {
        // March n overwrites the history that transfer n-1 reads.
        p.push(Planned { role: QueueRole::Trace, step: Step::March(n), waits: vec![transfer_prev] });
        let march = p.len() - 1;
        // Diffuse n-1 follows transfer n-1 in its own queue's order.
        let waits = match schedule {
            Schedule::Concurrent => vec![],
            Schedule::Sequential => vec![march],
        };
        p.push(Planned { role: QueueRole::Diffuse, step: Step::Diffuse(n - 1), waits });
        p.push(Planned { role: QueueRole::Diffuse, step: Step::Transfer(n), waits: vec![march] });
        transfer_prev = p.len() - 1;
    }
    p.push(Planned { role: QueueRole::Diffuse, step: Step::Diffuse(rounds - 1), waits: vec![] });
    p
}

/// Parsed knobs.
#[derive(Clone, Debug)]
pub struct LblSettings {
    pub grid: u32,
    /// The lattice's voxel grid over the medium for `grid`, built once here and used by every
    /// pass of the render (marching, the lattice, a warm start's wave field).
    pub geom: LatticeGeom,
    pub march: MarchSettings,
    pub lattice: Lattice,
    pub block: u32,
    pub block_steps: u32,
    /// `block` (and `block_steps` with it) were derived: the lattice steps down to a block the
    /// device can run.
    pub block_auto: bool,
    pub block_steps_auto: bool,
    pub iters_per_round: u32,
    pub tol: f32,
    pub max_iters: u32,
    /// Extrapolate the lattice iteration's geometric tail (`Diffuser::iterate`).
    pub extrapolate: bool,
    pub deterministic: bool,
    pub schedule: Schedule,
    pub view: ViewSettings,
    /// Initial guess of the lattice iteration: `None` (cold: from the deposits alone) or the
    /// wavefront field (`lbl.warm_start=wavefront`, its knobs as `lbl.wavefront_*`).
    pub warm_start: Option<WaveSettings>,
    /// Coarse levels of the cascadic start ([`cascade`]): 0 = none.
    pub cascade: u32,
    /// First-flight escape weights at the medium's boundary (D3Q6).
    pub escape: lattice::Escape,
    /// Light carried parallel to an open face drifts out through it (`lbl.drift`, D3Q6).
    pub drift: bool,
    /// Radius in voxels of the near ball lumped into the scene's only light, a point light
    /// inside the medium (`lbl.near_light`; 0: off).
    pub near_light: f32,
    /// Inject anisotropic media's once-scattered light with its first moment (`lbl.inject`).
    pub directed: bool,
    /// Carry the forward-scattered light along the light rays (`lbl.inject=forward`, and
    /// only for anisotropic media: nothing is scattered forward otherwise).
    pub forward: bool,
    /// Anisotropic media: how the view pass scatters the lattice's flux (`lbl.flux`; `None`:
    /// the lattice keeps no flux).
    pub flux: view::FluxUse,
    /// `scatterlab animate`: the previous frame's time-integrated field (the lattice's
    /// irradiance buffer, [c V + v]) to start from, and the iterations of a frame after the
    /// first (`lbl.iterations_per_frame`; `None`: to the tolerance).
    pub previous: Option<Vec<f32>>,
    /// The source the previous frame injected (the lattice state its deposits made, links
    /// [(i NCH + c) V + v]), added to the guess's state at t = 0: see [`start`].
    pub previous_source: Option<Vec<f32>>,
    /// Record this frame's injected source for the next frame ([`LatticeResult::source`]).
    pub keep_source: bool,
    pub iterations_per_frame: Option<u32>,
    /// This frame stops at `iterations_per_frame` by design (a sequence's): no "did not
    /// converge" warning.
    pub budgeted: bool,
}

impl LblSettings {
    pub fn parse(k: &Knobs, scene: &Scene) -> Result<LblSettings, SolverError> {
        // lbl's depth rule (default_grid), raised for 2 voxels across a thin medium (issue 44).
        let grid: u32 = k.get_or("grid", lattice::LBL_GRID.fitted_grid(scene, default_grid(scene), 512))?;
        let geom = LatticeGeom::new(scene, grid);
        let block: u32 = k.get_or("block", 8)?;
        // `auto` (lbl.inject, lbl.flux) carries the forward peak on the forward population
        // (lbl.inject=forward, docs/lbl.md) where no medium scatters backward (it models g > 0
        // only) and no refractive object traps light: with or without a light inside, since
        // the population follows the light's own rays and draws no "+" along the lattice's
        // axes (point-light-in-cloud at 64^2: relL2 0.128 -> 0.105). Inside glass its light,
        // collimated where the real forward lobe spreads past the critical angle, escapes too
        // easily (a g 0.9 glass sphere under a sky 0.90 of path's energy; directed 1.02).
        // Elsewhere the directed injection of the first moment, unless a point light is
        // inside the medium: there the radially injected first moment streams along the
        // lattice's axes and the "+" around the light grows (point-light-in-cloud at 64^2:
        // relL2 0.36 isotropic, 0.56 directed with the two-term flux).
        let light_inside = !wave_field::traced_lights(scene).is_empty();
        let no_backward =
            scene.medium.g >= 0.0 && scene.object.as_ref().map_or(true, |o| o.materials.iter().all(|m| m.g >= 0.0));
        let view = ViewSettings::parse(k, "view_", scene)?;
        let trapping = view.refraction && scene.object.as_ref().is_some_and(|o| o.refractive());
        let forward_auto = no_backward && !trapping;
        let out = LblSettings {
            grid,
            geom,
            march: MarchSettings::parse(k, "lbl", geom.lambda)?,
            lattice: k.get("lattice")?,
            block,
            block_steps: k.get_or("block_steps", block)?,
            block_auto: !k.is_set("block"),
            block_steps_auto: !k.is_set("block_steps"),
            iters_per_round: k.get("iters_per_round")?,
            tol: k.get("tol")?,
            max_iters: k.get("max_iters")?,
            extrapolate: k.get("extrapolate")?,
            deterministic: k.get("deterministic")?,
            schedule: k.get("schedule")?,
            view,
            warm_start: match k.get::<String>("warm_start")?.as_str() {
                "wavefront" => Some(WaveSettings::parse(k, "wavefront_")?),
                _ => None,
            },
            cascade: 0,
            escape: k.get("escape")?,
            drift: k.get("drift")?,
            near_light: 0.0,
            // (No light, no forward population: nothing scatters forward out of a beam.)
            forward: scene.features().anisotropic
                && !scene.lights.is_empty()
                && match k.get::<String>("inject")?.as_str() {
                    "auto" => forward_auto,
                    mode => mode == "forward",
                },
            directed: match k.get::<String>("inject")?.as_str() {
                "auto" => !forward_auto && !light_inside,
                mode => mode == "directed",
            },
            flux: match k.get::<String>("flux")?.as_str() {
                "auto" if light_inside && !forward_auto => view::FluxUse::None,
                "auto" | "two_term" => view::FluxUse::TwoTerm,
                "lobe" => view::FluxUse::Lobe,
                _ => view::FluxUse::None,
            },
            previous: None,
            previous_source: None,
            keep_source: false,
            iterations_per_frame: if k.is_set("iterations_per_frame") {
                Some(k.get("iterations_per_frame")?)
            } else {
                None
            },
            budgeted: false,
        };
        let lattice = out.lattice;
        let mut out = LblSettings { cascade: k.get("cascade")?, ..out };
        let several = scene.object.as_ref().is_some_and(|o| o.several_materials());
        if several && out.cascade > 0 {
            return Err(k.invalid(
                "cascade",
                "the cascadic start's coarse lattices hold one medium, and the scene's objects have several \
                 materials; use lbl.cascade=0",
            ));
        }
        if several && out.warm_start.is_some() {
            return Err(k.invalid(
                "warm_start",
                "the wavefront guess holds one medium, and the scene's objects have several materials; use \
                 lbl.warm_start=none",
            ));
        }
        if out.cascade > 0 && (lattice != Lattice::D3q6 || out.warm_start.is_some()) {
            return Err(k.invalid(
                "cascade",
                "the cascadic start seeds a d3q6 lattice from its own coarse solution; use lbl.lattice=d3q6 and no \
                 lbl.warm_start, or lbl.cascade=0",
            ));
        }
        // The near ball: only where the scene's only light is a point light inside the medium,
        // whose image the lumped light scales (the scaling would scale any other light's too).
        // A seeded start (lbl.cascade, lbl.warm_start) guesses the field of every deposit, the
        // near ones too, and would start far from the lattice's fixed point without them.
        // (An emitting medium's image is not the light's alone: the scaling would scale its glow too.)
        let lumpable = scene.lights.len() == 1 && light_inside && !out.seeded() && !scene.emissive();
        out.near_light = k.get_or("near_light", if lumpable { near_light_default(scene, &geom) } else { 0.0 })?;
        if out.near_light > 0.0 && !lumpable {
            return Err(k.invalid(
                "near_light",
                "the near ball lumps once-scattered light into the scene's only light, which must be a point light \
                 inside a medium that does not emit, without lbl.cascade or lbl.warm_start; set lbl.near_light=0",
            ));
        }
        // Each level halves the grid; the coarsest keeps at least 4 voxels along its longest side.
        out.cascade = out.cascade.min(grid.max(1).ilog2().saturating_sub(2));
        if out.warm_start.is_some() && out.lattice != Lattice::D3q6 {
            return Err(k.invalid(
                "warm_start",
                "the wavefront warm start is built for the d3q6 lattice; use lbl.lattice=d3q6",
            ));
        }
        if out.warm_start.is_some() && scene.lights.is_empty() {
            return Err(k.invalid(
                "warm_start",
                "the wavefront warm start guesses the lights' field, and the scene is lit by its emission alone; use \
                 lbl.warm_start=none",
            ));
        }
        if out.warm_start.is_some() && scene.object.is_some() {
            return Err(k.invalid(
                "warm_start",
                "the wavefront warm start does not trace the [[object]]'s mesh (its field would fill the medium's box); \
                 use lbl.warm_start=none",
            ));
        }
        out.view.refraction = k.get("refraction")?;
        Ok(out)
    }

    /// Whether the lattice runs all rounds of marching before it iterates (a warm start or a
    /// cascadic start needs every deposit first).
    fn seeded(&self) -> bool {
        self.warm_start.is_some() || self.cascade > 0 || self.previous.is_some()
    }

    /// Channels the lattice carries ([`gpu_scene::channels`]), three also where the medium's
    /// emission differs between channels (its source then does).
    pub fn channels(scene: &Scene, chromatic: bool) -> u32 {
        if lattice::emission::chromatic_emission(scene) && scene.emissive() {
            3
        } else {
            gpu_scene::channels(scene, chromatic)
        }
    }
}

/// Default radius in voxels of the near ball about a point light inside the medium
/// (`lbl.near_light`; docs/lbl.md has the sweep that chose it).
pub const NEAR_LIGHT_VOXELS: f32 = 3.0;

/// At most this many mean free paths (at the light's own extinction, largest channel) for the
/// default near ball: on a coarse lattice in a dense medium 3 voxels reach several mean free
/// paths, the ball then holds most of the light's first scattering and the lumping
/// (which moves each deposit to the light) loses its footing: a sphere of sigma_t 8, albedo
/// 0.95 with a light inside, grid 16 (one voxel a mean free path), gave energy 0.738 of path's
/// at 3 voxels, 1.079 at 1.5 and 1.113 at 1 (1.154 without a ball); at grid 32 (3 voxels =
/// 1.5 mean free paths) 1.005.
pub const NEAR_LIGHT_MFP: f32 = 1.5;

/// Reduced optical thickness a surface voxel of the default grid has at least (where the grid is
/// not already at [`GRID_MAX`]). The lattice's boundary treatment (escape weights and drift in
/// the surface voxel) was calibrated for surface voxels of reduced optical thickness 0.15-0.6;
/// thinner ones turn thick media bright as the grid is refined (the g 0.6 cube, sigma_t
/// 20: 1.019 / 1.033 / 1.113 / 1.179 / 1.269 of path's energy at grids 16 / 32 / 48 / 64 / 96;
/// docs/lbl.md, "the default grid").
const GRID_MIN_VOXEL_TAU: f32 = 0.25;
/// The default grid's bounds: 32 keeps thin and soft media resolved (the cloud's relL2 0.084 at
/// 32 against 0.080 at 64), 64 is the thesis-scale default the benches were measured at.
const GRID_MIN: u32 = 32;
const GRID_MAX: u32 = 64;

/// The default `lbl.grid`: voxels of reduced optical thickness at least
/// [`GRID_MIN_VOXEL_TAU`] at the medium's densest, in multiples of 8 (the block edge) within
/// [`GRID_MIN`]..=[`GRID_MAX`].
pub fn default_grid(scene: &Scene) -> u32 {
    let side = (scene.medium.bounds_max - scene.medium.bounds_min).max_element();
    // An optical length beyond f32 saturates at GRID_MAX (f32::min also drops a NaN).
    let t = lattice::max_reduced_sigma_t(scene) * side;
    let fit = 8 * (t / (8.0 * GRID_MIN_VOXEL_TAU)).floor().min(GRID_MAX as f32) as u32;
    fit.clamp(GRID_MIN, GRID_MAX)
}

/// The default `lbl.near_light`: [`NEAR_LIGHT_VOXELS`], or [`NEAR_LIGHT_MFP`] mean free paths
/// at the scene's (first) point light where that is fewer voxels.
fn near_light_default(scene: &Scene, geom: &LatticeGeom) -> f32 {
    let Some(crate::scene::Light::Point { position, .. }) = scene.lights.first() else {
        return NEAR_LIGHT_VOXELS;
    };
    // The extinction of the medium the light is in: its object's material's.
    let sigma_t = match &scene.object {
        Some(o) => o.material_at(*position).map_or(0.0, |m| o.materials[m].sigma_t.max_element()),
        None => scene.medium.sigma_t.max_element(),
    };
    let tau_voxel = sigma_t * scene.density_at(*position) * geom.lambda;
    if tau_voxel > 0.0 {
        NEAR_LIGHT_VOXELS.min(NEAR_LIGHT_MFP / tau_voxel)
    } else {
        NEAR_LIGHT_VOXELS
    }
}

/// A near ball past twice its default radius for the scene ([`near_light_default`]) moves
/// the light's first scattering too far and lumps a share k so large that 1 / (1 - k) scales
/// the image wrong: the radii measured best were 2-4 voxels (docs/lbl.md, issue 11), and on
/// point-light-in-cloud at 64^2 (grid 32, against path at 256 spp) relL2 was 0.125 / 0.119 at
/// 1 / 3 voxels (k 0.28 / 0.51), 0.99 at 10 (k 0.80) and 1.02 at 30 or 1e30.
fn near_light_trust(scene: &Scene, set: &LblSettings) -> Option<String> {
    let default = near_light_default(scene, &set.geom);
    (set.near_light > 2.0 * default).then(|| {
        format!(
            "lbl: the near ball (lbl.near_light = {} voxels) is past twice its default here ({default:.3} voxels: {} or \
             {} mean free paths at the light, whichever is fewer): it lumps too much of the light's first \
             scattering into the light and the image goes wrong (point-light-in-cloud: relL2 against path 0.12 at 3 \
             voxels, 0.99 at 10); lower lbl.near_light",
            if set.near_light < 1e7 { set.near_light.to_string() } else { format!("{:e}", set.near_light) },
            NEAR_LIGHT_VOXELS,
            NEAR_LIGHT_MFP
        )
    })
}

/// The once-scattered light about a point light inside the medium, lumped into the light
/// (`lbl.near_light`). Deposits within `radius` voxels of the light are not injected: they are
/// the share `k` (per channel) of the light's power 4 pi I scattered there, which is taken to
/// leave from the light itself, isotropically (from a ball this small, what leaves goes
/// outward in every direction). Emitted from the light, it is again a point light, of
/// intensity k I: its single scattering is k times the light's, its own near part k^2 I, and
/// its other deposits k times the light's. Summed over generations the near ball turns the
/// light's whole image (single scattering and the lattice's field) into 1 / (1 - k) times that
/// of the light with its near deposits left out, which is what `lbl` renders; the lattice
/// never sees the concentrated deposits whose six axial beams drew a "+" through the light.
#[derive(Clone, Debug, Serialize)]
pub struct NearLight {
    /// Ball radius, voxels.
    pub radius: f32,
    /// Share of the light's power scattered within the ball, per channel.
    pub k: [f64; 3],
}

/// Everything `lbl` measured, beside the image.
#[derive(Clone, Debug, Serialize)]
pub struct LblStats {
    pub lattice: LatticeGeom,
    /// How finely the lattice resolves the medium, against what lbl was validated at.
    pub trust: lattice::GridTrust,
    /// How far to trust the view march that gathers the lattice's field toward the camera
    /// (`lbl.view_step`, `lbl.view_shadow_step`).
    pub view_trust: view::ViewTrust,
    pub lattice_kind: Lattice,
    /// Whether the lattice ran: false where nothing in the scene scatters (`Scene::scatters`).
    /// The view scatters the lattice's field toward the camera by sigma_s, so there it would
    /// carry nothing: the image is the view's camera-ray march alone, exactly as with it.
    pub field: bool,
    /// Block edge and steps per dispatch the lattice ran with (a derived block may have
    /// stepped down to fit the device).
    pub block: u32,
    pub block_steps: u32,
    pub channels: u32,
    pub rays: u32,
    pub rounds: u32,
    pub iterations: u32,
    pub converged: bool,
    pub final_change: f64,
    /// The extrapolated tail of the iteration (`lbl.extrapolate`), none where the plain
    /// criterion stopped it. The energy book is the lattice's own tally: its `remaining` is
    /// the energy in flight that the tail stands for.
    pub tail: Option<lattice::Tail>,
    pub energy: EnergyBook,
    pub schedule: Schedule,
    pub deterministic: bool,
    /// Bytes of every lattice, ray and history buffer (what grey media save by one channel).
    pub device_bytes: u64,
    /// GPU time of the lattice steps alone, for the voxel-update throughput.
    pub diffuse_ms: f64,
    /// The iteration started from the wavefront solution (the energy book then does not
    /// balance: the seeded residual is signed).
    pub warm_start: bool,
    /// Cascadic start: the iterations run on each coarse level, coarsest first (empty: none).
    /// The energy book is not kept then either.
    pub cascade_iterations: Vec<u32>,
    /// Dispatches of the view pass.
    pub view_dispatches: u64,
    /// Once-scattered light injected with its first moment (anisotropic media, `lbl.inject`).
    pub directed: bool,
    /// Forward-scattered light carried along the light rays (`lbl.inject=forward`).
    pub forward: bool,
    /// Its energy book: what the forward population's collisions absorbed and what left with
    /// it; the lattice's `energy.injected` holds the rest of the once-scattered light.
    pub forward_book: Option<marching::ForwardBook>,
    /// The near ball lumped into a point light inside the medium (`lbl.near_light`).
    pub near_light: Option<NearLight>,
    /// The lattice's flux is integrated and scattered by the view pass (`lbl.flux`).
    pub flux: bool,
}

impl LblStats {
    /// What the settings decide before anything runs (the lattice and its trust, the view's,
    /// the kind, the block, the channels, the schedule, whether the injection is directed), with
    /// nothing made: no lattice run, no ray, no iteration. A render fills in what it did.
    fn of_settings(scene: &Scene, set: &LblSettings, nch: u32, directed: bool) -> LblStats {
        let geom = set.geom;
        LblStats {
            lattice: geom,
            trust: geom.trust(scene, set.grid, &lattice::LBL_GRID),
            view_trust: view::ViewTrust::of(scene, &set.view),
            lattice_kind: set.lattice,
            field: false,
            block: set.block,
            block_steps: set.block_steps,
            channels: nch,
            rays: 0,
            rounds: 0,
            iterations: 0,
            converged: true,
            final_change: 0.0,
            tail: None,
            energy: EnergyBook::default(),
            schedule: set.schedule,
            deterministic: set.deterministic,
            device_bytes: 0,
            diffuse_ms: 0.0,
            warm_start: false,
            cascade_iterations: Vec::new(),
            view_dispatches: 0,
            directed,
            forward: false,
            forward_book: None,
            near_light: None,
            flux: false,
        }
    }
}

/// The lattice's time-integrated energy and stats, without the view pass (for tests of the
/// diffusion itself and for warm starts).
pub struct LatticeResult {
    pub irradiance: Vec<f32>,
    /// With [`LblSettings::keep_source`] and a previous frame's field: the state this frame's
    /// deposits were injected as.
    pub source: Option<Vec<f32>>,
    /// With [`LblStats::forward`], the forward population's field follows the lattice's
    /// ([`view::MsVolume::forward`]).
    pub irradiance_buffer: crate::gpu::Buffer,
    pub stats: LblStats,
}

/// The lattice over `geom` for this scene and these knobs. (Its media come from the scene
/// block's material table: [`lattice_materials`].)
fn lattice_params(scene: &Scene, set: &LblSettings, geom: &LatticeGeom, nch: u32) -> LatticeParams {
    LatticeParams {
        dims: geom.dims,
        nch,
        lattice: set.lattice,
        lambda: geom.lambda,
        block: set.block,
        block_steps: set.block_steps,
        escape: set.escape,
        drift: set.drift,
        near: match (set.near_light > 0.0, scene.lights.first()) {
            (true, Some(crate::scene::Light::Point { position, .. })) => {
                Some(([0, 1, 2].map(|a| (position[a] - geom.origin[a]) / geom.lambda), set.near_light))
            }
            _ => None,
        },
        // Any medium's g (every object's material counts): the first moment is kept.
        directed: set.directed && scene.features().anisotropic,
        flux: set.flux != view::FluxUse::None && scene.features().anisotropic,
        // A sequence's frames hand the next the links' own time integrals ([`start`]).
        links: set.keep_source && set.lattice == Lattice::D3q6,
        extrapolate: set.extrapolate,
    }
}

/// What the lattice adds to the scene block's material table (glsl/include/lattice.glsl): per
/// material, the diffuse Fresnel reflectance from inside of its object's surface, for the links
/// leaving its voxels, where it refracts and `lbl.view_refraction` is on (0 elsewhere: a medium
/// without an object, or index-matched).
fn lattice_materials(scene: &Scene, set: &LblSettings) -> [f32; MAX_MATERIALS] {
    let mut reflect = [0.0; MAX_MATERIALS];
    if let Some(o) = &scene.object {
        for (r, m) in reflect.iter_mut().zip(&o.materials) {
            if m.ior != 1.0 && set.view.refraction {
                *r = crate::physics::dielectric::diffuse_fresnel(m.ior as f64) as f32;
            }
        }
    }
    reflect
}

/// Run marching, transfer and diffusion to convergence.
pub fn run_lattice(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    set: &LblSettings,
    progress: &dyn Fn(Progress),
) -> Result<LatticeResult, SolverError> {
    // Pipeline creation (a shader compile per kernel on a CPU driver) and the raymaps take
    // seconds before the first round: a stage of its own, so the rounds' bar does not sit at 0.
    progress(Progress::work("setup: pipelines, raymaps, lattice", 0, 1));
    let geom = set.geom;
    let nch = LblSettings::channels(scene, gs.modelled.chromatic);
    let info = gpu.info().clone();
    let set = &fitted(&info, set, nch)?;
    // Fixed point by default (the Determinism rule): its transfer took 462 ms where float atomics
    // took 446 (the default scene at 256^2 on lavapipe); float atomics only where asked for and
    // offered.
    let fixed = set.deterministic || !info.float_atomics;
    let params = lattice_params(scene, set, &geom, nch);
    let mut marcher = Marcher::new(gpu, scene, gs, geom, &set.march, nch, fixed, params.directed, true)?;
    if set.forward && marcher.ray_count > 0 {
        marcher.enable_forward(gpu, nch)?;
    }
    // Objects of several materials: each voxel names its material (the marcher's voxelisation).
    let several = scene.object.as_ref().is_some_and(|o| o.several_materials());
    let voxels = marcher.voxel_materials.as_deref().filter(|_| several);
    let materials = lattice::LatticeMaterials::new(gpu, &gs.block, lattice_materials(scene, set), voxels)?;
    let mut lattice = Diffuser::new(gpu, marcher.density.clone(), &params, &materials)?;
    let injector = Injector::new(gpu, &params, fixed, marcher.scale, &materials)?;
    let rounds = marcher.rounds;
    let density = lattice::read_f32(gpu, &marcher.density)?;
    // An emitting medium's source per voxel (lattice::emission): isotropic, into the rest
    // distribution beside the once-scattered deposits, once (the lattice's time integral is
    // the steady field of a constant source).
    let emission = lattice::emission::emission_source(scene, &geom, set.lattice, &density, voxels, nch);

    // A warm or cascadic start needs the whole deposit s before the iteration starts from the
    // guess, so the rounds only march and transfer (the sums accumulate until one injection).
    let warm = set.seeded();
    if let (Some(e), false) = (&emission, warm) {
        // Cold: the lattice is zero, and the rounds' injections add their deposits to this.
        gpu.write_buffer(lattice.state(), 0, bytemuck::cast_slice(e))?;
    }
    progress(Progress::work("setup: pipelines, raymaps, lattice", 1, 1));
    march_rounds(gpu, gs, set, (&marcher, &injector), &mut lattice, warm, progress)?;
    // A mesh sets what a round of k steps costs (its BVH traversals): measured, not assumed.
    marcher.check_loops(gpu)?;

    let inject = |l: &Diffuser| injector.pass(&marcher.sums, l);
    let (cascade_iterations, source) =
        start(gpu, (scene, gs, set), (&marcher, &params), &mut lattice, (&inject, emission.as_deref()))?;

    // Iterate to convergence: relative change of the time-integrated energy at sparse probes.
    // The wavefront guess and the cascade iterate plainly (their tails extrapolated gave
    // relL2 5e-3 on the cloud); a previous frame's field extrapolates its tail like a cold start
    // (the increments' magnitudes decay geometrically from it too): a plain stop there took
    // more iterations than a cold, extrapolated start (129 against 72 on the sphere at grid 16).
    if set.warm_start.is_some() || set.cascade > 0 {
        lattice.plain();
    }
    let it = lattice.iterate(gpu, &density, set.tol, set.max_iters, progress)?;
    gpu.wait_idle_roles()?;

    // Energy bookkeeping: injected = absorbed + leaked + what is still moving in the lattice.
    let mut book = lattice.book(gpu)?;
    book.injected = injector.injected(gpu)?;
    if let Some(e) = &emission {
        for (b, p) in book.injected.iter_mut().zip(lattice::emission::source_power(e, nch)) {
            *b += p;
        }
    }
    if nch == 1 {
        for b in [&mut book.injected, &mut book.absorbed, &mut book.leaked, &mut book.remaining] {
            b[1] = b[0];
            b[2] = b[0];
        }
    }
    let mut irr = lattice.irradiance().clone();
    let irradiance = lattice::read_f32(gpu, &irr)?;
    let forward_book = marcher.forward_book(gpu)?;
    let mut forward_field = false;
    if let Some(fwd) = marcher.forward_field(gpu, nch)? {
        // The forward population's field follows the lattice's for the view pass
        // (view::MsVolume::forward); the lattice's own stays in `irradiance`.
        // (The links' integrals, where the lattice keeps them, are not the view's.)
        let view_floats = LatticeParams { links: false, ..params }.irradiance_floats() as usize;
        let mut both = irradiance[..view_floats].to_vec();
        both.extend_from_slice(&fwd);
        irr = gpu.buffer_with("lattice and forward field", &both)?;
        forward_field = true;
    }
    let device_bytes = marcher.device_bytes()
        + injector.device_bytes()
        + lattice.device_bytes()
        + materials.buffer.size()
        + if forward_field { irr.size() } else { 0 };
    let near_light = near_light(gpu, scene, &params, &injector, nch)?;
    Ok(LatticeResult {
        irradiance,
        source,
        irradiance_buffer: irr,
        stats: LblStats {
            field: true,
            rays: marcher.ray_count,
            rounds,
            iterations: lattice.iterations,
            converged: it.converged,
            final_change: it.change,
            tail: it.tail,
            energy: book,
            deterministic: fixed,
            device_bytes,
            warm_start: set.warm_start.is_some(),
            cascade_iterations,
            forward: forward_field,
            forward_book,
            flux: params.flux,
            near_light,
            ..LblStats::of_settings(scene, set, nch, params.directed)
        },
    })
}

/// The settings fitted to the device: the lattice's state within one binding (else one line
/// naming lbl.grid), and a derived block stepped down (8, 4, 2) to what this device's shared
/// memory and workgroup size allow; one the user set is checked as it is.
fn fitted(info: &DeviceInfo, set: &LblSettings, nch: u32) -> Result<LblSettings, SolverError> {
    let geom = set.geom;
    let v = geom.voxels();
    let state_bytes = set.lattice.state_bytes(nch, v);
    if state_bytes > info.max_storage_buffer_range {
        return Err(SolverError::Setting {
            key: "lbl.grid".into(),
            reason: format!(
                "a {}x{}x{} lattice with {nch} channel(s) needs {state_bytes} bytes per state buffer, over this \
                    device's maxStorageBufferRange {}; lower lbl.grid",
                geom.dims[0], geom.dims[1], geom.dims[2], info.max_storage_buffer_range
            ),
        });
    }
    let mut set = set.clone();
    while set.block_auto && set.block > 2 && check_block(info, set.lattice, nch, set.block).is_err() {
        set.block /= 2;
        if set.block_steps_auto {
            set.block_steps = set.block;
        }
    }
    check_block(info, set.lattice, nch, set.block)
        .map_err(|reason| SolverError::Setting { key: "lbl.block".into(), reason })?;
    Ok(set)
}

/// The marching rounds (thesis 4.2): each round's march, its transfer into the deposit sums
/// (and, cold, its injection into the lattice), and diffusion steps between, submitted on the
/// queue roles in the schedule's order with the waits it plans (lbl.schedule); `warm` skips the
/// diffusion and injection (a seeded start injects the whole deposit once). Returns when the
/// last transfer has run, the rounds' progress reported as they finish.
fn march_rounds(
    gpu: &Gpu,
    gs: &GpuScene,
    set: &LblSettings,
    (marcher, injector): (&Marcher, &Injector),
    lattice: &mut Diffuser,
    warm: bool,
    progress: &dyn Fn(Progress),
) -> Result<(), SolverError> {
    let rounds = marcher.rounds;
    let steps = plan(rounds, set.schedule);
    let mut points: Vec<SyncPoint> = Vec::with_capacity(steps.len());
    progress(Progress::work("marching rounds", 0, rounds as u64));
    let mut transfers: Vec<SyncPoint> = Vec::with_capacity(rounds as usize);
    // Rounds reported done so far: the count never goes back (on a GPU the queues run ahead of
    // the submissions, so rounds are seen done here before the waits below).
    let mut reached = 0;
    for st in &steps {
        let waits: Vec<SyncPoint> = st.waits.iter().map(|w| points[*w]).collect();
        // lbl.max_iters bounds the lattice's steps in all, the rounds' included (1048576 steps
        // a round ran on past it for minutes, and max_iters = 1 stepped 72 times).
        let budget = set.iters_per_round.min(set.max_iters.saturating_sub(lattice.iterations));
        if (warm || budget == 0) && matches!(st.step, Step::Diffuse(_)) {
            // Nothing waits on a diffusion step: keep the plan's indices with a stand-in.
            points.push(*points.last().expect("a diffusion step follows a transfer"));
            continue;
        }
        let passes = match st.step {
            Step::March(_) => vec![marcher.march_pass(gs, 0..marcher.ray_count)],
            Step::Transfer(_) => {
                let mut p = vec![marcher.transfer_pass(QueueRole::Diffuse)];
                if !warm {
                    p.push(injector.pass(&marcher.sums, lattice));
                }
                p
            }
            Step::Diffuse(_) => lattice.passes(budget),
        };
        let point = gpu.submit(st.role, &passes, &waits)?;
        points.push(point);
        if let Step::Transfer(_) = st.step {
            transfers.push(point);
        }
        // Submission can block while the queues work (lavapipe's does): report what has run.
        while reached < transfers.len() && gpu.reached(transfers[reached])? {
            reached += 1;
        }
        progress(Progress::work("marching rounds", reached as u64, rounds as u64));
    }
    // Rounds count when their transfer has run, not when it was submitted (the queues run
    // ahead of the host): one wait for the last, the count polled while it lasts.
    if let Some(last) = transfers.last() {
        let tick = || {
            while reached < transfers.len() && gpu.reached(transfers[reached]).unwrap_or(false) {
                reached += 1;
            }
            progress(Progress::work("marching rounds", reached as u64, rounds as u64));
        };
        gpu.wait_ticking(*last, std::time::Duration::from_millis(100), tick)?;
        progress(Progress::work("marching rounds", rounds as u64, rounds as u64));
    }
    Ok(())
}

/// The pass that injects the marching's summed deposits into a lattice's current state.
type InjectPass<'a> = &'a dyn Fn(&Diffuser) -> crate::gpu::Pass;

/// Seed the lattice where the iteration starts from a guess ([`seed`]): a wavefront solve
/// (lbl.warm_start), the cascadic start (lbl.cascade) or the previous frame's field (animate).
/// Returns the cascade's iterations per level (empty otherwise), and with
/// [`LblSettings::keep_source`] and a previous field, this frame's injected source.
///
/// A previous frame's field G seeds the residual r = s + M G - G ([`seed`]). With G the
/// time-integrated state after the first step only, F_16 = sum_{t>=1} M^t s_old, the residual
/// is s_new - M s_old (as F_16 = M s_old + M F_16): as large as the deposits. With the previous
/// frame's injected source in the guess's state at t = 0 too, G = s_old + F_16, it is
/// s_new - s_old, small after a small move. The source is the injection into a zeroed state,
/// which the seed then adds after its step in place of the injection.
///
/// `emission`: an emitting medium's source per channel and voxel (lattice::emission), part of
/// s beside the deposits `inject` adds: added to the rest after the seed's step.
fn start(
    gpu: &Gpu,
    (scene, gs, set): (&Scene, &GpuScene, &LblSettings),
    (marcher, params): (&Marcher, &LatticeParams),
    lattice: &mut Diffuser,
    (inject, emission): (InjectPass<'_>, Option<&[f32]>),
) -> Result<(Vec<u32>, Option<Vec<f32>>), SolverError> {
    let mut cascade_iterations = Vec::new();
    let mut source = None;
    let (geom, v, nch) = (set.geom, set.geom.voxels(), params.nch);
    if let Some(ws) = &set.warm_start {
        let vol = wave_volume(gpu, scene, gs, ws, Some(geom))?;
        let wf: Vec<f32> = gpu.read_buffer_as(&vol.energy)?;
        let (energy, flux) = wf.split_at(vol.channels as usize * v as usize);
        let guess = Guess { energy: energy.to_vec(), flux: flux.to_vec(), channels: vol.channels as usize };
        seed(gpu, lattice, &guess.links(nch as usize, v as usize), Some(inject), emission)?;
    } else if set.cascade > 0 {
        let (guess, iterations) = cascade(gpu, (scene, gs, set), marcher, params, emission)?;
        cascade_iterations = iterations;
        seed(gpu, lattice, &guess.links(nch as usize, v as usize), Some(inject), emission)?;
    } else if let Some(previous) = &set.previous {
        // The previous frame's field, same lattice. Where it integrated every link's outgoing
        // value (params.links: a sequence's frames), the guess's links are those integrals as
        // they are; else they are made from its fluence and its flux where the lattice
        // integrated one (params.flux), or by Fick's law (the cascade's prolongation at a
        // factor of 1).
        let e = nch as usize * v as usize;
        let flux_rows = if params.flux { 3 * e } else { 0 };
        let dirs = Lattice::D3q6.dirs().len() - 1;
        let carried = previous.len() == e + flux_rows + dirs * e;
        if previous.len() != e && previous.len() != 4 * e && !carried {
            return Err(SolverError::Unsupported(
                "lbl: the previous frame's lattice has another size or channel count".to_string(),
            ));
        }
        let mut links = if carried {
            let (nch, v) = (nch as usize, v as usize);
            let rows = &previous[e + flux_rows..];
            let mut g = vec![0f32; (dirs + 1) * e];
            for c in 0..nch {
                for i in 1..=dirs {
                    let from = (dirs * c + i - 1) * v;
                    g[(i * nch + c) * v..(i * nch + c + 1) * v].copy_from_slice(&rows[from..from + v]);
                }
            }
            g
        } else {
            let (energy, flux) = previous[..e + flux_rows.min(previous.len() - e)].split_at(e);
            let g = Guess { energy: energy.to_vec(), flux: flux.to_vec(), channels: nch as usize };
            let guess = if flux.is_empty() {
                let density = lattice::read_f32(gpu, &marcher.density)?;
                prolong(&g, geom.dims, geom.lambda, geom.dims, geom.lambda, &density, &scene.medium)
            } else {
                g
            };
            guess.links(nch as usize, v as usize)
        };
        if let Some(old) = set.previous_source.as_ref().filter(|o| o.len() == links.len()) {
            for (g, s) in links.iter_mut().zip(old) {
                *g += s;
            }
        }
        if set.keep_source {
            // This frame's source alone: its deposits injected into a zeroed state (the
            // injection clears the sums, so the seed adds it instead of injecting).
            gpu.write_buffer(lattice.state(), 0, bytemuck::cast_slice(&vec![0f32; links.len()]))?;
            let point = gpu.submit(QueueRole::Diffuse, &[inject(lattice)], &[])?;
            gpu.wait(point)?;
            let mut s: Vec<f32> = gpu.read_buffer_as(lattice.state())?;
            s.truncate(links.len());
            // The emission is part of the frame's source (in the rest, with the deposits).
            for (a, e) in s.iter_mut().zip(emission.unwrap_or(&[])) {
                *a += e;
            }
            seed(gpu, lattice, &links, None, Some(&s))?;
            source = Some(s);
        } else {
            seed(gpu, lattice, &links, Some(inject), emission)?;
        }
    }
    Ok((cascade_iterations, source))
}

/// Where a point light sits inside the medium (params.near), the share k of its power the
/// lattice's injection near it scattered, per channel, for the view pass.
fn near_light(
    gpu: &Gpu,
    scene: &Scene,
    params: &LatticeParams,
    injector: &Injector,
    nch: u32,
) -> Result<Option<NearLight>, SolverError> {
    let near = match (params.near, scene.lights.first()) {
        (Some((_, radius)), Some(crate::scene::Light::Point { intensity, .. })) => {
            let mut e = injector.near_energy(gpu)?;
            if nch == 1 {
                e = [e[0]; 3];
            }
            // The raymap carries 4 pi I from a light inside (marching::raymaps); what scatters
            // is at most albedo times that, so k < 1.
            let k = [0, 1, 2].map(|c| {
                let power = 4.0 * std::f64::consts::PI * intensity[c] as f64;
                if power > 0.0 {
                    (e[c] / power).clamp(0.0, 0.999)
                } else {
                    0.0
                }
            });
            Some(NearLight { radius, k })
        }
        _ => None,
    };
    Ok(near)
}

/// A guess G of a lattice's time-integrated field, per voxel: the fluence times lambda^2 per
/// channel (`energy`, [c V + v]) and the net flux times lambda^2 per channel and axis (`flux`,
/// [(3 c + a) V + v]), as the wavefront solver gathers them and as a coarse lattice gives them.
struct Guess {
    energy: Vec<f32>,
    flux: Vec<f32>,
    channels: usize,
}

impl Guess {
    /// The guess as D3Q6 link values: G_i = energy / 6 + flux.e_i / 2, which gives back the
    /// fluence as the summed arrivals and the flux as their net flow; clamped at 0 (|flux| <=
    /// energy / 3 keeps every link non-negative).
    fn links(&self, nch: usize, v: usize) -> Vec<f32> {
        let links = Lattice::D3q6.dirs();
        let mut g = vec![0f32; 7 * nch * v];
        for c in 0..nch {
            let cw = c.min(self.channels - 1);
            for x in 0..v {
                let phi = self.energy[cw * v + x];
                let e = [0, 1, 2].map(|a| self.flux[(3 * cw + a) * v + x]);
                for (i, d) in links.iter().enumerate().skip(1) {
                    let flow = e[0] * d[0] as f32 + e[1] * d[1] as f32 + e[2] * d[2] as f32;
                    g[(i * nch + c) * v + x] = (phi / 6.0 + flow / 2.0).max(0.0);
                }
            }
        }
        g
    }
}

/// Start the lattice iteration from a guess G of its time-integrated field F (wavefront paper,
/// section 1.1: "an initial guess for an iterative solver"). F is the fixed point of
/// F = s + M F (s: all deposits, M: one lattice step), and running the lattice from the
/// deposits alone is the Jacobi iteration from F = 0. From G instead,
///   F_n = sum_{t<n} M^t s + M^n G = G + sum_{t<n} M^t (s + M G - G),
/// so the lattice is seeded with the residual r = s + M G - G and its accumulated irradiance
/// with that of G (one lattice step on G produces both M G and G's irradiance). The deposits
/// join the rest after that step: by `inject` (the fine lattice's injector pass) or `rest`
/// (host values per channel and voxel, for a coarse level). The residual is signed, so the
/// absorbed/leaked tallies no longer balance the deposits: the energy book is not kept.
fn seed(
    gpu: &Gpu,
    lattice: &mut Diffuser,
    g: &[f32],
    inject: Option<&dyn Fn(&Diffuser) -> crate::gpu::Pass>,
    rest: Option<&[f32]>,
) -> Result<(), SolverError> {
    gpu.write_buffer(lattice.state(), 0, bytemuck::cast_slice(g))?;
    let mut passes = lattice.passes(1);
    // After the step: into the state the step wrote.
    passes.extend(inject.map(|f| f(lattice)));
    let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
    gpu.wait(point)?;
    let mut st: Vec<f32> = gpu.read_buffer_as(lattice.state())?;
    for (a, b) in st.iter_mut().zip(g) {
        *a -= b;
    }
    if let Some(rest) = rest {
        for (a, r) in st.iter_mut().zip(rest) {
            *a += r;
        }
    }
    gpu.write_buffer(lattice.state(), 0, bytemuck::cast_slice(&st))?;
    Ok(())
}

/// The cascadic start (a coarse-to-fine multigrid start, as Bornemann and Deuflhard's cascadic
/// multigrid: solve coarse, prolong, solve finer): the deposits and density restricted to
/// grids of 2^L, ..., 2 times the voxel edge (sums of deposits, means of density over each
/// coarse voxel's children), the coarsest lattice run cold to convergence, each finer one
/// seeded ([`seed`]) with the fluence of the one below, prolonged trilinearly, and its flux
/// by Fick's law E = -grad(phi) / (3 sigma_t') (the lattice's own diffusion limit), and
/// run to convergence. Returns the guess for the fine lattice and each level's iterations.
/// A coarse lattice's absorption per step is larger (its steps are longer), so it converges
/// in fewer, cheaper steps, and the fine lattice starts with only the error the coarse grid
/// could not resolve. An emitting medium's source (`emission`, per fine voxel) joins the
/// deposits, summed over each coarse voxel's children like them.
fn cascade(
    gpu: &Gpu,
    (scene, gs, set): (&Scene, &GpuScene, &LblSettings),
    marcher: &Marcher,
    fine: &LatticeParams,
    emission: Option<&[f32]>,
) -> Result<(Guess, Vec<u32>), SolverError> {
    let nch = fine.nch as usize;
    let raw: Vec<u32> = gpu.read_buffer_as(&marcher.sums)?;
    let mut deposits: Vec<f32> = if marcher.fixed {
        raw.iter().map(|q| *q as f32 / marcher.scale).collect()
    } else {
        raw.iter().map(|b| f32::from_bits(*b)).collect()
    };
    for (d, e) in deposits.iter_mut().zip(emission.unwrap_or(&[])) {
        *d += e;
    }
    let density = lattice::read_f32(gpu, &marcher.density)?;
    // Levels coarsest first: dims and data restricted from the fine grid by 2^l.
    let levels: Vec<u32> = (1..=set.cascade).rev().collect();
    let mut guess: Option<(Guess, [u32; 3], f32)> = None;
    let mut iterations = Vec::new();
    for &l in &levels {
        let f = 1u32 << l;
        let dims = fine.dims.map(|d| d.div_ceil(f));
        let lambda = fine.lambda * f as f32;
        let dens = restrict(&density, fine.dims, 1, f, true);
        let dep = restrict(&deposits, fine.dims, nch, f, false);
        let params = LatticeParams { dims, lambda, links: false, ..*fine };
        let dens_buf = gpu.buffer_with("cascade density", &dens)?;
        // One medium (the settings refuse the cascade with several materials).
        let materials = lattice::LatticeMaterials::new(gpu, &gs.block, lattice_materials(scene, set), None)?;
        let mut d = Diffuser::new(gpu, dens_buf, &params, &materials)?;
        match &guess {
            Some((g, from, from_lambda)) => {
                d.plain();
                let p = prolong(g, *from, *from_lambda, dims, lambda, &dens, &scene.medium);
                seed(gpu, &mut d, &p.links(nch, dens.len()), None, Some(&dep))?;
            }
            None => {
                // Cold: the deposits are the rest distribution (link 0), as injection makes them.
                let mut state = vec![0f32; 7 * nch * dens.len()];
                state[..dep.len()].copy_from_slice(&dep);
                gpu.write_buffer(d.state(), 0, bytemuck::cast_slice(&state))?;
            }
        }
        d.iterate(gpu, &dens, set.tol, set.max_iters, &|_| {})?;
        iterations.push(d.iterations);
        let energy = lattice::read_f32(gpu, d.irradiance())?;
        guess = Some((Guess { energy, flux: Vec::new(), channels: nch }, dims, lambda));
    }
    let (g, from, from_lambda) = guess.expect("at least one level");
    Ok((prolong(&g, from, from_lambda, fine.dims, fine.lambda, &density, &scene.medium), iterations))
}

/// Restrict per-voxel values (`nch` channels, [c V + v]) from `dims` to the grid of `f` times
/// the voxel edge: the mean over each coarse voxel's children (`mean`) or their sum.
fn restrict(x: &[f32], dims: [u32; 3], nch: usize, f: u32, mean: bool) -> Vec<f32> {
    let [nx, ny, nz] = dims.map(|d| d as usize);
    let c = dims.map(|d| d.div_ceil(f) as usize);
    let (v, vc) = (nx * ny * nz, c[0] * c[1] * c[2]);
    let mut out = vec![0f32; nch * vc];
    let mut count = vec![0u32; vc];
    for z in 0..nz {
        for y in 0..ny {
            for xx in 0..nx {
                let (cx, cy, cz) = (xx / f as usize, y / f as usize, z / f as usize);
                let ci = cx + c[0] * (cy + c[1] * cz);
                count[ci] += 1;
                for ch in 0..nch {
                    out[ch * vc + ci] += x[ch * v + xx + nx * (y + ny * z)];
                }
            }
        }
    }
    if mean {
        for ch in 0..nch {
            for (o, n) in out[ch * vc..(ch + 1) * vc].iter_mut().zip(&count) {
                *o /= (*n).max(1) as f32;
            }
        }
    }
    out
}

/// Prolong a coarse guess (`from` voxels of edge `from_lambda`, same origin) to `dims` voxels of
/// edge `lambda`: the fluence trilinear between coarse voxel centres (energy = fluence
/// lambda^2 scales by (lambda / from_lambda)^2), and the flux by Fick's law from its central
/// differences, E = -grad(phi) / (3 sigma_t' density), none where the density is 0, sigma_t'
/// the reduced extinction of `medium` (the scene's one medium: a seeded start refuses several).
fn prolong(
    g: &Guess,
    from: [u32; 3],
    from_lambda: f32,
    dims: [u32; 3],
    lambda: f32,
    density: &[f32],
    medium: &crate::scene::Medium,
) -> Guess {
    let nch = g.channels;
    let [nx, ny, nz] = dims.map(|d| d as usize);
    let v = nx * ny * nz;
    let vc = from.iter().map(|d| *d as usize).product::<usize>();
    let scale = (lambda / from_lambda).powi(2);
    let at = |c: usize, q: [f32; 3]| -> f32 {
        // Coarse voxel coordinates of a point in fine voxel units.
        let u = [0, 1, 2].map(|a| ((q[a] + 0.5) * lambda / from_lambda - 0.5).clamp(0.0, (from[a] - 1) as f32));
        let i0 = u.map(|x| x.floor() as usize);
        let i1 = [0, 1, 2].map(|a| (i0[a] + 1).min(from[a] as usize - 1));
        let t = [0, 1, 2].map(|a| u[a] - i0[a] as f32);
        let idx = |x: usize, y: usize, z: usize| c * vc + x + from[0] as usize * (y + from[1] as usize * z);
        let mut s = 0.0;
        for (dz, wz) in [(i0[2], 1.0 - t[2]), (i1[2], t[2])] {
            for (dy, wy) in [(i0[1], 1.0 - t[1]), (i1[1], t[1])] {
                for (dx, wx) in [(i0[0], 1.0 - t[0]), (i1[0], t[0])] {
                    s += wx * wy * wz * g.energy[idx(dx, dy, dz)];
                }
            }
        }
        s * scale
    };
    let mut energy = vec![0f32; nch * v];
    for c in 0..nch {
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    energy[c * v + x + nx * (y + ny * z)] = at(c, [x as f32, y as f32, z as f32]);
                }
            }
        }
    }
    // Fick's law on the fine grid: flux lambda^2 = -(energy difference / (2 lambda)) / (3 sigma_t').
    let mut flux = vec![0f32; 3 * nch * v];
    let n = [nx, ny, nz];
    for c in 0..nch {
        let st = medium.sigma_t[c] * (1.0 - medium.albedo[c] * medium.g);
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let i = x + nx * (y + ny * z);
                    let sigma = st * density[i];
                    if sigma <= 0.0 {
                        continue;
                    }
                    let q = [x, y, z];
                    for a in 0..3 {
                        let (mut lo, mut hi) = (q, q);
                        lo[a] = q[a].saturating_sub(1);
                        hi[a] = (q[a] + 1).min(n[a] - 1);
                        let span = (hi[a] - lo[a]) as f32;
                        if span == 0.0 {
                            continue;
                        }
                        let e = |r: [usize; 3]| energy[c * v + r[0] + nx * (r[1] + ny * r[2])];
                        let grad = (e(hi) - e(lo)) / (span * lambda);
                        flux[(3 * c + a) * v + i] = -grad / (3.0 * sigma);
                    }
                }
            }
        }
    }
    Guess { energy, flux, channels: nch }
}
