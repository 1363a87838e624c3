#version 460
// probe/fresnel: runs glsl/include/dielectric.glsl on the device so tests can check Fresnel
// reflectance, Snell's law and total internal reflection against the CPU formulas.
#extension GL_GOOGLE_include_directive : require
#include "../include/common.glsl"
#include "../include/dielectric.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

// Case i: (cos_i, eta = n_i / n_t) of a ray d = (sqrt(1 - cos_i^2), 0, -cos_i) meeting a
// surface of normal +z from above.
layout(std430, binding = 0) readonly buffer Cases { vec2 cases[]; };
// Case i: (F, cos_t) and the refracted direction (xyz; w unused).
layout(std430, binding = 1) writeonly buffer Out { vec4 out_f[]; };
layout(std430, binding = 2) writeonly buffer Dir { vec4 out_dir[]; };

layout(push_constant) uniform Push { uint count; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    float cos_i = cases[i].x;
    float eta = cases[i].y;
    vec3 d = vec3(sqrt(max(0.0, 1.0 - cos_i * cos_i)), 0.0, -cos_i);
    vec3 n = vec3(0.0, 0.0, 1.0);
    float cos_t;
    float F = fresnel_dielectric(cos_i, eta, cos_t);
    out_f[i] = vec4(F, cos_t, 0.0, 0.0);
    out_dir[i] = F < 1.0 ? vec4(refract_dir(d, n, eta, cos_i, cos_t), 0.0) : vec4(reflect(d, n), 1.0);
}
