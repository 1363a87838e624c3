//! Set-up without round trips (issue 42 item 4): where device memory is not host-visible, new
//! buffers are zeroed and uploads staged through one ring and submitted with the next
//! submission, instead of a submission and a host wait each. lavapipe's memory is host-visible,
//! so these tests open it a second time as if it were not (`unmapped_device_memory`): that device
//! takes the staged path a discrete GPU takes, and must give the same images, bit for bit.

use scatterlab::gpu::{Gpu, GpuOptions};
use scatterlab::scene::Scene;
use scatterlab::solvers::{self, RenderOutput, Solver};

use crate::common::{assert_clean, gpu, repo_scene, try_render};

fn unmapped() -> Gpu {
    Gpu::new(&GpuOptions { validate: true, unmapped_device_memory: true, ..GpuOptions::default() })
        .expect("a validated device")
}

/// Each solver's knobs for a quick render (networks and dom below their defaults: CI time).
fn knobs(solver: &str) -> Vec<(&'static str, &'static str)> {
    match solver {
        "lbl" => vec![("lbl.grid", "32"), ("lbl.deterministic", "true")],
        "networks" => vec![("networks.particles", "256"), ("networks.directions", "32")],
        "dom" => vec![("dom.grid", "16"), ("dom.directions", "s4"), ("dom.rays", "4096")],
        "sh-single" => vec![("sh-single.samples", "500"), ("sh-single.order", "3")],
        _ => vec![],
    }
}

fn render(gpu: &Gpu, scene: &Scene, solver: &dyn Solver) -> RenderOutput {
    let out = try_render(gpu, scene, solver, &knobs(solver.name()), false)
        .unwrap_or_else(|e| panic!("{}: {e}", solver.name()));
    assert_clean(gpu);
    out
}

#[test]
fn staged_setup_gives_the_same_images_without_a_wait_per_buffer() {
    let mapped = gpu();
    let staged = unmapped();
    let size = [("render.width", "16"), ("render.height", "16")];
    let every: Vec<&str> = solvers::names();
    let scenes = [
        ("sphere", repo_scene("scenes/homogeneous-sphere.toml", &size), every),
        // A density grid to upload and a point light inside it (wavefront traces it): the
        // solvers that build volumes of their own from it (the others only sample it, as on
        // the sphere; CI time).
        (
            "point light in cloud",
            repo_scene("scenes/point-light-in-cloud.toml", &size),
            vec!["single", "lbl", "wavefront"],
        ),
    ];
    let mut staged_buffers = 0;
    for (what, scene, names) in &scenes {
        for &name in names {
            let started = std::time::Instant::now();
            let solver = solvers::find(name).unwrap();
            let a = render(&mapped, scene, solver);
            let b = render(&staged, scene, solver);
            assert_eq!(a.image.data, b.image.data, "{name} on the {what}: staged set-up changed the image");
            let (ha, hb) = (&a.report.host, &b.report.host);
            // Every device buffer was zeroed, most written: as many round trips before this
            // change. Now none of them waits; the staged device's extra waits are its
            // readbacks' copies (the mapped device reads through its mapping).
            staged_buffers += hb.fills.count + hb.uploads.count;
            println!(
                "{name} on the {what}: waits {} mapped, {} staged ({} fills, {} uploads, {} readbacks), {:.1} s",
                ha.waits.count,
                hb.waits.count,
                hb.fills.count,
                hb.uploads.count,
                hb.readbacks.count,
                started.elapsed().as_secs_f64()
            );
            assert!(
                hb.waits.count <= ha.waits.count + hb.readbacks.count,
                "{name} on the {what}: {} host waits staged against {} mapped with {} readbacks: set-up work waited \
                 for",
                hb.waits.count,
                ha.waits.count,
                hb.readbacks.count
            );
        }
    }
    assert!(staged_buffers > 50, "the renders staged only {staged_buffers} fills and uploads");
}

/// Uploads past the ring's size: the ring wraps, submits what holds the space it needs or waits
/// for it, and no byte is lost; a fill recorded after an upload into the same buffer wins.
#[test]
fn the_upload_ring_wraps_without_losing_a_byte() {
    let gpu = unmapped();
    let before = gpu.setup_submissions();
    // 40 uploads of 3 MiB: 120 MiB through a 32 MiB ring, with no submission in between.
    let buffers: Vec<_> = (0..40u32)
        .map(|i| {
            let data: Vec<u32> = (0..(3 << 18)).map(|j| j ^ i.wrapping_mul(0x9e37_79b9)).collect();
            gpu.buffer_with(&format!("ring test {i}"), &data).unwrap()
        })
        .collect();
    // An upload at an offset, then a fill of another buffer after its upload.
    gpu.write_buffer(&buffers[3], 8, bytemuck::cast_slice(&[7u32, 8, 9])).unwrap();
    gpu.fill_zero(&buffers[5]).unwrap();
    for (i, b) in buffers.iter().enumerate() {
        let got: Vec<u32> = gpu.read_buffer_as(b).unwrap();
        let mut want: Vec<u32> = (0..(3u32 << 18)).map(|j| j ^ (i as u32).wrapping_mul(0x9e37_79b9)).collect();
        if i == 3 {
            want[2..5].copy_from_slice(&[7, 8, 9]);
        }
        if i == 5 {
            want.iter_mut().for_each(|w| *w = 0);
        }
        assert!(got == want, "buffer {i} differs after staging");
    }
    let flushes = gpu.setup_submissions() - before;
    // 120 MiB through 32 MiB: at least three submissions to free the space, a handful more.
    assert!((3..=12).contains(&flushes), "{flushes} set-up submissions");
    assert_clean(&gpu);
}

/// A 3D image (a density grid) is staged and uploaded with the next submission's set-up work:
/// no submission and no host wait of its own (one per grid before), on a mapped device too
/// (images are always in device memory). What the render then reads is checked bit for bit by
/// tools/render-digest and the grid scenes above.
#[test]
fn a_grid_upload_waits_for_nothing() {
    for gpu in [gpu(), unmapped()] {
        let data: Vec<f32> = (0..32 * 16 * 8).map(|i| i as f32 * 0.5).collect();
        let before = gpu.setup_submissions();
        gpu.take_host_times();
        let image = gpu.image3d_with("grid", [32, 16, 8], scatterlab::gpu::VolumeFormat::R32F, &data).unwrap();
        let host = gpu.take_host_times();
        assert_eq!(host.waits.count, 0, "uploading a grid waited {} times", host.waits.count);
        assert_eq!(host.uploads.bytes, 32 * 16 * 8 * 4, "the grid's upload is not counted as one");
        assert_eq!(gpu.setup_submissions(), before, "the grid was submitted on its own");
        // The next submission carries it (an empty one here), and the device stays clean.
        let point = gpu.submit(scatterlab::gpu::QueueRole::Trace, &[], &[]).unwrap();
        gpu.wait(point).unwrap();
        assert_eq!(gpu.setup_submissions(), before + 1, "the grid's upload went with no submission");
        assert_eq!(image.dims(), [32, 16, 8]);
        assert_clean(&gpu);
    }
}
