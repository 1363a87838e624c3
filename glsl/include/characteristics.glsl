// characteristics.glsl: the step-characteristics coefficients of dom's sweeps (thesis 5.3.1;
// glsl/ordinates/sweep.comp and block_sweep.comp).
#ifndef SCATTERLAB_CHARACTERISTICS
#define SCATTERLAB_CHARACTERISTICS

// The factors per direction, f[i][o] then s[i][o] (18 floats, padded to 20; src/solvers/dom/
// ordinates.rs Tables), at binding GEOMETRY_BINDING (defined first). A uniform block, not a
// storage buffer: every invocation reads the same direction's factors at once, which llvmpipe
// loads once a SIMD batch where a storage buffer's read is a loop over the lanes
// (docs/lavapipe.md: the sweeps 1.45x faster). 64 KiB at most (the host checks the device's
// maxUniformBufferRange): 819 directions.
layout(std140, binding = GEOMETRY_BINDING) uniform Geometry { vec4 geometry4[4096]; };
float geometry(uint i) { return geometry4[i >> 2u][i & 3u]; }

// (1 - e^-x) / x and (x - 1 + e^-x) / x^2 without cancellation near 0: float has no expm1, so
// their Taylor series below x = 0.5 (the first term left out is below 3e-8 there; above it,
// x - 1 + e^-x > 0.1 keeps the direct form within 1e-6).
vec2 phi_psi(float x) {
    if (x < 0.5) {
        float p = 1.0, q = 0.5, t = 1.0;
        // x^k / (k + 1)! and x^k / (k + 2)!, alternating.
        float fp = 1.0, fq = 0.5;
        for (int k = 1; k <= 7; ++k) {
            t *= -x;
            fp /= float(k + 1);
            fq /= float(k + 2);
            p += t * fp;
            q += t * fq;
        }
        return vec2(p, q);
    }
    float e = exp(-x);
    return vec2((1.0 - e) / x, (x - 1.0 + e) / (x * x));
}

#endif
