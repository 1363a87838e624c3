//! glsl/include/one_minus_exp.glsl on the device (glsl/probe/extinction.comp) against double
//! precision: the share of light a step of optical depth x extinguishes, 1 - exp(-x), and its
//! mean transmittance, (1 - exp(-x)) / x, from 1e-9 mean free paths to 80, the quotient for
//! either sign (the view march's step fit takes it of a depth difference). Beside them the plain
//! float forms, to show the cancellation the header is for is real on this device.

use scatterlab::gpu::{Pass, QueueRole};
use scatterlab::solvers::parts::probes::{ExtinctionPush, EXTINCTION};

use crate::common::{assert_clean, gpu};

#[test]
fn one_minus_exp_keeps_its_precision_from_thin_steps_to_thick() {
    let gpu = gpu();
    // Depths log-spaced over 1e-9 .. 80, both signs for the quotient (-x only up to 20:
    // exp(20) is still finite in float).
    let mut xs: Vec<f32> = (0..=2000).map(|i| 1e-9f32 * 10f32.powf(i as f32 * 10.9 / 2000.0)).collect();
    xs.extend((0..=1600).map(|i| -1e-9f32 * 10f32.powf(i as f32 * 10.3 / 1600.0)));
    let p = gpu.pipeline(&EXTINCTION, &[]).unwrap();
    let input = gpu.buffer_with("depths", &xs).unwrap();
    let out = gpu.buffer("values", xs.len() as u64 * 16).unwrap();
    let pass = Pass::new("probe.extinction", QueueRole::Trace, &p)
        .read(0, &input)
        .write(1, &out)
        .push(&ExtinctionPush { count: xs.len() as u32 })
        .cover([xs.len() as u32, 1, 1]);
    let point = gpu.submit(QueueRole::Trace, &[pass], &[]).unwrap();
    gpu.wait(point).unwrap();
    let v: Vec<[f32; 4]> = gpu.read_buffer_as(&out).unwrap();
    let rel = |got: f32, exact: f64| ((got as f64 - exact) / exact).abs();
    // Worst relative errors: the header's and the plain forms', where |x| < 0.1 and above.
    let (mut ours_thin, mut ours_thick, mut plain_thin) = (0f64, 0f64, 0f64);
    for (x, r) in xs.iter().zip(&v) {
        let x64 = *x as f64;
        let a = x64.abs();
        let share = -(-a).exp_m1();
        let mean = if x64 == 0.0 { 1.0 } else { -(-x64).exp_m1() / x64 };
        assert!(r.iter().take(2).all(|q| q.is_finite()), "x {x}: {r:?}");
        let e = if x64 > 0.0 { rel(r[0], share).max(rel(r[1], mean)) } else { rel(r[1], mean) };
        if a < 0.1 {
            ours_thin = ours_thin.max(e);
            if (1e-6..1e-4).contains(&a) {
                plain_thin = plain_thin.max(rel(r[2], share).max(rel(r[3], mean)));
            }
        } else {
            ours_thick = ours_thick.max(e);
        }
    }
    eprintln!(
        "worst relative error: one_minus_exp(_over) {ours_thin:.2e} below 0.1, {ours_thick:.2e} above; \
         the plain float forms {plain_thin:.2e} at 1e-6 .. 1e-4"
    );
    // The series is good to float rounding; above 0.1 the subtraction loses at most 2^-24 / 0.1
    // of the value (6e-7), plus exp's own error. (The switch at 0.01 gave 1.5e-5 above it.)
    assert!(ours_thin < 1e-6, "below 0.1: {ours_thin:e}");
    assert!(ours_thick < 3e-6, "above 0.1: {ours_thick:e}");
    // What it replaces: at depths of 1e-6 .. 1e-4 the plain forms keep a few bits at most.
    assert!(plain_thin > 1e-3, "the plain forms were {plain_thin:e} off: nothing to guard against?");
    assert_clean(&gpu);
}
