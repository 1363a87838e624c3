// networks/lights.glsl: the light units' direct light at particle p scattered into direction w,
// sum_j L_j(p) p(w_j . w) (illumination networks 3.3), L_j the unit's irradiance at p through
// the medium and w_j the way it travels (networks/direct.comp's two vec4 per unit), p the
// Henyey-Greenstein phase function of g (1/sr). One loop for the three kernels that take it
// (iterate.comp where it sums the units itself, lit.comp's table, gather.comp toward the camera),
// so the table and the sum it replaces are the same arithmetic. The includer declares `direct`.

vec3 lights_scattered(uint p, uint units, float g, vec3 w) {
    vec3 sum = vec3(0.0);
    for (uint j = 0u; j < units; ++j) {
        uint e = 2u * (p * units + j);
        sum += direct[e].rgb * hg_eval(g, dot(direct[e + 1u].xyz, w));
    }
    return sum;
}
