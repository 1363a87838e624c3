#version 460
// probe/phase: runs the GLSL Henyey-Greenstein code on the device so tests can check it
// against the Rust reference and statistically (normalisation, pdf, mean cosine, chi-square).
#extension GL_GOOGLE_include_directive : require
#include "../include/rng.glsl"
#include "../include/phase.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

// For sample i: direction sampled around +z (xyz) and its pdf by hg_eval (w).
layout(std430, binding = 0) writeonly buffer Samples { vec4 samples[]; };
// For evaluation point i: hg_eval(g, cos_in[i]).
layout(std430, binding = 1) readonly buffer CosIn { float cos_in[]; };
layout(std430, binding = 2) writeonly buffer EvalOut { float eval_out[]; };

layout(push_constant) uniform Push {
    float g;
    uint count;
    uint eval_count;
    uint seed;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < pc.count) {
        uvec2 rng = rng_init(pc.seed, 0u, i, 0u);
        vec3 w = hg_sample(pc.g, vec3(0.0, 0.0, 1.0), rnd2(rng));
        samples[i] = vec4(w, hg_eval(pc.g, w.z));
    }
    if (i < pc.eval_count) eval_out[i] = hg_eval(pc.g, cos_in[i]);
}
