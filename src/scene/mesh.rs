//! Triangle meshes of scene format v2: a Wavefront OBJ file, placed in the scene by a
//! similarity transform and checked to bound a solid.
//!
//! A medium fills the inside of its mesh, and the solvers decide inside from outside by
//! counting surface crossings along a ray ([`super::bvh`]), so a mesh is only usable when it is
//! watertight: every edge joins exactly two triangles that run along it in opposite directions.
//! [`load_obj`] refuses anything else, and faces wound inward, with one-line [`MeshError`]s.
//!
//! Units: positions are in scene units, after the mesh's [`MeshTransform`]. Normals are
//! geometric, never read from the file: `cross(v1 - v0, v2 - v0)` of each triangle, which
//! points outward because a loaded mesh winds its faces counter-clockwise seen from outside.
//!
//! Numbering in messages: from 1, as in the OBJ file. Vertex `k` is the file's `k`-th `v` line
//! (`positions[k - 1]`); face `k` is the `k`-th triangle in file order (`triangles[k - 1]`),
//! which is the OBJ face number itself where the file has only triangles (quads and polygons
//! are split into fans, so each adds more than one).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Affine3A, DVec3, Quat, Vec3};

/// The 12 triangles of a box whose 8 corners are numbered with x from bit 0, y from bit 1 and
/// z from bit 2 (0 = low, 1 = high), counter-clockwise seen from outside.
pub const BOX_TRIANGLES: [[u32; 3]; 12] = [
    [0, 3, 1],
    [0, 2, 3], // -z
    [4, 5, 7],
    [4, 7, 6], // +z
    [0, 1, 5],
    [0, 5, 4], // -y
    [2, 6, 7],
    [2, 7, 3], // +y
    [0, 4, 6],
    [0, 6, 2], // -x
    [1, 3, 7],
    [1, 7, 5], // +x
];

/// A triangle mesh in scene units.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangleMesh {
    /// Every vertex of the file, in its `v` order, so that index `k - 1` is the file's vertex
    /// `k` (a file may hold vertices no triangle uses; [`TriangleMesh::bounds`], `area` and
    /// `volume` look at the triangles' vertices only).
    pub positions: Vec<Vec3>,
    /// Indices into `positions`, counter-clockwise seen from outside. Vertices at exactly the
    /// same position are one vertex here (the first of them), so edges are shared by index.
    pub triangles: Vec<[u32; 3]>,
    /// The OBJ file it came from.
    pub file: PathBuf,
}

/// Where a mesh sits in the scene: `p' = translate + scale * rotate(p)`.
///
/// `rotate_deg` are XYZ Euler angles in degrees, about the fixed scene axes (right-handed,
/// counter-clockwise looking down the axis toward the origin), applied X first, then Y, then
/// Z: `rotate = Rz * Ry * Rx`. So `[90, 90, 0]` takes +y to +z (X) and then +z to +x (Y).
/// The scale is uniform (the transform is a similarity), which keeps a watertight mesh
/// watertight, its orientation outward, and scales its volume by `scale^3`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshTransform {
    /// Scene units.
    pub translate: Vec3,
    /// Degrees, XYZ order as above.
    pub rotate_deg: Vec3,
    /// Finite and positive (a negative one would mirror the mesh and wind it inward).
    pub scale: f32,
}

impl MeshTransform {
    /// The transform that leaves the file's coordinates as they are.
    pub fn identity() -> Self {
        MeshTransform { translate: Vec3::ZERO, rotate_deg: Vec3::ZERO, scale: 1.0 }
    }

    /// The affine map `p -> translate + scale * rotate(p)`.
    pub fn matrix(&self) -> Affine3A {
        let r = self.rotate_deg * (std::f32::consts::PI / 180.0);
        // Quaternion products apply right to left: X first.
        let rotation = Quat::from_rotation_z(r.z) * Quat::from_rotation_y(r.y) * Quat::from_rotation_x(r.x);
        Affine3A::from_scale_rotation_translation(Vec3::splat(self.scale), rotation, self.translate)
    }

    fn check(&self) -> Result<(), MeshError> {
        let problem = if !(self.scale.is_finite() && self.scale > 0.0) {
            format!("scale must be finite and positive, not {}", self.scale)
        } else if !self.rotate_deg.is_finite() {
            format!("rotation must be finite, not {}", fmt_vec(self.rotate_deg))
        } else if !self.translate.is_finite() {
            format!("translation must be finite, not {}", fmt_vec(self.translate))
        } else {
            return Ok(());
        };
        Err(MeshError::Transform { problem })
    }
}

impl Default for MeshTransform {
    fn default() -> Self {
        Self::identity()
    }
}

/// Why a mesh cannot bound a medium. `Display` is one line that says what is wrong and what to
/// do, with vertex and face numbers counted from 1 (see the module documentation); it does not
/// name the mesh or scene file, which the caller says.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The file could not be read (missing, a directory, no permission).
    #[error("cannot read the mesh file: {source}; check the path")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The text is not OBJ as `tobj` reads it; `message` is `tobj`'s.
    #[error("not a readable Wavefront OBJ file ({message}); a mesh needs `v x y z` and `f i j k` lines")]
    Parse { message: String },

    /// A face refers to a vertex the file does not have.
    #[error("line {line}: a face refers to vertex {index}, but the file has {vertices} vertices (OBJ indices count from 1, negative ones back from the latest vertex); fix the face's indices")]
    IndexOutOfRange { line: usize, index: i64, vertices: usize },

    /// No face with three or more vertices (points and lines are ignored).
    #[error("the file has no triangles (no `f` line with 3 or more vertices); a medium needs a closed triangle mesh")]
    NoTriangles,

    /// A coordinate of the file is NaN or infinite.
    #[error("vertex {vertex} is not finite {}; give every coordinate as a finite number", fmt_vec(*.position))]
    NonFiniteVertex { vertex: usize, position: Vec3 },

    /// The transform itself is unusable.
    #[error("invalid transform: {problem}")]
    Transform { problem: String },

    /// The transform carries a vertex beyond the range of f32.
    #[error("vertex {vertex} is not finite after the transform {}; use a smaller scale or translation", fmt_vec(*.position))]
    TransformOverflow { vertex: usize, position: Vec3 },

    /// A vertex past the coordinates a scene may use (docs/scene-format.md, "Magnitudes"),
    /// as read or after the transform: checked before the faces, whose areas it would make
    /// every other face's look like nothing.
    #[error("vertex {vertex} at {} is past +-{max:e} (after the transform): the solvers step through the scene in 32-bit floats, whose steps vanish against coordinates that large; use a smaller scale or translation, or express the mesh in larger units", fmt_vec(*.position))]
    VertexTooFar { vertex: usize, position: Vec3, max: f32 },

    /// A triangle without area: its vertices coincide or lie on a line.
    #[error("face {face} (vertices {}, {}, {}) is degenerate: its vertices coincide or lie on a line (area {}); remove it and reconnect its neighbours", .vertices[0], .vertices[1], .vertices[2], fmt_num(*.area))]
    Degenerate { face: usize, vertices: [usize; 3], area: f64 },

    /// An edge used by one triangle (a hole) or by more than two (not a 2-manifold).
    #[error("{}", edge_message(*.a, *.b, *.triangles))]
    Edge { a: usize, b: usize, triangles: usize },

    /// Two triangles run along their shared edge the same way: their windings disagree.
    #[error("faces {} and {} are wound inconsistently (both run along edge {a}-{b} from {a} to {b}); wind every face counter-clockwise seen from outside", .faces[0], .faces[1])]
    Inconsistent { a: usize, b: usize, faces: [usize; 2] },

    /// Closed and consistent, but wound the wrong way round.
    #[error("faces are wound inward (clockwise seen from outside: the enclosed volume comes out as {}); flip the winding", fmt_num(*.volume))]
    Inverted { volume: f64 },

    /// Closed and consistent, but enclosing nothing (e.g. a sheet with both sides modelled).
    #[error("the mesh encloses no volume (volume {}); a medium needs a solid, not a surface", fmt_num(*.volume))]
    NoVolume { volume: f64 },
}

fn edge_message(a: usize, b: usize, triangles: usize) -> String {
    if triangles < 2 {
        format!(
            "the mesh is not closed (edge {a}-{b} belongs to {triangles} triangle); a medium needs a watertight mesh"
        )
    } else {
        format!(
            "the mesh is not a 2-manifold (edge {a}-{b} belongs to {triangles} triangles); a medium needs a watertight \
             mesh whose every edge joins exactly two triangles"
        )
    }
}

/// Four decimals (trailing zeros dropped), or scientific notation where those would hide the value.
fn fmt_num(x: f64) -> String {
    if x == 0.0 || (1e-3..1e6).contains(&x.abs()) {
        format!("{:.4}", x).trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        format!("{x:.3e}")
    }
}

fn fmt_vec(v: Vec3) -> String {
    let c = |x: f32| {
        if !x.is_finite() || x == 0.0 || (1e-4..1e6).contains(&x.abs()) {
            x.to_string()
        } else {
            format!("{x:e}")
        }
    };
    format!("({}, {}, {})", c(v.x), c(v.y), c(v.z))
}

/// Read an OBJ file as one mesh, place it with `transform`, and check it can bound a medium:
/// every vertex of the file finite, no degenerate triangle, watertight and consistently
/// oriented ([`check_closed`]), wound outward (positive volume).
///
/// Every object and group of the file joins the one mesh; quads and polygons are split into
/// fans; normals, texture coordinates and materials (`mtllib`, `usemtl`) are ignored, as are
/// points and lines. Vertices at exactly the same position are welded (as
/// [`TriangleMesh::triangles`] says), so a file that repeats a vertex per face, as exporters
/// writing per-face normals do, still counts as closed.
///
/// [`check_closed`]: TriangleMesh::check_closed
pub fn load_obj(path: &Path, transform: &MeshTransform) -> Result<TriangleMesh, MeshError> {
    transform.check()?;
    let bytes = std::fs::read(path).map_err(|source| MeshError::Read { path: path.to_owned(), source })?;
    // The update covers the fields tobj's optional features add.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Materials belong to the scene file: a `mtllib` line loads nothing.
    let (models, _) = tobj::load_obj_buf(&mut bytes.as_slice(), &options, |_| Err(tobj::LoadError::OpenFileFailed))
        .map_err(|e| match e {
            tobj::LoadError::FaceVertexOutOfBounds => {
                bad_face_index(&bytes).unwrap_or(MeshError::Parse { message: e.to_string() })
            }
            e => MeshError::Parse { message: e.to_string() },
        })?;

    // tobj renumbers vertices per object in order of first use, and duplicates them where faces
    // give them different normals; the file's own list (read again here, as tobj reads it) keeps
    // messages in the file's numbering, and welding by exact position restores shared edges.
    let text = std::str::from_utf8(&bytes).map_err(|e| MeshError::Parse { message: e.to_string() })?;
    let mut positions = file_positions(text)?;
    if let Some(k) = positions.iter().position(|p| !p.is_finite()) {
        return Err(MeshError::NonFiniteVertex { vertex: k + 1, position: positions[k] });
    }
    let mut first_at: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
    for (k, p) in positions.iter().enumerate() {
        first_at.entry(weld_key(*p)).or_insert(k as u32);
    }
    let mut triangles = Vec::new();
    for model in &models {
        let mesh = &model.mesh;
        let mut index_of = |i: u32| -> u32 {
            let i = i as usize * 3;
            let p = Vec3::new(mesh.positions[i], mesh.positions[i + 1], mesh.positions[i + 2]);
            // Always found, since both lists come from the same `v` lines; appending keeps an
            // unforeseen tobj behaviour from turning into a panic.
            *first_at.entry(weld_key(p)).or_insert_with(|| {
                positions.push(p);
                positions.len() as u32 - 1
            })
        };
        for t in mesh.indices.chunks_exact(3) {
            triangles.push([index_of(t[0]), index_of(t[1]), index_of(t[2])]);
        }
    }
    if triangles.is_empty() {
        return Err(MeshError::NoTriangles);
    }

    let matrix = transform.matrix();
    for (k, p) in positions.iter_mut().enumerate() {
        *p = matrix.transform_point3(*p);
        if !p.is_finite() {
            return Err(MeshError::TransformOverflow { vertex: k + 1, position: *p });
        }
        if p.abs().max_element() > super::parse::COORDINATE_MAX {
            return Err(MeshError::VertexTooFar { vertex: k + 1, position: *p, max: super::parse::COORDINATE_MAX });
        }
    }
    let mesh = TriangleMesh { positions, triangles, file: path.to_owned() };

    let (lo, hi) = mesh.bounds();
    let diagonal = (hi.as_dvec3() - lo.as_dvec3()).length();
    for (f, t) in mesh.triangles.iter().enumerate() {
        let area = mesh.triangle_area(t);
        if area < 1e-12 * diagonal * diagonal {
            return Err(MeshError::Degenerate { face: f + 1, vertices: t.map(|i| i as usize + 1), area });
        }
    }
    mesh.check_closed()?;
    let volume = mesh.volume();
    if volume.abs() <= 1e-9 * diagonal.powi(3) {
        return Err(MeshError::NoVolume { volume });
    }
    if volume < 0.0 {
        return Err(MeshError::Inverted { volume });
    }
    Ok(mesh)
}

/// Exactly equal positions share a key (both zeros included, so -0 welds to +0).
fn weld_key(p: Vec3) -> [u32; 3] {
    (p + Vec3::ZERO).to_array().map(f32::to_bits)
}

/// The `v` lines of an OBJ text, parsed as tobj parses them (three f32, an optional fourth `w`
/// dividing them; three more are a vertex colour).
fn file_positions(text: &str) -> Result<Vec<Vec3>, MeshError> {
    let mut positions = Vec::new();
    for line in text.lines() {
        let mut words = line.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        let rest: Vec<&str> = words.collect();
        let parse = |s: &str| s.parse::<f32>().map_err(|e| MeshError::Parse { message: format!("vertex {s:?}: {e}") });
        if rest.len() < 3 {
            return Err(MeshError::Parse { message: "a `v` line with fewer than 3 coordinates".into() });
        }
        let mut p = Vec3::new(parse(rest[0])?, parse(rest[1])?, parse(rest[2])?);
        if rest.len() == 4 {
            let w = parse(rest[3])?;
            p = Vec3::new(p.x / w, p.y / w, p.z / w);
        }
        positions.push(p);
    }
    Ok(positions)
}

/// The first face (of three or more vertices, the ones tobj keeps) whose position index falls
/// outside the file's vertices, for a message with its line; `None` where tobj's complaint was
/// about something this does not see.
fn bad_face_index(bytes: &[u8]) -> Option<MeshError> {
    let text = std::str::from_utf8(bytes).ok()?;
    let vertices = text.lines().filter(|l| l.split_whitespace().next() == Some("v")).count();
    let mut seen = 0usize;
    for (n, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => seen += 1,
            Some("f") => {
                let corners: Vec<&str> = words.collect();
                if corners.len() < 3 {
                    continue;
                }
                for corner in corners {
                    let index: i64 = corner.split('/').next()?.parse().ok()?;
                    let resolved = if index < 0 { seen as i64 + index } else { index - 1 };
                    if resolved < 0 || resolved >= vertices as i64 {
                        return Some(MeshError::IndexOutOfRange { line: n + 1, index, vertices });
                    }
                }
            }
            _ => {}
        }
    }
    None
}

impl TriangleMesh {
    /// The meshes as one: positions and triangles concatenated in order (indices offset, no
    /// welding across meshes), named after the first. One mesh comes back unchanged. Closed
    /// meshes give a closed union; disjoint ones bound the union of their insides.
    pub fn union(meshes: Vec<TriangleMesh>) -> TriangleMesh {
        let mut it = meshes.into_iter();
        let mut out = it.next().expect("at least one mesh");
        for m in it {
            let offset = u32::try_from(out.positions.len()).expect("a mesh holds at most 2^32 vertices");
            out.positions.extend_from_slice(&m.positions);
            out.triangles.extend(m.triangles.iter().map(|t| t.map(|i| i + offset)));
        }
        out
    }

    /// Axis-aligned bounds `(min, max)` of the triangles' vertices, in scene units; a mesh
    /// without triangles has the empty box `(+inf, -inf)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for &i in self.triangles.iter().flatten() {
            let p = self.positions[i as usize];
            lo = lo.min(p);
            hi = hi.max(p);
        }
        (lo, hi)
    }

    /// Surface area in square scene units (summed in f64).
    pub fn area(&self) -> f64 {
        self.triangles.iter().map(|t| self.triangle_area(t)).sum()
    }

    /// Enclosed volume in cubic scene units by the divergence theorem (summed in f64): positive
    /// when the faces wind outward, negative when inward; only meaningful for a closed mesh.
    pub fn volume(&self) -> f64 {
        // Any reference point gives the same sum for a closed mesh; the box centre keeps the
        // terms small, so a mesh far from the origin loses no precision to cancellation.
        let (lo, hi) = self.bounds();
        let centre = (lo.as_dvec3() + hi.as_dvec3()) * 0.5;
        let sum: f64 = self
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t).map(|p| p - centre);
                a.dot(b.cross(c))
            })
            .sum();
        sum / 6.0
    }

    /// Check the mesh is watertight: every undirected edge is shared by exactly two triangles,
    /// which run along it in opposite directions (so the orientation is consistent across it).
    /// Whether the mesh (closed and consistently wound, as loaded) bounds one convex solid:
    /// connected, and across every edge the neighbouring triangle's far vertex lies behind (or,
    /// within float rounding of the mesh's size, on) the triangle's plane. A closed connected
    /// surface that is locally convex at every edge is the boundary of a convex body
    /// (Hadamard's theorem for surfaces), so O(edges) checks decide it.
    pub fn is_convex(&self) -> bool {
        let n = self.triangles.len();
        if n == 0 {
            return false;
        }
        let key = |a: u32, b: u32| (u64::from(a) << 32) | u64::from(b);
        let mut across: HashMap<u64, usize> = HashMap::with_capacity(n * 3);
        for (f, t) in self.triangles.iter().enumerate() {
            for k in 0..3 {
                across.insert(key(t[k], t[(k + 1) % 3]), f);
            }
        }
        let (lo, hi) = self.bounds();
        let tol = 1e-6 * f64::from((hi - lo).length());
        let mut parent: Vec<usize> = (0..n).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for (f, t) in self.triangles.iter().enumerate() {
            let [a, b, c] = self.corners(t);
            let normal = (b - a).cross(c - a).normalize_or_zero();
            for k in 0..3 {
                let Some(&g) = across.get(&key(t[(k + 1) % 3], t[k])) else { return false };
                let u = self.triangles[g];
                let far = u.iter().find(|v| !t.contains(v)).copied().unwrap_or(u[0]);
                if (self.positions[far as usize].as_dvec3() - a).dot(normal) > tol {
                    return false;
                }
                let (rf, rg) = (root(&mut parent, f), root(&mut parent, g));
                parent[rf] = rg;
            }
        }
        let r = root(&mut parent, 0);
        (1..n).all(|f| root(&mut parent, f) == r)
    }

    /// Reports the first offending edge in face order, with its vertices numbered from 1.
    /// Looks at indices only, so it never reads `positions`.
    pub fn check_closed(&self) -> Result<(), MeshError> {
        /// Triangles running along one directed edge: how many, and the first two (0-based).
        #[derive(Default, Clone, Copy)]
        struct Uses {
            count: usize,
            faces: [usize; 2],
        }
        let edges = |t: &[u32; 3]| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])];
        let key = |(a, b): (u32, u32)| (u64::from(a) << 32) | u64::from(b);

        let mut directed: HashMap<u64, Uses> = HashMap::with_capacity(self.triangles.len() * 3);
        for (f, t) in self.triangles.iter().enumerate() {
            if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
                return Err(MeshError::Degenerate { face: f + 1, vertices: t.map(|i| i as usize + 1), area: 0.0 });
            }
            for e in edges(t) {
                let uses = directed.entry(key(e)).or_default();
                if uses.count < 2 {
                    uses.faces[uses.count] = f;
                }
                uses.count += 1;
            }
        }
        for t in &self.triangles {
            for (a, b) in edges(t) {
                let along = directed[&key((a, b))];
                let back = directed.get(&key((b, a))).map_or(0, |u| u.count);
                let (va, vb) = (a as usize + 1, b as usize + 1);
                if along.count + back != 2 {
                    return Err(MeshError::Edge { a: va, b: vb, triangles: along.count + back });
                }
                if along.count == 2 {
                    return Err(MeshError::Inconsistent { a: va, b: vb, faces: along.faces.map(|f| f + 1) });
                }
            }
        }
        Ok(())
    }

    fn corners(&self, t: &[u32; 3]) -> [DVec3; 3] {
        t.map(|i| self.positions[i as usize].as_dvec3())
    }

    fn triangle_area(&self, t: &[u32; 3]) -> f64 {
        let [a, b, c] = self.corners(t);
        0.5 * (b - a).cross(c - a).length()
    }
}
