//! Specialization on the host (src/gpu/specialize.rs): every kernel, specialised as solvers
//! ask for it, is valid SPIR-V with no specialization constant left, and renders the images
//! the driver's own specialization renders, bit for bit.

use std::process::Command;

use scatterlab::gpu::specialize::specialize;
use scatterlab::gpu::{reflect, Gpu, GpuOptions, Spec, SpecKind};
use scatterlab::solvers;

use crate::common::{assert_clean, render, repo_scene, LBL, PATH, SINGLE};

fn words(bytes: &[u8]) -> Vec<u32> {
    ash::util::read_spv(&mut std::io::Cursor::new(bytes)).expect("a SPIR-V module")
}

/// The values a kernel is specialised with in this test: every constant at its kernel's usual
/// value, then each bool flipped, then all bools false and all true, and the density kinds
/// (constant, sphere, grid) and octave counts (1, 4) the solvers use.
fn variants(spec: &[(u32, SpecKind)]) -> Vec<Vec<(u32, Spec)>> {
    let base: Vec<(u32, Spec)> = spec
        .iter()
        .map(|&(id, kind)| {
            (
                id,
                match kind {
                    SpecKind::Bool => Spec::Bool(false),
                    // Sizes (workgroups, channels, links) must be at least 1; 2 is a grid density.
                    SpecKind::U32 => Spec::U32(if id == 7 { 6 } else { 2 }),
                    SpecKind::I32 => Spec::I32(1),
                    SpecKind::F32 => Spec::F32(0.5),
                },
            )
        })
        .collect();
    let mut out = vec![base.clone()];
    for (k, &(_, kind)) in spec.iter().enumerate() {
        if kind == SpecKind::Bool {
            let mut v = base.clone();
            v[k].1 = Spec::Bool(true);
            out.push(v);
        }
    }
    out.push(base.iter().map(|&(id, v)| (id, if matches!(v, Spec::Bool(_)) { Spec::Bool(true) } else { v })).collect());
    for (k, &(id, _)) in spec.iter().enumerate() {
        let values: &[u32] = match id {
            0 => &[0, 1], // DENSITY_KIND: constant, sphere (grid above)
            8 => &[1, 4], // OCTAVES
            3 => &[1, 3], // NCH
            _ => &[],
        };
        for &x in values {
            let mut v = base.clone();
            v[k].1 = Spec::U32(x);
            out.push(v);
        }
    }
    out
}

#[test]
fn every_kernel_specialised_on_the_host_is_valid_spirv_without_specialization_constants() {
    let dir = tempfile::tempdir().unwrap();
    let mut checked = 0;
    for k in &solvers::kernels() {
        let original = words(k.shader.spirv);
        for (n, values) in variants(k.spec).iter().enumerate() {
            let out = specialize(&original, values).unwrap_or_else(|e| panic!("{} {values:?}: {e}", k.shader.name));
            let bytes: Vec<u8> = out.iter().flat_map(|w| w.to_le_bytes()).collect();
            let r =
                reflect(&scatterlab::gpu::ShaderSource { name: k.shader.name, spirv: Box::leak(bytes.clone().into()) })
                    .unwrap_or_else(|e| panic!("{} {values:?}: {e}", k.shader.name));
            assert!(r.spec_constants.is_empty(), "{} {values:?}: {:?} left", k.shader.name, r.spec_constants);
            let file = dir.path().join(format!("{}.{n}.spv", k.shader.name.replace('/', "_")));
            std::fs::write(&file, &bytes).unwrap();
            let val = Command::new("spirv-val")
                .args(["--target-env", "vulkan1.2"])
                .arg(&file)
                .output()
                .expect("spirv-val (tools/setup-deps installs spirv-tools)");
            assert!(
                val.status.success(),
                "{} specialised with {values:?} is not valid SPIR-V: {}",
                k.shader.name,
                String::from_utf8_lossy(&val.stderr)
            );
            checked += 1;
        }
    }
    println!("{checked} specialised modules valid");
    assert!(checked > 100, "only {checked} modules checked");
}

/// The camera-ray march specialised for a scene without a mesh loses the mesh's code: what
/// lavapipe compiled for 1.3-1.5 s before (src/gpu/specialize.rs).
#[test]
fn decided_branches_leave_the_module() {
    let k = solvers::parts::view::MARCH;
    let original = words(k.shader.spirv);
    let values: Vec<(u32, Spec)> = k
        .spec
        .iter()
        .map(|&(id, kind)| {
            (id, if kind == SpecKind::Bool { Spec::Bool(false) } else { Spec::U32(if id == 8 { 1 } else { 2 }) })
        })
        .collect();
    let out = specialize(&original, &values).unwrap();
    println!("view/march: {} words, {} specialised without a mesh", original.len(), out.len());
    assert!(out.len() * 10 < original.len() * 9, "{} of {} words left", out.len(), original.len());
    // A kernel without specialization constants comes back as it was.
    let copy = words(solvers::parts::feedback::COPY.shader.spirv);
    assert_eq!(specialize(&copy, &[]).unwrap(), copy);
}

/// The same images from host and driver specialization, bit for bit, on a grid density under
/// a sun and a sky (lbl deterministic: its float-atomic sums' order otherwise varies).
#[test]
fn host_and_driver_specialization_render_the_same_images() {
    let host = Gpu::new(&GpuOptions { validate: true, driver_specialization: false, ..GpuOptions::default() }).unwrap();
    let driver =
        Gpu::new(&GpuOptions { validate: true, driver_specialization: true, ..GpuOptions::default() }).unwrap();
    let cloud =
        repo_scene("scenes/cloud.toml", &[("render.width", "16"), ("render.height", "16"), ("render.spp", "8")]);
    for (solver, sets) in
        [(PATH, vec![]), (SINGLE, vec![]), (LBL, vec![("lbl.grid", "16"), ("lbl.deterministic", "true")])]
    {
        let a = render(&host, &cloud, solver, &sets);
        let b = render(&driver, &cloud, solver, &sets);
        assert!(a.image.data == b.image.data, "{}: host and driver specialization differ", solver.name());
        let (ra, rb) = (&a.report.pipelines, &b.report.pipelines);
        assert!(ra.iter().all(|p| p.driver_specialized.is_none()), "{}: {ra:?}", solver.name());
        assert!(rb.iter().filter(|p| !p.reused).all(|p| p.driver_specialized.is_some()), "{}: {rb:?}", solver.name());
    }
    assert_clean(&host);
    assert_clean(&driver);
}
