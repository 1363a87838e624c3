//! The Vulkan core on the test device: reflection, pass checking, the host-order rule, queue
//! roles and timeline semaphores, timestamps, limits.

use scatterlab::gpu::{reflect, BindingKind, GpuError, Pass, QueueRole, SyncPoint};
use scatterlab::solvers::parts::gpu_scene::{majorant_dims, majorant_grid, SceneHeader};
use scatterlab::solvers::parts::probes::{PhasePush as ProbePush, PHASE};
use scatterlab::solvers::parts::view;
use scatterlab::solvers::path;

use crate::common::{assert_clean, gpu};

#[test]
fn scene_kernels_share_a_layout() {
    for src in [path::TRACE.shader, view::MARCH.shader] {
        let r = reflect(&src).unwrap();
        assert_eq!(r.bindings[&0].0, BindingKind::StorageBuffer, "{}: binding 0 is the scene block", src.name);
        assert_eq!(r.bindings[&1].0, BindingKind::StorageImage, "{}: binding 1 is the density volume", src.name);
        assert_eq!(r.bindings[&2].0, BindingKind::StorageBuffer, "{}: binding 2 is the majorant grid", src.name);
    }
    // The scene block header is 11 vec4s in scene_block.glsl (the 11th: the emission grid's
    // size), then the material table (MAX_MATERIALS entries of 4 vec4s: coefficients, ior,
    // emission) and the density fields' (of 5).
    assert_eq!(std::mem::size_of::<SceneHeader>(), (11 + 9 * scatterlab::scene::MAX_MATERIALS) * 16);
}

#[test]
fn pass_bindings_are_checked_against_reflection() {
    let gpu = gpu();
    let p = gpu.pipeline(&PHASE, &[]).unwrap();
    let a = gpu.buffer("a", 64).unwrap();
    let push = ProbePush { g: 0.0, count: 0, eval_count: 0, seed: 0 };
    // Missing binding 2.
    let pass = Pass::new("probe.missing", QueueRole::Trace, &p).write(0, &a).read(1, &a).push(&push);
    let e = gpu.submit(QueueRole::Trace, &[pass], &[]).expect_err("must fail");
    let msg = e.to_string();
    assert!(matches!(e, GpuError::Binding { binding: 2, .. }), "{msg}");
    assert!(msg.contains("probe.missing") && msg.contains("binding 2"), "{msg}");
    // A binding the shader does not declare.
    let img = gpu.image3d_with("vol", [1, 1, 1], scatterlab::gpu::VolumeFormat::R32F, &[0.0]).unwrap();
    let pass =
        Pass::new("probe.extra", QueueRole::Trace, &p).write(0, &a).read(1, &a).write(2, &a).read(7, &img).push(&push);
    let msg = gpu.submit(QueueRole::Trace, &[pass], &[]).expect_err("must fail").to_string();
    assert!(msg.contains("probe.extra") && msg.contains("binding 7"), "{msg}");
    // An image where a buffer is declared.
    let pass = Pass::new("probe.kind", QueueRole::Trace, &p).write(0, &img).read(1, &a).write(2, &a).push(&push);
    let msg = gpu.submit(QueueRole::Trace, &[pass], &[]).expect_err("must fail").to_string();
    assert!(msg.contains("probe.kind") && msg.contains("binding 0"), "{msg}");
    // Wrong push-constant size.
    let pass = Pass::new("probe.push", QueueRole::Trace, &p).write(0, &a).read(1, &a).write(2, &a).push(&0u32);
    let msg = gpu.submit(QueueRole::Trace, &[pass], &[]).expect_err("must fail").to_string();
    assert!(msg.contains("probe.push") && msg.contains("push constants"), "{msg}");
    assert_clean(&gpu);
}

#[test]
fn a_wait_before_its_signal_is_refused_not_deadlocked() {
    let gpu = gpu();
    let p = gpu.pipeline(&PHASE, &[]).unwrap();
    let a = gpu.buffer("a", 64).unwrap();
    let push = ProbePush { g: 0.0, count: 0, eval_count: 0, seed: 0 };
    let pass = Pass::new("probe", QueueRole::Diffuse, &p).write(0, &a).read(1, &a).write(2, &a).push(&push);
    let future = SyncPoint { role: QueueRole::Trace, value: gpu.submitted(QueueRole::Trace).value + 1 };
    let e = gpu.submit(QueueRole::Diffuse, &[pass], &[future]).expect_err("must be refused");
    assert!(matches!(e, GpuError::WaitBeforeSignal { .. }), "{e}");
    assert!(e.to_string().contains("deadlock"));
    assert_clean(&gpu);
}

/// A chain trace -> diffuse -> trace through timeline semaphores computes the right values on
/// any queue mapping, including lavapipe's single shared queue.
#[test]
fn roles_chain_through_timeline_semaphores() {
    let gpu = gpu();
    let p = gpu.pipeline(&PHASE, &[]).unwrap();
    let n = 256u32;
    let cos: Vec<f32> = (0..n).map(|i| -1.0 + 2.0 * i as f32 / (n - 1) as f32).collect();
    let cos_buf = gpu.buffer_with("cos", &cos).unwrap();
    let samples = gpu.buffer("samples", n as u64 * 16).unwrap();
    let eval = gpu.buffer("eval", n as u64 * 4).unwrap();
    let mk = |name: &str, role, g: f32| {
        Pass::new(name, role, &p)
            .write(0, &samples)
            .read(1, &cos_buf)
            .write(2, &eval)
            .push(&ProbePush { g, count: n, eval_count: n, seed: 1 })
            .cover([n, 1, 1])
    };
    let t1 = gpu.submit(QueueRole::Trace, &[mk("t1", QueueRole::Trace, 0.3)], &[]).unwrap();
    let d1 = gpu.submit(QueueRole::Diffuse, &[mk("d1", QueueRole::Diffuse, -0.4)], &[t1]).unwrap();
    let t2 = gpu.submit(QueueRole::Trace, &[mk("t2", QueueRole::Trace, 0.7)], &[d1]).unwrap();
    gpu.wait(t2).unwrap();
    let out: Vec<f32> = gpu.read_buffer_as(&eval).unwrap();
    for (c, v) in cos.iter().zip(&out) {
        let want = scatterlab::physics::phase::hg_eval(0.7, *c);
        assert!((v - want).abs() <= 1e-5 * want.max(1.0), "last writer wins: got {v}, want {want}");
    }
    let timings = gpu.take_timings();
    let names: Vec<&str> = timings.iter().map(|t| t.name.as_str()).collect();
    for want in ["t1", "d1", "t2"] {
        assert!(names.contains(&want), "timestamps for {want}: {names:?}");
    }
    let d1t = timings.iter().find(|t| t.name == "d1").unwrap();
    assert_eq!(d1t.role, QueueRole::Diffuse);
    for t in &timings {
        assert!(t.end_ns >= t.start_ns, "{}: negative duration", t.name);
    }
    // Ordering holds on the host clock: d1 starts after t1 ends (it waited on it).
    let t1t = timings.iter().find(|t| t.name == "t1").unwrap();
    if t1t.host_clock && d1t.host_clock {
        assert!(d1t.start_ns >= t1t.end_ns - 1_000, "d1 started before t1 ended");
    }
    assert_clean(&gpu);
}

#[test]
fn bindings_beyond_max_storage_buffer_range_are_refused() {
    let gpu = gpu();
    let max = gpu.info().max_storage_buffer_range;
    let e = gpu.buffer("huge", max + 4).err().expect("must be refused");
    assert!(matches!(e, GpuError::BindingTooLarge { .. }));
    assert!(e.to_string().contains("maxStorageBufferRange"), "{e}");
    assert_clean(&gpu);
}

#[test]
fn buffers_round_trip() {
    let gpu = gpu();
    let data: Vec<u32> = (0..1000).map(|i| i * 7 + 3).collect();
    let b = gpu.buffer_with("round trip", &data).unwrap();
    let back: Vec<u32> = gpu.read_buffer_as(&b).unwrap();
    assert_eq!(back, data);
    let z = gpu.buffer("zeroed", 4096).unwrap();
    assert!(gpu.read_buffer(&z).unwrap().iter().all(|b| *b == 0));
    assert_clean(&gpu);
}

/// The host-work counters (reports' `host`) count what the core did, with the bytes it moved,
/// and start again from zero once taken.
#[test]
fn host_work_is_counted() {
    let gpu = gpu();
    gpu.take_host_times();
    let data: Vec<u32> = (0..1000).collect();
    let b = gpu.buffer_with("counted", &data).unwrap();
    let _z = gpu.buffer("counted zeros", 4096).unwrap();
    let back = gpu.read_buffer(&b).unwrap();
    assert_eq!(back.len(), 4000);
    let h = gpu.take_host_times();
    assert!(h.allocations.count >= 2, "{h:?}");
    assert!(h.allocations.bytes >= 4000 + 4096, "{h:?}");
    assert_eq!(h.fills.count, 2, "{h:?}");
    assert_eq!(h.fills.bytes, 4000 + 4096, "{h:?}");
    assert_eq!((h.uploads.count, h.uploads.bytes), (1, 4000), "{h:?}");
    assert_eq!((h.readbacks.count, h.readbacks.bytes), (1, 4000), "{h:?}");
    assert!([h.allocations.ms, h.fills.ms, h.uploads.ms, h.readbacks.ms].iter().all(|ms| *ms >= 0.0 && ms.is_finite()));
    let again = gpu.take_host_times();
    assert_eq!(again, scatterlab::gpu::HostTimes::default());
    assert_clean(&gpu);
}

/// The transfer role copies between buffers made for it (host staging and transfer buffers),
/// ordered against the compute roles by timeline semaphores, and refuses any other buffer (on
/// a device with a transfer-only family its queue could not touch one).
#[test]
fn transfer_role_copies_only_buffers_made_for_it() {
    use scatterlab::gpu::Copy;
    let gpu = gpu();
    let n = 256u64;
    let (stage, ptr) = gpu.host_buffer("transfer staging", n * 4).unwrap();
    let data: Vec<f32> = (0..n).map(|i| i as f32 * 0.5).collect();
    unsafe { std::ptr::copy_nonoverlapping(data.as_ptr() as *const u8, ptr, (n * 4) as usize) };
    let pool = gpu.transfer_buffer("transfer pool", n * 4).unwrap();
    let up = Copy { src: stage.clone(), src_offset: 0, dst: pool.clone(), dst_offset: 0, size: n * 4 };
    let p = gpu.submit_copies(QueueRole::Transfer, &[vec![up]], &[]).unwrap();
    assert_eq!(p.role, QueueRole::Transfer);
    gpu.wait(p).unwrap();
    let back: Vec<f32> = gpu.read_buffer_as(&pool).unwrap();
    assert_eq!(back, data);
    let plain = gpu.buffer("plain", n * 4).unwrap();
    let bad = Copy { src: stage.clone(), src_offset: 0, dst: plain, dst_offset: 0, size: n * 4 };
    let e = gpu.submit_copies(QueueRole::Transfer, &[vec![bad]], &[]).unwrap_err().to_string();
    assert!(e.contains("\"plain\"") && e.contains("transfer_buffer"), "{e}");
    // The copy is timed on the transfer role's track.
    let timings = gpu.take_timings();
    assert!(timings.iter().any(|t| t.role == QueueRole::Transfer && t.name == "copies"), "{timings:?}");
    assert_clean(&gpu);
}

/// The majorant grid bounds the trilinear density everywhere (a low majorant would bias
/// delta tracking): dense random points against the CPU reference interpolation.
#[test]
fn majorant_grid_bounds_trilinear_density() {
    let dims = [13u32, 7, 10];
    let mut rng = scatterlab::physics::rng::Pcg32::new(7, 1);
    let data: Vec<f32> = (0..dims.iter().product::<u32>()).map(|_| rng.next_f32().powi(4)).collect();
    for cell in [1u32, 2, 4, 5] {
        let m = majorant_dims(dims, cell);
        let maj = majorant_grid(dims, &data, m);
        let grid = scatterlab::scene::Grid { dims, data: data.clone(), file: "mem".into() };
        for _ in 0..20000 {
            let u = glam::Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let d = grid.sample(u);
            let c = [0, 1, 2].map(|a| ((u[a] * m[a] as f32) as u32).min(m[a] - 1));
            let bound = maj[(c[0] + m[0] * (c[1] + m[1] * c[2])) as usize];
            assert!(d <= bound + 1e-6, "cell {c:?} (edge {cell}): density {d} above majorant {bound}");
        }
    }
}

#[test]
fn queue_mapping_is_reported() {
    let gpu = gpu();
    let info = gpu.info();
    assert!(!info.name.is_empty());
    let fams = &info.queue_families;
    assert!(fams.iter().any(|f| f.index == info.mapping.trace.family && f.compute));
    if info.driver_name.to_lowercase().contains("llvmpipe") || info.name.to_lowercase().contains("llvmpipe") {
        // Lavapipe: one family, one queue; both roles share it.
        assert!(info.mapping.shared());
        assert!(info.software);
    }
    assert_clean(&gpu);
}

/// Tests run with the validation layer, and an error-severity message is counted (so
/// `assert_clean` can fail a test).
#[test]
fn validation_errors_are_counted() {
    let gpu = gpu();
    assert!(gpu.validation_enabled(), "GPU tests must run with the validation layer");
    assert_eq!(gpu.validation_errors(), 0);
    assert!(gpu.inject_validation_error_for_test("scatterlab test: injected error"));
    assert_eq!(gpu.validation_errors(), 1);
    assert!(gpu.validation_messages()[0].contains("injected"));
}

/// Closing a device with work in flight (a render that returned an error mid-flight, a test
/// that panicked, a timeout) frees nothing the device still uses: the last handle waits for the
/// work before the submissions' buffers go. Before, the buffers were destroyed under the
/// running copies (the validation layer: VUID-vkDestroyBuffer-buffer-00922; on lavapipe its
/// threads then wrote freed memory). The copies here (1 GiB through the compute queue) are still
/// running when the handle drops: the test checks that they were, so it cannot pass vacuously.
#[test]
fn closing_a_device_with_work_in_flight_frees_nothing_under_it() {
    use scatterlab::gpu::Copy;
    let gpu = gpu();
    let log = gpu.validation_log();
    let n = 128u64 << 20;
    let a = gpu.buffer("in flight a", n).unwrap();
    let b = gpu.buffer("in flight b", n).unwrap();
    let stage: Vec<Copy> = vec![Copy { src: a.clone(), src_offset: 0, dst: b.clone(), dst_offset: 0, size: n }];
    let point = gpu.submit_copies(QueueRole::Trace, &vec![stage; 8], &[]).unwrap();
    drop((a, b));
    let running = !gpu.reached(point).unwrap();
    drop(gpu);
    let errors = log.errors.load(std::sync::atomic::Ordering::SeqCst);
    let messages = log.first_errors.lock().unwrap().clone();
    assert_eq!(errors, 0, "closing the device with work in flight: {messages:#?}");
    assert!(running, "the copies had finished before the device was closed: the test proved nothing");
}

/// `scatterlab view`'s device tone map (glsl/view/tonemap.comp) against the PNG writer's host
/// operator (`output::tonemap_rgb8`), over radiances from 1e-6 to 1e5 on a log scale, zero,
/// negatives, NaN and infinities, at exposures of -3, 0 and +2.5 stops: the same bytes but where
/// the device's float arithmetic rounds across an 8-bit step (at most 1, in few channels).
#[test]
fn the_device_tone_map_is_the_png_writers() {
    let gpu = gpu();
    let mut values: Vec<f32> = (0..3000).map(|i| 10f32.powf(-6.0 + 11.0 * i as f32 / 2999.0)).collect();
    values.extend([0.0, -1.0, -1e-3, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e30, f32::MIN_POSITIVE]);
    while values.len() % 3 != 0 {
        values.push(0.5);
    }
    let w = (values.len() / 3) as u32;
    for exposure in [-3.0f32, 0.0, 2.5] {
        let image = scatterlab::output::Image { width: w, height: 1, data: values.clone() };
        let host = scatterlab::output::tonemap_rgb8(&image, exposure);
        let device = scatterlab::gpu::tonemap_on_device(&gpu, &values, exposure).unwrap();
        assert_eq!(host.len(), device.len());
        let differ = host.iter().zip(&device).filter(|(a, b)| a != b).count();
        let worst = host.iter().zip(&device).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
        eprintln!("exposure {exposure:+}: {differ} of {} channels differ, by at most {worst}", host.len());
        assert!(worst <= 1, "exposure {exposure}: a channel differs by {worst}");
        assert!(differ * 100 <= host.len(), "exposure {exposure}: {differ} channels differ");
        // NaN and the infinities are magenta in both (NON_FINITE_RGB8); negatives black.
        let px = |i: usize| &device[3 * i..3 * i + 3];
        let at = |v: f32| values.iter().position(|x| x.to_bits() == v.to_bits()).unwrap() / 3;
        assert_eq!(px(at(f32::NAN)), scatterlab::output::png::NON_FINITE_RGB8);
        assert_eq!(px(at(f32::INFINITY)), scatterlab::output::png::NON_FINITE_RGB8);
    }
    assert_clean(&gpu);
}
