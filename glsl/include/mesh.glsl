// mesh.glsl: the [[object]]'s closed triangle mesh (scene format v2) and its smooth dielectric
// boundary. The BVH is built on the host (src/scene/bvh.rs, binned SAH, depth <= 64); its
// layout and traversal here mirror `Bvh::intersect`, which the host tests against brute force.
// Needs budget.glsl: the traversal counts every iteration of each of its three loops (nodes,
// a leaf's triangles, popping the stack) into `iters` (LOOP_EDGE: and the batch's where the
// kernel counts it), since llvmpipe's loop limiter counts every loop back-edge of an
// invocation's SIMD batch together, and a loop left uncounted let the path kernel's batches
// reach it at the default budget (silently wrong images, caught by rendering at several
// budgets: tests/refraction_tests.rs) and MESH_NODES_BINDING, MESH_TRIS_BINDING defined first.
#ifndef SCATTERLAB_MESH
#define SCATTERLAB_MESH
#include "dielectric.glsl"

// std430: a vec3 then a uint pack into 16 bytes, so a node is 32 bytes (`BvhNode`).
struct BvhNode {
    vec3 lo;
    uint left_or_first;   // interior (count 0): children left_or_first, left_or_first + 1
    vec3 hi;
    uint count;           // leaf: triangles [left_or_first, left_or_first + count)
};
struct Triangle {
    vec4 v0;   // xyz: first vertex; e1 = v1 - v0, e2 = v2 - v0 (outward normal cross(e1, e2))
    vec4 e1;
    vec4 e2;
};
layout(std430, binding = MESH_NODES_BINDING) readonly buffer MeshNodes { BvhNode nodes[]; };
layout(std430, binding = MESH_TRIS_BINDING) readonly buffer MeshTris { Triangle tris[]; };

// Whether the scene has an [[object]] (its mesh bounds the medium), and whether its boundary
// refracts (ior != 1). Specialised: v1 scenes compile none of this.
layout(constant_id = 10) const bool HAS_MESH = false;
layout(constant_id = 11) const bool REFRACTIVE = false;

const int BVH_STACK = 64;
// The far slab distance is widened by this fraction (bvh.rs FAR_SLACK), so a hit on a box face
// is not lost to rounding.
const float FAR_SLACK = 3.6e-7;

// Slab test of a node's box: the entry distance clipped to t_min, or INF where the ray misses
// the box within [t_min, t_max]. bvh.rs `slab`.
float node_entry(BvhNode n, vec3 o, vec3 inv_d, float t_min, float t_max) {
    vec3 ta = (n.lo - o) * inv_d;
    vec3 tb = (n.hi - o) * inv_d;
    float t0 = max(max(max(min(ta.x, tb.x), min(ta.y, tb.y)), min(ta.z, tb.z)), t_min);
    float t1 = min(min(max(ta.x, tb.x), max(ta.y, tb.y)), max(ta.z, tb.z));
    t1 = min(t1 + abs(t1) * FAR_SLACK, t_max);
    return t0 <= t1 ? t0 : INF;
}

// 1 / d with zero components replaced by a huge value of their sign (bvh.rs `safe_inverse`).
vec3 safe_inverse(vec3 d) {
    return vec3(abs(d.x) < 1e-30 ? (d.x < 0.0 ? -1e30 : 1e30) : 1.0 / d.x,
                abs(d.y) < 1e-30 ? (d.y < 0.0 ? -1e30 : 1e30) : 1.0 / d.y,
                abs(d.z) < 1e-30 ? (d.z < 0.0 ? -1e30 : 1e30) : 1.0 / d.z);
}

// Moller-Trumbore (Moller & Trumbore 1997), either side: the ray parameter where o + t d meets
// the triangle, or INF. Every test fails on a NaN (bvh.rs `moller_trumbore`).
float triangle_t(Triangle tr, vec3 o, vec3 d) {
    vec3 p = cross(d, tr.e2.xyz);
    float det = dot(tr.e1.xyz, p);
    if (det == 0.0) return INF;
    float inv = 1.0 / det;
    vec3 s = o - tr.v0.xyz;
    float u = dot(s, p) * inv;
    if (!(u >= 0.0 && u <= 1.0)) return INF;
    vec3 q = cross(s, tr.e1.xyz);
    float v = dot(d, q) * inv;
    if (!(v >= 0.0 && u + v <= 1.0)) return INF;
    float t = dot(tr.e2.xyz, q) * inv;
    return isnan(t) ? INF : t;
}

// How far a ray leaving a surface point p starts off it, toward the side it leaves on: relative
// to the coordinates' magnitude (float rounding), so the surface just crossed is not met again.
float surface_eps(vec3 p) { return 1e-5 * max(1.0, max3(abs(p))); }

// Unit outward geometric normal of triangle `tri` (an index from mesh_hit_tri).
vec3 triangle_normal(uint tri) { return normalize(cross(tris[tri].e1.xyz, tris[tri].e2.xyz)); }

// The material (index into scene.materials) of the object triangle `tri` bounds: each
// triangle carries its object's in v0.w as uint bits (src/scene/bvh.rs build_tagged).
uint triangle_material(uint tri) { return min(floatBitsToUint(tris[tri].v0.w), uint(MAX_MATERIALS - 1)); }

// The loop constructs of one mesh_hit_tri (batch.glsl's S): its traversal loop and the two in it.
const uint MESH_HIT_LOOPS = 3u;

// Closest crossing of the ray o + t d with t in (t_min, t_max), from either side: the
// traversal of bvh.rs `Bvh::intersect` (explicit stack, nearer child first, the farther one
// deferred with its entry distance and skipped once a closer hit is known). Returns false on
// a miss; `tri` is the index of the triangle hit.
bool mesh_hit_tri(vec3 o, vec3 d, float t_min, float t_max, out float t_hit, out uint tri) {
    t_hit = t_max;
    tri = 0xffffffffu;
    vec3 inv_d = safe_inverse(d);
    uint stack_node[BVH_STACK];
    float stack_t[BVH_STACK];
    int sp = 0;
    if (node_entry(nodes[0], o, inv_d, t_min, t_hit) == INF) return false;
    uint node = 0u;
    while (true) {
        LOOP_EDGE(MESH_HIT_LOOPS);   // itself and its two nested loops (batch.glsl)
        BvhNode nd = nodes[node];
        bool descend = false;
        if (nd.count > 0u) {
            for (uint i = nd.left_or_first; i < nd.left_or_first + nd.count; i++) {
                LOOP_EDGE(1u);
                float t = triangle_t(tris[i], o, d);
                if (t > t_min && t < t_hit) { t_hit = t; tri = i; }
            }
        } else {
            uint a = nd.left_or_first, b = a + 1u;
            float ta = node_entry(nodes[a], o, inv_d, t_min, t_hit);
            float tb = node_entry(nodes[b], o, inv_d, t_min, t_hit);
            if (tb < ta) { uint x = a; a = b; b = x; float y = ta; ta = tb; tb = y; }
            if (ta != INF) {
                if (tb != INF && sp < BVH_STACK) { stack_node[sp] = b; stack_t[sp] = tb; sp++; }
                node = a;
                descend = true;
            }
        }
        if (descend) continue;
        // Nothing below this node: the nearest deferred child still in front of the closest hit.
        bool next = false;
        while (sp > 0) {
            LOOP_EDGE(1u);
            sp--;
            if (stack_t[sp] < t_hit) { node = stack_node[sp]; next = true; break; }
        }
        if (!next) break;
    }
    if (tri == 0xffffffffu) { t_hit = t_max; return false; }
    return true;
}

// mesh_hit_tri with the unit outward geometric normal n of the triangle hit.
bool mesh_hit(vec3 o, vec3 d, float t_min, float t_max, out float t_hit, out vec3 n) {
    uint tri;
    bool hit = mesh_hit_tri(o, d, t_min, t_max, t_hit, tri);
    n = hit ? triangle_normal(tri) : vec3(0.0);
    return hit;
}

// ---- Manifold next-event estimation through flat facets (path, REFRACTIVE) -------------
// A point or directional light outside a refractive object reaches a point x inside only along
// refracted paths: light -> facet point ps -> x with Snell's law at ps. On a mesh of flat
// facets each facet's plane holds at most one such point (src/physics/dielectric.rs
// `refraction_point`), and the light reaches x through every facet whose point lies on the
// facet: on a tessellated sphere up to four or more at once, since each facet is a small prism
// whose beams overlap (measured on the icosphere: a third of the lit points take light through
// two facets or more), so one solution found by a local search (Hanika et al. 2015's manifold
// walk) is not enough; every facet is tried. The mesh is convex (the host checks), so the
// segment from x to ps and the way from ps to the light cross nothing else.

// The barycentric coordinates (u, v) of p's projection on the plane of triangle tri: p = v0 +
// u e1 + v e2 where p lies on it. False for a degenerate triangle.
bool triangle_coords(uint tri, vec3 p, out vec2 uv) {
    vec3 e1 = tris[tri].e1.xyz, e2 = tris[tri].e2.xyz, w = p - tris[tri].v0.xyz;
    float d11 = dot(e1, e1), d12 = dot(e1, e2), d22 = dot(e2, e2);
    float w1 = dot(w, e1), w2 = dot(w, e2);
    float den = d11 * d22 - d12 * d12;
    uv = vec2(1.0 / 3.0);
    if (!(den > 0.0)) return false;
    uv = vec2((d22 * w1 - d12 * w2) / den, (d11 * w2 - d12 * w1) / den);
    return true;
}

// Whether p (on the plane of triangle tri) lies in it: barycentric coordinates, edges shared
// by two facets counted by both (a set of measure zero).
bool point_in_triangle(uint tri, vec3 p) {
    vec2 uv;
    if (!triangle_coords(tri, p, uv)) return false;
    return uv.x >= 0.0 && uv.y >= 0.0 && uv.x + uv.y <= 1.0;
}

// Barycentric coordinates moved onto the triangle (negative ones to 0, a sum past 1 scaled to 1).
vec2 onto_triangle(vec2 uv) {
    uv = max(uv, vec2(0.0));
    return uv.x + uv.y > 1.0 ? uv / (uv.x + uv.y) : uv;
}

// Facet j's refraction point ps toward x (inside) for the light (`point`: a point light at
// `light`; else a directional light travelling along `light`) in the vacuum outside an object
// of index ior, and the irradiance E it delivers at x per unit of the light's intensity (W/sr)
// or irradiance (W/m^2), on a surface facing the ray (dielectric.rs
// refracted_point_irradiance, refracted_directional_irradiance; cos_o outside, cos_i inside):
//   point: E = (1 - F) / [(l_o + l_i / ior) (l_o cos_i / cos_o + (l_i / ior) cos_o / cos_i)],
//   directional: E = (1 - F) cos_o / cos_i.
// dielectric.rs `facet_irradiance` is the CPU reference, summed over the facets.
bool facet_refraction(uint j, vec3 x, vec3 light, bool point, float ior, out vec3 ps, out float E) {
    ps = vec3(0.0);
    E = 0.0;
    vec3 v0 = tris[j].v0.xyz, e1 = tris[j].e1.xyz, e2 = tris[j].e2.xyz;
    vec3 n = normalize(cross(e1, e2));
    float dx = dot(v0 - x, n);
    if (!(dx > 0.0)) return false;
    float cos_o;
    if (point) {
        float h = dot(light - v0, n);
        if (!(h > 0.0)) return false;
        vec3 lf = light - h * n, xf = x + dx * n;
        // The point lies on the segment between the feet: skip facets whose bounding circle
        // the segment misses (most of them).
        vec3 m = v0 + (e1 + e2) * (1.0 / 3.0);
        float r2 = max(max(dot(v0 - m, v0 - m), dot(v0 + e1 - m, v0 + e1 - m)), dot(v0 + e2 - m, v0 + e2 - m));
        vec3 seg = lf - xf;
        float len2 = dot(seg, seg);
        float s = len2 > 0.0 ? clamp(dot(m - xf, seg) / len2, 0.0, 1.0) : 0.0;
        vec3 closest = xf + seg * s - m;
        if (dot(closest, closest) > r2 * 1.0001) return false;
        // Bisection on f(s) = (1 - s) D / |((1 - s) D, h)| - ior s D / |(s D, dx)|, which falls
        // from > 0 to < 0 over [0, 1].
        float D = sqrt(len2);
        float lo = 0.0, hi = 1.0;
        for (uint k = 0u; k < 32u; k++) {
            LOOP_EDGE(1u);
            float t = 0.5 * (lo + hi);
            float a = (1.0 - t) * D, b = t * D;
            float f = a / sqrt(a * a + h * h) - ior * b / sqrt(b * b + dx * dx);
            if (f > 0.0) lo = t; else hi = t;
        }
        ps = xf + seg * (0.5 * (lo + hi));
        vec3 out_dir = light - ps;
        float l_o = length(out_dir);
        cos_o = dot(out_dir, n) / l_o;
        if (!point_in_triangle(j, ps)) return false;
        vec3 to = ps - x;
        float l_i = length(to);
        float cos_i = dot(to, n) / l_i;
        if (!(cos_o > 0.0 && cos_i > 0.0)) return false;
        float cos_t;
        float tr = 1.0 - fresnel_dielectric(cos_o, 1.0 / ior, cos_t);
        float li_n = l_i / ior;
        E = tr / ((l_o + li_n) * (l_o * cos_i / cos_o + li_n * cos_o / cos_i));
        return true;
    }
    cos_o = -dot(light, n);
    if (!(cos_o > 0.0)) return false;
    float cos_t;
    float tr = 1.0 - fresnel_dielectric(cos_o, 1.0 / ior, cos_t);
    vec3 wt = refract_dir(light, n, 1.0 / ior, cos_o, cos_t);
    // Back from x against the refracted direction to the facet's plane.
    float cos_i = dot(wt, -n);
    if (!(cos_i > 0.0)) return false;
    ps = x - wt * (dx / cos_i);
    if (!point_in_triangle(j, ps)) return false;
    E = tr * cos_o / cos_i;
    return true;
}

#endif
