//! Manifold next-event estimation in `path` (issue 16: lights outside a refractive object):
//! point and directional lights outside one convex object reach its medium through one flat
//! facet (glsl/path/trace.comp `mnee_estimate`, glsl/include/mesh.glsl `mnee_point`,
//! `mnee_directional`). Checked: the irradiance through a plane (src/physics/dielectric.rs)
//! against the spreading of a ray bundle, traced independently; single scattering in a thick
//! glass slab under a directional light against the closed form, and under a point light
//! against a quadrature of the same physics along each pixel's ray; a far point light against
//! the directional light it tends to, on a glass sphere with multiple scattering.

use glam::{DVec3, Vec3};
use scatterlab::physics::dielectric::{
    facet_irradiance, fresnel_dielectric, refract, refracted_directional_irradiance, refracted_point_irradiance,
    refraction_point,
};
use scatterlab::scene::bvh::Bvh;
use scatterlab::scene::mesh::{load_obj, MeshTransform};
use scatterlab::solvers::path::PathStats;

use crate::common::{assert_clean, gpu, render, scene};
use crate::common::{mean_and_stderr, PATH};
use crate::refraction_tests::{mesh, write_box, write_box_named};

/// Where the ray o + t d meets the plane through q with normal n.
fn hit_plane(o: DVec3, d: DVec3, q: DVec3, n: DVec3) -> DVec3 {
    o + d * ((q - o).dot(n) / d.dot(n))
}

#[test]
fn refracted_point_irradiance_is_the_spreading_of_a_ray_bundle() {
    // A point light above the plane z = 0 (glass below): trace the central ray to the
    // refraction point, and two neighbours a small angle away in orthogonal directions;
    // refract all three and follow them to the plane through x across the central ray. The
    // patch they span per solid angle gives E = I (1 - F) dOmega / dA, independent of the closed
    // form under test.
    let n = DVec3::Z;
    let q = DVec3::ZERO;
    for (ior, light, x) in [
        (1.5, DVec3::new(0.3, -0.2, 1.2), DVec3::new(-0.4, 0.5, -0.7)),
        (1.33, DVec3::new(2.0, 0.0, 0.5), DVec3::new(-0.1, 0.0, -0.2)),
        (2.0, DVec3::new(0.0, 0.0, 3.0), DVec3::new(0.01, 0.0, -1.0)),
        (1.5, DVec3::new(-3.0, 1.0, 0.3), DVec3::new(1.0, -0.3, -2.0)),
        (1.0, DVec3::new(0.5, 0.5, 1.0), DVec3::new(-0.5, 0.2, -0.5)),
    ] {
        let ps = refraction_point(light, x, q, n, ior).expect("opposite sides");
        assert!(ps.z.abs() < 1e-12, "off the plane: {ps}");
        let w_o = (ps - light).normalize();
        let w_i = (x - ps).normalize();
        // Snell's law, and the three rays in one plane.
        let (sin_o, sin_i) = (w_o.cross(n).length(), w_i.cross(n).length());
        assert!((sin_o - ior * sin_i).abs() < 1e-9, "ior {ior}: Snell {sin_o} against {}", ior * sin_i);
        assert!(w_o.cross(w_i).dot(n).abs() < 1e-9);
        let refracted = refract(w_o, n, 1.0 / ior).unwrap();
        assert!((refracted - w_i).length() < 1e-7);
        // The bundle.
        let (l_o, l_i) = (light.distance(ps), ps.distance(x));
        let (cos_o, cos_i) = (-w_o.dot(n), w_i.dot(-n));
        let e = 1e-6;
        let u = w_o.any_orthonormal_vector();
        let v = w_o.cross(u);
        let land = |w: DVec3| {
            let p = hit_plane(light, w, q, n);
            let t = refract(w, n, 1.0 / ior).unwrap();
            hit_plane(p, t, x, w_i)
        };
        let (pu, pv, pm_u, pm_v) = (
            land((w_o + u * e).normalize()),
            land((w_o + v * e).normalize()),
            land((w_o - u * e).normalize()),
            land((w_o - v * e).normalize()),
        );
        let area = ((pu - pm_u) / (2.0 * e)).cross((pv - pm_v) / (2.0 * e)).length();
        let t = 1.0 - fresnel_dielectric(cos_o, 1.0 / ior);
        let bundle = t / area;
        let closed = refracted_point_irradiance(1.0, l_o, cos_o, l_i, cos_i, ior);
        eprintln!("ior {ior}: bundle {bundle:.6e}, closed form {closed:.6e}");
        assert!((bundle / closed - 1.0).abs() < 1e-4, "ior {ior}: bundle {bundle} against {closed}");
        if ior == 1.0 {
            assert!((closed * light.distance_squared(x) - 1.0).abs() < 1e-9);
        }
    }
    // A parallel beam's cross-section: cos_o -> cos_i per unit of the boundary's area.
    let e = refracted_directional_irradiance(2.0, 0.6, 0.8, 1.5);
    assert!((e - 2.0 * (1.0 - fresnel_dielectric(0.6, 1.0 / 1.5)) * 0.75).abs() < 1e-12);
}

/// A slab of glass [-2, 2]^2 x [-1, 0] holding `medium`, lit by `light`, seen straight down by
/// an orthographic camera `extent` wide at `size`^2 pixels, single scattering only.
fn slab_scene(dir: &std::path::Path, medium: &str, light: &str, extent: f32, size: u32, spp: u32) -> String {
    let obj = write_box(dir, Vec3::new(-2.0, -2.0, -1.0), Vec3::new(2.0, 2.0, 0.0));
    format!(
        "[render]\nwidth = {size}\nheight = {size}\nseed = 7\nspp = {spp}\n\
         [camera]\nkind = \"orthographic\"\norigin = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nextent = {extent}\n\
         [[object]]\nmesh = \"{}\"\nior = 1.5\n[object.medium]\n{medium}\n[[light]]\n{light}\n",
        obj.display()
    )
}

/// Every pixel of `out` (`size` square, red channel) against the mean of `radiance` at its
/// 2 x 2 sub-pixel centres (continuous pixel coordinates, row 0 at the top), within 5 of its
/// standard deviation plus `slack` of the expected value: the largest such ratio.
fn assert_pixels_match(
    out: &scatterlab::solvers::RenderOutput,
    size: u32,
    radiance: &dyn Fn(f64, f64) -> f64,
    slack: f64,
) -> f64 {
    let var = out.variance.as_ref().expect("path's variance");
    let mut worst: f64 = 0.0;
    for py in 0..size {
        for px in 0..size {
            let mut expect = 0.0;
            for (sx, sy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                expect += radiance(px as f64 + sx, py as f64 + sy) / 4.0;
            }
            let i = ((py * size + px) * 3) as usize;
            let (v, sd) = (out.image.data[i] as f64, (var.data[i] as f64).sqrt());
            let z = (v - expect).abs() / (sd + slack * expect + 1e-9);
            worst = worst.max(z);
            assert!(z < 5.0, "pixel ({px}, {py}): path {v} +- {sd} against {expect}");
        }
    }
    worst
}

/// Henyey-Greenstein phase function (1/sr).
fn hg(g: f64, cos: f64) -> f64 {
    (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g * g - 2.0 * g * cos).powf(1.5))
}

#[test]
fn directional_light_through_a_glass_slab_matches_the_single_scattering_closed_form() {
    // A thick slab (optical depth 10), camera at normal incidence, light at 40 degrees outside:
    // L = (1 - F_c)(1 - F_l) albedo p(cos) E cos_o / (n^2 (mu_l + mu_c)), mu the inside cosines
    // (the light's irradiance inside, E (1 - F_l) cos_o / mu_l, attenuated over z / mu_l,
    // scattered toward the camera over z, summed over depth; the camera's radiance leaves
    // divided by n^2). The bottom face's reflections are e^-20 down.
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let n = 1.5f64;
    let theta = 40f64.to_radians();
    let travel = DVec3::new(theta.sin(), 0.0, -theta.cos());
    for g in [0.0f64, 0.6] {
        let text = slab_scene(
            dir.path(),
            &format!("sigma_t = 10.0\nalbedo = 0.8\ng = {g}"),
            &format!(
                "kind = \"directional\"\ndirection = [{}, {}, {}]\nirradiance = 3.0",
                travel.x, travel.y, travel.z
            ),
            0.5,
            8,
            64,
        );
        let out = render(&gpu, &scene(&text), PATH, &[("path.max_depth", "1")]);
        let (m, se) = mean_and_stderr(&out.image, out.variance.as_ref().unwrap());
        let cos_o = theta.cos();
        let inside = (travel * DVec3::new(1.0 / n, 1.0 / n, 0.0) - DVec3::Z * (1.0 - (theta.sin() / n).powi(2)).sqrt())
            .normalize();
        let mu_l = -inside.z;
        let f_l = fresnel_dielectric(cos_o, 1.0 / n);
        let f_c = fresnel_dielectric(1.0, 1.0 / n);
        // Scattering angle between the light's inside direction and the way to the camera (+z).
        let p = hg(g, inside.dot(DVec3::Z));
        let expect = (1.0 - f_c) * (1.0 - f_l) * 0.8 * p * 3.0 * cos_o / (n * n * (mu_l + 1.0));
        eprintln!("slab g {g}: path {m:.6} +- {se:.6}, closed form {expect:.6}");
        assert!((m - expect).abs() < 4.0 * se + 2e-3 * expect, "g {g}: {m} +- {se} against {expect}");
    }
    assert_clean(&gpu);
}

#[test]
fn point_light_through_a_glass_slab_matches_a_quadrature_along_each_ray() {
    // The same slab under a point light 0.8 above its face: each pixel's radiance is
    // int_0^inf sigma_s p E(z) e^(-sigma_t (z + l_i(z))) dz (1 - F_c) / n^2, with the refraction
    // point and E from src/physics/dielectric.rs (checked against the ray bundle above), by
    // the midpoint rule at the 2 x 2 sub-pixel centres: the kernel's facet search, its
    // irradiance and its inside transmittance against the CPU.
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let (n, sigma_t, albedo, g) = (1.5f64, 6.0f64, 0.9f64, 0.3f64);
    let light = DVec3::new(0.3, 0.1, 0.8);
    let (size, extent) = (6u32, 1.2f64);
    let text = slab_scene(
        dir.path(),
        &format!("sigma_t = {sigma_t}\nalbedo = {albedo}\ng = {g}"),
        &format!("kind = \"point\"\nposition = [{}, {}, {}]\nintensity = 2.0", light.x, light.y, light.z),
        extent as f32,
        size,
        256,
    );
    let out = render(&gpu, &scene(&text), PATH, &[("path.max_depth", "1")]);
    let f_c = fresnel_dielectric(1.0, 1.0 / n);
    let radiance = |px: f64, py: f64| {
        // Pixel (px, py) continuous; row 0 at the top (+y), extent along x.
        let x0 = (px / size as f64 - 0.5) * extent;
        let y0 = (0.5 - py / size as f64) * extent;
        let dz = 0.002;
        let mut sum = 0.0;
        for k in 0..500 {
            let z = (k as f64 + 0.5) * dz;
            let x = DVec3::new(x0, y0, -z);
            let ps = refraction_point(light, x, DVec3::ZERO, DVec3::Z, n).unwrap();
            let (l_o, l_i) = (light.distance(ps), ps.distance(x));
            let cos_o = (light - ps).normalize().z;
            let wi = (ps - x).normalize();
            let e = refracted_point_irradiance(2.0, l_o, cos_o, l_i, wi.z, n);
            // The camera ray goes down (-z): the scattering angle's cosine is dot(-z, wi).
            sum += sigma_t * albedo * hg(g, -wi.z) * e * (-sigma_t * (z + l_i)).exp() * dz;
        }
        sum * (1.0 - f_c) / (n * n)
    };
    let worst = assert_pixels_match(&out, size, &radiance, 5e-3);
    eprintln!("point-lit slab: worst pixel {worst:.2} (sigma + 0.5% of the quadrature)");
    assert_clean(&gpu);
}

#[test]
fn far_point_light_through_glass_tends_to_the_directional_light() {
    // A glass sphere holding a scattering medium (all orders): a point light 1000 away of
    // intensity E 1000^2 and a directional light of irradiance E from the same side must agree
    // to the light's 1/r^2 variation over the object (1e-3). Same seed, same paths: the
    // difference is the two estimators', not noise.
    let gpu = gpu();
    let toward = Vec3::new(0.6, 0.5, 0.62).normalize();
    let far = 1000.0f32;
    let text = |light: String| {
        format!(
            "[render]\nwidth = 12\nheight = 12\nseed = 3\nspp = 64\n\
             [camera]\norigin = [0.0, 0.4, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 34.0\n\
             [[object]]\nmesh = \"{}\"\nscale = 0.8\nior = 1.5\n\
             [object.medium]\nsigma_t = 4.0\nalbedo = 0.9\ng = 0.4\n[[light]]\n{light}\n",
            mesh("icosphere.obj")
        )
    };
    let p = toward * far;
    let point = scene(&text(format!(
        "kind = \"point\"\nposition = [{}, {}, {}]\nintensity = {}",
        p.x,
        p.y,
        p.z,
        2.0 * far * far
    )));
    let d = -toward;
    let directional =
        scene(&text(format!("kind = \"directional\"\ndirection = [{}, {}, {}]\nirradiance = 2.0", d.x, d.y, d.z)));
    let a = render(&gpu, &point, PATH, &[]);
    let b = render(&gpu, &directional, PATH, &[]);
    // Plain relL2 and energy: the two images share their paths, so their noise does not add.
    let (mut num, mut den, mut sa, mut sb) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (x, y) in a.image.data.iter().zip(&b.image.data) {
        let (x, y) = (*x as f64, *y as f64);
        num += (x - y) * (x - y);
        den += y * y;
        sa += x;
        sb += y;
    }
    let (rel, energy) = ((num / den).sqrt(), sa / sb);
    let mean = sb / b.image.data.len() as f64;
    eprintln!("far point against directional: relL2 {rel:.5}, energy {energy:.5}; directional mean {mean:.4}");
    assert!(mean > 1e-3, "the directional light lit nothing: {mean}");
    assert!((energy - 1.0).abs() < 3e-3, "energy ratio {energy}");
    assert!(rel < 0.01, "relL2 {rel}");
    assert_clean(&gpu);
}

/// The shipped icosphere (unit radius) as facets in f64, with its BVH.
fn icosphere() -> (Vec<[DVec3; 3]>, Bvh) {
    let path = std::path::PathBuf::from(mesh("icosphere.obj"));
    let m = load_obj(&path, &MeshTransform::identity()).unwrap();
    let bvh = Bvh::build(&m);
    let f = |a: [f32; 4]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
    (bvh.triangles.iter().map(|t| [f(t.v0), f(t.e1), f(t.e2)]).collect(), bvh)
}

/// xorshift64 in [0, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[test]
fn facet_irradiance_in_a_glass_icosphere_integrates_to_the_power_photons_carry_in() {
    // With nothing inside, the volume integral of the irradiance (on surfaces facing each ray)
    // is the power that enters times the length it travels inside: photons traced from the
    // light through the facets (Fresnel-weighted) measure the second, random points summing
    // every facet's irradiance the first. On the icosphere a point is lit through up to four
    // facets and more at once (each facet a small prism); keeping one, as a local manifold
    // search does, measured half the power.
    let (facets, bvh) = icosphere();
    let ior = 1.5;
    let light = DVec3::new(1.5, 1.8, 1.6);
    let mut rng = Rng(0x9e3779b97f4a7c15);
    // Photons, uniform over the cone that holds the unit sphere; intensity 1.
    let dist = light.length();
    let cos_max = (1.0 - 1.0 / (dist * dist)).sqrt();
    let axis = -light / dist;
    let (u, v) = (axis.any_orthonormal_vector(), axis.cross(axis.any_orthonormal_vector()));
    let photons = 200_000;
    let mut track = Vec::with_capacity(photons);
    for _ in 0..photons {
        let c = 1.0 - rng.next() * (1.0 - cos_max);
        let ph = 2.0 * std::f64::consts::PI * rng.next();
        let sn = (1.0 - c * c).sqrt();
        let d = (axis * c + u * sn * ph.cos() + v * sn * ph.sin()).normalize();
        let mut t = 0.0;
        if let Some(h) = bvh.intersect(light.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY) {
            let n = h.normal.as_dvec3();
            let cos_o = -d.dot(n);
            if let (true, Some(w)) = (cos_o > 0.0, refract(d, n, 1.0 / ior)) {
                let p = light + d * h.t as f64 - n * 1e-6;
                if let Some(h2) = bvh.intersect(p.as_vec3(), w.as_vec3(), 0.0, f32::INFINITY) {
                    t = (1.0 - fresnel_dielectric(cos_o, 1.0 / ior)) * h2.t as f64;
                }
            }
        }
        track.push(t);
    }
    let omega = 2.0 * std::f64::consts::PI * (1.0 - cos_max);
    let (pm, pse) = mean_se(&track);
    let (photon, photon_se) = (pm * omega, pse * omega);
    // Random points in the cube [-1, 1]^3; outside the mesh they count 0.
    let inside = |x: DVec3| {
        let d = glam::Vec3::new(0.5773, 0.5774, 0.5773503).normalize();
        let (mut t, mut odd) = (0.0f32, false);
        while let Some(h) = bvh.intersect(x.as_vec3(), d, t, f32::INFINITY) {
            odd = !odd;
            t = h.t;
        }
        odd
    };
    let mut samples = Vec::new();
    let mut several = 0usize;
    for _ in 0..40_000 {
        let x = DVec3::new(rng.next() * 2.0 - 1.0, rng.next() * 2.0 - 1.0, rng.next() * 2.0 - 1.0);
        if !inside(x) {
            samples.push(0.0);
            continue;
        }
        let sol = facet_irradiance(&facets, x, light, true, ior);
        several += (sol.len() > 1) as usize;
        samples.push(8.0 * sol.iter().map(|(_, e)| e).sum::<f64>());
    }
    let (integral, se) = mean_se(&samples);
    eprintln!(
        "photons {photon:.5} +- {photon_se:.5}, facets {integral:.5} +- {se:.5} (ratio {:.4}); {several} points lit through 2+ facets",
        integral / photon
    );
    assert!((integral - photon).abs() < 4.0 * (se * se + photon_se * photon_se).sqrt(), "{integral} against {photon}");
    assert!(several > 1000, "{several}");
}

fn mean_se(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

#[test]
fn facet_grid_gives_the_image_of_the_full_scan() {
    // `path.mnee_cells` = 1 tries every chain; the default grid only the chains whose beam
    // meets the point's cell, in the same order: the same image, bit for bit (a chain missing
    // from a cell it lights would change it). The icosphere under a point and a directional
    // light (single refractions and one inside reflection: depth 2 for one convex object); the
    // torus (not convex: light through one sheet into another, depth 3) and two objects (the
    // light through the sphere into the blob). Every budget too: the chains' loops count into
    // it, so the kernel pauses and resumes exactly (counting a tried chain as one iteration
    // let llvmpipe's loop limiter end loops on the full scan at budgets of 2000 and up).
    let gpu = gpu();
    let sphere = |light: &str| {
        format!(
            "[render]\nwidth = 8\nheight = 8\nseed = 3\nspp = 8\n\
             [camera]\norigin = [0.0, 0.4, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 34.0\n\
             [[object]]\nmesh = \"{}\"\nscale = 0.8\nior = 1.5\n\
             [object.medium]\nsigma_t = 2.0\nalbedo = 0.9\ng = 0.3\n[[light]]\n{light}\n",
            mesh("icosphere.obj")
        )
    };
    let torus = format!(
        "[render]\nwidth = 6\nheight = 6\nseed = 3\nspp = 4\n\
         [camera]\norigin = [0.0, 1.6, 3.6]\ntarget = [0.0, 0.0, 0.0]\nfov = 40.0\n\
         [[object]]\nmesh = \"{}\"\nior = 1.5\n\
         [object.medium]\nsigma_t = 2.0\nalbedo = 0.9\ng = 0.3\n[[light]]\nkind = \"point\"\nposition = [1.5, 1.8, 1.6]\nintensity = 6.0\n",
        mesh("torus.obj")
    );
    let pair = format!(
        "[render]\nwidth = 6\nheight = 6\nseed = 3\nspp = 4\n\
         [camera]\norigin = [0.0, 0.4, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 40.0\n\
         [[object]]\nmesh = \"{}\"\nscale = 0.5\ntranslate = [-0.6, 0.0, 0.0]\nior = 1.5\n[object.medium]\nsigma_t = 1.0\nalbedo = 0.9\n\
         [[object]]\nmesh = \"{}\"\nscale = 0.45\ntranslate = [0.6, 0.0, 0.0]\nior = 1.5\n[object.medium]\nsigma_t = 1.0\nalbedo = 0.9\n\
         [[light]]\nkind = \"directional\"\ndirection = [1.0, -0.1, 0.0]\nirradiance = 2.0\n",
        mesh("icosphere.obj"),
        mesh("blob.obj")
    );
    for (what, text, budgets) in [
        ("sphere, point light", sphere("kind = \"point\"\nposition = [1.5, 1.8, 1.6]\nintensity = 6.0"), &["150"][..]),
        (
            "sphere, directional light",
            sphere("kind = \"directional\"\ndirection = [-0.5, -0.6, -0.62]\nirradiance = 2.0"),
            &[],
        ),
        ("torus", torus, &["300"]),
        ("sphere and blob", pair, &[]),
    ] {
        let s = scene(&text);
        let grid = render(&gpu, &s, PATH, &[]);
        let chains = grid.report.detail::<PathStats>().unwrap().manifold_nee_chains.clone();
        eprintln!("{what}: chains of 1, 2, 3 facets: {chains:?}");
        assert!(chains.len() >= 2 && chains[1] > 0, "{what}: no longer chains: {chains:?}");
        let scan = render(&gpu, &s, PATH, &[("path.mnee_cells", "1")]);
        assert!(grid.image.data.iter().any(|v| *v > 0.0), "{what}: black");
        assert!(grid.image.data == scan.image.data, "{what}: the grid and the full scan differ");
        for budget in budgets {
            let other = render(&gpu, &s, PATH, &[("path.budget", budget)]);
            assert!(other.image.data == grid.image.data, "{what}: budget {budget} changed the image");
        }
    }
    assert_clean(&gpu);
}

#[test]
fn glass_sphere_single_scattering_matches_a_quadrature_through_every_facet() {
    // The icosphere holding a dense medium (the camera's refracted ray never reaches the back),
    // seen straight down by an orthographic camera, single scattering: each pixel against
    // (1 - F_c) / n^2 int sigma_s e^(-sigma_t s) sum over facets of p E e^(-sigma_t l_i) ds
    // along the refracted ray, with every facet's irradiance from the CPU (checked above against
    // the photons): the kernel's facet grid, irradiance and transmittances on a real mesh.
    let gpu = gpu();
    let (facets, bvh) = icosphere();
    let (n, sigma_t, albedo, g) = (1.5f64, 8.0f64, 0.9f64, 0.3f64);
    let light = DVec3::new(1.5, 1.8, 1.6);
    let (size, extent) = (8u32, 1.2f64);
    let text = format!(
        "[render]\nwidth = {size}\nheight = {size}\nseed = 5\nspp = 256\n\
         [camera]\nkind = \"orthographic\"\norigin = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nextent = {extent}\n\
         [[object]]\nmesh = \"{}\"\nior = {n}\n[object.medium]\nsigma_t = {sigma_t}\nalbedo = {albedo}\ng = {g}\n\
         [[light]]\nkind = \"point\"\nposition = [{}, {}, {}]\nintensity = 1.0\n",
        mesh("icosphere.obj"),
        light.x,
        light.y,
        light.z
    );
    let out = render(&gpu, &scene(&text), PATH, &[("path.max_depth", "1")]);
    let radiance = |px: f64, py: f64| {
        let o = DVec3::new((px / size as f64 - 0.5) * extent, (0.5 - py / size as f64) * extent, 3.0);
        let d = DVec3::NEG_Z;
        let Some(h) = bvh.intersect(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY) else { return 0.0 };
        let nrm = h.normal.as_dvec3();
        let cos_c = -d.dot(nrm);
        let t = refract(d, nrm, 1.0 / n).unwrap();
        let p0 = o + d * h.t as f64;
        let ds = 0.01;
        let mut sum = 0.0;
        for k in 0..120 {
            let s = (k as f64 + 0.5) * ds;
            let x = p0 + t * s;
            let mut l = 0.0;
            for (ps, e) in facet_irradiance(&facets, x, light, true, n) {
                let wi = (ps - x).normalize();
                l += hg(g, t.dot(wi)) * e * (-sigma_t * ps.distance(x)).exp();
            }
            sum += sigma_t * albedo * l * (-sigma_t * s).exp() * ds;
        }
        sum * (1.0 - fresnel_dielectric(cos_c, 1.0 / n)) / (n * n)
    };
    let worst = assert_pixels_match(&out, size, &radiance, 0.01);
    eprintln!("glass sphere: worst pixel {worst:.2} (sigma + 1% of the quadrature)");
    assert_clean(&gpu);
}

// ------------------------------------------------------------------ specular chains

/// The light of a slab of glass (index n, faces z = 0 and z = -h) at a point of depth t: its
/// beams, unfolded. Beam b has met the faces b times inside (reflecting each time, at the same
/// inside angle: parallel faces), so along its straightened path it reaches the image of the
/// point at depth z_b (t, 2h - t, 2h + t, 4h - t, ...). For each: the irradiance (per unit of
/// the light's intensity or irradiance, before the inside reflections), the unit direction
/// toward the light at the point (unfolded back), the inside path length and the inside cosine.
enum SlabLight {
    /// A point light above the top face.
    Point(DVec3),
    /// A directional light travelling along the unit vector, with a factor for what it met
    /// before the slab's top face.
    Directional(DVec3, f64),
}

fn slab_beam(light: &SlabLight, n: f64, h: f64, x0: f64, y0: f64, t: f64, b: usize) -> (f64, DVec3, f64, f64) {
    let z_b = if b % 2 == 0 { b as f64 * h + t } else { (b + 1) as f64 * h - t };
    let (e, mut wi, len, cos_i) = match *light {
        SlabLight::Point(p) => {
            let x = DVec3::new(x0, y0, -z_b);
            let ps = refraction_point(p, x, DVec3::ZERO, DVec3::Z, n).unwrap();
            let (l_o, l_i) = (p.distance(ps), ps.distance(x));
            let cos_o = (p - ps).normalize().z;
            let wi = (ps - x).normalize();
            (refracted_point_irradiance(1.0, l_o, cos_o, l_i, wi.z, n), wi, l_i, wi.z)
        }
        SlabLight::Directional(travel, factor) => {
            let inside = refract(travel, DVec3::Z, 1.0 / n).unwrap();
            let mu = -inside.z;
            (factor * refracted_directional_irradiance(1.0, -travel.z, mu, n), -inside, z_b / mu, mu)
        }
    };
    if b % 2 == 1 {
        wi.z = -wi.z;
    }
    let r = fresnel_dielectric(cos_i, n).powi(b as i32);
    (e * r, wi, len, cos_i)
}

/// Single-scattering radiance seen along the slab's normal at (x0, y0), from above (`below`
/// false: the camera ray enters the top face going down) or from below: the integral over
/// depth of sigma_s p E_b e^(-sigma_t (l_b + d_m)) summed over the light's first `beams` beams
/// and the camera ray's first 4 legs (leg m after m inside reflections, R_c each), times
/// (1 - R_c) / n^2 (the camera ray's entry). Midpoint rule, 2000 steps.
#[allow(clippy::too_many_arguments)]
fn slab_single_scattering(
    light: &SlabLight,
    [n, h, sigma_t, albedo, g]: [f64; 5],
    x0: f64,
    y0: f64,
    below: bool,
    beams: usize,
) -> f64 {
    let r_c = fresnel_dielectric(1.0, 1.0 / n);
    let steps = 2000;
    let dt = h / steps as f64;
    let mut sum = 0.0;
    for k in 0..steps {
        let t = (k as f64 + 0.5) * dt;
        // The camera's depth measured from the face it enters.
        let s = if below { h - t } else { t };
        for m in 0..4 {
            // Leg m: distance travelled to the point, and the direction the scattered light must
            // leave in to go back along it (+z toward the top face).
            let (d_m, up) = if m % 2 == 0 { (m as f64 * h + s, !below) } else { ((m + 1) as f64 * h - s, below) };
            let out = if up { DVec3::Z } else { -DVec3::Z };
            for b in 0..beams {
                let (e, wi, len, _) = slab_beam(light, n, h, x0, y0, t, b);
                sum += r_c.powi(m) * sigma_t * albedo * hg(g, -wi.dot(out)) * e * (-sigma_t * (len + d_m)).exp() * dt;
            }
        }
    }
    sum * (1.0 - r_c) / (n * n)
}

#[test]
fn light_reflected_inside_a_glass_slab_matches_the_unfolded_closed_form() {
    // A thin glass slab (optical depth 1), single scattering, seen straight down. A directional
    // light at 70 degrees meets the bottom face inside at 39 degrees, near the critical angle
    // (42): 17% of it reflects back up (and again at the top). The chain refract-reflect adds
    // the beam reflected once, refract-reflect-reflect the one reflected twice: against the
    // closed form (parallel faces: each reflected beam is the direct one at an unfolded depth),
    // `path.mnee_depth` 3 matches it, and 1 (single refractions, what path had before) falls
    // short by the reflected beams' share. A point light likewise: each reflected beam is the
    // light refracted toward the point's mirror image (src/physics/dielectric.rs, checked
    // against a ray bundle above), which tests the chain's ray-tube spreading independently.
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let (n, h, sigma_t, albedo) = (1.5f64, 0.5f64, 2.0f64, 0.8f64);
    let obj = write_box(dir.path(), Vec3::new(-6.0, -6.0, -h as f32), Vec3::new(6.0, 6.0, 0.0));
    let theta = 70f64.to_radians();
    let travel = DVec3::new(theta.sin(), 0.0, -theta.cos());
    let point = DVec3::new(0.3, 0.1, 0.6);
    for (g, light, light_toml, size) in [
        (
            0.0,
            SlabLight::Directional(travel, 1.0),
            format!("kind = \"directional\"\ndirection = [{}, {}, {}]\nirradiance = 1.0", travel.x, travel.y, travel.z),
            4u32,
        ),
        (
            0.6,
            SlabLight::Directional(travel, 1.0),
            format!("kind = \"directional\"\ndirection = [{}, {}, {}]\nirradiance = 1.0", travel.x, travel.y, travel.z),
            4,
        ),
        (
            0.3,
            SlabLight::Point(point),
            format!("kind = \"point\"\nposition = [{}, {}, {}]\nintensity = 1.0", point.x, point.y, point.z),
            6,
        ),
    ] {
        let extent = 1.2f64;
        let text = format!(
            "[render]\nwidth = {size}\nheight = {size}\nseed = 5\nspp = 256\n\
             [camera]\nkind = \"orthographic\"\norigin = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nextent = {extent}\n\
             [[object]]\nmesh = \"{}\"\nior = {n}\n[object.medium]\nsigma_t = {sigma_t}\nalbedo = {albedo}\ng = {g}\n[[light]]\n{light_toml}\n",
            obj.display()
        );
        let s = scene(&text);
        let params = [n, h, sigma_t, albedo, g];
        let light = &light;
        let radiance = |beams: usize| {
            move |px: f64, py: f64| {
                let x0 = (px / size as f64 - 0.5) * extent;
                let y0 = (0.5 - py / size as f64) * extent;
                slab_single_scattering(light, params, x0, y0, false, beams)
            }
        };
        let out = render(&gpu, &s, PATH, &[("path.max_depth", "1"), ("path.mnee_depth", "3")]);
        let worst = assert_pixels_match(&out, size, &radiance(3), 3e-3);
        // What the beams reflected once and twice add, and what the third would (left out).
        let mean = |beams: usize| {
            let f = radiance(beams);
            (0..size * size).map(|i| f((i % size) as f64 + 0.5, (i / size) as f64 + 0.5)).sum::<f64>()
        };
        let (m1, m3, m4) = (mean(1), mean(3), mean(4));
        eprintln!(
            "slab, g {g}: worst pixel {worst:.2}; reflected beams {:.2}% of the image, the fourth beam {:.4}%",
            100.0 * (m3 / m1 - 1.0),
            100.0 * (m4 / m3 - 1.0)
        );
        assert!(m3 / m1 - 1.0 > 0.02 && m4 / m3 - 1.0 < 1e-3, "the test's slab: {m1} {m3} {m4}");
        // Single refractions only: short by the reflected beams.
        let single = render(&gpu, &s, PATH, &[("path.max_depth", "1"), ("path.mnee_depth", "1")]);
        let (m, se) = mean_and_stderr(&single.image, single.variance.as_ref().unwrap());
        let expect1 = m1 / (size * size) as f64;
        assert!((m - expect1).abs() < 4.0 * se + 3e-3 * expect1, "depth 1: {m} +- {se} against {expect1}");
    }
    assert_clean(&gpu);
}

#[test]
fn light_through_one_glass_object_into_another_matches_the_closed_form() {
    // Two objects: an absorbing glass block A above and to the left of a scattering glass
    // slab B, a directional light at 40 degrees whose only way to the seen part of B is through
    // A (the straight way is A's shadow; a leg in vacuum that meets a surface is refused). The
    // camera looks up at B from below, orthographic, where A is not behind B. The light that
    // reaches B: (1 - F)^2 e^(-tau_A / mu_A) through A (the chain A top, A bottom, B top), and
    // F^2 e^(-2 tau_A / mu_A) of that again after a round trip inside A (five facets), then
    // B's own inside reflections (B bottom, then B top: four and five facets), summed over
    // depth in B as the slab closed form does.
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let (n, h, sigma_t, albedo, g) = (1.5f64, 0.5f64, 2.0f64, 0.8f64, 0.4f64);
    let (h_a, sigma_a) = (0.5f64, 1.0f64);
    let a = write_box_named(dir.path(), "a.obj", Vec3::new(-3.0, -3.0, 3.0), Vec3::new(-1.0, 3.0, 3.0 + h_a as f32));
    let b = write_box_named(dir.path(), "b.obj", Vec3::new(-6.0, -6.0, -h as f32), Vec3::new(6.0, 6.0, 0.0));
    let theta = 40f64.to_radians();
    let travel = DVec3::new(theta.sin(), 0.0, -theta.cos());
    let size = 4u32;
    let text = format!(
        "[render]\nwidth = {size}\nheight = {size}\nseed = 9\nspp = 512\n\
         [camera]\nkind = \"orthographic\"\norigin = [0.75, 0.0, -3.0]\ntarget = [0.75, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nextent = 0.5\n\
         [[object]]\nmesh = \"{}\"\nior = {n}\n[object.medium]\nsigma_t = {sigma_a}\nalbedo = 0.0\n\
         [[object]]\nmesh = \"{}\"\nior = {n}\n[object.medium]\nsigma_t = {sigma_t}\nalbedo = {albedo}\ng = {g}\n\
         [[light]]\nkind = \"directional\"\ndirection = [{}, {}, {}]\nirradiance = 1.0\n",
        a.display(),
        b.display(),
        travel.x,
        travel.y,
        travel.z
    );
    let s = scene(&text);
    let out = render(&gpu, &s, PATH, &[("path.max_depth", "1"), ("path.mnee_depth", "5")]);
    let (m, se) = mean_and_stderr(&out.image, out.variance.as_ref().unwrap());
    let cos_o = theta.cos();
    let mu_a = refract(travel, DVec3::Z, 1.0 / n).unwrap().z.abs();
    let f = fresnel_dielectric(cos_o, 1.0 / n);
    let f_in = fresnel_dielectric(mu_a, n);
    let through = (1.0 - f) * (1.0 - fresnel_dielectric(mu_a, n)) * (-sigma_a * h_a / mu_a).exp();
    let params = [n, h, sigma_t, albedo, g];
    // The lit part is laterally uniform: any point of it.
    let direct = slab_single_scattering(&SlabLight::Directional(travel, through), params, 0.75, 0.0, true, 3);
    let round = through * f_in * f_in * (-2.0 * sigma_a * h_a / mu_a).exp();
    let again = slab_single_scattering(&SlabLight::Directional(travel, round), params, 0.75, 0.0, true, 1);
    let expect = direct + again;
    eprintln!(
        "through A into B: path {m:.6} +- {se:.6}, closed form {expect:.6} (the round trip in A {:.3}%)",
        100.0 * again / expect
    );
    assert!(m > 0.0 && (m - expect).abs() < 4.0 * se + 3e-3 * expect, "{m} +- {se} against {expect}");
    // Without the chains through A (single refractions), B's seen part is dark: A shades it.
    let single = render(&gpu, &s, PATH, &[("path.max_depth", "1"), ("path.mnee_depth", "1")]);
    let dark = single.image.data.iter().map(|v| *v as f64).sum::<f64>();
    assert!(dark < 1e-3 * m * single.image.data.len() as f64, "light through A's shadow: {dark}");
    assert_clean(&gpu);
}

#[test]
fn light_inside_a_glass_slab_reflected_at_its_faces_matches_the_mirror_images() {
    // A point light inside a thin glass slab: besides its straight light, each face reflects
    // its beam back inside (Fresnel F at the inside angle, 1 beyond the critical angle, 42
    // degrees in glass): a flat mirror keeps the spherical wave, so the reflected light at x is
    // the light's mirror image's, F / r^2 over the unfolded path. Single scattering seen straight
    // down against that quadrature (the camera ray's own reflections summed as in the slab closed
    // form), with one reflection per chain (the default) and without (`path.mnee_reflections=0`,
    // what path had before: the straight light alone).
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let (n, h, sigma_t, albedo, g) = (1.5f64, 0.5f64, 2.0f64, 0.8f64, 0.3f64);
    let obj = write_box(dir.path(), Vec3::new(-6.0, -6.0, -h as f32), Vec3::new(6.0, 6.0, 0.0));
    let light = DVec3::new(1.2, 0.3, -0.25);
    let (size, extent) = (6u32, 1.2f64);
    let text = format!(
        "[render]\nwidth = {size}\nheight = {size}\nseed = 5\nspp = 256\n\
         [camera]\nkind = \"orthographic\"\norigin = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nextent = {extent}\n\
         [[object]]\nmesh = \"{}\"\nior = {n}\n[object.medium]\nsigma_t = {sigma_t}\nalbedo = {albedo}\ng = {g}\n\
         [[light]]\nkind = \"point\"\nposition = [{}, {}, {}]\nintensity = 1.0\n",
        obj.display(),
        light.x,
        light.y,
        light.z
    );
    let s = scene(&text);
    let r_c = fresnel_dielectric(1.0, 1.0 / n);
    // The light's images: itself, mirrored in the top face (z = 0) and in the bottom (z = -h).
    let images = [light, DVec3::new(light.x, light.y, -light.z), DVec3::new(light.x, light.y, -2.0 * h - light.z)];
    let radiance = |reflections: usize| {
        move |px: f64, py: f64| {
            let x0 = (px / size as f64 - 0.5) * extent;
            let y0 = (0.5 - py / size as f64) * extent;
            let steps = 2000;
            let dt = h / steps as f64;
            let mut sum = 0.0;
            for k in 0..steps {
                let t = (k as f64 + 0.5) * dt;
                let x = DVec3::new(x0, y0, -t);
                for m in 0..4 {
                    let (d_m, out) =
                        if m % 2 == 0 { (m as f64 * h + t, DVec3::Z) } else { ((m + 1) as f64 * h - t, -DVec3::Z) };
                    for (b, image) in images.iter().enumerate().take(1 + reflections) {
                        let to = *image - x;
                        let r = to.length();
                        let wi = to / r;
                        let f = if b == 0 { 1.0 } else { fresnel_dielectric(wi.z.abs(), n) };
                        sum += r_c.powi(m) * sigma_t * albedo * hg(g, -wi.dot(out)) * f * (-sigma_t * (r + d_m)).exp()
                            / (r * r)
                            * dt;
                    }
                }
            }
            sum * (1.0 - r_c) / (n * n)
        }
    };
    for reflections in [1usize, 0] {
        let r = reflections.to_string();
        let out = render(&gpu, &s, PATH, &[("path.max_depth", "1"), ("path.mnee_reflections", &r)]);
        let worst = assert_pixels_match(&out, size, &radiance(reflections * 2), 3e-3);
        eprintln!("light inside a slab, {reflections} reflection(s): worst pixel {worst:.2}");
    }
    let mean = |b: usize| {
        let f = radiance(b);
        (0..size * size).map(|i| f((i % size) as f64 + 0.5, (i / size) as f64 + 0.5)).sum::<f64>()
    };
    let share = mean(2) / mean(0) - 1.0;
    eprintln!("the reflected beams: {:.1}% of the image", 100.0 * share);
    assert!(share > 0.05, "the test's slab reflects too little to tell: {share}");
    assert_clean(&gpu);
}

#[test]
fn light_inside_one_glass_slab_lights_another_through_two_refractions() {
    // A point light inside an absorbing glass slab A lights a scattering glass slab B below it
    // across a vacuum gap: out of A's bottom face and into B's top (two refractions), also after
    // a reflection at A's top face (its mirror image) or at B's bottom face (the depth
    // unfolded). The reference follows the axially symmetric ray tube: a ray leaving the light
    // at angle theta inside glass lands at lateral distance rho(theta) at depth t in B, and
    // carries E = I T sin(theta) / (rho rho'(theta) cos(theta)) (rho' by central difference),
    // T the Fresnel and medium factors. The camera looks up at B from below; its ray's
    // reflections at B's faces (and off A's bottom, across the gap) are summed as in the slab
    // closed form. The straight shadow ray is blocked (it crosses two refractive faces).
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let n = 1.5f64;
    let (h_b, sigma_b, albedo, g) = (0.5f64, 2.0f64, 0.8f64, 0.3f64);
    let (a_lo, a_hi, sigma_a) = (0.6f64, 1.6f64, 0.5f64);
    let a = write_box_named(dir.path(), "a.obj", Vec3::new(-6.0, -6.0, a_lo as f32), Vec3::new(6.0, 6.0, a_hi as f32));
    let b = write_box_named(dir.path(), "b.obj", Vec3::new(-6.0, -6.0, -h_b as f32), Vec3::new(6.0, 6.0, 0.0));
    let light = DVec3::new(0.9, 0.2, 0.8);
    let (size, extent) = (6u32, 1.2f64);
    let text = format!(
        "[render]\nwidth = {size}\nheight = {size}\nseed = 8\nspp = 256\n\
         [camera]\nkind = \"orthographic\"\norigin = [0.0, 0.0, -3.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nextent = {extent}\n\
         [[object]]\nmesh = \"{}\"\nior = {n}\n[object.medium]\nsigma_t = {sigma_a}\nalbedo = 0.0\n\
         [[object]]\nmesh = \"{}\"\nior = {n}\n[object.medium]\nsigma_t = {sigma_b}\nalbedo = {albedo}\ng = {g}\n\
         [[light]]\nkind = \"point\"\nposition = [{}, {}, {}]\nintensity = 1.0\n",
        a.display(),
        b.display(),
        light.x,
        light.y,
        light.z
    );
    let out = render(&gpu, &scene(&text), PATH, &[("path.max_depth", "1")]);
    let r_c = fresnel_dielectric(1.0, 1.0 / n);
    let gap = a_lo;
    // The light's beams: (its height above A's bottom, unfolded; Fresnel reflection factor
    // index: 0 none, 1 at A's top, 2 at B's bottom).
    let beams = [(light.z - a_lo, 0usize), (2.0 * a_hi - light.z - a_lo, 1), (light.z - a_lo, 2)];
    // The camera's top reflectance: inside B's top face, or through it off A's bottom.
    let r_top = r_c + (1.0 - r_c).powi(2) * r_c;
    // Where the camera ray at (x0, y0) sees the light, summed over depth and camera legs.
    let radiance = |px: f64, py: f64| {
        // The camera looks up (+z) with up = +y: x runs the other way in the image.
        let x0 = -(px / size as f64 - 0.5) * extent;
        let y0 = (0.5 - py / size as f64) * extent;
        let lateral = DVec3::new(x0 - light.x, y0 - light.y, 0.0);
        let rho_x = lateral.length();
        let side = lateral / rho_x;
        let steps = 1000;
        let dt = h_b / steps as f64;
        let mut sum = 0.0;
        for k in 0..steps {
            let t = (k as f64 + 0.5) * dt;
            for &(above, kind) in &beams {
                let depth = if kind == 2 { 2.0 * h_b - t } else { t };
                let rho = |theta: f64| {
                    let s0 = n * theta.sin();
                    above * theta.tan() + gap * s0 / (1.0 - s0 * s0).sqrt() + depth * theta.tan()
                };
                // rho is increasing on [0, asin(1 / n)): bisection for rho = rho_x.
                let (mut lo, mut hi) = (0.0f64, (1.0 / n).asin() * (1.0 - 1e-12));
                for _ in 0..100 {
                    let mid = 0.5 * (lo + hi);
                    if rho(mid) < rho_x {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                let theta = 0.5 * (lo + hi);
                let e = 1e-6 * theta;
                let drho = (rho(theta + e) - rho(theta - e)) / (2.0 * e);
                let (c1, c0) = (theta.cos(), (1.0 - (n * theta.sin()).powi(2)).sqrt());
                let fresnel = (1.0 - fresnel_dielectric(c1, n)) * (1.0 - fresnel_dielectric(c0, 1.0 / n));
                let reflect = if kind == 0 { 1.0 } else { fresnel_dielectric(c1, n) };
                let media = (-sigma_a * above / c1).exp() * (-sigma_b * depth / c1).exp();
                let irradiance = fresnel * reflect * media * theta.sin() / (rho_x * drho * c1);
                // The light's direction of travel at the point: down, or up after B's bottom.
                let travel = side * theta.sin() + DVec3::Z * if kind == 2 { c1 } else { -c1 };
                for m in 0..4 {
                    // Leg m of the camera ray in B (entering at the bottom, going up first).
                    let s = h_b - t;
                    let (d_m, out, f) = match m {
                        0 => (s, -DVec3::Z, 1.0),
                        1 => (h_b + t, DVec3::Z, r_top),
                        2 => (2.0 * h_b + s, -DVec3::Z, r_top * r_c),
                        _ => (3.0 * h_b + t, DVec3::Z, r_top * r_top * r_c),
                    };
                    sum += f * sigma_b * albedo * hg(g, travel.dot(out)) * irradiance * (-sigma_b * d_m).exp() * dt;
                }
            }
        }
        sum * (1.0 - r_c) / (n * n)
    };
    let worst = assert_pixels_match(&out, size, &radiance, 3e-3);
    eprintln!("light inside A lighting B: worst pixel {worst:.2}");
    assert_clean(&gpu);
}
