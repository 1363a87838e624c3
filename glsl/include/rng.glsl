// rng.glsl: counter-based random numbers. Every stream is a pure function of
// (scene seed, pixel, sample index), so a render is deterministic on a given device
// whatever the batch split or thread count.
#ifndef SCATTERLAB_RNG
#define SCATTERLAB_RNG

// PCG-RXS-M-XS 32-bit output permutation as a hash (Jarzynski and Olano 2020).
uint pcg_hash(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

uint rng_init(uint seed_lo, uint seed_hi, uint pixel, uint sample_index) {
    return pcg_hash(seed_lo ^ pcg_hash(pixel ^ pcg_hash(sample_index ^ pcg_hash(seed_hi))));
}

// Uniform in [0, 1): 24 random bits, so 1 - u is never 0 and -log(1 - u) is finite.
float rnd(inout uint s) {
    s = s * 747796405u + 2891336453u;
    uint w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    w = (w >> 22u) ^ w;
    return float(w >> 8u) * (1.0 / 16777216.0);
}

vec2 rnd2(inout uint s) { float a = rnd(s); return vec2(a, rnd(s)); }
#endif
