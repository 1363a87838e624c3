#version 460
// view/tonemap: `scatterlab view`'s frame, tone-mapped on the device by the operator that
// `render --png` applies on the host (src/output/png.rs: exposure 2^stops, Narkowicz's ACES
// fit, the sRGB OETF, 8 bits rounded half up), packed as the swapchain's 8-bit pixels (BGRA or
// RGBA, alpha 255) for a copy into its image (src/gpu/present.rs). A non-finite value shows as
// NON_FINITE_RGB8 (magenta), as in the PNG.

#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 256, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"

layout(std430, binding = 0) readonly buffer Linear { float rgb[]; };  // 3 per pixel, rows top-down
layout(std430, binding = 1) writeonly buffer Packed { uint px[]; };   // one 8-bit pixel per word

layout(push_constant) uniform Push {
    uint pixels;
    float scale;     // 2^exposure
    uint bgra;       // 1: B8G8R8A8 byte order; 0: R8G8B8A8
} pc;

float aces_narkowicz(float x) {
    const float a = 2.51, b = 0.03, c = 2.43, d = 0.59, e = 0.14;
    return clamp((x * (a * x + b)) / (x * (c * x + d) + e), 0.0, 1.0);
}

float srgb_oetf(float linear) {
    float l = clamp(linear, 0.0, 1.0);
    return l <= 0.0031308 ? 12.92 * l : 1.055 * pow(l, 1.0 / 2.4) - 0.055;
}

// Rust's f32::round is half away from zero; on [0, 255] that is floor(x + 0.5).
uint to_u8(float v) {
    return uint(floor(clamp(v, 0.0, 1.0) * 255.0 + 0.5));
}

void main() {
    uint i = linear_id();
    if (i >= pc.pixels) return;
    vec3 v = vec3(rgb[3u * i], rgb[3u * i + 1u], rgb[3u * i + 2u]);
    uvec3 c;
    if (any(isnan(v)) || any(isinf(v))) {
        c = uvec3(255u, 0u, 255u);
    } else {
        for (int k = 0; k < 3; ++k) {
            c[k] = to_u8(srgb_oetf(aces_narkowicz(max(v[k], 0.0) * pc.scale)));
        }
    }
    px[i] = pc.bgra != 0u ? (c.b | (c.g << 8) | (c.r << 16) | (255u << 24))
                          : (c.r | (c.g << 8) | (c.b << 16) | (255u << 24));
}
