// characteristics.glsl: the step-characteristics coefficients of dom's sweeps (thesis 5.3.1;
// glsl/ordinates/sweep.comp and block_sweep.comp).
#ifndef SCATTERLAB_CHARACTERISTICS
#define SCATTERLAB_CHARACTERISTICS

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
