#version 460
// networks/splat: the image (illumination networks 3.3: "sorts the particles according to their
// distance from the camera, splats them, and adds their contributions with alpha blending").
// One invocation per pixel, through the pixel's centre: every particle within three widths of
// the ray is a splat with a Gaussian footprint of width s, its extinction cross-section
// sigma_t m spread over it (the column density integrates to m over the plane, so a splat
// stops as much light in all as the particle holds), opacity alpha = 1 - exp(-sigma_t m K(rho)),
// K the normalised 2D Gaussian at the ray's distance rho from the particle. Front to back:
//   L = sum_k c_k alpha_k prod_(j before k) (1 - alpha_j) + sky prod_all (1 - alpha_j),
// c_k from networks/gather. The splats on a pixel are kept in a local array (at most MAX_SPLATS,
// the nearest; overflow counted: at 96 the cloud's centre at 1024 particles dropped 23158 splats
// over 64 x 64 pixels, at 256 none) and composited in camera-distance order: deterministic.
//
// A pixel tests the particles of its screen tile's list (src/solvers/networks/image.rs,
// `SplatTiles`: built on the host, nearest the camera first, every particle whose reach could
// touch a ray through the tile), not all N: the same particles pass, in the same order, so the
// image is the one the test of every particle gives, bit for bit (one tile of all of them is
// that kernel, `--model-all`), at a fraction of the work (4096 particles at 512^2: N per pixel
// was 20 s of lavapipe).
//
// Transmittance (pc.step > 0, `networks.transmittance = medium`, the default): the splats'
// optical depths along the ray are scaled, per channel, so that they sum to the medium's own
// optical depth along it, sigma_t times the density's integral (view.glsl's density_depth,
// midpoint steps of pc.step): the particles still decide where along the ray the light is
// scattered and with what radiance, but how much of the sky and of each splat the ray lets
// through is the medium's, not the particles' (a few thousand particles give each pixel a
// noisy sample of its optical depth: the paper's splats, pc.step = 0, keep it). A ray that
// crosses medium but meets no splat sees the sky through the medium and no in-scattering.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/budget.glsl"
#include "../include/view.glsl"
#include "../include/one_minus_exp.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, binding = 3) readonly buffer Positions { vec4 positions[]; };
layout(std430, binding = 4) readonly buffer Colour { vec4 colour[]; };
// rgb; w = splats dropped, or -1 where the loops reached the guard (glsl/include/budget.glsl)
layout(std430, binding = 5) writeonly buffer Image { vec4 image[]; };
// Each tile's particles, nearest first, one list after another; tile t's is
// items[starts[t] .. starts[t + 1]).
layout(std430, binding = 6) readonly buffer Items { uint items[]; };
layout(std430, binding = 7) readonly buffer Starts { uint starts[]; };

layout(push_constant) uniform Push {
    vec4 sigma_m;     // rgb: sigma_t m, a particle's extinction cross-section (scene units^2)
    vec4 sky;         // rgb: the background's radiance
    float width;      // s, the footprint's width (scene units)
    uint tile;        // pixels along a screen tile's side
    float step;       // > 0: the medium's transmittance along the ray, by this step; 0: the splats'
    uint tiles_x;     // tiles along the image's width
} pc;

const uint MAX_SPLATS = 256u;

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    if (px.x >= scene.image.x || px.y >= scene.image.y) return;
    vec3 o, d;
    camera_ray(vec2(px) + 0.5, o, d);
    uint which[MAX_SPLATS];
    uint n = 0u, dropped = 0u;
    float reach2 = 9.0 * pc.width * pc.width;
    // The particles come nearest the camera first (sorted on the host by distance
    // from the camera, along its axis for an orthographic one, ties by index): each splat is
    // appended, with no insertion loop whose lanes diverge (llvmpipe counts a SIMD batch's
    // loop back-edges together, so per-lane counts could not see a divergent insertion sort
    // reach its limiter: at 16384 particles it did, silently), and once MAX_SPLATS are kept
    // the rest are the farthest, counted.
    uint t = (px.y / pc.tile) * pc.tiles_x + px.x / pc.tile;
    for (uint q = starts[t]; q < starts[t + 1u]; ++q) {
        iters++;
        uint k = items[q];
        vec3 v = positions[k].xyz - o;
        float t = dot(v, d);
        if (t <= 0.0) continue;
        vec3 off = v - t * d;
        if (dot(off, off) > reach2) continue;
        if (n == MAX_SPLATS) {
            ++dropped;
            continue;
        }
        which[n] = k;
        ++n;
    }
    float norm = 1.0 / (2.0 * PI * pc.width * pc.width);
    float inv2w2 = 1.0 / (2.0 * pc.width * pc.width);
    // Each splat's optical depth is sigma_m K(rho) times `scale` (per channel).
    vec3 scale = vec3(1.0);
    vec3 T_medium = vec3(1.0);
    if (pc.step > 0.0) {
        vec3 tau = scene.materials[0].sigma_t.rgb * density_depth(o, d, 1e30, pc.step);
        float kernels = 0.0;
        for (uint j = 0u; j < n; ++j) {
            iters++;
            vec3 v = positions[which[j]].xyz - o;
            vec3 off = v - dot(v, d) * d;
            kernels += norm * exp(-dot(off, off) * inv2w2);
        }
        vec3 splats = pc.sigma_m.rgb * kernels;
        scale = vec3(
            splats.r > 0.0 ? tau.r / splats.r : 0.0,
            splats.g > 0.0 ? tau.g / splats.g : 0.0,
            splats.b > 0.0 ? tau.b / splats.b : 0.0);
        T_medium = exp(-tau);
    }
    vec3 L = vec3(0.0), T = vec3(1.0);
    for (uint j = 0u; j < n; ++j) {
        iters++;
        uint k = which[j];
        vec3 v = positions[k].xyz - o;
        vec3 off = v - dot(v, d) * d;
        float kernel = norm * exp(-dot(off, off) * inv2w2);
        vec3 alpha = one_minus_exp3(pc.sigma_m.rgb * kernel * scale);
        L += T * alpha * colour[k].rgb;
        T *= vec3(1.0) - alpha;
    }
    // With the medium's transmittance, what the splats let through is exp(-tau) by
    // construction where any splat is met; where none is, T is 1 and the medium's applies.
    if (pc.step > 0.0) T = T_medium;
    image[px.y * scene.image.x + px.x] = vec4(L + T * pc.sky.rgb, iters > LOOP_GUARD ? -1.0 : float(dropped));
}
