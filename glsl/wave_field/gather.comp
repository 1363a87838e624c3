#version 460
// wave_field/gather: back to the Cartesian grid (end of paper section 2.1). At every voxel
// centre x, at distance r and direction w_x from the light, the wavefront's fluence and
// vector irradiance are psi0 / r^2 and psi1 / r^2 w_x (trilinear in the spherical grid). The
// view pass adds the exact single-scattering term itself, so what is stored here is the
// multiply scattered part: the wavefront's total minus the direct term it carried in the same
// march (direct fluence Phi e^-tau / r^2, flowing along w_x):
//   phi_ms = max(0, psi0 / r^2 - Phi e^-tau / r^2)
//   E_ms   = (psi1 / r^2 - Phi e^-tau / r^2) w_x, its length clamped to phi_ms (the flux of
//            any radiance distribution is at most its fluence). Not to phi_ms / 3, where the
//            two-term radiance phi / 4pi + 3 E.w / 4pi would stay non-negative in every
//            direction: at the medium's boundary diffusion theory has |E| = phi / 2 (Marshak,
//            phi = 2 E; march.comp), and cutting it to phi / 3 took a third of the forward
//            in-scattering 3 g E away there (measured: the g = 0.3 cloud 10% too dark). What
//            reads the volume clamps its own use at 0: the view's phase-weighted in-scattering
//            phi + 3 g E.(-d) (glsl/view/march.comp) and lbl's warm-start links phi / 6 + E.e / 2.
// Near the light diffusion theory underestimates the 1/r^2 direct term (phi ~ 1/r there), so
// phi_ms is clamped at 0 rather than made negative. A voxel containing the light is
// evaluated at r = lambda / 2 (its own size): the point value at r = 0 is singular.
// Stored as in `lbl` (MsVolume in glsl/view/march.comp): energy = phi lambda^2 at [c V + v],
// then the flux E lambda^2 at [C V + (3 c + a) V + v] for C channels. Sums over lights (one
// dispatch per light, in order: deterministic).
#extension GL_GOOGLE_include_directive : require
#include "../include/wave_field.glsl"

layout(local_size_x = 4, local_size_y = 4, local_size_z = 4) in;
layout(std430, binding = 0) readonly buffer Psi0 { vec4 psi0[]; };
layout(std430, binding = 1) readonly buffer Psi1 { vec4 psi1[]; };
layout(std430, binding = 2) readonly buffer Tau { vec4 tau[]; };
layout(std430, binding = 3) buffer Volume { float volume[]; };
// [0] voxels where the wavefront was not finite (set to 0; the explicit integrator's failure).
layout(std430, binding = 4) buffer Stats { uint stats[]; };

struct Sample { vec3 p0; vec3 p1; vec3 t; };

Sample fetch(uint i, uint j, uint n) {
    uint node = wf_node(wf_ray(i, j), n);
    return Sample(psi0[node].rgb, psi1[node].rgb, tau[node].rgb);
}

Sample lerp_s(Sample a, Sample b, float f) {
    return Sample(mix(a.p0, b.p0, f), mix(a.p1, b.p1, f), mix(a.t, b.t, f));
}

void main() {
    uvec3 id = gl_GlobalInvocationID;
    uvec3 n3 = pc.cart_dims.xyz;
    if (any(greaterThanEqual(id, n3))) return;
    uint V = n3.x * n3.y * n3.z;
    uint v = id.x + n3.x * (id.y + n3.y * id.z);
    float lambda = pc.cart_origin.w;
    vec3 x = pc.cart_origin.xyz + (vec3(id) + 0.5) * lambda;
    vec3 d = x - pc.light.xyz;
    float r = length(d);
    vec3 wx = r > 0.0 ? d / r : vec3(0.0, 0.0, 1.0);
    r = max(r, 0.5 * lambda);

    // Continuous grid coordinates: u wraps around the azimuth, v and the radius clamp.
    uint nu = pc.dims.x, nv = pc.dims.y, layers = pc.dims.z;
    float u = atan(wx.y, wx.x) * (0.5 / PI);
    if (u < 0.0) u += 1.0;
    float vv = 0.5 * (1.0 - wx.z);
    float fu = u * float(nu) - 0.5;
    float fv = clamp(vv * float(nv) - 0.5, 0.0, float(nv - 1u));
    float fr = clamp(r / pc.light.w, 0.0, float(layers));
    int iu0 = int(floor(fu));
    float au = fu - float(iu0);
    uint u0 = uint((iu0 + int(nu)) % int(nu));
    uint u1 = (u0 + 1u) % nu;
    uint v0 = uint(floor(fv));
    uint v1 = min(v0 + 1u, nv - 1u);
    float av = fv - float(v0);
    uint r0 = min(uint(floor(fr)), layers - 1u);
    float ar = fr - float(r0);
    Sample s = lerp_s(
        lerp_s(lerp_s(fetch(u0, v0, r0), fetch(u1, v0, r0), au), lerp_s(fetch(u0, v1, r0), fetch(u1, v1, r0), au), av),
        lerp_s(lerp_s(fetch(u0, v0, r0 + 1u), fetch(u1, v0, r0 + 1u), au), lerp_s(fetch(u0, v1, r0 + 1u), fetch(u1, v1, r0 + 1u), au), av),
        ar);

    // The explicit integrator can leave NaN/Inf in the spherical grid: never let it through.
    bool bad = any(isnan(s.p0)) || any(isinf(s.p0)) || any(isnan(s.p1)) || any(isinf(s.p1)) || any(isnan(s.t));
    vec3 phi = vec3(0.0);
    vec3 e = vec3(0.0);
    if (bad) {
        atomicAdd(stats[0], 1u);
    } else {
        float inv_r2 = 1.0 / (r * r);
        vec3 direct = pc.intensity.rgb * exp(-s.t) * inv_r2;
        phi = max(vec3(0.0), s.p0 * inv_r2 - direct);
        e = clamp(s.p1 * inv_r2 - direct, -phi, phi);
    }
    uint C = pc.cart_dims.w;
    float l2 = lambda * lambda;
    for (uint c = 0u; c < C; ++c) {
        volume[c * V + v] += phi[c] * l2;
        for (uint a = 0u; a < 3u; ++a) volume[C * V + (3u * c + a) * V + v] += e[c] * wx[a] * l2;
    }
}
