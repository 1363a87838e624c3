//! Blackbody emission as linear sRGB: Planck's law integrated against the CIE 1931 2-degree
//! colour-matching functions, for media whose emission is a temperature field (`temperature =
//! { ... }` in a scene's medium; docs/scene-format.md, "Emission").
//!
//! **Units.** [`blackbody_xyz`] integrates the spectral radiance B(lambda, T) in W/(m^2 sr m)
//! over wavelength with the colour-matching functions (dimensionless, ybar peaking at 1), so
//! X, Y, Z are radiances in W/(m^2 sr): Y is B weighted by the eye's luminous efficiency
//! (without the 683 lm/W of photometry). [`blackbody_rgb`] converts XYZ to linear sRGB (D65
//! white: XYZ = (0.9505, 1, 1.089) is RGB (1, 1, 1)), so an emitter of this RGB radiance has the
//! blackbody's luminance and, within the sRGB gamut, its chromaticity; below about 1900 K the
//! blackbody lies outside the gamut on the red side, and the negative blue is clipped to 0.
//!
//! **Against pbrt-v4.** pbrt-v4's `BlackbodySpectrum(T)` is normalised to a peak of 1 (it
//! divides by B(lambda_max, T) = 4.0956e-15 T^5 W/(m^2 sr nm) at Wien's lambda_max) and its film
//! divides XYZ by the ybar integral (106.857 nm). So a medium with `emission_scale = 1` here
//! emits 4.0956e-15 T^5 x 106.857 = 4.376e-13 T^5 times the radiance of pbrt-v4's with
//! `Lescale 1` at the same temperature: 0.44 at 1000 K, 106 at 2000 K, 5.1e6 at 6500 K. We keep
//! Planck's absolute radiance because it is monotone in temperature at every wavelength (a
//! hotter voxel is never darker), which pbrt-v4's peak-normalised spectrum is not (its
//! luminance falls as T^-4 once the peak has passed into the ultraviolet). Physical radiances
//! span decades: Y is 3.9e-3 W/(m^2 sr) at 1000 K, 11 at 1500 K, 4.4e4 at 3000 K; scale them to
//! the scene with `emission_scale`.
//!
//! The integral is a sum over the 5 nm samples 360..830 nm of the table below (the 1 nm sum
//! differs by under 1e-5 in chromaticity and 1e-6 relative in Y at 1000-6500 K).

use glam::{DVec3, Vec3};

/// Planck's constant (J s), the speed of light (m/s) and Boltzmann's constant (J/K): CODATA
/// 2010, the values pbrt-v4 uses.
const H: f64 = 6.62606957e-34;
const C: f64 = 299_792_458.0;
const KB: f64 = 1.3806488e-23;

/// Spectral radiance of a blackbody at `lambda_nm` nanometres and `t` kelvin, W/(m^2 sr m):
/// Planck's law, 2 h c^2 / (lambda^5 (exp(h c / (lambda k T)) - 1)); 0 at or below 0 K.
pub fn planck(lambda_nm: f64, t: f64) -> f64 {
    if t <= 0.0 {
        return 0.0;
    }
    let l = lambda_nm * 1e-9;
    // exp_m1 keeps the Rayleigh-Jeans end (x -> 0) exact; a huge x overflows to +inf: radiance 0.
    2.0 * H * C * C / (l.powi(5) * (H * C / (l * KB * t)).exp_m1())
}

/// First wavelength of [`CIE_1931`], nm, and the step between its rows.
pub const CIE_FIRST_NM: f64 = 360.0;
pub const CIE_STEP_NM: f64 = 5.0;

/// The CIE 1931 2-degree standard observer's colour-matching functions xbar, ybar, zbar at 360,
/// 365, ..., 830 nm: every fifth row of the 1 nm table in pbrt-v4 (src/pbrt/util/spectrum.cpp,
/// `CIE_X`, `CIE_Y`, `CIE_Z`; Apache-2.0), which is the CIE's own table (CIE 015:2004, table T.4).
#[rustfmt::skip]
pub const CIE_1931: [[f64; 3]; 95] = [
    [0.0001299, 3.917e-06, 0.0006061],
    [0.0002321, 6.965e-06, 0.001086],
    [0.0004149, 1.239e-05, 0.001946],
    [0.0007416, 2.202e-05, 0.003486],
    [0.001368, 3.9e-05, 0.006450001],
    [0.002236, 6.4e-05, 0.01054999],
    [0.004243, 0.00012, 0.02005001],
    [0.00765, 0.000217, 0.03621],
    [0.01431, 0.000396, 0.06785001],
    [0.02319, 0.00064, 0.1102],
    [0.04351, 0.00121, 0.2074],
    [0.07763, 0.00218, 0.3713],
    [0.13438, 0.004, 0.6456],
    [0.21477, 0.0073, 1.0390501],
    [0.2839, 0.0116, 1.3856],
    [0.3285, 0.01684, 1.62296],
    [0.34828, 0.023, 1.74706],
    [0.34806, 0.0298, 1.7826],
    [0.3362, 0.038, 1.77211],
    [0.3187, 0.048, 1.7441],
    [0.2908, 0.06, 1.6692],
    [0.2511, 0.0739, 1.5281],
    [0.19536, 0.09098, 1.28764],
    [0.1421, 0.1126, 1.0419],
    [0.09564, 0.13902, 0.8129501],
    [0.05795001, 0.1693, 0.6162],
    [0.03201, 0.20802, 0.46518],
    [0.0147, 0.2586, 0.3533],
    [0.0049, 0.323, 0.272],
    [0.0024, 0.4073, 0.2123],
    [0.0093, 0.503, 0.1582],
    [0.0291, 0.6082, 0.1117],
    [0.06327, 0.71, 0.07824999],
    [0.1096, 0.7932, 0.05725001],
    [0.1655, 0.862, 0.04216],
    [0.2257499, 0.9148501, 0.02984],
    [0.2904, 0.954, 0.0203],
    [0.3597, 0.9803, 0.0134],
    [0.4334499, 0.9949501, 0.008749999],
    [0.5120501, 1.0, 0.005749999],
    [0.5945, 0.995, 0.0039],
    [0.6784, 0.9786, 0.002749999],
    [0.7621, 0.952, 0.0021],
    [0.8425, 0.9154, 0.0018],
    [0.9163, 0.87, 0.001650001],
    [0.9786, 0.8163, 0.0014],
    [1.0263, 0.757, 0.0011],
    [1.0567, 0.6949, 0.001],
    [1.0622, 0.631, 0.0008],
    [1.0456, 0.5668, 0.0006],
    [1.0026, 0.503, 0.00034],
    [0.9384, 0.4412, 0.00024],
    [0.8544499, 0.381, 0.00019],
    [0.7514, 0.321, 0.0001],
    [0.6424, 0.265, 4.999999e-05],
    [0.5419, 0.217, 3e-05],
    [0.4479, 0.175, 2e-05],
    [0.3608, 0.1382, 1e-05],
    [0.2835, 0.107, 0.0],
    [0.2187, 0.0816, 0.0],
    [0.1649, 0.061, 0.0],
    [0.1212, 0.04458, 0.0],
    [0.0874, 0.032, 0.0],
    [0.0636, 0.0232, 0.0],
    [0.04677, 0.017, 0.0],
    [0.0329, 0.01192, 0.0],
    [0.0227, 0.00821, 0.0],
    [0.01584, 0.005723, 0.0],
    [0.01135916, 0.004102, 0.0],
    [0.008110916, 0.002929, 0.0],
    [0.005790346, 0.002091, 0.0],
    [0.004109457, 0.001484, 0.0],
    [0.002899327, 0.001047, 0.0],
    [0.00204919, 0.00074, 0.0],
    [0.001439971, 0.00052, 0.0],
    [0.0009999493, 0.0003611, 0.0],
    [0.0006900786, 0.0002492, 0.0],
    [0.0004760213, 0.0001719, 0.0],
    [0.0003323011, 0.00012, 0.0],
    [0.0002348261, 8.48e-05, 0.0],
    [0.0001661505, 6e-05, 0.0],
    [0.000117413, 4.24e-05, 0.0],
    [8.307527e-05, 3e-05, 0.0],
    [5.870652e-05, 2.12e-05, 0.0],
    [4.150994e-05, 1.499e-05, 0.0],
    [2.935326e-05, 1.06e-05, 0.0],
    [2.067383e-05, 7.4657e-06, 0.0],
    [1.455977e-05, 5.2578e-06, 0.0],
    [1.025398e-05, 3.7029e-06, 0.0],
    [7.221456e-06, 2.6078e-06, 0.0],
    [5.085868e-06, 1.8366e-06, 0.0],
    [3.581652e-06, 1.2934e-06, 0.0],
    [2.522525e-06, 9.1093e-07, 0.0],
    [1.776509e-06, 6.4153e-07, 0.0],
    [1.251141e-06, 4.5181e-07, 0.0],
];

/// CIE XYZ of a blackbody at `t` kelvin, radiances in W/(m^2 sr) (module docs: Y is the
/// luminance-weighted radiance, without 683 lm/W). Zero at or below 0 K.
pub fn blackbody_xyz(t: f64) -> DVec3 {
    let mut xyz = DVec3::ZERO;
    for (i, cmf) in CIE_1931.iter().enumerate() {
        let b = planck(CIE_FIRST_NM + CIE_STEP_NM * i as f64, t);
        xyz += DVec3::from_array(*cmf) * b;
    }
    // The sum times the step (5 nm in metres) is the integral over wavelength.
    xyz * (CIE_STEP_NM * 1e-9)
}

/// Linear sRGB (D65) of CIE XYZ: IEC 61966-2-1's matrix. Out-of-gamut colours come out with a
/// negative channel.
pub fn xyz_to_linear_srgb(xyz: DVec3) -> DVec3 {
    DVec3::new(
        3.2404542 * xyz.x - 1.5371385 * xyz.y - 0.4985314 * xyz.z,
        -0.9692660 * xyz.x + 1.8760108 * xyz.y + 0.0415560 * xyz.z,
        0.0556434 * xyz.x - 0.2040259 * xyz.y + 1.0572252 * xyz.z,
    )
}

/// Emitted radiance Le of a blackbody at `t` kelvin as linear sRGB, W/(m^2 sr) per channel,
/// negative channels (below about 1900 K, outside the gamut) clipped to 0: the radiance a
/// temperature voxel emits at `emission_scale = 1`.
pub fn blackbody_rgb(t: f64) -> Vec3 {
    xyz_to_linear_srgb(blackbody_xyz(t)).max(DVec3::ZERO).as_vec3()
}

/// Chromaticity (x, y) of CIE XYZ.
pub fn chromaticity(xyz: DVec3) -> (f64, f64) {
    let s = xyz.x + xyz.y + xyz.z;
    (xyz.x / s, xyz.y / s)
}
