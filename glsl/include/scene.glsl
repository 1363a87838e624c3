// scene.glsl: the scene block every solver reads (binding SCENE_BINDING; its layout in
// scene_block.glsl), the medium's density, the camera, and majorant segments for tracking.
#ifndef SCATTERLAB_SCENE
#define SCATTERLAB_SCENE
#include "scene_block.glsl"
#include "batch.glsl"

#define DENSITY_CONSTANT 0u
#define DENSITY_SPHERE 1u
#define DENSITY_GRID 2u

// Specialisation: the kernels compile only the density kind and physics a scene needs.
layout(constant_id = 0) const uint DENSITY_KIND = 0u;
layout(constant_id = 1) const bool CHROMATIC = true;
layout(constant_id = 2) const bool ANISOTROPIC = true;
// The objects have several density fields (scene.fields): density, support and majorant are
// looked up per field. False for every scene of one field, whose kernels read the header's.
layout(constant_id = 12) const bool FIELDS = false;
// What the medium emits: nothing, a constant Le per material, or Le from the emission grid (a
// material may still be constant). Kernels that collect emission compile it in only when the
// scene has it.
#define EMISSION_NONE 0u
#define EMISSION_CONSTANT 1u
#define EMISSION_GRID 2u
layout(constant_id = 17) const uint EMISSION = 0u;

// The material of the medium a tracked ray is in (an index into scene.materials; mesh.glsl's
// triangles name theirs): its density field is the one medium_interval, density_at and the
// majorant segments read, and segments_next's majorant scales by its extinction. 0, the
// medium's, unless a kernel that follows paths across several objects sets it (path/trace,
// view/march).
uint medium_mat = 0u;

// The density field of medium_mat, and its kind.
uint medium_field() { return min(floatBitsToUint(scene.materials[medium_mat].ior.y), uint(MAX_MATERIALS - 1)); }
uint field_kind(DensityField f) { return floatBitsToUint(f.bounds_min.w); }

layout(r32f, binding = DENSITY_BINDING) uniform readonly image3D density_grid;
layout(std430, binding = MAJORANT_BINDING) readonly buffer MajorantGrid { float maj[]; };

// Camera ray through image position `px` (pixels, continuous; row 0 at the top).
void camera_ray(vec2 px, out vec3 o, out vec3 d) {
    vec2 res = vec2(scene.image.xy);
    vec2 ndc = vec2(px.x / res.x * 2.0 - 1.0, 1.0 - px.y / res.y * 2.0);
    float aspect = res.y / res.x;   // fov/extent is along x; pixels are square
    float k = scene.cam_forward.w;
    if (scene.cam_origin.w < 0.5) {
        o = scene.cam_origin.xyz;
        d = normalize(scene.cam_forward.xyz + scene.cam_right.xyz * (ndc.x * k) + scene.cam_up.xyz * (ndc.y * k * aspect));
    } else {
        o = scene.cam_origin.xyz + scene.cam_right.xyz * (ndc.x * k) + scene.cam_up.xyz * (ndc.y * k * aspect);
        d = scene.cam_forward.xyz;
    }
}

// Whether every camera ray through pixel `px`'s square [px, px + 1)^2 misses the medium's
// support, conservatively (false when unsure). The support (box, and the sphere for sphere
// density) lies in a bounding sphere: the box's circumsphere, or the density sphere where that
// is smaller. Perspective: the pixel's rays fill the pyramid over its corners, which lies in the
// circular cone about the centre ray whose half-angle reaches the farthest corner (the angle to
// the axis is quasi-convex over the image plane, so its maximum is at a corner); the cone misses
// the sphere when the axis-to-centre angle exceeds the half-angle plus the sphere's angular
// radius. Orthographic: the rays fill a prism about the centre ray, half a pixel diagonal wide.
// A pixel that passes sees only the environment, whatever its samples' positions.
bool pixel_misses_medium(uvec2 px) {
    vec3 c = 0.5 * (scene.bounds_min.xyz + scene.bounds_max.xyz);
    float r = 0.5 * length(scene.bounds_max.xyz - scene.bounds_min.xyz);
    // (Objects of several density fields leave the header's sphere 0: the box bounds them.)
    if (DENSITY_KIND == DENSITY_SPHERE && scene.sphere.w > 0.0 && scene.sphere.w < r) { c = scene.sphere.xyz; r = scene.sphere.w; }
    r = r * 1.001 + 1e-6;   // float rounding of the rays: keep the test conservative
    vec2 p = vec2(px);
    vec3 o, d, oc, dc;
    camera_ray(p + 0.5, o, dc);
    if (scene.cam_origin.w < 0.5) {
        vec3 v = c - o;
        float dist = length(v);
        if (dist <= r) return false;
        float cos_half = 1.0;
        for (uint i = 0u; i < 4u; i++) {
            BATCH_EDGE(1u);
            camera_ray(p + vec2(float(i & 1u), float(i >> 1u)), oc, d);
            cos_half = min(cos_half, dot(d, dc));
        }
        float reach = acos(clamp(cos_half, -1.0, 1.0)) + asin(r / dist) + 1e-4;
        return reach < PI && acos(clamp(dot(v, dc) / dist, -1.0, 1.0)) > reach;
    }
    vec3 v = c - o;
    float dist = length(v - dc * dot(v, dc));
    camera_ray(p, oc, d);   // a corner: the prism's half-width is the corner's offset
    return dist > r + 1.001 * length(oc - o) + 1e-6;
}

// Interval of the ray inside the whole medium's support: the header's box (every density
// field's, for objects of several fields), and its sphere for a sphere density.
vec2 scene_interval(vec3 o, vec3 d) {
    vec2 t = ray_box(o, d, scene.bounds_min.xyz, scene.bounds_max.xyz);
    if (DENSITY_KIND == DENSITY_SPHERE && scene.sphere.w > 0.0) {
        vec2 s = ray_sphere(o, d, scene.sphere.xyz, scene.sphere.w);
        t = vec2(max(t.x, s.x), min(t.y, s.y));
    }
    return t;
}

// Interval of the ray inside the medium's support (box, and the sphere for sphere density):
// medium_mat's density field.
vec2 medium_interval(vec3 o, vec3 d) {
    // A scene of one field: the header's box and density, the same code as before fields
    // existed, so such scenes render bit for bit as they did (the compiler contracts the field
    // form's arithmetic differently: 1-2 ulp).
    if (!FIELDS) return scene_interval(o, d);
    DensityField f = scene.fields[medium_field()];
    vec2 t = ray_box(o, d, f.bounds_min.xyz, f.bounds_max.xyz);
    if (DENSITY_KIND != DENSITY_CONSTANT && field_kind(f) == DENSITY_SPHERE) {
        vec2 s = ray_sphere(o, d, f.sphere.xyz, f.sphere.w);
        t = vec2(max(t.x, s.x), min(t.y, s.y));
    }
    return t;
}

// Corners and weights of a trilinear lookup at continuous voxel coordinate g (voxel centres at
// integers) on a grid of n voxels, clamped at the outer half voxel: the density, and the view
// pass's volumes, all interpolate this way.
void grid_corners(vec3 g, ivec3 n, out ivec3 i0, out ivec3 i1, out vec3 f) {
    g = clamp(g, vec3(0.0), vec3(n - 1));
    i0 = ivec3(floor(g));
    i1 = min(i0 + 1, n - 1);
    f = g - vec3(i0);
}

// Voxel coordinate of world position p on a grid of n voxels spanning the medium's box.
vec3 box_voxel_coord(vec3 p, ivec3 n) {
    return (p - scene.bounds_min.xyz) / (scene.bounds_max.xyz - scene.bounds_min.xyz) * vec3(n) - 0.5;
}

// The trilinear lookup of voxel coordinate g on the grid of n voxels from z slice z0 on.
float grid_lookup(vec3 g, ivec3 n, int z0) {
    ivec3 i0, i1;
    vec3 f;
    grid_corners(g, n, i0, i1, f);
    i0.z += z0;
    i1.z += z0;
    float c000 = imageLoad(density_grid, ivec3(i0.x, i0.y, i0.z)).r;
    float c100 = imageLoad(density_grid, ivec3(i1.x, i0.y, i0.z)).r;
    float c010 = imageLoad(density_grid, ivec3(i0.x, i1.y, i0.z)).r;
    float c110 = imageLoad(density_grid, ivec3(i1.x, i1.y, i0.z)).r;
    float c001 = imageLoad(density_grid, ivec3(i0.x, i0.y, i1.z)).r;
    float c101 = imageLoad(density_grid, ivec3(i1.x, i0.y, i1.z)).r;
    float c011 = imageLoad(density_grid, ivec3(i0.x, i1.y, i1.z)).r;
    float c111 = imageLoad(density_grid, ivec3(i1.x, i1.y, i1.z)).r;
    return mix(mix(mix(c000, c100, f.x), mix(c010, c110, f.x), f.y),
               mix(mix(c001, c101, f.x), mix(c011, c111, f.x), f.y), f.z);
}

// The header's density (a scene of one field), in the arithmetic it always had.
float header_density(vec3 p) {
    if (DENSITY_KIND == DENSITY_CONSTANT) return 1.0;
    if (DENSITY_KIND == DENSITY_SPHERE) {
        vec3 q = p - scene.sphere.xyz;
        return dot(q, q) <= scene.sphere.w * scene.sphere.w ? 1.0 : 0.0;
    }
    ivec3 n = ivec3(scene.grid_dims.xyz);
    return grid_lookup(box_voxel_coord(p, n), n, 0);
}

// Density in [0, 1+] at world position p (docs/design.md: voxel-centred, trilinear, clamped):
// medium_mat's density field (a grid's voxels from its first slice in the atlas on). A scene of
// one field reads the header's, bit for bit as before fields existed (the field form's
// arithmetic compiles 1-2 ulp differently).
float density_at(vec3 p) {
    if (DENSITY_KIND == DENSITY_CONSTANT) return 1.0;
    if (!FIELDS) return header_density(p);
    DensityField fd = scene.fields[medium_field()];
    uint kind = field_kind(fd);
    if (kind == DENSITY_CONSTANT) return 1.0;
    if (kind == DENSITY_SPHERE) {
        vec3 q = p - fd.sphere.xyz;
        return dot(q, q) <= fd.sphere.w * fd.sphere.w ? 1.0 : 0.0;
    }
    ivec3 n = ivec3(fd.grid_dims.xyz);
    vec3 g = (p - fd.bounds_min.xyz) / (fd.bounds_max.xyz - fd.bounds_min.xyz) * vec3(n) - 0.5;
    return grid_lookup(g, n, int(floatBitsToUint(fd.bounds_max.w)));
}

// Density with the medium's box applied: 0 outside the bounds (vacuum), for callers that
// sample anywhere (lattice resampling, photon marching) rather than inside a ray's interval.
float medium_density(vec3 p) {
    if (!FIELDS) {
        if (any(lessThan(p, scene.bounds_min.xyz)) || any(greaterThan(p, scene.bounds_max.xyz))) return 0.0;
        return density_at(p);
    }
    DensityField f = scene.fields[medium_field()];
    if (any(lessThan(p, f.bounds_min.xyz)) || any(greaterThan(p, f.bounds_max.xyz))) return 0.0;
    return density_at(p);
}

#ifdef EMISSION_BINDING
// The emission grid (src/solvers/parts/gpu_scene.rs, emission planes): one plane of voxels per
// channel, each spanning the medium's box as the density grid does (voxel centres, trilinear).
layout(std430, binding = EMISSION_BINDING) readonly buffer EmissionGrid { float emis[]; };

// Voxel (x, y, z) of channel plane c of the emission grid of n voxels.
float emission_voxel(ivec3 v, ivec3 n, uint c) {
    return emis[c * uint(n.x * n.y * n.z) + uint(v.x) + uint(n.x) * (uint(v.y) + uint(n.y) * uint(v.z))];
}

// Trilinear lookup of channel plane c of the emission grid at voxel coordinate g.
float emission_lookup(vec3 g, ivec3 n, uint c) {
    ivec3 a, b;
    vec3 f;
    grid_corners(g, n, a, b, f);
    float c00 = mix(emission_voxel(a, n, c), emission_voxel(ivec3(b.x, a.y, a.z), n, c), f.x);
    float c10 = mix(emission_voxel(ivec3(a.x, b.y, a.z), n, c), emission_voxel(ivec3(b.x, b.y, a.z), n, c), f.x);
    float c01 = mix(emission_voxel(ivec3(a.x, a.y, b.z), n, c), emission_voxel(ivec3(b.x, a.y, b.z), n, c), f.x);
    float c11 = mix(emission_voxel(ivec3(a.x, b.y, b.z), n, c), emission_voxel(b, n, c), f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

// Emitted radiance Le at p, W/(m^2 sr) per channel, of medium_mat's material (inside the medium:
// callers ask where the density is non-zero). The scene's Scene::emission_at on the host.
vec3 emission_at(vec3 p) {
    if (EMISSION == EMISSION_NONE) return vec3(0.0);
    vec4 e = scene.materials[medium_mat].emission;
    if (EMISSION == EMISSION_CONSTANT || e.w == 0.0) return e.rgb;
    ivec3 n = ivec3(scene.emission_dims.xyz);
    vec3 g = box_voxel_coord(p, n);
    if (scene.emission_dims.w == 1u) return e.rgb * emission_lookup(g, n, 0u);
    return e.rgb * vec3(emission_lookup(g, n, 0u), emission_lookup(g, n, 1u), emission_lookup(g, n, 2u));
}

// The transfer equation's emission source at p, sigma_a(p) Le(p) = sigma_t (1 - albedo)
// density Le (W/(m^3 sr) per channel), for medium_mat at a point of the given density.
vec3 emission_source(vec3 p, float density) {
    if (EMISSION == EMISSION_NONE || density <= 0.0) return vec3(0.0);
    ObjectMaterial m = scene.materials[medium_mat];
    return m.sigma_t.rgb * (1.0 - m.albedo.rgb) * density * emission_at(p);
}
#endif

// Majorant segments along a ray (pbrt-v4's DDAMajorantIterator): piecewise-constant
// sigma_maj (1/unit, grey: max over channels) over [t_min, t_max]. Constant and sphere media
// have one segment with density 1; grids walk a coarse grid of per-cell maximum density.
struct Segments {
    vec3 org;       // ray origin, direction
    vec3 dir;
    float t_min;
    float t_max;
    vec3 next_t;
    vec3 delta_t;
    ivec3 step;
    ivec3 cell;
    bool done;
};

Segments segments_begin(vec3 o, vec3 d, float t0, float t1) {
    Segments s;
    s.org = o; s.dir = d; s.t_min = t0; s.t_max = t1; s.done = !(t0 < t1);
    s.next_t = vec3(INF); s.delta_t = vec3(0.0); s.step = ivec3(0); s.cell = ivec3(0);
    if (DENSITY_KIND != DENSITY_GRID || s.done) return s;
    DensityField f = scene.fields[medium_field()];
    if (field_kind(f) != DENSITY_GRID) return s;
    vec3 ext = f.bounds_max.xyz - f.bounds_min.xyz;
    vec3 m = vec3(f.maj_dims.xyz);
    vec3 go = (o + d * t0 - f.bounds_min.xyz) / ext * m;
    vec3 gd = d / ext * m;
    for (int a = 0; a < 3; ++a) {
        BATCH_EDGE(1u);
        s.cell[a] = clamp(int(floor(go[a])), 0, int(f.maj_dims[a]) - 1);
        if (gd[a] > 0.0) {
            s.next_t[a] = t0 + (float(s.cell[a] + 1) - go[a]) / gd[a];
            s.delta_t[a] = 1.0 / gd[a];
            s.step[a] = 1;
        } else if (gd[a] < 0.0) {
            s.next_t[a] = t0 + (float(s.cell[a]) - go[a]) / gd[a];
            s.delta_t[a] = -1.0 / gd[a];
            s.step[a] = -1;
        }
    }
    return s;
}

// Next segment: returns false when the ray has left the medium.
bool segments_next(inout Segments s, out float seg_t0, out float seg_t1, out float sigma_maj) {
    if (s.done) return false;
    DensityField f = scene.fields[medium_field()];
    if (DENSITY_KIND != DENSITY_GRID || field_kind(f) != DENSITY_GRID) {
        seg_t0 = s.t_min; seg_t1 = s.t_max; sigma_maj = scene.materials[medium_mat].sigma_t.w;
        s.done = true;
        return true;
    }
    int axis = (s.next_t.x < s.next_t.y) ? ((s.next_t.x < s.next_t.z) ? 0 : 2) : ((s.next_t.y < s.next_t.z) ? 1 : 2);
    float t_end = min(s.t_max, s.next_t[axis]);
    uvec3 md = f.maj_dims.xyz;
    uint idx = f.grid_dims.w + uint(s.cell.x) + md.x * (uint(s.cell.y) + md.y * uint(s.cell.z));
    seg_t0 = s.t_min; seg_t1 = t_end; sigma_maj = maj[idx] * scene.materials[medium_mat].sigma_t.w;
    s.t_min = t_end;
    if (s.next_t[axis] >= s.t_max) {
        s.done = true;
    } else {
        s.cell[axis] += s.step[axis];
        if (s.cell[axis] < 0 || s.cell[axis] >= int(md[axis])) s.done = true;
        s.next_t[axis] += s.delta_t[axis];
    }
    return true;
}
#endif
