// one_minus_exp.glsl: 1 - exp(-x), x >= 0 an optical depth, the share of light a step of it
// extinguishes, without the cancellation of the subtraction.
//
// exp(-x) for small x rounds to a float just under 1, whose neighbours are 2^-24 apart, so
// 1 - exp(-x) keeps few correct bits once x is below 1e-4 or so (GLSL has no expm1).
// Measured on the homogeneous sphere at sigma_t 1e-5 (lbl, steps of 2e-7 mean free paths): the
// once-scattered power the march deposited was 1.14x the analytic one, at sigma_t 1e-3 1.001x.
// Below 0.1 the series x (1 - x/2 + x^2/6 - x^3/24 + x^4/120) is used: its first omitted
// term, x^6/720, is x^5/720 < 1.4e-8 of the value, where the subtraction's rounding (2^-24 of
// 1) is 6e-7 of the value at 0.1 (at a switch at 0.01 it had been 6e-6, measured 1.5e-5 with
// exp's own error: tests/extinction_gpu.rs).
// Kept out of common.glsl: `path`'s kernels include that, and need none of this.
#ifndef SCATTERLAB_ONE_MINUS_EXP
#define SCATTERLAB_ONE_MINUS_EXP
float one_minus_exp(float x) {
    return x < 0.1 ? x * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0))))) : 1.0 - exp(-x);
}
// (1 - exp(-x)) / x for x of either sign (1 at 0): the mean of exp(-x u) over u in [0, 1], a
// step's transmittance averaged along it. The same cancellation spoils the quotient for small
// |x| (6e-4 of it at 1e-4); below 0.1 the same series over x.
float one_minus_exp_over(float x) {
    return abs(x) < 0.1 ? 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0))))
                        : (1.0 - exp(-x)) / x;
}
// Per channel. (Not an overload of the name: tools/glsl-loop-counts resolves calls by name.)
vec3 one_minus_exp3(vec3 x) { return vec3(one_minus_exp(x.x), one_minus_exp(x.y), one_minus_exp(x.z)); }
#endif
