//! Scene format v2 meshes: OBJ loading and its checks, transforms, and the BVH the GPU traverses
//! (pure Rust, no GPU). The meshes are `tools/make-meshes`'s, committed in `scenes/meshes/`.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use glam::Vec3;
use scatterlab::scene::bvh::*;
use scatterlab::scene::mesh::*;

// ---------------------------------------------------------------------------- helpers

fn mesh_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/meshes").join(name)
}

fn load(name: &str) -> TriangleMesh {
    load_obj(&mesh_path(name), &MeshTransform::identity()).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn load_with(name: &str, transform: MeshTransform) -> TriangleMesh {
    load_obj(&mesh_path(name), &transform).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// `# volume = ...` and `# area = ...` from the header `tools/make-meshes` writes.
fn header_value(name: &str, key: &str) -> f64 {
    let text = std::fs::read_to_string(mesh_path(name)).unwrap();
    let prefix = format!("# {key} = ");
    let line = text.lines().find(|l| l.starts_with(&prefix)).unwrap_or_else(|| panic!("{name}: no {prefix:?} line"));
    line[prefix.len()..].parse().unwrap()
}

fn relative(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

/// splitmix64: deterministic, no dependency.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    fn in_box(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        lo + (hi - lo) * Vec3::new(self.uniform(), self.uniform(), self.uniform())
    }

    fn direction(&mut self) -> Vec3 {
        let z = 1.0 - 2.0 * self.uniform();
        let phi = 2.0 * std::f32::consts::PI * self.uniform();
        let s = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(s * phi.cos(), s * phi.sin(), z)
    }
}

/// A mesh triangle as the GPU stores it, computed independently of the BVH build.
fn gpu_triangle(mesh: &TriangleMesh, t: [u32; 3]) -> GpuTriangle {
    let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
    GpuTriangle { v0: a.extend(0.0).into(), e1: (b - a).extend(0.0).into(), e2: (c - a).extend(0.0).into() }
}

/// Moller-Trumbore in the same f32 arithmetic as the traversal, so a triangle's t agrees bit
/// for bit and only the hierarchy can make the answers differ.
fn brute_force_triangle(tri: &GpuTriangle, o: Vec3, d: Vec3) -> Option<f32> {
    let (v0, e1, e2) = (Vec3::from_slice(&tri.v0), Vec3::from_slice(&tri.e1), Vec3::from_slice(&tri.e2));
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - v0;
    let u = s.dot(p) * inv;
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    let t = e2.dot(q) * inv;
    ((0.0..=1.0).contains(&u) && v >= 0.0 && u + v <= 1.0 && !t.is_nan()).then_some(t)
}

/// Closest hit over all triangles: (t, triangle).
fn brute_force(tris: &[GpuTriangle], o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Option<(f32, GpuTriangle)> {
    let mut best: Option<(f32, GpuTriangle)> = None;
    for tri in tris {
        if let Some(t) = brute_force_triangle(tri, o, d) {
            if t > t_min && t < best.map_or(t_max, |b| b.0) {
                best = Some((t, *tri));
            }
        }
    }
    best
}

/// The error message of a load that must fail; checks it is one line.
fn error_of(result: Result<TriangleMesh, MeshError>) -> String {
    let msg = match result {
        Ok(_) => panic!("mesh loaded but should have failed"),
        Err(e) => e.to_string(),
    };
    eprintln!("error message: {msg}");
    assert!(!msg.contains('\n'), "error is not one line: {msg:?}");
    msg
}

fn assert_mentions(msg: &str, words: &[&str]) {
    for w in words {
        assert!(msg.contains(w), "error {msg:?} does not mention {w:?}");
    }
}

/// Plane distance of the origin from every face, and whether every vertex lies on the inner
/// side of every face plane (the mesh is convex).
fn face_planes(mesh: &TriangleMesh) -> (f64, bool) {
    let mut d_min = f64::INFINITY;
    let mut convex = true;
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize].as_dvec3());
        let n = (b - a).cross(c - a).normalize();
        d_min = d_min.min(n.dot(a));
        convex &= mesh.positions.iter().all(|p| n.dot(p.as_dvec3() - a) <= 1e-7);
    }
    (d_min, convex)
}

// ---------------------------------------------------------------------------- meshes

/// The icosphere is a convex polyhedron with every vertex on the unit sphere (to f32), so it
/// lies inside the unit ball and contains the ball of radius d_min, the least distance from the
/// centre to a face plane. Volume and area (monotone under inclusion for convex bodies) are
/// then bracketed by those two balls': the subdivision's error bound, computed from the mesh.
#[test]
fn mesh_icosphere_volume_and_area_within_the_subdivision_bound() {
    let mesh = load("icosphere.obj");
    assert_eq!(mesh.triangles.len(), 1280);
    assert_eq!(mesh.positions.len(), 642);
    mesh.check_closed().unwrap();
    for p in &mesh.positions {
        assert!((p.length() - 1.0).abs() < 3e-7, "vertex {p} is off the unit sphere");
    }

    let (volume, area) = (mesh.volume(), mesh.area());
    let (header_volume, header_area) = (header_value("icosphere.obj", "volume"), header_value("icosphere.obj", "area"));
    assert!(relative(volume, header_volume) < 1e-12, "volume {volume} against the header's {header_volume}");
    assert!(relative(area, header_area) < 1e-12, "area {area} against the header's {header_area}");

    let (d_min, convex) = face_planes(&mesh);
    assert!(convex, "the icosphere should be convex");
    // Level 3: edges about 1.05 / 8 long, circumradius about 0.08, so d_min about 0.996.
    assert!(d_min > 0.99 && d_min < 1.0, "d_min {d_min}");
    let outer = 1.0f64 + 3e-7; // vertices are on the sphere to f32 rounding
    let (ball_volume, ball_area) = (4.0 / 3.0 * PI, 4.0 * PI);
    let (volume_floor, area_floor) = (ball_volume * d_min.powi(3), ball_area * d_min.powi(2));
    eprintln!("icosphere: volume {volume:.6} in [{volume_floor:.6}, {ball_volume:.6}], area {area:.6} in [{area_floor:.6}, {ball_area:.6}]");
    assert!(volume_floor <= volume && volume <= ball_volume * outer.powi(3), "volume {volume}");
    assert!(area_floor <= area && area <= ball_area * outer.powi(2), "area {area}");
    // The bound is tight to a factor of a few, not loose: the error is a sizeable part of it.
    let error = 1.0 - volume / ball_volume;
    assert!(error > 0.25 * (1.0 - d_min.powi(3)), "volume error {error} is far below the bound");
}

/// The 64 x 32 torus has planar quads, so its exact volume is that of a 32-gon of circumradius
/// r swept about y in 64 steps: N sin(2 pi / N) R * (M / 2) r^2 sin(2 pi / M), which tends to
/// 2 pi^2 R r^2; the ratio is the polygonisation error.
#[test]
fn mesh_torus_volume_matches_its_polygonisation() {
    let mesh = load("torus.obj");
    mesh.check_closed().unwrap();
    assert_eq!(mesh.triangles.len(), 2 * 64 * 32);
    let (r_major, r_minor, n, m) = (0.7f64, 0.3f64, 64.0f64, 32.0f64);
    let polygonal = n * (2.0 * PI / n).sin() * r_major * (m / 2.0) * r_minor * r_minor * (2.0 * PI / m).sin();
    let analytic = 2.0 * PI * PI * r_major * r_minor * r_minor;
    let volume = mesh.volume();
    eprintln!("torus: volume {volume:.7}, polygonal {polygonal:.7}, analytic {analytic:.7}");
    assert!(relative(volume, polygonal) < 1e-6, "volume {volume} against the exact polygonal {polygonal}");
    let expected_error = 1.0 - polygonal / analytic; // about 0.8%
    assert!((1.0 - volume / analytic - expected_error).abs() < 1e-6, "volume {volume} against 2 pi^2 R r^2");
    assert!(relative(volume, header_value("torus.obj", "volume")) < 1e-12);
    assert!(relative(mesh.area(), header_value("torus.obj", "area")) < 1e-12);
    let (lo, hi) = mesh.bounds();
    assert!((hi - Vec3::new(1.0, 0.3, 1.0)).abs().max_element() < 2e-3 && (lo + hi).abs().max_element() < 2e-3);
}

#[test]
fn mesh_blob_is_closed_star_shaped_and_not_convex() {
    let mesh = load("blob.obj");
    mesh.check_closed().unwrap();
    assert_eq!(mesh.triangles.len(), 5120);
    assert!(relative(mesh.volume(), header_value("blob.obj", "volume")) < 1e-12);
    assert!(relative(mesh.area(), header_value("blob.obj", "area")) < 1e-12);
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize].as_dvec3());
        assert!(a.dot(b.cross(c)) > 0.0, "face {t:?} does not face away from the centre");
    }
    for p in &mesh.positions {
        assert!((0.6 - 1e-6..=1.4 + 1e-6).contains(&p.length()), "radius {} out of [0.6, 1.4]", p.length());
    }
    assert!(!face_planes(&mesh).1, "the blob should not be convex");
}

#[test]
fn mesh_transform_scales_rotates_and_translates() {
    let plain = load("icosphere.obj");
    let (volume, area) = (plain.volume(), plain.area());
    let identity = MeshTransform::identity();

    let scaled = load_with("icosphere.obj", MeshTransform { scale: 2.0, ..identity });
    assert!(relative(scaled.volume(), 8.0 * volume) < 1e-12);
    assert!(relative(scaled.area(), 4.0 * area) < 1e-12);

    let rotated = load_with("icosphere.obj", MeshTransform { rotate_deg: Vec3::new(30.0, 45.0, 60.0), ..identity });
    assert!(relative(rotated.volume(), volume) < 1e-6, "rotation changed the volume");
    assert!(relative(rotated.area(), area) < 1e-6, "rotation changed the area");

    let shift = Vec3::new(10.0, -5.0, 3.0);
    let moved = load_with("icosphere.obj", MeshTransform { translate: shift, ..identity });
    let ((lo, hi), (lo0, hi0)) = (moved.bounds(), plain.bounds());
    assert!((lo - (lo0 + shift)).abs().max_element() < 1e-5 && (hi - (hi0 + shift)).abs().max_element() < 1e-5);
    assert!(relative(moved.volume(), volume) < 1e-5);

    // All three: p' = translate + scale * rotate(p).
    let all = MeshTransform { translate: shift, rotate_deg: Vec3::new(10.0, 20.0, 30.0), scale: 0.5 };
    let placed = load_with("blob.obj", all);
    let blob = load("blob.obj");
    assert!(relative(placed.volume(), blob.volume() / 8.0) < 1e-5);
    let m = all.matrix();
    for (p, q) in blob.positions.iter().zip(&placed.positions) {
        assert!((m.transform_point3(*p) - *q).length() < 1e-6);
    }

    // The Euler convention: about fixed axes, X first, then Y, then Z.
    let rot =
        |deg: [f32; 3], p: Vec3| MeshTransform { rotate_deg: deg.into(), ..identity }.matrix().transform_point3(p);
    let close = |a: Vec3, b: Vec3| (a - b).length() < 1e-6;
    assert!(close(rot([90.0, 0.0, 0.0], Vec3::Y), Vec3::Z), "+90 about x takes +y to +z");
    assert!(close(rot([0.0, 90.0, 0.0], Vec3::Z), Vec3::X), "+90 about y takes +z to +x");
    assert!(close(rot([0.0, 0.0, 90.0], Vec3::X), Vec3::Y), "+90 about z takes +x to +y");
    assert!(close(rot([90.0, 90.0, 0.0], Vec3::Y), Vec3::X), "X first: +y -> +z, then Y: +z -> +x");
    assert!(close(rot([0.0, 90.0, 90.0], Vec3::Z), Vec3::Y), "Y first: +z -> +x, then Z: +x -> +y");
}

// ---------------------------------------------------------------------------- BVH

/// The distance from `p` to a triangle by another route than the BVH's (Ericson's Voronoi
/// regions): the plane's foot where it falls inside (barycentric), else the nearest of the
/// three edges as segments.
fn triangle_distance(t: &GpuTriangle, p: Vec3) -> f32 {
    let a = Vec3::from_slice(&t.v0[..3]);
    let (b, c) = (a + Vec3::from_slice(&t.e1[..3]), a + Vec3::from_slice(&t.e2[..3]));
    let n = (b - a).cross(c - a).normalize();
    let foot = p - n * n.dot(p - a);
    let inside = [(a, b), (b, c), (c, a)].iter().all(|&(u, v)| (v - u).cross(foot - u).dot(n) >= 0.0);
    if inside {
        return (p - foot).length();
    }
    let segment = |u: Vec3, v: Vec3| {
        let s = ((p - u).dot(v - u) / (v - u).length_squared()).clamp(0.0, 1.0);
        (p - (u + (v - u) * s)).length()
    };
    segment(a, b).min(segment(b, c)).min(segment(c, a))
}

/// A shipped mesh's BVH, its triangles in the mesh's order as the GPU tests them, and the
/// centre and half-extent of its bounds: what the brute-force comparisons start from.
fn bvh_and_triangles(name: &str) -> (Bvh, Vec<GpuTriangle>, Vec3, Vec3) {
    let mesh = load(name);
    let tris = mesh.triangles.iter().map(|&t| gpu_triangle(&mesh, t)).collect();
    let (lo, hi) = mesh.bounds();
    (Bvh::build(&mesh), tris, (lo + hi) * 0.5, (hi - lo) * 0.5)
}

/// sh-single's offset surfaces are level sets of the distance to the mesh: the BVH's nearest
/// point agrees with every triangle's distance, inside and outside the surface, and lies on
/// the surface at that distance.
#[test]
fn mesh_bvh_closest_point_agrees_with_brute_force() {
    let mut rng = Rng(0x5eed_0017);
    for name in ["icosphere.obj", "torus.obj", "blob.obj"] {
        let (bvh, tris, centre, extent) = bvh_and_triangles(name);
        for k in 0..3000 {
            let p = rng.in_box(centre - 1.5 * extent, centre + 1.5 * extent);
            let (q, d) = bvh.closest_point(p).expect("a mesh has triangles");
            let want = tris.iter().map(|t| triangle_distance(t, p)).fold(f32::INFINITY, f32::min);
            // f32 rounding of coordinates of order the mesh's size: an absolute part.
            let tol = |x: f32| 1e-5 * x + 1e-6 * extent.max_element();
            assert!((d - want).abs() <= tol(want), "{name}: point {k}: {d} against {want}");
            assert!(((q - p).length() - d).abs() <= tol(d), "{name}: point {k}");
            let on = tris.iter().map(|t| triangle_distance(t, q)).fold(f32::INFINITY, f32::min);
            assert!(on <= 1e-5 * extent.max_element(), "{name}: point {k}: the nearest point is {on} off the surface");
        }
    }
    // The icosphere's centre lies between the inscribed and the circumscribed sphere's radius
    // from its faces.
    let mesh = load("icosphere.obj");
    let (_, d) = Bvh::build(&mesh).closest_point(Vec3::ZERO).unwrap();
    assert!(d > 0.98 && d <= 1.0, "{d}");
}

#[test]
fn mesh_bvh_agrees_with_brute_force() {
    let mut rng = Rng(0x5eed_0016);
    for name in ["icosphere.obj", "torus.obj", "blob.obj"] {
        let (bvh, tris, centre, extent) = bvh_and_triangles(name);
        let (mut hits, mut ties) = (0, 0);
        for k in 0..20_000 {
            let (o, d) = match k % 4 {
                // Inside the bounds (inside or outside the surface), any direction.
                0 | 1 => (rng.in_box(centre - extent, centre + extent), rng.direction()),
                // Outside, aimed at a point of the bounds.
                2 => {
                    let o = centre + rng.direction() * 3.0 * extent.max_element();
                    (o, rng.in_box(centre - extent, centre + extent) - o)
                }
                // Outside, along an axis: the box test's zero-direction components.
                _ => {
                    let mut o = rng.in_box(centre - extent, centre + extent);
                    let axis = k / 4 % 3;
                    o[axis] = centre[axis] - 2.0 * extent[axis];
                    (o, Vec3::AXES[axis])
                }
            };
            // Mostly the whole ray; sometimes a segment, as shadow rays and tracking ask.
            let (t_min, t_max) =
                if k % 7 == 0 { (0.3 * rng.uniform(), 0.5 + rng.uniform()) } else { (0.0, f32::INFINITY) };
            let got = bvh.intersect(o, d, t_min, t_max);
            let want = brute_force(&tris, o, d, t_min, t_max);
            match (got, want) {
                (None, None) => {}
                (Some(h), Some((t, tri))) => {
                    hits += 1;
                    assert!((h.t - t).abs() <= 1e-5 * t.abs(), "{name}: ray {k}: t {} against {t}", h.t);
                    if bvh.triangles[h.triangle as usize] != tri {
                        // A different triangle only at a tie: the ray meets a shared edge or vertex.
                        assert!((h.t - t).abs() <= 1e-6 * t.abs(), "{name}: ray {k}: another triangle at t {}", h.t);
                        ties += 1;
                    } else {
                        assert_eq!(h.t, t, "{name}: ray {k}: the same triangle at another t");
                    }
                    let tri = &bvh.triangles[h.triangle as usize];
                    let n = Vec3::from_slice(&tri.e1).cross(Vec3::from_slice(&tri.e2)).normalize();
                    assert!((h.normal - n).length() < 1e-6 && (h.normal.length() - 1.0).abs() < 1e-6);
                }
                (got, want) => panic!("{name}: ray {k} from {o} along {d}: BVH {got:?}, brute force {want:?}"),
            }
        }
        eprintln!("{name}: 20000 rays, {hits} hits, {ties} ties at shared edges, depth {}", bvh.depth);
        assert!(hits > 8000, "{name}: too few hits ({hits}) to test anything");
    }
}

/// Analytically inside (`Some(true)`), outside, or too near the mesh's surface to say.
type InsideTest<'a> = &'a dyn Fn(Vec3) -> Option<bool>;

/// Inside or outside by the parity of the crossings along a ray, as a shader decides whether a
/// point is in a mesh medium. A ray that grazes an edge can count one crossing twice or none;
/// the crossings must alternate (entering, leaving, ..., leaving last), and a ray that breaks
/// that is re-drawn, as rarely as the test asserts.
#[test]
fn mesh_bvh_crossing_parity_matches_the_analytic_inside() {
    let sphere = load("icosphere.obj");
    let (d_min, _) = face_planes(&sphere);
    // The polyhedron's surface lies between radius d_min and 1; keep 1e-3 clear of that shell.
    let sphere_inside = move |p: Vec3| -> Option<bool> {
        let r = f64::from(p.length());
        if r < d_min - 1e-3 {
            Some(true)
        } else if r > 1.0 + 1e-3 {
            Some(false)
        } else {
            None
        }
    };

    // The torus's surface lies within a tube radius of [r cos(pi/M) - s, r + s] about the core
    // circle, s = (R + r)(1 - cos(pi/N)) being how far a chord of a major step sags.
    let (r_major, r_minor) = (0.7f64, 0.3f64);
    let sag = (r_major + r_minor) * (1.0 - (PI / 64.0).cos());
    let (tube_lo, tube_hi) = (r_minor * (PI / 32.0).cos() - sag, r_minor + sag);
    let torus_inside = move |p: Vec3| -> Option<bool> {
        let p = p.as_dvec3();
        let rho = (p.x * p.x + p.z * p.z).sqrt();
        let tube = ((rho - r_major).powi(2) + p.y * p.y).sqrt();
        if tube < tube_lo - 1e-3 {
            Some(true)
        } else if tube > tube_hi + 1e-3 {
            Some(false)
        } else {
            None
        }
    };

    let mut rng = Rng(0xface_0016);
    let cases: [(&str, InsideTest); 2] = [("icosphere.obj", &sphere_inside), ("torus.obj", &torus_inside)];
    for (name, inside) in cases {
        let bvh = Bvh::build(&load(name));
        let (mut points, mut redrawn, mut inside_count) = (0, 0, 0);
        while points < 4000 {
            let p = rng.in_box(Vec3::splat(-1.3), Vec3::splat(1.3));
            let Some(expected) = inside(p) else { continue };
            points += 1;
            let parity = loop {
                let d = rng.direction();
                // Leaving (+1) or entering (-1) at each crossing, in order.
                let mut sides = Vec::new();
                let mut t = 0.0;
                while let Some(hit) = bvh.intersect(p, d, t, f32::INFINITY) {
                    sides.push(hit.normal.dot(d).signum());
                    t = hit.t;
                    assert!(sides.len() < 100, "{name}: runaway crossings");
                }
                let alternates = sides.iter().rev().enumerate().all(|(k, &s)| s == if k % 2 == 0 { 1.0 } else { -1.0 });
                if alternates {
                    break sides.len() % 2 == 1;
                }
                redrawn += 1;
            };
            assert_eq!(parity, expected, "{name}: point {p} inside by parity {parity}, analytically {expected}");
            inside_count += usize::from(expected);
        }
        eprintln!("{name}: {points} points, {inside_count} inside, {redrawn} rays re-drawn");
        assert!(inside_count > 200 && inside_count < points - 200, "{name}: too one-sided a sample");
        assert!(redrawn * 100 < points, "{name}: {redrawn} of {points} rays grazed an edge");
    }
}

/// Walk the tree: every node reached once, children's boxes inside their parent's, leaves
/// covering every triangle once, the depth as recorded and within the stack.
fn check_invariants(name: &str, mesh: &TriangleMesh, bvh: &Bvh) {
    let n = mesh.triangles.len();
    assert!(bvh.nodes.len() < 2 * n, "{name}: {} nodes for {n} triangles", bvh.nodes.len());
    assert_eq!(bvh.bytes(), 32 * bvh.nodes.len() as u64 + 48 * n as u64);
    let (lo, hi) = mesh.bounds();
    assert_eq!((bvh.nodes[0].min, bvh.nodes[0].max), (lo.to_array(), hi.to_array()), "{name}: root box");

    let mut reached = vec![false; bvh.nodes.len()];
    let mut covered = vec![0u32; n];
    let mut depth = 0;
    let mut stack = vec![(0usize, 1u32)];
    while let Some((i, d)) = stack.pop() {
        assert!(!reached[i], "{name}: node {i} reached twice");
        reached[i] = true;
        depth = depth.max(d);
        let node = bvh.nodes[i];
        assert!((0..3).all(|a| node.min[a] <= node.max[a]), "{name}: node {i} has an empty box");
        if node.count > 0 {
            assert!(node.count as usize <= MAX_LEAF, "{name}: leaf {i} holds {}", node.count);
            for t in node.left_or_first..node.left_or_first + node.count {
                covered[t as usize] += 1;
                let tri = &bvh.triangles[t as usize];
                let v0 = Vec3::from_slice(&tri.v0);
                for p in [v0, v0 + Vec3::from_slice(&tri.e1), v0 + Vec3::from_slice(&tri.e2)] {
                    let slack = 1e-6 * (1.0 + p.abs().max_element());
                    assert!(
                        (0..3).all(|a| p[a] >= node.min[a] - slack && p[a] <= node.max[a] + slack),
                        "{name}: triangle {t} outside leaf {i}"
                    );
                }
            }
        } else {
            for c in [node.left_or_first as usize, node.left_or_first as usize + 1] {
                let child = bvh.nodes[c];
                assert!(
                    (0..3).all(|a| child.min[a] >= node.min[a] && child.max[a] <= node.max[a]),
                    "{name}: node {c}'s box is not inside its parent {i}'s"
                );
                stack.push((c, d + 1));
            }
        }
    }
    assert!(reached.iter().all(|&r| r), "{name}: unreachable nodes");
    assert!(covered.iter().all(|&c| c == 1), "{name}: a triangle is in no leaf or in two");
    assert_eq!(depth, bvh.depth, "{name}: recorded depth");
    assert!(bvh.depth <= MAX_DEPTH, "{name}: depth {} exceeds the stack", bvh.depth);

    // The leaves hold exactly the mesh's triangles, reordered.
    let key = |t: &GpuTriangle| [t.v0, t.e1, t.e2].map(|v| v.map(f32::to_bits));
    let mut from_mesh: Vec<_> = mesh.triangles.iter().map(|&t| key(&gpu_triangle(mesh, t))).collect();
    let mut from_bvh: Vec<_> = bvh.triangles.iter().map(key).collect();
    from_mesh.sort_unstable();
    from_bvh.sort_unstable();
    assert!(from_mesh == from_bvh, "{name}: the BVH's triangles are not the mesh's");
}

#[test]
fn mesh_bvh_invariants() {
    for name in ["icosphere.obj", "torus.obj", "blob.obj"] {
        let mesh = load(name);
        let bvh = Bvh::build(&mesh);
        check_invariants(name, &mesh, &bvh);
        eprintln!("{name}: {} nodes, depth {}, {} bytes", bvh.nodes.len(), bvh.depth, bvh.bytes());
    }
}

/// Distributions binned SAH handles badly: triangles at exponentially growing distances (each
/// split peels off a few, which would make a deep tree) and many triangles with one centroid
/// (no split separates them). Both stay within the stack depth and still find the closest hit.
#[test]
fn mesh_bvh_depth_bounded_on_degenerate_distributions() {
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for k in 0..300 {
        let x = 1.3f32.powi(k);
        let s = 0.25 * x.min(1.0);
        let base = positions.len() as u32;
        positions.extend([Vec3::new(x, -s, -s), Vec3::new(x, s, -s), Vec3::new(x, 0.0, s)]);
        triangles.push([base, base + 1, base + 2]);
    }
    let spread = TriangleMesh { positions, triangles, file: "spread".into() };
    let bvh = Bvh::build(&spread);
    check_invariants("spread", &spread, &bvh);
    let hit = bvh.intersect(Vec3::new(-1.0, 0.0, 0.0), Vec3::X, 0.0, f32::INFINITY).unwrap();
    assert_eq!(hit.t, 2.0, "the nearest triangle is at x = 1");
    let far = bvh.intersect(Vec3::new(-1.0, 0.0, 0.0), Vec3::X, 1e20, f32::INFINITY).unwrap();
    assert!(far.t >= 1e20 && far.t < 1.3e20 * 1.3, "t {}", far.t);

    let stacked = TriangleMesh {
        positions: vec![Vec3::new(0.0, -1.0, -1.0), Vec3::new(0.0, 1.0, -1.0), Vec3::new(0.0, 0.0, 1.0)],
        triangles: vec![[0, 1, 2]; 1000],
        file: "stacked".into(),
    };
    let bvh = Bvh::build(&stacked);
    check_invariants("stacked", &stacked, &bvh);
    assert!(bvh.depth <= 10, "1000 coincident triangles should halve down, depth {}", bvh.depth);
    let hit = bvh.intersect(Vec3::new(-2.0, 0.0, 0.0), Vec3::X, 0.0, f32::INFINITY).unwrap();
    assert_eq!((hit.t, hit.normal), (2.0, Vec3::X));

    let empty = TriangleMesh { positions: vec![], triangles: vec![], file: "empty".into() };
    assert_eq!(Bvh::build(&empty).intersect(Vec3::ZERO, Vec3::X, 0.0, f32::INFINITY), None);
}

// ---------------------------------------------------------------------------- loading and errors

/// The unit cube [0, 1]^3 as quads, counter-clockwise seen from outside.
const CUBE_VERTICES: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n";
const CUBE_FACES: [[u32; 4]; 6] = [[1, 4, 3, 2], [5, 6, 7, 8], [1, 2, 6, 5], [4, 8, 7, 3], [1, 5, 8, 4], [2, 3, 7, 6]];

fn cube_text(faces: &[[u32; 4]]) -> String {
    let mut text = String::from(CUBE_VERTICES);
    for f in faces {
        text += &format!("f {} {} {} {}\n", f[0], f[1], f[2], f[3]);
    }
    text
}

fn load_text(dir: &Path, text: &str) -> Result<TriangleMesh, MeshError> {
    let path = dir.join("mesh.obj");
    std::fs::write(&path, text).unwrap();
    load_obj(&path, &MeshTransform::identity())
}

#[test]
fn mesh_loads_quads_per_face_vertices_and_several_objects() {
    let dir = tempfile::tempdir().unwrap();
    let cube = load_text(dir.path(), &cube_text(&CUBE_FACES)).unwrap();
    assert_eq!(cube.triangles.len(), 12);
    assert!(relative(cube.volume(), 1.0) < 1e-12 && relative(cube.area(), 6.0) < 1e-12);
    assert_eq!(cube.bounds(), (Vec3::ZERO, Vec3::ONE));

    // As exporters write it: each face its own vertices (with a normal and texture
    // coordinates per corner), two objects, negative indices, -0 beside 0. Welded, it is the
    // same closed cube.
    let corners = ["0 0 0", "1 0 0", "1 1 0", "0 1 0", "0 0 1", "1 0 1", "1 1 1", "0 1 1"];
    let mut text = String::from("# exported\nmtllib missing.mtl\nvt 0 0\nvn 0 0 1\n");
    for (k, f) in CUBE_FACES.iter().enumerate() {
        if k % 3 == 0 {
            text += &format!("o part{k}\nusemtl stone\n");
        }
        for &v in f {
            let p = corners[v as usize - 1].replace("0 0 0", "-0 0 -0");
            text += &format!("v {p}\n");
        }
        text += "f -4/1/1 -3/1/1 -2/1/1 -1/1/1\n";
    }
    let welded = load_text(dir.path(), &text).unwrap();
    assert_eq!(welded.positions.len(), 24, "vertices keep the file's numbering");
    assert_eq!(welded.triangles.len(), 12);
    assert!(relative(welded.volume(), 1.0) < 1e-12);
    assert_eq!(welded.file, dir.path().join("mesh.obj"));
}

#[test]
fn mesh_errors_are_one_line_and_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let identity = MeshTransform::identity();

    let msg = error_of(load_obj(&dir.path().join("absent.obj"), &identity));
    assert_mentions(&msg, &["cannot read", "check the path"]);

    let msg = error_of(load_text(dir.path(), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n"));
    assert_mentions(&msg, &["not a readable Wavefront OBJ"]);

    let msg = error_of(load_text(dir.path(), "v 0 0 0\nv 1 0 0\nv 0 1 0\n"));
    assert_mentions(&msg, &["no triangles"]);

    let nan = cube_text(&CUBE_FACES).replace("v 1 1 0\n", "v 1 nan 0\n");
    let msg = error_of(load_text(dir.path(), &nan));
    assert_mentions(&msg, &["vertex 3", "not finite", "NaN"]);
    let inf = cube_text(&CUBE_FACES).replace("v 0 1 1\n", "v 0 1 1e39\n");
    assert_mentions(&error_of(load_text(dir.path(), &inf)), &["vertex 8", "not finite", "inf"]);
    // A finite vertex past the coordinates a scene may use is said to be that, not called a
    // degenerate face (its faces' areas made every other face's look like nothing).
    let far = cube_text(&CUBE_FACES).replace("v 0 1 1\n", "v 0 1 1e30\n");
    let msg = error_of(load_text(dir.path(), &far));
    assert_mentions(&msg, &["vertex 8", "past +-1e9", "larger units"]);
    assert!(!msg.contains("degenerate"), "{msg}");
    let scaled = MeshTransform { scale: 1e10, ..identity };
    let msg = error_of(load_obj(&mesh_path("icosphere.obj"), &scaled));
    assert_mentions(&msg, &["past +-1e9", "after the transform"]);

    // Vertex 9 halfway along the edge 1-2: face 13 is a sliver of no area.
    let degenerate = cube_text(&CUBE_FACES) + "v 0.5 0 0\nf 1 9 2\n";
    let msg = error_of(load_text(dir.path(), &degenerate));
    assert_mentions(&msg, &["face 13", "vertices 1, 9, 2", "degenerate"]);

    let open = cube_text(&CUBE_FACES[..5]);
    let msg = error_of(load_text(dir.path(), &open));
    assert_mentions(&msg, &["not closed", "belongs to 1 triangle", "watertight"]);
    assert!(msg.contains("edge 2-") || msg.contains("edge 3-") || msg.contains("edge 6-") || msg.contains("edge 7-"));

    let inverted: Vec<[u32; 4]> = CUBE_FACES.iter().map(|&[a, b, c, d]| [d, c, b, a]).collect();
    let msg = error_of(load_text(dir.path(), &cube_text(&inverted)));
    assert_mentions(&msg, &["wound inward", "flip the winding"]);

    let mut one_flipped = CUBE_FACES;
    one_flipped[5].reverse();
    let msg = error_of(load_text(dir.path(), &cube_text(&one_flipped)));
    assert_mentions(&msg, &["wound inconsistently", "counter-clockwise"]);

    // A second cube sharing the edge 3-7 (at x = 1, y = 1): four triangles on one edge.
    let mut two = cube_text(&CUBE_FACES);
    two += "v 2 1 0\nv 2 2 0\nv 1 2 0\nv 2 1 1\nv 2 2 1\nv 1 2 1\n";
    for f in [[3, 11, 10, 9], [7, 12, 13, 14], [3, 9, 12, 7], [11, 14, 13, 10], [3, 7, 14, 11], [9, 10, 13, 12]] {
        two += &format!("f {} {} {} {}\n", f[0], f[1], f[2], f[3]);
    }
    let msg = error_of(load_text(dir.path(), &two));
    assert_mentions(&msg, &["2-manifold", "belongs to 4 triangles"]);

    let out_of_range = cube_text(&CUBE_FACES) + "f 1 2 9\n";
    let msg = error_of(load_text(dir.path(), &out_of_range));
    assert_mentions(&msg, &["line 15", "vertex 9", "8 vertices"]);
    let zero = cube_text(&CUBE_FACES).replace("f 5 6 7 8", "f 5 6 7 0");
    assert_mentions(&error_of(load_text(dir.path(), &zero)), &["line 10", "vertex 0", "count from 1"]);

    // A sheet modelled on both sides is closed and consistent but holds nothing.
    let sheet = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 2\n";
    assert_mentions(&error_of(load_text(dir.path(), sheet)), &["encloses no volume"]);

    let path = mesh_path("icosphere.obj");
    let msg = error_of(load_obj(&path, &MeshTransform { scale: 0.0, ..identity }));
    assert_mentions(&msg, &["invalid transform", "scale", "positive"]);
    let far = MeshTransform { translate: Vec3::new(3e38, 0.0, 0.0), scale: 1e38, ..identity };
    let msg = error_of(load_obj(&path, &far));
    assert_mentions(&msg, &["after the transform", "past +-1e9", "smaller scale"]);

    // None of them names a file: the caller prefixes the scene file and key.
    assert!(!msg.contains("icosphere"));
}

#[test]
fn mesh_convexity_is_decided_per_edge_and_by_connection() {
    // path's manifold next-event estimation needs a convex mesh (a straight path from inside
    // crosses the surface once): the icosphere and the cube are, the torus (a hole) and the
    // blob (dents) are not, and two cubes in one file are not either (locally convex at every
    // edge, but not one solid).
    assert!(load("icosphere.obj").is_convex());
    assert!(!load("torus.obj").is_convex());
    assert!(!load("blob.obj").is_convex());
    let dir = tempfile::tempdir().unwrap();
    let cube = load_text(dir.path(), &cube_text(&CUBE_FACES)).unwrap();
    assert!(cube.is_convex());
    // The same cube 3 units along x, in the same file.
    let shifted: String = CUBE_VERTICES
        .lines()
        .map(|l| {
            let f: Vec<f64> = l[2..].split(' ').map(|x| x.parse().unwrap()).collect();
            format!("v {} {} {}\n", f[0] + 3.0, f[1], f[2])
        })
        .collect();
    let mut two = cube_text(&CUBE_FACES) + &shifted;
    for f in CUBE_FACES {
        two += &format!("f {} {} {} {}\n", f[0] + 8, f[1] + 8, f[2] + 8, f[3] + 8);
    }
    let two = load_text(dir.path(), &two).unwrap();
    assert_eq!(two.triangles.len(), 24);
    assert!(!two.is_convex(), "two separate cubes taken for one convex solid");
}
