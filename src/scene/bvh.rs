//! A bounding volume hierarchy over a [`TriangleMesh`], built on the host and traversed by the
//! GPU to find where rays cross a mesh medium's surface.
//!
//! The two buffers are the GPU layout, uploaded as they are (std430):
//!
//! ```glsl
//! struct BvhNode { vec3 min; uint left_or_first; vec3 max; uint count; };  // 32 bytes
//! struct Triangle { vec4 v0; vec4 e1; vec4 e2; };                          // 48 bytes
//! ```
//!
//! Node 0 is the root and its box is the mesh's bounds. A node with `count == 0` is interior:
//! its children are the adjacent nodes `left_or_first` and `left_or_first + 1`. A node with
//! `count > 0` is a leaf holding triangles `left_or_first .. left_or_first + count` (at most
//! [`MAX_LEAF`]). The tree is at most [`MAX_DEPTH`] nodes deep, so a traversal that keeps one
//! deferred child per level fits a fixed stack of [`MAX_DEPTH`] entries.
//!
//! [`Bvh::intersect`] is the traversal the shader does, step for step, written here so that the
//! layout has an executable definition and the tests can hold the GPU code to it.

use bytemuck::Zeroable as _;
use glam::Vec3;

use super::mesh::TriangleMesh;

/// Longest root-to-leaf path, in nodes (the root alone is depth 1), and so the size of the
/// traversal stack, which holds at most one deferred child per level below the root.
pub const MAX_DEPTH: u32 = 64;
/// Most triangles in a leaf.
pub const MAX_LEAF: usize = 4;
/// SAH bins per axis.
const BINS: usize = 16;
/// From this depth on, nodes split at the median instead of by SAH. A median split halves the
/// triangles, and a node at this depth holds fewer than 2^32 of them, so at most
/// log2(2^32 / MAX_LEAF) = 30 more levels follow: depth <= 62 < MAX_DEPTH for any mesh,
/// however degenerate its triangle distribution.
const SAH_DEPTH_LIMIT: u32 = 32;
/// Cost of visiting a node (testing two child boxes) relative to one triangle test.
const TRAVERSAL_COST: f32 = 1.0;
/// Slack on a box's far distance, 2 gamma(3) in Ize's "Robust BVH Ray Traversal" (2013): the
/// rounding of the slab distances then never culls a box that the ray actually meets.
const FAR_SLACK: f32 = 3.6e-7;

/// One node of the tree (the GPU's `BvhNode`). Scene units.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct BvhNode {
    pub min: [f32; 3],
    /// Interior: index of the left child (the right one follows it). Leaf: first triangle.
    pub left_or_first: u32,
    pub max: [f32; 3],
    /// 0 for an interior node; the number of triangles of a leaf.
    pub count: u32,
}

/// One triangle as the GPU tests it: a corner and the two edges from it (Moller-Trumbore
/// needs exactly these). `v0[3]` holds the triangle's tag as `f32` bits (its material: 0 for one
/// material, [`Bvh::build_tagged`]); the other `w`s are 0. Scene units.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTriangle {
    pub v0: [f32; 4],
    /// `v1 - v0`.
    pub e1: [f32; 4],
    /// `v2 - v0`.
    pub e2: [f32; 4],
}

const _: () = assert!(std::mem::size_of::<BvhNode>() == 32 && std::mem::size_of::<GpuTriangle>() == 48);

/// The hierarchy and its triangles, in the order the leaves refer to them.
#[derive(Debug, Clone, PartialEq)]
pub struct Bvh {
    /// Root first; empty only for a mesh without triangles (which `load_obj` never returns).
    pub nodes: Vec<BvhNode>,
    /// The mesh's triangles, reordered so that each leaf's are contiguous.
    pub triangles: Vec<GpuTriangle>,
    /// Longest root-to-leaf path in nodes (1 for a root that is a leaf), <= [`MAX_DEPTH`].
    pub depth: u32,
}

/// The closest crossing of a ray with the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter: the crossing is at `o + t * d` (in scene units when `d` is a unit vector).
    pub t: f32,
    /// Index into [`Bvh::triangles`] (leaf order, not the mesh's order).
    pub triangle: u32,
    /// Unit geometric normal `normalize(cross(e1, e2))`: outward for a loaded mesh, whichever
    /// side the ray came from (the sign of `dot(normal, d)` says whether it enters or leaves).
    pub normal: Vec3,
}

/// A triangle's bounds and centroid, what the build sorts by.
#[derive(Clone, Copy)]
struct Primitive {
    min: Vec3,
    max: Vec3,
    centroid: Vec3,
}

#[derive(Clone, Copy)]
struct Aabb {
    min: Vec3,
    max: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) };

    fn grow(&mut self, min: Vec3, max: Vec3) {
        self.min = self.min.min(min);
        self.max = self.max.max(max);
    }

    /// Half the surface area (the SAH only compares areas); 0 for an empty box.
    fn half_area(&self) -> f32 {
        let e = (self.max - self.min).max(Vec3::ZERO);
        e.x * e.y + e.y * e.z + e.z * e.x
    }
}

/// Where a split puts a node's triangles.
enum Split {
    Leaf,
    /// Triangles whose centroid falls in bins `0 ..= bin` along `axis` go left.
    Binned {
        axis: usize,
        bin: usize,
        cmin: f32,
        scale: f32,
    },
    /// The first half, by centroid along `axis`, goes left.
    Median {
        axis: usize,
    },
}

struct Builder<'a> {
    primitives: &'a [Primitive],
    /// Mesh triangle indices, permuted so that each node's are contiguous.
    order: Vec<u32>,
    nodes: Vec<BvhNode>,
}

impl Bvh {
    /// Build by binned SAH (16 bins per axis, leaves of at most [`MAX_LEAF`] triangles,
    /// kept as a leaf where the SAH says splitting does not pay). A mesh of `n` triangles gives
    /// at most `2n - 1` nodes.
    pub fn build(mesh: &TriangleMesh) -> Bvh {
        Bvh::build_tagged(mesh, &[])
    }

    /// The tag [`Bvh::build_tagged`] gave triangle `triangle` (an index into [`Bvh::triangles`],
    /// as [`Hit::triangle`]): its object's material.
    pub fn tag(&self, triangle: u32) -> u32 {
        self.triangles[triangle as usize].v0[3].to_bits()
    }

    /// [`Bvh::build`] with a tag per triangle of `mesh` (its order; missing tags are 0) in each
    /// [`GpuTriangle`]'s `v0[3]` as `f32` bits: the index of its object's material.
    pub fn build_tagged(mesh: &TriangleMesh, tags: &[u32]) -> Bvh {
        let n = mesh.triangles.len();
        assert!(u32::try_from(n).is_ok(), "a BVH holds at most 2^32 - 1 triangles");
        if n == 0 {
            return Bvh { nodes: Vec::new(), triangles: Vec::new(), depth: 0 };
        }
        let corners = |t: &[u32; 3]| t.map(|i| mesh.positions[i as usize]);
        let primitives: Vec<Primitive> = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = corners(t);
                Primitive { min: a.min(b).min(c), max: a.max(b).max(c), centroid: (a + b + c) / 3.0 }
            })
            .collect();
        let mut builder =
            Builder { primitives: &primitives, order: (0..n as u32).collect(), nodes: Vec::with_capacity(2 * n - 1) };
        builder.nodes.push(BvhNode::zeroed());
        let depth = builder.build_node(0, 0, n, 1);
        assert!(depth <= MAX_DEPTH, "BVH depth {depth} exceeds the traversal stack ({MAX_DEPTH})");
        let triangles = builder
            .order
            .iter()
            .map(|&i| {
                let [a, b, c] = corners(&mesh.triangles[i as usize]);
                let tag = tags.get(i as usize).copied().unwrap_or(0);
                GpuTriangle {
                    v0: a.extend(f32::from_bits(tag)).to_array(),
                    e1: (b - a).extend(0.0).to_array(),
                    e2: (c - a).extend(0.0).to_array(),
                }
            })
            .collect();
        Bvh { nodes: builder.nodes, triangles, depth }
    }

    /// Closest crossing with `t` in the open interval `(t_min, t_max)`, from either side of the
    /// surface (Moller-Trumbore without culling), or `None`.
    ///
    /// The shader's traversal: an explicit stack, the nearer child first, the farther one
    /// deferred with its entry distance and skipped when popped if a closer hit has been found
    /// since. `d` need not be normalised.
    pub fn intersect(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Option<Hit> {
        self.intersect_counted(o, d, t_min, t_max).0
    }

    /// [`Bvh::intersect`] and the loop iterations the shader's traversal takes for it
    /// (glsl/include/mesh.glsl's `iters`: one per node visited, per leaf triangle tested and
    /// per deferred child popped), what one query costs a lane against llvmpipe's loop limit.
    pub fn intersect_counted(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> (Option<Hit>, u32) {
        let mut iters = 0u32;
        if self.nodes.is_empty() {
            return (None, iters);
        }
        let inv_d = safe_inverse(d);
        let mut closest = t_max;
        let mut hit = u32::MAX;
        // At most one deferred child per level below the root: MAX_DEPTH - 1 entries.
        let mut stack_node = [0u32; MAX_DEPTH as usize];
        let mut stack_t = [0f32; MAX_DEPTH as usize];
        let mut sp = 0usize;

        if slab(&self.nodes[0], o, inv_d, t_min, closest) == f32::INFINITY {
            return (None, iters);
        }
        let mut node = 0u32;
        loop {
            iters += 1;
            let n = self.nodes[node as usize];
            if n.count > 0 {
                for i in n.left_or_first..n.left_or_first + n.count {
                    iters += 1;
                    let t = moller_trumbore(&self.triangles[i as usize], o, d);
                    if t > t_min && t < closest {
                        closest = t;
                        hit = i;
                    }
                }
            } else {
                let left = n.left_or_first;
                let right = left + 1;
                let t_left = slab(&self.nodes[left as usize], o, inv_d, t_min, closest);
                let t_right = slab(&self.nodes[right as usize], o, inv_d, t_min, closest);
                let (near, t_near, far, t_far) =
                    if t_left <= t_right { (left, t_left, right, t_right) } else { (right, t_right, left, t_left) };
                if t_near != f32::INFINITY {
                    if t_far != f32::INFINITY {
                        stack_node[sp] = far;
                        stack_t[sp] = t_far;
                        sp += 1;
                    }
                    node = near;
                    continue;
                }
            }
            // Nothing below this node: resume at the nearest deferred child still in front of
            // the closest hit.
            loop {
                if sp == 0 {
                    return ((hit != u32::MAX).then(|| self.hit(hit, closest)), iters);
                }
                iters += 1;
                sp -= 1;
                if stack_t[sp] < closest {
                    node = stack_node[sp];
                    break;
                }
            }
        }
    }

    /// The most loop iterations ([`Bvh::intersect_counted`]) any of `rays` closest-hit queries
    /// took: rays from points uniform in the root box, in directions uniform on the sphere
    /// (seeded, so the same tree gives the same figure). Most meshes take a few dozen and at
    /// most a few hundred (the shipped icosphere 80, torus 123, blob 180 at 20000 rays, seed
    /// 1); a mesh whose triangles' boxes pile up along rays takes thousands (a cone whose side
    /// is a fan of 8192 triangles about its apex: 14491), which one lane's query spends in a
    /// loop that cannot pause.
    pub fn worst_query(&self, rays: u32, seed: u64) -> u32 {
        let Some(root) = self.nodes.first() else { return 0 };
        let (lo, hi) = (Vec3::from(root.min), Vec3::from(root.max));
        let mut rng = crate::physics::rng::Pcg32::new(seed, 0x62766871);
        let mut worst = 0;
        for _ in 0..rays {
            let o = lo + (hi - lo) * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let z = 2.0 * rng.next_f32() - 1.0;
            let phi = std::f32::consts::TAU * rng.next_f32();
            let r = (1.0 - z * z).max(0.0).sqrt();
            let (_, n) = self.intersect_counted(o, Vec3::new(r * phi.cos(), r * phi.sin(), z), 0.0, f32::INFINITY);
            worst = worst.max(n);
        }
        worst
    }

    /// Device memory of the two buffers, in bytes.
    pub fn bytes(&self) -> u64 {
        (self.nodes.len() * std::mem::size_of::<BvhNode>() + self.triangles.len() * std::mem::size_of::<GpuTriangle>())
            as u64
    }

    /// The point of the surface nearest `p` and its distance (scene units); `None` for a tree
    /// without triangles. Nearer child first by the squared distance to its box, a child
    /// skipped once its box lies farther than the nearest point found (exact: every triangle
    /// that could be nearer is tested). sh-single's offset surfaces (thesis 3.2.2) are the
    /// level sets of this distance.
    pub fn closest_point(&self, p: Vec3) -> Option<(Vec3, f32)> {
        if self.nodes.is_empty() {
            return None;
        }
        let box_d2 = |n: &BvhNode| {
            let q = p.clamp(Vec3::from(n.min), Vec3::from(n.max));
            q.distance_squared(p)
        };
        let (mut best, mut best_d2) = (p, f32::INFINITY);
        let mut stack = [(0u32, 0f32); MAX_DEPTH as usize + 1];
        let mut sp = 1usize;
        stack[0] = (0, box_d2(&self.nodes[0]));
        while sp > 0 {
            sp -= 1;
            let (node, d2) = stack[sp];
            if d2 >= best_d2 {
                continue;
            }
            let n = self.nodes[node as usize];
            if n.count > 0 {
                for i in n.left_or_first..n.left_or_first + n.count {
                    let q = closest_on_triangle(&self.triangles[i as usize], p);
                    let d2 = q.distance_squared(p);
                    if d2 < best_d2 {
                        (best, best_d2) = (q, d2);
                    }
                }
            } else {
                let (l, r) = (n.left_or_first, n.left_or_first + 1);
                let (dl, dr) = (box_d2(&self.nodes[l as usize]), box_d2(&self.nodes[r as usize]));
                // The farther child below the nearer one, so the nearer is visited first.
                let (near, d_near, far, d_far) = if dl <= dr { (l, dl, r, dr) } else { (r, dr, l, dl) };
                stack[sp] = (far, d_far);
                stack[sp + 1] = (near, d_near);
                sp += 2;
            }
        }
        best_d2.is_finite().then(|| (best, best_d2.sqrt()))
    }

    fn hit(&self, triangle: u32, t: f32) -> Hit {
        let tri = &self.triangles[triangle as usize];
        let normal = Vec3::from_slice(&tri.e1).cross(Vec3::from_slice(&tri.e2)).normalize_or_zero();
        Hit { t, triangle, normal }
    }
}

/// The point of triangle `t` nearest `p`: Ericson, Real-Time Collision Detection (2005),
/// 5.1.5, by the Voronoi regions of the corners, edges and face.
fn closest_on_triangle(t: &GpuTriangle, p: Vec3) -> Vec3 {
    let a = Vec3::from_slice(&t.v0[..3]);
    let (ab, ac) = (Vec3::from_slice(&t.e1[..3]), Vec3::from_slice(&t.e2[..3]));
    let ap = p - a;
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = ap - ab;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return a + ab;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = ap - ac;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return a + ac;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return a + ab + (ac - ab) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// `1 / d` with zero components replaced by a tiny value of the same sign, so that the slab
/// distances are never `0 * inf = NaN` (a ray lying in a box face's plane counts as inside it).
fn safe_inverse(d: Vec3) -> Vec3 {
    let guard = |x: f32| if x.abs() < 1e-30 { 1e30f32.copysign(x) } else { 1.0 / x };
    Vec3::new(guard(d.x), guard(d.y), guard(d.z))
}

/// Entry distance of the ray into the node's box, clipped to `[t_min, t_max]`, or `+inf` where
/// the ray misses the box within that interval.
fn slab(node: &BvhNode, o: Vec3, inv_d: Vec3, t_min: f32, t_max: f32) -> f32 {
    let t0 = (Vec3::from(node.min) - o) * inv_d;
    let t1 = (Vec3::from(node.max) - o) * inv_d;
    let near = t0.min(t1).max_element().max(t_min);
    let far = t0.max(t1).min_element();
    let far = (far + far.abs() * FAR_SLACK).min(t_max);
    if near <= far {
        near
    } else {
        f32::INFINITY
    }
}

/// Moller-Trumbore: the ray parameter where `o + t d` meets the triangle (either side), or
/// `+inf`. Each test is written so that a NaN fails it.
fn moller_trumbore(tri: &GpuTriangle, o: Vec3, d: Vec3) -> f32 {
    let v0 = Vec3::from_slice(&tri.v0);
    let e1 = Vec3::from_slice(&tri.e1);
    let e2 = Vec3::from_slice(&tri.e2);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return f32::INFINITY; // the ray runs parallel to the triangle's plane
    }
    let inv_det = 1.0 / det;
    let s = o - v0;
    let u = s.dot(p) * inv_det;
    if !(0.0..=1.0).contains(&u) {
        return f32::INFINITY;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv_det;
    if !(v >= 0.0 && u + v <= 1.0) {
        return f32::INFINITY;
    }
    let t = e2.dot(q) * inv_det;
    if t.is_nan() {
        f32::INFINITY
    } else {
        t
    }
}

impl Builder<'_> {
    /// Fill in node `index` over `order[start..end]` and its subtree; returns the subtree's depth
    /// counted from the root (`depth` is this node's).
    fn build_node(&mut self, index: usize, start: usize, end: usize, depth: u32) -> u32 {
        let mut bounds = Aabb::EMPTY;
        let mut centroids = Aabb::EMPTY;
        for &i in &self.order[start..end] {
            let p = &self.primitives[i as usize];
            bounds.grow(p.min, p.max);
            centroids.grow(p.centroid, p.centroid);
        }
        self.nodes[index].min = bounds.min.to_array();
        self.nodes[index].max = bounds.max.to_array();

        let mid = match self.choose(start, end, depth, &bounds, &centroids) {
            Split::Leaf => {
                self.nodes[index].left_or_first = start as u32;
                self.nodes[index].count = (end - start) as u32;
                return depth;
            }
            Split::Binned { axis, bin, cmin, scale } => {
                let (primitives, order) = (self.primitives, &mut self.order[start..end]);
                let mut left = 0;
                for k in 0..order.len() {
                    if bin_of(primitives[order[k] as usize].centroid[axis], cmin, scale) <= bin {
                        order.swap(left, k);
                        left += 1;
                    }
                }
                start + left
            }
            Split::Median { axis } => {
                let primitives = self.primitives;
                let half = (end - start) / 2;
                self.order[start..end].select_nth_unstable_by(half, |&a, &b| {
                    primitives[a as usize].centroid[axis].total_cmp(&primitives[b as usize].centroid[axis])
                });
                start + half
            }
        };
        let left = self.nodes.len();
        self.nodes[index].left_or_first = left as u32;
        self.nodes[index].count = 0;
        self.nodes.extend([BvhNode::zeroed(); 2]);
        let depth_left = self.build_node(left, start, mid, depth + 1);
        let depth_right = self.build_node(left + 1, mid, end, depth + 1);
        depth_left.max(depth_right)
    }

    /// The split with the lowest surface area heuristic cost over every axis's bin boundaries,
    /// or a leaf where that is cheaper and allowed.
    fn choose(&self, start: usize, end: usize, depth: u32, bounds: &Aabb, centroids: &Aabb) -> Split {
        let count = end - start;
        let extent = centroids.max - centroids.min;
        let widest = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        if count == 1 {
            return Split::Leaf;
        }
        if depth >= SAH_DEPTH_LIMIT {
            return if count <= MAX_LEAF { Split::Leaf } else { Split::Median { axis: widest } };
        }

        let mut best: Option<(f32, Split)> = None;
        for axis in 0..3 {
            // All centroids on one plane: this axis cannot separate them.
            if extent[axis].is_nan() || extent[axis] <= 0.0 {
                continue;
            }
            let cmin = centroids.min[axis];
            let scale = BINS as f32 / extent[axis];
            let mut boxes = [Aabb::EMPTY; BINS];
            let mut counts = [0usize; BINS];
            for &i in &self.order[start..end] {
                let p = &self.primitives[i as usize];
                let b = bin_of(p.centroid[axis], cmin, scale);
                boxes[b].grow(p.min, p.max);
                counts[b] += 1;
            }
            // right_cost[b]: area * count of everything in bins b+1 .. BINS.
            let mut right_cost = [0f32; BINS];
            let (mut right, mut right_count) = (Aabb::EMPTY, 0);
            for b in (1..BINS).rev() {
                right.grow(boxes[b].min, boxes[b].max);
                right_count += counts[b];
                right_cost[b - 1] = right.half_area() * right_count as f32;
            }
            let (mut left, mut left_count) = (Aabb::EMPTY, 0);
            for b in 0..BINS - 1 {
                left.grow(boxes[b].min, boxes[b].max);
                left_count += counts[b];
                if left_count == 0 || left_count == count {
                    continue;
                }
                let cost = left.half_area() * left_count as f32 + right_cost[b];
                if best.as_ref().map_or(true, |(c, _)| cost < *c) {
                    best = Some((cost, Split::Binned { axis, bin: b, cmin, scale }));
                }
            }
        }

        let area = bounds.half_area();
        match best {
            Some((cost, split)) => {
                let split_cost = TRAVERSAL_COST * area + cost;
                if count <= MAX_LEAF && count as f32 * area <= split_cost {
                    Split::Leaf
                } else {
                    split
                }
            }
            // Every centroid at one point (coincident or duplicated triangles).
            None if count <= MAX_LEAF => Split::Leaf,
            None => Split::Median { axis: widest },
        }
    }
}

/// The bin of a centroid coordinate; the same arithmetic for binning and partitioning, so a
/// chosen boundary separates exactly the counted triangles.
fn bin_of(c: f32, cmin: f32, scale: f32) -> usize {
    (((c - cmin) * scale) as usize).min(BINS - 1)
}

/// Where two meshes of a list meet: mesh `b` (the later) intersects mesh `a`, or lies inside it
/// (`nested`), or holds it inside (`nested`, with `a` and `b` as listed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Overlap {
    pub a: usize,
    pub b: usize,
    /// No surface crossing was found: one mesh lies wholly inside the other.
    pub nested: bool,
    /// A point where they meet (a crossing, or a vertex of the inner mesh).
    pub at: Vec3,
}

/// The first pair of closed meshes in `meshes` (in list order of the later one) that are not
/// disjoint: their surfaces cross, or one lies inside the other. Surfaces cross exactly where
/// an edge of one meets a triangle of the other (for triangles that are not coplanar), so every
/// edge of each mesh of a pair is tested as a segment against the other's BVH; without a
/// crossing, each mesh is wholly inside or outside the other, which one vertex decides.
pub fn first_overlap(meshes: &[TriangleMesh]) -> Option<Overlap> {
    if meshes.len() < 2 {
        return None; // one mesh: no BVH to build for a pair that does not exist
    }
    let bvhs: Vec<Bvh> = meshes.iter().map(Bvh::build).collect();
    let bounds: Vec<(Vec3, Vec3)> = meshes.iter().map(TriangleMesh::bounds).collect();
    for b in 1..meshes.len() {
        for a in 0..b {
            let ((alo, ahi), (blo, bhi)) = (bounds[a], bounds[b]);
            if alo.cmpgt(bhi).any() || blo.cmpgt(ahi).any() {
                continue;
            }
            let crossing = edge_crossing(&meshes[b], &bvhs[a]).or_else(|| edge_crossing(&meshes[a], &bvhs[b]));
            if let Some(at) = crossing {
                return Some(Overlap { a, b, nested: false, at });
            }
            for (inner, outer) in [(b, a), (a, b)] {
                let Some(&[v, ..]) = meshes[inner].triangles.first() else { continue };
                let p = meshes[inner].positions[v as usize];
                if super::bvh_contains(&bvhs[outer], meshes[outer].triangles.len(), p) {
                    return Some(Overlap { a, b, nested: true, at: p });
                }
            }
        }
    }
    None
}

/// A point where an edge of `mesh` crosses the surface under `bvh`, if any.
fn edge_crossing(mesh: &TriangleMesh, bvh: &Bvh) -> Option<Vec3> {
    for t in &mesh.triangles {
        for k in 0..3 {
            let (p, q) = (mesh.positions[t[k] as usize], mesh.positions[t[(k + 1) % 3] as usize]);
            let len = p.distance(q);
            if len.is_nan() || len <= 0.0 {
                continue;
            }
            let d = (q - p) / len;
            if let Some(hit) = bvh.intersect(p, d, 0.0, len) {
                return Some(p + d * hit.t);
            }
        }
    }
    None
}
