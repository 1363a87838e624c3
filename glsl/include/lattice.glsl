// lattice.glsl: the Lattice-Boltzmann lighting lattice (solvers/lattice.rs, used by `lbl`; thesis 4.5,
// Geist et al. 2004 for the lattice; section 2.2.3).
//
// D3Q6 + rest (thesis 4.5), or Geist's D3Q18 + rest (section 2.2.3): distribution 0 is the rest
// (newly deposited, once-scattered energy, emitted isotropically at the next step), 1..6 move
// along +x, -x, +y, -y, +z, -z by one voxel per step, 7..18 (D3Q18 only) along the 12 face
// diagonals. Storage: one float per (distribution, channel, voxel): f[(i * NCH + c) * V + v].
// The state buffers hold *outgoing* distributions at their source voxel; a step pulls
// in_i(v) = out_i(v - e_i).
#ifndef SCATTERLAB_LATTICE
#define SCATTERLAB_LATTICE

// Channels carried: 1 for grey media (model only what the scene requires), 3 for chromatic.
layout(constant_id = 3) const uint NCH = 3u;

#include "one_minus_exp.glsl"

// Links per voxel besides the rest: 6 (D3Q6) or 18 (D3Q18).
layout(constant_id = 7) const uint LINKS = 6u;

#ifdef LATTICE_MATERIALS_BINDING
// The voxels' media come from the scene block's material table (scene_block.glsl, bound at
// SCENE_BINDING): the one route by which sigma_t, albedo and g reach every kernel. Entry 0 is
// the medium's; with several materials (lbl over [[object]]s of different media,
// src/solvers/lbl/mod.rs) each voxel names the material it holds most of
// (src/scene/voxelise.rs, material_occupancy). (Declared only by the kernels that read media.)
#include "scene_block.glsl"
layout(constant_id = 13) const bool MATS = false;

// What the lattice adds to the table: per material, the reflectance of its object's surface
// for the links leaving it (0: index-matched, or refraction off; the diffuse Fresnel
// reflectance from inside, computed on the host), then with MATS the material of every voxel.
layout(std430, binding = LATTICE_MATERIALS_BINDING) readonly buffer LatticeMaterials {
    float boundary_r[MAX_MATERIALS];
    uint vmat[];
};

// The material of voxel v: 0, the medium's, unless the voxels name theirs.
uint lattice_material(uint v) { return MATS ? min(vmat[v], uint(MAX_MATERIALS - 1)) : 0u; }
#endif

const ivec3 LATTICE_DIR[19] = ivec3[19](ivec3(0),
    ivec3(1, 0, 0), ivec3(-1, 0, 0), ivec3(0, 1, 0), ivec3(0, -1, 0), ivec3(0, 0, 1), ivec3(0, 0, -1),
    ivec3(1, 1, 0), ivec3(-1, -1, 0), ivec3(1, -1, 0), ivec3(-1, 1, 0),
    ivec3(1, 0, 1), ivec3(-1, 0, -1), ivec3(1, 0, -1), ivec3(-1, 0, 1),
    ivec3(0, 1, 1), ivec3(0, -1, -1), ivec3(0, 1, -1), ivec3(0, -1, 1));

// Share of scattered (and rest) energy sent along link i: 1/6 each in D3Q6; in D3Q18 1/12 per
// axial and 1/24 per diagonal link (Geist's collision matrix, section 2.2.3).
float link_weight(uint i) { return LINKS == 6u ? 1.0 / 6.0 : (i <= 6u ? 1.0 / 12.0 : 1.0 / 24.0); }

uint lattice_index(ivec3 p, uvec3 n) { return uint(p.x) + n.x * (uint(p.y) + n.y * uint(p.z)); }
bool lattice_inside(ivec3 p, uvec3 n) { return all(greaterThanEqual(p, ivec3(0))) && all(lessThan(p, ivec3(n))); }

// Per-step interaction probabilities of a voxel (eq. 4.5 in probability form): of the energy
// moving through a voxel of size lambda, kappa_t = 1 - exp(-sigma_t' lambda) interacts, and of
// that kappa_a = 1 - exp(-sigma_a lambda) is absorbed (the exact absorption over the step's
// path) and kappa_s = kappa_t - kappa_a scatters (isotropically, 1/6 to each link). Splitting
// kappa_t by the albedo instead (kappa_s = albedo' kappa_t) absorbs too little once
// sigma_t' lambda is not small: 14% too little at sigma_t' lambda = 0.31 (sigma_t 20 at grid
// 64), which left the fluence, and lbl's image, that much too bright in absorbing media.
// sigma_t' = sigma_a + sigma_s (1 - g) and
// albedo' = sigma_s (1 - g) / sigma_t' are the reduced (similarity) coefficients, which is how
// g enters a lattice that can only scatter isotropically. The exponential keeps every
// coefficient of eq. 4.5 non-negative even for optically thick voxels, where
// 1 - kappa_t + kappa_s/6 would otherwise go below zero.
//
// D3Q18: half its energy moves on sqrt 2 links, so a step is l = (1 + sqrt 2)/2 voxels of path
// on average (the time a step stands for) and 1.5 voxels^2 in mean square. Matching the
// physical diffusion coefficient 1 / (3 sigma_t') over that time takes
// kappa_t = 1 - exp(-sigma_t' lambda 1.5 / l), and the physical absorption over that path
// kappa_a = 1 - exp(-sigma_a lambda l). D3Q6: l = 1, mean square 1, kappa_t from sigma_t' lambda.
const float MEAN_LINK_D3Q18 = 1.20710678;   // (1 + sqrt 2) / 2

void lattice_kappa(float sigma_t, float albedo, float g, float lambda, out float kt, out float ks) {
    float ss = sigma_t * albedo * (1.0 - g);
    float sa = sigma_t * (1.0 - albedo);
    float st = sa + ss;
    if (LINKS == 6u) {
        kt = one_minus_exp(st * lambda);
        ks = kt - min(kt, one_minus_exp(sa * lambda));
    } else {
        kt = one_minus_exp(st * lambda * (1.5 / MEAN_LINK_D3Q18));
        ks = kt - min(kt, one_minus_exp(sa * lambda * MEAN_LINK_D3Q18));
    }
}

// Kahan-compensated running sum (s, comp) += x: the per-workgroup energy tallies of the
// lattice kernels, which add many small values to a large total.
void kahan_add(inout float s, inout float comp, float x) {
    float y = x - comp;
    float t = s + y;
    comp = (t - s) - y;
    s = t;
}

// Path length of link i in voxels: each arrival adds energy x length to the fluence integral.
float link_length(uint i) { return i <= 6u ? 1.0 : 1.41421356; }
#endif
