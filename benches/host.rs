//! Host-side hot paths, measured with criterion: scene loading (TOML parse and validation,
//! the .vol read), grid work (the majorant grid built before every upload, CPU trilinear
//! sampling), SPIR-V reflection of every embedded shader, and the lbl solver's host work
//! (raymaps, the lattice energy count). Nothing here needs a GPU.
//!
//! `cargo bench` runs them all (about a minute on two cores); `cargo bench -- grid` runs
//! one group, `cargo bench -- --quick` a faster, rougher pass.

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, SamplingMode, Throughput};
use glam::Vec3;
use scatterlab::gpu::reflect;
use scatterlab::physics::rng::Pcg32;
use scatterlab::scene::{Density, Grid, LoadOptions, Scene};
use scatterlab::solvers::parts::gpu_scene::{majorant_dims, majorant_grid, MAJORANT_CELL};
use scatterlab::solvers::parts::lattice::{lattice_content, Lattice, LatticeGeom};
use scatterlab::solvers::parts::marching::raymaps;

fn scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(name)
}

fn load(name: &str) -> Scene {
    Scene::load(&scene_path(name), &[], &LoadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn cloud_grid(scene: &Scene) -> &Grid {
    match &scene.medium.density {
        Density::Grid(g) => g,
        other => panic!("cloud.toml: expected a grid density, got {other:?}"),
    }
}

fn file_len(p: &Path) -> u64 {
    std::fs::metadata(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())).len()
}

fn scene_loading(c: &mut Criterion) {
    let mut g = c.benchmark_group("scene_load");
    g.warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3)).sample_size(20);
    let opts = LoadOptions::default();

    // Parse and validate a small analytic scene: all TOML, no grid.
    let sphere = scene_path("homogeneous-sphere.toml");
    g.throughput(Throughput::Bytes(file_len(&sphere)));
    g.bench_function("homogeneous-sphere", |b| b.iter(|| Scene::load(black_box(&sphere), &[], &opts).unwrap()));

    // The cloud: the TOML plus the 64^3 float32 .vol (1 MiB) read and checked.
    let cloud = scene_path("cloud.toml");
    let bytes = file_len(&cloud) + file_len(&scene_path("cloud64.vol"));
    g.throughput(Throughput::Bytes(bytes));
    g.bench_function("cloud-64^3", |b| b.iter(|| Scene::load(black_box(&cloud), &[], &opts).unwrap()));
    g.finish();
}

fn grid_work(c: &mut Criterion) {
    let cloud = load("cloud.toml");
    let grid = cloud_grid(&cloud);

    let mut g = c.benchmark_group("grid");
    g.warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3)).sample_size(20);

    // The majorant grid GpuScene::upload builds from the density before every render.
    let voxels = |d: [u32; 3]| d.iter().map(|&n| n as u64).product::<u64>();
    g.throughput(Throughput::Elements(voxels(grid.dims)));
    let md = majorant_dims(grid.dims, MAJORANT_CELL);
    g.bench_function("majorant/cloud-64^3", |b| {
        b.iter(|| majorant_grid(black_box(grid.dims), black_box(&grid.data), md))
    });

    // A synthetic 256^3 grid (64 MiB): the size a production cloud would have.
    let n = 256u32;
    let dims = [n; 3];
    let big: Vec<f32> = (0..voxels(dims))
        .map(|i| {
            let (x, y, z) = ((i % 256) as f32, ((i / 256) % 256) as f32, (i / 65536) as f32);
            ((x * 0.05).sin() * (y * 0.07).cos() * (z * 0.03).sin()).max(0.0)
        })
        .collect();
    g.throughput(Throughput::Elements(voxels(dims)));
    let md = majorant_dims(dims, MAJORANT_CELL);
    // A third of a second per call: ten flat samples of one call each.
    g.sampling_mode(SamplingMode::Flat).sample_size(10).measurement_time(Duration::from_secs(6));
    g.bench_function("majorant/synthetic-256^3", |b| b.iter(|| majorant_grid(black_box(dims), black_box(&big), md)));
    g.sampling_mode(SamplingMode::Auto).sample_size(20).measurement_time(Duration::from_secs(3));

    // CPU trilinear sampling (the reference kernels' density lookup) at random points.
    const POINTS: usize = 65536;
    let mut rng = Pcg32::new(7, 1);
    let points: Vec<Vec3> = (0..POINTS).map(|_| Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32())).collect();
    g.throughput(Throughput::Elements(POINTS as u64));
    g.bench_function("sample/cloud-64^3", |b| {
        b.iter(|| {
            let mut sum = 0f32;
            for p in black_box(&points) {
                sum += grid.sample(*p);
            }
            sum
        })
    });
    g.finish();
}

fn reflection(c: &mut Criterion) {
    let mut g = c.benchmark_group("reflect");
    g.warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1)).sample_size(20);
    let kernels = scatterlab::solvers::kernels();
    for src in kernels.iter().map(|k| &k.shader) {
        g.throughput(Throughput::Bytes(src.spirv.len() as u64));
        g.bench_with_input(BenchmarkId::from_parameter(src.name), src, |b, src| {
            b.iter(|| reflect(black_box(src)).unwrap())
        });
    }
    // Every shader once, as a pipeline cache miss on all of them would cost.
    g.throughput(Throughput::Bytes(kernels.iter().map(|k| k.shader.spirv.len() as u64).sum()));
    g.bench_function("all", |b| {
        b.iter(|| {
            for src in kernels.iter().map(|k| &k.shader) {
                black_box(reflect(black_box(src)).unwrap());
            }
        })
    });
    g.finish();
}

fn lbl_host(c: &mut Criterion) {
    let cloud = load("cloud.toml");
    let mut g = c.benchmark_group("lbl");
    g.warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3)).sample_size(20);

    // The raymaps with the solver's defaults (lbl.grid 64, 65536 rays per light, 14
    // environment directions, step half a voxel); throughput counts the rays produced.
    let geom = LatticeGeom::new(&cloud, 64);
    let (rays, env_lights, step) = (65536, 14, geom.lambda * 0.5);
    let produced = raymaps(&cloud, &geom, rays, env_lights, step, cloud.render.seed).len() as u64;
    g.throughput(Throughput::Elements(produced));
    g.bench_function("raymaps/cloud-65536", |b| {
        b.iter(|| raymaps(black_box(&cloud), &geom, rays, env_lights, step, cloud.render.seed))
    });

    // The energy still in a lattice state, read back and counted on the host after every
    // round: a 64^3, 3-channel state per lattice; throughput counts voxels.
    let dims = [64u32; 3];
    let v = 64usize * 64 * 64;
    g.sampling_mode(SamplingMode::Flat).sample_size(10);
    for lattice in [Lattice::D3q6, Lattice::D3q18] {
        let nch = 3u32;
        let mut rng = Pcg32::new(11, 2);
        let state: Vec<f32> = (0..(lattice.links() as usize + 1) * nch as usize * v).map(|_| rng.next_f32()).collect();
        g.throughput(Throughput::Elements(v as u64));
        let id = format!("lattice_content/{}-64^3x3", if lattice == Lattice::D3q6 { "d3q6" } else { "d3q18" });
        g.bench_function(id, |b| b.iter(|| lattice_content(black_box(&state), dims, nch, lattice)));
    }
    g.finish();
}

criterion_group!(benches, scene_loading, grid_work, reflection, lbl_host);
criterion_main!(benches);
