#version 460
// lattice/diffuse: Lattice-Boltzmann diffusion of the deposited once-scattered energy (thesis 4.5,
// eq. 4.4-4.5), blockwise: one workgroup owns a block of B^3 voxels and runs `inner_steps`
// lattice steps on it in shared memory (thesis Fig. 4.5). Energy that crosses a block face
// during the dispatch is summed per link and handed to the neighbour block through the state
// buffer, which it reads at its first step of the next dispatch: the interface buffer of
// Fig. 4.5, ping-ponged with the state. `inner_steps` = 1 is the global (unblocked) lattice,
// exactly; more inner steps delay energy at block faces but visit the same voxels, so the
// time-integrated field converges to the same result (thesis 4.7.2, Fig. 4.7; tested).
//
// Per step and channel at voxel v: S = sum_i in_i (arrived), r = rest (deposited);
//   out_i = (1 - kappa_t) in_i + (kappa_s S + r) w_i                 (eq. 4.4-4.5)
// with w_i = 1/6 (D3Q6) or 1/12 axial, 1/24 diagonal (D3Q18).
//   irradiance(v) += sum_i in_i l_i  (arrived energy times the path it travelled, l_i = 1 or
//                                  sqrt 2 voxels: the fluence integral, up to
//                                  the factor 1/lambda^2 applied in the view pass)
//   flux(v) += sum_i in_i l_i e_i / |e_i| = sum_i in_i e_i   (with pc.flux: the vector
//                                  irradiance, the first moment the view pass's two-term
//                                  expansion scatters toward the camera)
//   absorbed += (kappa_t - kappa_s) S;  leaked += out_i where v + e_i leaves the lattice.
#extension GL_GOOGLE_include_directive : require
#define LATTICE_MATERIALS_BINDING 6
#define SCENE_BINDING 8
#include "../include/lattice.glsl"

layout(constant_id = 4) const uint B = 4u;   // block edge in voxels
layout(local_size_x_id = 5, local_size_y_id = 5, local_size_z_id = 5) in;
layout(constant_id = 5) const uint WG = 4u;  // = B (a separate id: local_size_*_id must be one)

layout(std430, binding = 0) readonly buffer Density { float density[]; };  // resampled medium, per voxel
layout(std430, binding = 1) readonly buffer StateIn { float fin[]; };
layout(std430, binding = 2) writeonly buffer StateOut { float fout[]; };
// [c * V + v], then with pc.flux the flux [NCH V + (3 c + axis) V + v].
layout(std430, binding = 3) buffer Irradiance { float irr[]; };
// Per workgroup and channel, Kahan-compensated running sums: absorbed (sum, comp), leaked (sum, comp).
layout(std430, binding = 4) buffer Tally { vec4 tally[]; };
// With pc.snapshot: the time-integrated field before this dispatch adds to it (same layout as
// Irradiance), so the host can take the increment over a chunk of steps for the tail
// extrapolation (src/solvers/lattice.rs, Diffuser::iterate).
layout(std430, binding = 5) writeonly buffer Snapshot { float snap[]; };
// The iteration's control (lattice/check.comp): word 0 set once it has converged, after which
// the rest of a submitted batch of steps returns at once and leaves the lattice as it stood.
layout(std430, binding = 7) readonly buffer Control { uint ctrl_stopped; };

layout(push_constant) uniform Push {
    uvec4 dims;          // lattice voxels xyz, w = number of voxels V
    float lambda;        // voxel edge, scene units
    uint inner_steps;
    uint escape;         // first-flight escape weights (D3Q6): 0 none, 1 at the box's faces, 2 also at zero density
    uint flux;           // 1: integrate the flux too
    uint snapshot;       // 1: copy the field to Snapshot before adding this dispatch's part
    float drift;         // share of a link's carried light leaving per open face parallel to it (0: off)
    float drift_pair;    // the share leaving through either of two such faces on different axes counted twice
    uint links;          // 1: integrate every link's outgoing value too (rows after energy and flux)
} pc;

shared float sh_out[LINKS * B * B * B];
shared float sh_red[2u * B * B * B];
shared uint sh_busy;

// Exponential integrals E_1 (Abramowitz & Stegun 5.1.53 on (0, 1], 5.1.56 beyond; |error| <
// 2e-7 and 5e-5 relative), E_2 and E_3 by the recurrence E_{n+1}(x) = (e^-x - x E_n(x)) / n.
float expint_e1(float x) {
    if (x <= 1.0) {
        return -log(x) - 0.57721566 + x * (0.99999193 + x * (-0.24991055 + x * (0.05519968 + x * (-0.00976004 + x * 0.00107857))));
    }
    float num = x * x + 2.334733 * x + 0.250621;
    float den = x * x + 3.330657 * x + 1.681534;
    return exp(-x) / x * num / den;
}
float expint_e3(float x) {
    if (x <= 0.0) return 0.5;
    float e2 = exp(-x) - x * expint_e1(x);
    return 0.5 * (exp(-x) - x * e2);
}

// First-flight escape probability through one face of a voxel of optical thickness tau for an
// isotropic source spread uniformly through it: (1/tau) int_0^tau E_2(z) dz / 2 =
// (1/2 - E_3(tau)) / (2 tau); 1/2 for a thin voxel, 1/(4 tau) for a thick one.
float escape_probability(float tau) {
    if (tau < 1e-4) return 0.5;
    return (0.5 - expint_e3(tau)) / (2.0 * tau);
}

// The same escape through several open faces of the voxel at once, where some are adjacent (an
// edge or a corner of the medium's box). Per-face probabilities add only for disjoint events,
// i.e. opposite faces: a photon heading out through +x and +y at once leaves through whichever
// it meets first, and counting it at both let an edge voxel of optical edge 0.29 lose 0.67 of
// what it scattered where 0.54 escapes, a corner 1.0 for 0.67 (the 2-mfp cube at 7^3 voxels
// 0.86 of path's energy, docs/lbl.md). Split the directions into octants: in one whose signs
// meet k open faces the escape is q_k(tau) (q_1 = 2 escape_probability, the first-flight
// integral restricted to the octant), so the union is sum over the eight octants q_k / 8.
// ESC_Q2 and ESC_Q3 tabulate q_2 / q_1 and q_3 / q_1 (1 for a thin voxel, 2 and 3 for a
// thick one, whose escape happens near one face at a time) at tau = 2^(j - 5), j = 0..10, from
// the quadrature in src/solvers/parts/lattice/escape.rs (which a unit test checks this table
// against); linear in log2 tau between nodes, in tau below the first (from 1 at tau = 0).
const float ESC_Q2[11] = float[11](1.04976, 1.08213, 1.13243, 1.20800, 1.31659, 1.46220, 1.63385,
    1.79168, 1.89393, 1.94695, 1.97347);
const float ESC_Q3[11] = float[11](1.05892, 1.10033, 1.16847, 1.27868, 1.45264, 1.71414, 2.06471,
    2.43144, 2.69669, 2.84458, 2.92136);
float escape_ratio(uint k, float tau) {
    if (k <= 1u) return float(k);
    float x = log2(max(tau, 1e-30)) + 5.0;
    float lo = k == 2u ? ESC_Q2[0] : ESC_Q3[0];
    if (x <= 0.0) return 1.0 + (lo - 1.0) * tau * 32.0;
    if (x >= 10.0) return k == 2u ? ESC_Q2[10] : ESC_Q3[10];
    uint j = uint(floor(x));
    float f = x - float(j);
    return k == 2u ? mix(ESC_Q2[j], ESC_Q2[j + 1u], f) : mix(ESC_Q3[j], ESC_Q3[j + 1u], f);
}
// Total first-flight escape of a D3Q6 voxel whose links to vacuum are `vac_mask` (bit i - 1 for
// link i: +x, -x, +y, -y, +z, -z).
float escape_union(uint vac_mask, float tau) {
    float sum = 0.0;
    for (uint o = 0u; o < 8u; ++o) {
        uint k = 0u;
        for (uint a = 0u; a < 3u; ++a) {
            uint link_bit = 2u * a + ((o >> a) & 1u);   // the octant's side of axis a: + (0) or - (1)
            k += (vac_mask >> link_bit) & 1u;
        }
        sum += escape_ratio(k, tau);
    }
    return 2.0 * escape_probability(tau) * sum / 8.0;
}

void main() {
    // Uniform over the dispatch, before any barrier.
    if (ctrl_stopped != 0u) return;
    uvec3 n = pc.dims.xyz;
    uint V = pc.dims.w;
    ivec3 local = ivec3(gl_LocalInvocationID);
    ivec3 p = ivec3(gl_WorkGroupID) * int(B) + local;
    bool inside = lattice_inside(p, n);
    uint v = inside ? lattice_index(p, n) : 0u;
    uint li = uint(local.x) + B * (uint(local.y) + B * uint(local.z));
    uint BB = B * B * B;

    float kt[3], ks[3];
    float dens = inside ? density[v] : 0.0;
    // The voxel's medium: the material table's entry for it (the medium's unless MATS).
    uint mat = inside ? lattice_material(v) : 0u;
    vec4 m_sigma_t = scene.materials[mat].sigma_t, m_albedo = scene.materials[mat].albedo;
    float m_boundary_r = boundary_r[mat];
    for (uint c = 0u; c < NCH; ++c) lattice_kappa(m_sigma_t[c] * dens, m_albedo[c], m_albedo.w, pc.lambda, kt[c], ks[c]);

    // Share of scattered (and rest) energy per link and channel. D3Q6 sends 1/6 to each link;
    // at the medium's boundary (a neighbour outside the lattice or of zero density) that lets
    // too little escape: of isotropically scattered light near a surface, about half leaves
    // through it, the first-flight escape probability of the voxel, where the six beams send
    // one sixth. With pc.escape, each link toward vacuum gets that probability (at least 1/6)
    // and the others share the rest: at the lattice box's faces (escape = 1: where the medium
    // is cut by its flat bounds), or also toward zero-density voxels (escape = 2: a voxelised
    // curved surface, whose staircase exposes about 1.5x the true area, and escapes too much).
    float wgt[18 * 3];
    uint vac_mask = 0u;   // bit i - 1: the neighbour along link i is vacuum (as escape counts it)
    for (uint c = 0u; c < NCH; ++c) {
        uint vac = 0u;
        vac_mask = 0u;
        for (uint i = 1u; i <= LINKS; ++i) {
            ivec3 q = p + LATTICE_DIR[i];
            bool vacuum = !lattice_inside(q, n) || (pc.escape == 2u && density[lattice_index(q, n)] <= 0.0);
            wgt[(i - 1u) * 3u + c] = vacuum ? -1.0 : 0.0;
            if (vacuum) { vac++; vac_mask |= 1u << (i - 1u); }
        }
        float w_out = 0.0, w_in = 1.0 / 6.0;
        if (LINKS == 6u && pc.escape != 0u && vac > 0u && inside && dens > 0.0) {
            float ss = m_sigma_t[c] * dens * m_albedo[c] * (1.0 - m_albedo.w);
            float sa = m_sigma_t[c] * dens * (1.0 - m_albedo[c]);
            float tau = (ss + sa) * pc.lambda;
            // The union over the open faces, shared evenly among their links (by symmetry for
            // an edge or a corner; a face or opposite faces give escape_probability each, as
            // before).
            w_out = min(max(escape_union(vac_mask, tau) / float(vac), 1.0 / 6.0), 1.0 / float(vac));
            w_in = vac < 6u ? (1.0 - float(vac) * w_out) / float(6u - vac) : 0.0;
        }
        for (uint i = 1u; i <= LINKS; ++i) {
            uint k = (i - 1u) * 3u + c;
            wgt[k] = (LINKS == 6u && pc.escape != 0u && vac > 0u && inside && dens > 0.0) ? (wgt[k] < 0.0 ? w_out : w_in) : link_weight(i);
        }
    }

    // Drift through a vacuum face of light streaming parallel to it (D3Q6 with pc.escape). A link
    // stands for the cone of directions nearest its axis: a photon of the +x cone in a voxel
    // whose -z face is open moves toward that face at max(0, -w_z) per voxel of path, 0.167 on
    // average over the cone (uniform depth in the voxel), and leaves through it. The six beams
    // move only along x, so light streaming parallel to a surface never left it except by
    // scattering: with the outward link (1/6 of an isotropic population, all of which leaves)
    // the surface let 1/6 of its light out per step where the cones let 1/4 = (0.831 + 4 x
    // 0.167) / 6 out, and the near-surface fluence built up (the issue's cube 16-20% too
    // bright in multiple scattering; a plane-parallel model of the lattice against Monte Carlo
    // gave the same excess, 1.21x, and 1.01x with this leak). Applied to the light a link
    // carries on, not to the freshly scattered share, whose first-flight escape the weights
    // above already give. lk[i - 1]: the fraction link i loses per step, 0.167 per open face
    // perpendicular to it (pc.drift = CONE_DRIFT in src/solvers/lattice.rs, where the value is
    // derived; 0 with lbl.drift=false). Along an edge (open faces on both axes perpendicular to
    // the link) a photon leaves through one or the other: the union, less pc.drift_pair (the
    // cone's mean of max(0, -w_y) max(0, -w_z)) for each pair of faces on different axes.
    float lk[6];
    for (uint i = 1u; i <= 6u; ++i) {
        float f = 0.0;
        if (LINKS == 6u && pc.escape != 0u && inside && dens > 0.0) {
            uint ax = (i - 1u) / 2u;
            float na = 0.0, nb = 0.0;   // open faces on the two other axes
            for (uint j = 1u; j <= 6u; ++j) {
                uint aj = (j - 1u) / 2u;
                if (aj != ax && (vac_mask & (1u << (j - 1u))) != 0u) {
                    if (aj == (ax + 1u) % 3u) na += 1.0; else nb += 1.0;
                }
            }
            f = pc.drift * (na + nb) - pc.drift_pair * na * nb;
        }
        lk[i - 1u] = f;
    }

    // A refractive object's boundary (boundary_r > 0: an [[object]] with ior != 1): light
    // inside a dense medium meets its surface from inside and is partly reflected back (all of
    // it beyond the critical angle), which traps it: the fluence of a glass-bound medium is
    // higher than that of the same medium index-matched. The link leaving an occupied voxel
    // toward an unoccupied one (or out of the lattice) gives the share boundary_r of what it
    // carries to the opposite link, which carries it back in: the diffuse (cosine-weighted
    // hemispherical) Fresnel reflectance from inside, computed on the host
    // (src/physics/dielectric.rs, diffuse_fresnel), the boundary condition of diffusion
    // theory's partial currents, J_out = (1 - R) J_+. The thesis' lattice has none (its eikonal
    // rays refract, its lattice leaks as if index-matched).
    // (Tried and not kept: scaling the transmitted share by 1 / |m|_1 for the staircase's
    // exposed area, m the surface normal from the density's gradient; it overshot everywhere,
    // docs/lbl.md.)
    uint refl_mask = 0u;
    if (m_boundary_r > 0.0 && inside && dens > 0.0) {
        for (uint i = 1u; i <= LINKS; ++i) {
            ivec3 q = p + LATTICE_DIR[i];
            if (!lattice_inside(q, n) || density[lattice_index(q, n)] <= 0.0) refl_mask |= 1u << (i - 1u);
        }
    }

    // The channels never exchange energy, so each runs all its inner steps in turn through one
    // channel's shared links: shared memory is (LINKS + 2) B^3 floats whatever NCH is, which
    // lets B = 8 fit where it would not with every channel at once.
    uint wg = gl_WorkGroupID.x + gl_NumWorkGroups.x * (gl_WorkGroupID.y + gl_NumWorkGroups.y * gl_WorkGroupID.z);
    for (uint c = 0u; c < NCH; ++c) {
        float out_face[18];   // per link: summed over steps if it crosses the block face
        float out_last[18];   // the last step's out, for links staying in the block
        for (uint k = 0u; k < 18u; ++k) { out_face[k] = 0.0; out_last[k] = 0.0; }
        float absorbed = 0.0, leaked = 0.0, irr_add = 0.0;
        vec3 flux_add = vec3(0.0);
        // With pc.links: each link's outgoing value summed over the steps, the time integral
        // of the state after the first step that a later frame starts from exactly
        // (src/solvers/lbl/mod.rs, `start`).
        float osum[18];
        for (uint k = 0u; k < 18u; ++k) osum[k] = 0.0;

        // What arrives at the first step (through the state buffer) and the rest. Where nothing
        // arrives anywhere in the block and nothing rests in it, every step gives zeros: such a
        // block (ahead of the light early on, or in empty space no beam crosses) skips its
        // steps, and writes the zeros and the unchanged field below exactly as the steps would
        // have. The test is uniform over the workgroup, so the steps' barriers stay uniform.
        float in0[18];
        float r0 = inside ? fin[c * V + v] : 0.0;
        bool busy = r0 != 0.0;
        for (uint i = 1u; i <= LINKS; ++i) {
            ivec3 q = p - LATTICE_DIR[i];
            in0[i - 1u] = (inside && lattice_inside(q, n)) ? fin[(i * NCH + c) * V + lattice_index(q, n)] : 0.0;
            busy = busy || in0[i - 1u] != 0.0;
        }
        if (li == 0u) sh_busy = 0u;
        barrier();
        if (busy) sh_busy = 1u;
        barrier();
        uint steps = sh_busy != 0u ? pc.inner_steps : 0u;

        for (uint s = 0u; s < steps; ++s) {
            float in_[18];
            float S = 0.0;
            for (uint i = 1u; i <= LINKS; ++i) {
                ivec3 ql = local - LATTICE_DIR[i];
                bool in_block = all(greaterThanEqual(ql, ivec3(0))) && all(lessThan(ql, ivec3(B)));
                float x = 0.0;
                if (s == 0u) {
                    // First step: everything arrives through the state buffer (in-block links
                    // from the last step of the previous dispatch, face links summed over it).
                    x = in0[i - 1u];
                } else if (in_block) {
                    uint qi = uint(ql.x) + B * (uint(ql.y) + B * uint(ql.z));
                    x = sh_out[(i - 1u) * BB + qi];
                }
                in_[i - 1u] = x;
                S += x;
                irr_add += x * link_length(i);
                if (pc.flux != 0u) flux_add += x * vec3(LATTICE_DIR[i]);
            }
            float r = s == 0u ? r0 : 0.0;
            absorbed += (kt[c] - ks[c]) * S;
            float outs[18];
            for (uint i = 1u; i <= LINKS; ++i) {
                float w = wgt[(i - 1u) * 3u + c];
                float carried = (1.0 - kt[c]) * in_[i - 1u];
                float drift = LINKS == 6u ? carried * lk[min(i, 6u) - 1u] : 0.0;
                outs[i - 1u] = inside ? carried - drift + (ks[c] * S + r) * w : 0.0;
                if (inside) leaked += drift;
            }
            if (refl_mask != 0u) {
                // Links come in opposite pairs (1, 2), (3, 4), ...: outs[i] and outs[i + 1] for
                // even i. Each gives its reflected share to the other.
                for (uint i = 0u; i < LINKS; i += 2u) {
                    float a = (refl_mask & (1u << i)) != 0u ? m_boundary_r * outs[i] : 0.0;
                    float b = (refl_mask & (2u << i)) != 0u ? m_boundary_r * outs[i + 1u] : 0.0;
                    outs[i] = outs[i] - a + b;
                    outs[i + 1u] = outs[i + 1u] - b + a;
                }
            }
            for (uint i = 1u; i <= LINKS; ++i) {
                float o = outs[i - 1u];
                if (pc.links != 0u) osum[i - 1u] += o;   // uniform: off outside a sequence
                ivec3 ql = local + LATTICE_DIR[i];
                bool stays = all(greaterThanEqual(ql, ivec3(0))) && all(lessThan(ql, ivec3(B)));
                if (stays) out_last[i - 1u] = o; else out_face[i - 1u] += o;
                if (inside && !lattice_inside(p + LATTICE_DIR[i], n)) leaked += o;
            }
            // All of this step's outs must be visible before anyone reads them, and all reads
            // of the previous step's outs (or the previous channel's) done before they are
            // overwritten.
            barrier();
            for (uint i = 1u; i <= LINKS; ++i) sh_out[(i - 1u) * BB + li] = out_last[i - 1u];
            barrier();
        }

        if (inside) {
            fout[c * V + v] = 0.0;   // the rest was emitted at the first step
            for (uint i = 1u; i <= LINKS; ++i) {
                ivec3 ql = local + LATTICE_DIR[i];
                bool stays = all(greaterThanEqual(ql, ivec3(0))) && all(lessThan(ql, ivec3(B)));
                fout[(i * NCH + c) * V + v] = stays ? out_last[i - 1u] : out_face[i - 1u];
            }
            float e = irr[c * V + v];
            if (pc.snapshot != 0u) snap[c * V + v] = e;
            irr[c * V + v] = e + irr_add;
            if (pc.flux != 0u) {
                for (uint a = 0u; a < 3u; ++a) {
                    uint k = (NCH + 3u * c + a) * V + v;
                    float f = irr[k];
                    if (pc.snapshot != 0u) snap[k] = f;
                    irr[k] = f + flux_add[a];
                }
            }
            if (pc.links != 0u) {
                uint base = NCH * (pc.flux != 0u ? 4u : 1u);
                for (uint i = 1u; i <= LINKS; ++i) {
                    uint k = (base + LINKS * c + i - 1u) * V + v;
                    float f = irr[k];
                    if (pc.snapshot != 0u) snap[k] = f;
                    irr[k] = f + osum[i - 1u];
                }
            }
        }

        // Workgroup sums of absorbed and leaked energy (tree reduction), kept per workgroup so
        // the totals are deterministic; the host adds the workgroups up in double precision.
        sh_red[li] = absorbed;
        sh_red[BB + li] = leaked;
        barrier();
        for (uint stride = BB / 2u; stride > 0u; stride >>= 1u) {
            if (li < stride) {
                sh_red[li] += sh_red[li + stride];
                sh_red[BB + li] += sh_red[BB + li + stride];
            }
            barrier();
        }
        if (li == 0u) {
            vec4 t = tally[wg * NCH + c];
            kahan_add(t.x, t.y, sh_red[0]);
            kahan_add(t.z, t.w, sh_red[BB]);
            tally[wg * NCH + c] = t;
        }
        // sh_red is read by lane 0 before the next channel's first write to it.
        barrier();
    }
}
