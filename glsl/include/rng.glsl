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

// A stream is (key, counter): the key identifies (seed, pixel, sample), the counter counts
// draws. Output n of a stream is hash(key ^ hash(n)); for a fixed n, key -> output is a
// bijection, so distinct streams never replay each other's numbers (a 32-bit LCG state per
// stream would: streams land on shifted copies of one 2^32 cycle, correlating pixels).
uvec2 rng_init(uint seed_lo, uint seed_hi, uint pixel, uint sample_index) {
    uint key = pcg_hash(seed_lo ^ pcg_hash(pixel ^ pcg_hash(sample_index ^ pcg_hash(seed_hi + 0x9e3779b9u))));
    return uvec2(key, 0u);
}

// Uniform in [0, 1): 24 random bits, so 1 - u is never 0 and -log(1 - u) is finite.
float rnd(inout uvec2 s) {
    s.y += 1u;
    uint w = pcg_hash(s.x ^ pcg_hash(s.y));
    return float(w >> 8u) * (1.0 / 16777216.0);
}

vec2 rnd2(inout uvec2 s) { float a = rnd(s); return vec2(a, rnd(s)); }
#endif
