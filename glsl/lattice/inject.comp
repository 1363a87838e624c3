#version 460
// lattice/inject: move the round's summed deposits into the lattice and clear the sums. Keeps a
// per-workgroup, Kahan-compensated tally of the energy injected, for the conservation check.
//
// Isotropic media (or lbl.inject=isotropic): a voxel's deposit E joins the rest distribution,
// emitted isotropically at the next lattice step.
//
// Directed (pc.directed = 1, anisotropic media): the sums also carry each voxel's deposit
// flux F = sum of E d over the beams that deposited there (d the beam's unit direction). Light
// scattered once by Henyey-Greenstein leaves with mean cosine g about d, so the once-scattered
// source has first moment g F; the lattice, which scatters isotropically with the reduced
// coefficient sigma_s (1 - g) (lattice.glsl), then carries it a mean g / sigma_t' further along
// d before it forgets the direction, which is the forward displacement of the real photon,
// sum_k g^k / sigma_t = g / (sigma_t (1 - g)). Emitted isotropically instead, the forward peak of
// the first scattering is lost: a g = 0.6 cloud lit from behind loses 20% of its brightness.
// The first moment m = g F is carried by the axial links: |m_k| s along sign(m_k) e_k with
// s = |m|_2 / |m|_1, i.e. an energy |m|_2 <= |g| E flowing along m^ (its share on axis k
// |m^_k| / |m^|_1), whose first moment is m / |m^|_1: a flow along a diagonal travels the
// lattice's axial links, so its net flux is 1 / |m^|_1 of its energy where a real beam's is
// all of it. The lattice keeps that scale throughout, and the view pass undoes it (k =
// |E| |E^|_1 / phi, glsl/view/march.comp): a beam's mean cosine g stays g whatever its
// direction, and the injection is always feasible. The remainder E - |m|_2 joins the rest.
// Links that would leave the lattice go to the rest instead (its first-flight escape weights
// send them out, and the energy book counts what leaks).
//
// Near a point light (pc.near.w > 0: voxels whose centre lies within pc.near.w voxels of the
// light at pc.near.xyz) the deposits are not injected but tallied apart: lbl lumps that
// once-scattered light into the light itself (src/solvers/lbl.rs, `lbl.near_light`), because
// concentrated deposits emitted on six axial links stream along the axes and draw a "+"
// through the light.
#extension GL_GOOGLE_include_directive : require
#define LATTICE_MATERIALS_BINDING 4
#define SCENE_BINDING 5
#include "../include/lattice.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"
layout(constant_id = 6) const bool FIXED = false;

// [c V + v] energies, then with pc.directed [NCH V + (3 c + a) V + v] fluxes: float bits, or
// fixed point (two's complement for the signed fluxes).
layout(std430, binding = 0) buffer Accum { uint acc[]; };
layout(std430, binding = 1) buffer State { float f[]; };     // the current lattice state
layout(std430, binding = 2) buffer Tally { vec2 tally[]; };  // per workgroup and channel: (sum, comp)
layout(std430, binding = 3) buffer NearTally { vec2 near_tally[]; };  // the same, for the near ball

layout(push_constant) uniform Push {
    uvec4 dims;        // lattice voxels xyz, w = V
    float inv_scale;   // 1 / fixed-point scale
    uint directed;     // 1: the sums carry the deposit fluxes (above)
    uint pad0, pad1;
    vec4 near;         // the near ball: centre (voxel units from the min corner), radius in voxels (0: none)
} pc;

shared float sh[3 * 64];
shared float sh_near[3 * 64];

float take(uint i, bool signed_) {
    uint a = acc[i];
    acc[i] = 0u;
    if (!FIXED) return uintBitsToFloat(a);
    return (signed_ ? float(int(a)) : float(a)) * pc.inv_scale;
}

void main() {
    uint v = linear_id();
    uint li = gl_LocalInvocationID.x;
    uint V = pc.dims.w;
    uvec3 n = pc.dims.xyz;
    ivec3 p = ivec3(v % n.x, (v / n.x) % n.y, v / (n.x * n.y));
    bool near = pc.near.w > 0.0 && distance(vec3(p) + 0.5, pc.near.xyz) <= pc.near.w;
    for (uint c = 0u; c < NCH; ++c) {
        float e = 0.0, e_near = 0.0;
        if (v < V && near) {
            e_near = take(c * V + v, false);
            if (pc.directed != 0u)
                for (uint a = 0u; a < 3u; ++a) take(NCH * V + (3u * c + a) * V + v, true);
        } else if (v < V) {
            e = take(c * V + v, false);
            float rest = e;
            if (pc.directed != 0u) {
                // The voxel's g (Henyey-Greenstein asymmetry of its once-scattered light): its
                // material's in the table (the medium's unless MATS).
                float g = scene.materials[lattice_material(v)].albedo.w;
                vec3 m = g * vec3(take(NCH * V + (3u * c) * V + v, true),
                                     take(NCH * V + (3u * c + 1u) * V + v, true),
                                     take(NCH * V + (3u * c + 2u) * V + v, true));
                float l1 = abs(m.x) + abs(m.y) + abs(m.z);
                if (l1 > 0.0 && e > 0.0) {
                    float s = length(m) / l1;
                    for (uint k = 0u; k < 3u; ++k) {
                        uint link = 2u * k + (m[k] < 0.0 ? 2u : 1u);   // 1 +x, 2 -x, 3 +y, ...
                        float q = min(abs(m[k]) * s, rest);
                        if (q > 0.0 && lattice_inside(p + LATTICE_DIR[link], n)) {
                            f[(link * NCH + c) * V + v] += q;
                            rest -= q;
                        }
                    }
                }
            }
            f[c * V + v] += rest;   // distribution 0 (rest) of channel c
        }
        sh[c * 64u + li] = e;
        sh_near[c * 64u + li] = e_near;
    }
    barrier();
    for (uint stride = 32u; stride > 0u; stride >>= 1u) {
        if (li < stride)
            for (uint c = 0u; c < NCH; ++c) {
                sh[c * 64u + li] += sh[c * 64u + li + stride];
                sh_near[c * 64u + li] += sh_near[c * 64u + li + stride];
            }
        barrier();
    }
    // The last row of a folded line has groups past the voxels (linear.glsl): no slot of theirs.
    if (li == 0u && linear_group() * 64u < V) {
        for (uint c = 0u; c < NCH; ++c) {
            uint k = linear_group() * NCH + c;
            vec2 t = tally[k];
            kahan_add(t.x, t.y, sh[c * 64u]);
            tally[k] = t;
            if (pc.near.w > 0.0) {
                vec2 u = near_tally[k];
                kahan_add(u.x, u.y, sh_near[c * 64u]);
                near_tally[k] = u;
            }
        }
    }
}
