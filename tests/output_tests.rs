//! Pure-Rust tests of `scatterlab::output`: EXR round trips, PNG previews, metrics on
//! hand-computed examples, atomic writes and JSON reports.

use std::path::Path;

use scatterlab::output::{
    compare, error_png, read_exr, read_exr_layer, write_atomically, write_exr, write_json, write_png_tonemapped, Image,
    OutputError, TONEMAP_DESCRIPTION,
};

fn ramp(width: u32, height: u32) -> Image {
    // Distinct, awkward values: negatives, subnormals, huge, tiny, non-dyadic.
    Image::from_fn(width, height, |x, y| {
        let v = (x as f32 + 0.1) * 1.37 - (y as f32) * 0.73;
        [v, v * 1e-30, 1.0 / (1.0 + v.abs()) * 3.3e7]
    })
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

// --- Image -------------------------------------------------------------------------------

#[test]
fn output_image_accessors() {
    let mut img = Image::new(3, 2);
    assert_eq!(img.data.len(), 18);
    img.set(2, 1, [1.0, 2.0, 3.0]);
    assert_eq!(img.get(2, 1), [1.0, 2.0, 3.0]);
    // Row-major, row 0 on top: (2, 1) is the last pixel.
    assert_eq!(&img.data[15..18], &[1.0, 2.0, 3.0]);
    assert_eq!(img.pixels().count(), 6);
    assert_eq!(img.mean(), [1.0 / 6.0, 2.0 / 6.0, 3.0 / 6.0]);
    assert_eq!(img.nan_inf_count(), 0);
    img.set(0, 0, [f32::NAN, 0.0, 0.0]);
    img.set(1, 0, [0.0, f32::INFINITY, f32::NEG_INFINITY]);
    assert_eq!(img.nan_inf_count(), 2);
    assert!(img.mean()[0].is_nan());
}

// --- EXR ---------------------------------------------------------------------------------

#[test]
fn output_exr_round_trip_is_bit_exact_with_variance_layer() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("render.exr");
    let mut radiance = ramp(17, 9);
    radiance.set(3, 4, [f32::NAN, f32::INFINITY, -0.0]);
    radiance.set(4, 4, [f32::MIN_POSITIVE / 4.0, f32::MAX, f32::EPSILON]);
    let variance = Image::from_fn(17, 9, |x, y| [x as f32 * 0.01, y as f32 * 0.02, 1e-12]);

    write_exr(&path, &[("", &radiance), ("variance", &variance)]).unwrap();
    assert_eq!(files_in(dir.path()), vec!["render.exr"], "no temporary file left behind");

    let back = read_exr(&path).unwrap();
    assert_eq!((back.width, back.height), (17, 9));
    let bits = |img: &Image| img.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&back), bits(&radiance), "main layer differs after round trip");
    let back_var = read_exr_layer(&path, "variance").unwrap();
    assert_eq!(bits(&back_var), bits(&variance), "variance layer differs after round trip");

    match read_exr_layer(&path, "albedo") {
        Err(err @ OutputError::MissingLayer { .. }) => {
            let msg = err.to_string();
            assert!(msg.contains("albedo") && msg.contains("variance.R") && msg.contains("render.exr"), "{msg}");
        }
        other => panic!("expected MissingLayer, got {other:?}"),
    }
}

#[test]
fn output_exr_rejects_mismatched_layers_and_missing_files() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.exr");
    let err = write_exr(&path, &[("", &Image::new(4, 4)), ("variance", &Image::new(4, 3))]).unwrap_err();
    assert!(matches!(err, OutputError::SizeMismatch { .. }), "{err}");
    assert!(!path.exists());
    let broken = Image { width: 2, height: 2, data: vec![0.0; 5] };
    assert!(matches!(write_exr(&path, &[("", &broken)]), Err(OutputError::InvalidImage { .. })));
    assert!(matches!(read_exr(&dir.path().join("absent.exr")), Err(OutputError::Exr { .. })));
    assert!(files_in(dir.path()).is_empty());
}

// --- PNG ---------------------------------------------------------------------------------

#[test]
fn output_png_has_the_right_size_and_marks_nan_magenta() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("preview.png");
    let mut img = Image::from_fn(13, 7, |x, _| [x as f32 * 0.1, 0.5, 4.0]);
    img.set(5, 2, [f32::NAN, 1.0, 1.0]);
    img.set(0, 0, [0.0, 0.0, 0.0]);
    write_png_tonemapped(&path, &img, 0.0).unwrap();
    assert_eq!(files_in(dir.path()), vec!["preview.png"]);

    let decoded = image::open(&path).unwrap().to_rgb8();
    assert_eq!(decoded.dimensions(), (13, 7));
    assert_eq!(decoded.get_pixel(5, 2).0, [255, 0, 255], "NaN must render magenta");
    assert_eq!(decoded.get_pixel(0, 0).0, [0, 0, 0], "black stays black");
    // Monotone in radiance along x (red channel), and exposure brightens.
    let reds: Vec<u8> = (1..13).filter(|&x| x != 5).map(|x| decoded.get_pixel(x, 3).0[0]).collect();
    assert!(reds.windows(2).all(|w| w[0] <= w[1]), "{reds:?}");
    let brighter = dir.path().join("brighter.png");
    write_png_tonemapped(&brighter, &img, 2.0).unwrap();
    let b = image::open(&brighter).unwrap().to_rgb8();
    assert!(b.get_pixel(3, 3).0[0] > decoded.get_pixel(3, 3).0[0]);
    assert!(TONEMAP_DESCRIPTION.contains("ACES") && TONEMAP_DESCRIPTION.contains("sRGB"));
}

// --- metrics -----------------------------------------------------------------------------

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * b.abs().max(1.0)
}

#[test]
fn output_metrics_hand_computed() {
    // Reference: two pixels, values 1..6. Image: reference plus errors chosen by hand.
    let reference = Image { width: 2, height: 1, data: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0] };
    let a = Image { width: 2, height: 1, data: vec![1.0, 2.0, 3.0, 4.0, 5.0, 8.0] };
    let m = compare(&a, &reference).unwrap();
    // diff = (0,0,0,0,0,2): ||d|| = 2, ||r|| = sqrt(91).
    assert!(close(m.rel_l2, 2.0 / 91f64.sqrt()), "rel_l2 {}", m.rel_l2);
    assert!(close(m.rel_mse, 4.0 / (36.0 + 0.01) / 6.0), "rel_mse {}", m.rel_mse);
    assert!(close(m.rmse, (4.0f64 / 6.0).sqrt()), "rmse {}", m.rmse);
    assert!(close(m.energy_ratio, 23.0 / 21.0), "energy {}", m.energy_ratio);
    assert!(close(m.max_abs_error, 2.0));
    assert_eq!((m.nan_inf_count, m.pixels), (0, 2));

    // Identical images: everything zero, energy ratio one.
    let m = compare(&reference, &reference).unwrap();
    assert_eq!((m.rel_l2, m.rel_mse, m.rmse, m.max_abs_error, m.energy_ratio), (0.0, 0.0, 0.0, 0.0, 1.0));
}

#[test]
fn output_metrics_count_and_exclude_non_finite_pixels() {
    let reference = Image { width: 3, height: 1, data: vec![1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 3.0, 3.0, 3.0] };
    let a = Image { width: 3, height: 1, data: vec![f32::NAN, 1.0, 1.0, 2.0, 2.0, 2.0, 3.0, 3.0, f32::INFINITY] };
    let m = compare(&a, &reference).unwrap();
    assert_eq!(m.nan_inf_count, 2);
    assert_eq!(m.pixels, 3);
    // Only the middle pixel remains, and it is exact: the bad pixels poison nothing.
    assert_eq!((m.rel_l2, m.rmse, m.max_abs_error, m.energy_ratio), (0.0, 0.0, 0.0, 1.0));

    // A non-finite reference is an error, not a silent NaN.
    let err = compare(&reference, &a).unwrap_err();
    assert!(matches!(err, OutputError::NonFiniteReference { count: 2 }), "{err}");
}

#[test]
fn output_metrics_size_mismatch_is_an_error() {
    let err = compare(&Image::new(4, 3), &Image::new(3, 4)).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, OutputError::SizeMismatch { .. }));
    assert!(msg.contains("4x3") && msg.contains("3x4"), "{msg}");
}

#[test]
fn output_error_png_and_json_report() {
    let dir = tempfile::tempdir().unwrap();
    let reference = Image::from_fn(8, 4, |x, _| [1.0, 1.0, 1.0 + x as f32]);
    let mut a = reference.clone();
    a.set(2, 2, [1.5, 1.0, 1.0]);
    a.set(3, 3, [f32::NAN, 0.0, 0.0]);
    let png = dir.path().join("error.png");
    error_png(&png, &a, &reference).unwrap();
    let decoded = image::open(&png).unwrap().to_rgb8();
    let (gap, bar) = scatterlab::output::metrics::error_map_legend_rows(4);
    assert_eq!(decoded.dimensions(), (8, 4 + gap + bar));
    // The legend: white gap, then the ramp from its dark end (left) to its bright end (right).
    assert_eq!(decoded.get_pixel(4, 4).0, [255, 255, 255]);
    assert_eq!(decoded.get_pixel(0, 4 + gap).0, [68, 1, 84]);
    assert_eq!(decoded.get_pixel(7, 4 + gap).0, [253, 231, 37]);
    assert_eq!(decoded.get_pixel(0, 4 + gap + bar - 1).0, [0, 0, 0], "a tick at 1e-4");
    assert_eq!(decoded.get_pixel(3, 3).0, [255, 0, 255]);
    assert_eq!(decoded.get_pixel(0, 0).0, [68, 1, 84], "zero error is the dark end of the ramp");
    assert_ne!(decoded.get_pixel(2, 2).0, [68, 1, 84]);
    assert!(error_png(&dir.path().join("x.png"), &a, &Image::new(2, 2)).is_err());

    let metrics = compare(&a, &reference).unwrap();
    let json_path = dir.path().join("metrics.json");
    write_json(&json_path, &metrics).unwrap();
    let text = std::fs::read_to_string(&json_path).unwrap();
    let value: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(value["nan_inf_count"], 1);
    assert_eq!(value["pixels"], 32);
    assert!(value["rel_l2"].as_f64().unwrap() > 0.0);
    assert!(text.ends_with('\n') && text.contains("\n  \"rel_l2\""), "pretty-printed");
}

// --- atomic writes -----------------------------------------------------------------------

#[test]
fn output_atomic_write_leaves_nothing_when_the_closure_fails() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("result.json");
    let err = write_atomically(&path, |tmp| {
        // Write half a file, then fail.
        std::fs::write(tmp, b"{\"half\": ").unwrap();
        Err(OutputError::Io {
            path: tmp.to_owned(),
            action: "write",
            source: std::io::Error::other("disk full (simulated)"),
        })
    })
    .unwrap_err();
    assert!(err.to_string().contains("disk full"));
    assert!(files_in(dir.path()).is_empty(), "left behind: {:?}", files_in(dir.path()));

    // A failure keeps an existing file intact.
    std::fs::write(&path, b"old").unwrap();
    let _ = write_atomically(&path, |tmp| {
        std::fs::write(tmp, b"new but broken").unwrap();
        Err(OutputError::NonFiniteReference { count: 1 })
    });
    assert_eq!(std::fs::read(&path).unwrap(), b"old");
    assert_eq!(files_in(dir.path()), vec!["result.json"]);

    // Success replaces it.
    write_atomically(&path, |tmp| {
        std::fs::write(tmp, b"new").map_err(|source| OutputError::Io { path: tmp.to_owned(), action: "write", source })
    })
    .unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), b"new");
    assert_eq!(files_in(dir.path()), vec!["result.json"]);
}

#[test]
fn output_writers_fail_cleanly_into_a_missing_directory() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("no-such-dir").join("out.png");
    let err = write_png_tonemapped(&path, &Image::new(2, 2), 0.0).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("no-such-dir") && msg.contains("exists"), "{msg}");
}

/// The noise floor's arithmetic on images with known variance: a noise-free image 0.5 above a
/// reference of 1 whose values have variance 0.01 measures sqrt(0.25 - 0.01) once the
/// reference's noise is removed; an image that differs by no more than both noises measures 0.
#[test]
fn noise_floor_removes_known_variance() {
    use scatterlab::output::metrics::noise_floor;
    let n = 10u32;
    let flat = |v: f32| Image::from_fn(n, n, |_, _| [v, v, v]);
    let (r, var_r) = (flat(1.0), flat(0.01));
    // Bias 0.5, no noise of its own: sum d^2 = 0.25 N, minus the reference's 0.01 N.
    let f = noise_floor(&flat(1.5), &r, None, Some(&var_r)).unwrap();
    assert!((f.reference.unwrap() - 0.1).abs() < 1e-6, "{f:?}");
    assert!(f.image.is_none());
    assert!((f.rel_l2_corrected.unwrap() - 0.24f64.sqrt()).abs() < 1e-6, "{f:?}");
    // The resolution: sqrt(2 sqrt(2 N 0.01^2) / N) with N = 300 values.
    let values = 3.0 * (n * n) as f64;
    let want = (2.0 * (2.0 * values * 1e-4).sqrt() / values).sqrt();
    assert!((f.resolution.unwrap() - want).abs() < 1e-6, "{f:?} vs {want}");
    // Differences no larger than both variances: no bias.
    let f = noise_floor(&flat(1.1), &r, Some(&flat(0.01)), Some(&var_r)).unwrap();
    assert_eq!(f.rel_l2_corrected, Some(0.0), "{f:?}");
    assert!((f.image.unwrap() - 0.1).abs() < 1e-6);
    // Without the reference's variance nothing can be said.
    let f = noise_floor(&flat(1.1), &r, Some(&var_r), None).unwrap();
    assert!(f.rel_l2_corrected.is_none() && f.reference.is_none() && f.resolution.is_none(), "{f:?}");
}
