// lattice.glsl: the Lattice-Boltzmann lighting lattice of solver `lbl` (thesis 4.5, eq. 4.4-4.5;
// Geist et al. 2004 for the lattice; section 2.2.3).
//
// D3Q6 + rest: distribution 0 is the rest (newly deposited, once-scattered energy, emitted
// isotropically at the next step), 1..6 move along +x, -x, +y, -y, +z, -z by one voxel per step.
// Storage: one float per (distribution, channel, voxel): f[(i * NCH + c) * V + v], x fastest.
// The state buffers hold *outgoing* distributions at their source voxel; a step pulls
// in_i(v) = out_i(v - e_i).
#ifndef SCATTERLAB_LATTICE
#define SCATTERLAB_LATTICE

// Channels carried: 1 for grey media (model only what the scene requires), 3 for chromatic.
layout(constant_id = 3) const uint NCH = 3u;

const ivec3 LATTICE_DIR[7] = ivec3[7](ivec3(0), ivec3(1, 0, 0), ivec3(-1, 0, 0), ivec3(0, 1, 0), ivec3(0, -1, 0), ivec3(0, 0, 1), ivec3(0, 0, -1));

uint lattice_index(ivec3 p, uvec3 n) { return uint(p.x) + n.x * (uint(p.y) + n.y * uint(p.z)); }
bool lattice_inside(ivec3 p, uvec3 n) { return all(greaterThanEqual(p, ivec3(0))) && all(lessThan(p, ivec3(n))); }

// Per-step interaction probabilities of a voxel (eq. 4.5 in probability form): of the energy
// moving through a voxel of size lambda, kappa_t = 1 - exp(-sigma_t' lambda) interacts, and of
// that kappa_s = albedo' kappa_t scatters (isotropically, 1/6 to each link) and the rest is
// absorbed and leaves the lattice. sigma_t' = sigma_a + sigma_s (1 - g) and
// albedo' = sigma_s (1 - g) / sigma_t' are the reduced (similarity) coefficients, which is how
// g enters a lattice that can only scatter isotropically. The exponential keeps every
// coefficient of eq. 4.5 non-negative even for optically thick voxels, where
// 1 - kappa_t + kappa_s/6 would otherwise go below zero.
void lattice_kappa(float sigma_t, float albedo, float g, float lambda, out float kt, out float ks) {
    float ss = sigma_t * albedo * (1.0 - g);
    float st = sigma_t * (1.0 - albedo) + ss;
    kt = 1.0 - exp(-st * lambda);
    ks = st > 0.0 ? kt * (ss / st) : 0.0;
}
#endif
