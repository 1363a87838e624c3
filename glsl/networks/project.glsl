// networks/project.glsl: where a particle falls on direction i's window and its depth along
// the direction (illumination networks, Szirmay-Kalos et al. 2005, 3.1: orthographic
// projection onto an M x M window on the bounding sphere's plane). The arithmetic is
// src/solvers/networks.rs's `Network::key`, operation for operation and without contraction
// (`precise`), so the CPU construction the tests compare with gives the same bits.
//
// Per direction three vec4 from the host: u, v (the window's axes) and w (the direction of
// travel), each xyz; dirs[3i].w holds nothing.

struct Key {
    uint pixel;  // y * M + x
    float depth; // along the direction of travel: upstream particles have smaller depth
};

Key project(vec3 x, uint i, vec4 centre_radius, float inv_pixel, uint m) {
    precise vec3 rel = x - centre_radius.xyz;
    vec3 u = dirs[3u * i].xyz, v = dirs[3u * i + 1u].xyz, w = dirs[3u * i + 2u].xyz;
    precise float a = rel.x * u.x + rel.y * u.y + rel.z * u.z;
    precise float b = rel.x * v.x + rel.y * v.y + rel.z * v.z;
    precise float d = rel.x * w.x + rel.y * w.y + rel.z * w.z;
    precise float fa = (a + centre_radius.w) * inv_pixel;
    precise float fb = (b + centre_radius.w) * inv_pixel;
    int last = int(m) - 1;
    int px = clamp(int(floor(fa)), 0, last);
    int py = clamp(int(floor(fb)), 0, last);
    return Key(uint(py) * m + uint(px), d);
}
