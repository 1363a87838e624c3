// common.glsl: constants and the one direction convention of scatterlab.
//
// Direction convention (used by every shader and by src/physics): a direction is the way
// light *propagates*. A ray leaving the camera propagates away from it; for phase functions,
// cos_theta = dot(incoming propagation direction, outgoing propagation direction), so
// Henyey-Greenstein g > 0 scatters forward (cos_theta near +1).
#ifndef SCATTERLAB_COMMON
#define SCATTERLAB_COMMON

// Most distinct materials of a scene's objects (src/scene/mod.rs MAX_MATERIALS): the length
// of scene.glsl's material table.
#define MAX_MATERIALS 16

const float PI = 3.14159265358979323846;
const float INV_4PI = 0.07957747154594767;
const float INF = 1.0 / 0.0;

float max3(vec3 v) { return max(v.x, max(v.y, v.z)); }
float avg3(vec3 v) { return (v.x + v.y + v.z) * (1.0 / 3.0); }

// Orthonormal basis around n (Duff et al. 2017, "Building an orthonormal basis, revisited").
void onb(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

// Uniform direction on the sphere from two uniforms in [0,1).
vec3 uniform_sphere(vec2 u) {
    float z = 1.0 - 2.0 * u.x;
    float r = sqrt(max(0.0, 1.0 - z * z));
    float phi = 2.0 * PI * u.y;
    return vec3(r * cos(phi), r * sin(phi), z);
}

// Ray / axis-aligned box: the parametric interval [t0, t1] inside the box, empty if t0 > t1.
vec2 ray_box(vec3 o, vec3 d, vec3 bmin, vec3 bmax) {
    vec3 inv = 1.0 / d;
    vec3 ta = (bmin - o) * inv;
    vec3 tb = (bmax - o) * inv;
    vec3 tn = min(ta, tb);
    vec3 tf = max(ta, tb);
    return vec2(max(max(tn.x, tn.y), tn.z), min(min(tf.x, tf.y), tf.z));
}

// Ray / sphere: [t0, t1] inside the sphere, empty (t0 > t1) on a miss. d is unit length.
vec2 ray_sphere(vec3 o, vec3 d, vec3 c, float r) {
    vec3 oc = o - c;
    float b = dot(oc, d);
    // Numerically stable discriminant: |oc - b d|^2 avoids cancellation in b*b - |oc|^2.
    vec3 perp = oc - b * d;
    float h = r * r - dot(perp, perp);
    if (h < 0.0) return vec2(INF, -INF);
    h = sqrt(h);
    return vec2(-b - h, -b + h);
}
#endif
