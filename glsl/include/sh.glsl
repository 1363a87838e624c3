// sh.glsl: real spherical harmonics on the device, the basis of `sh-single` (issue 17, thesis
// chapter 3 and appendix A.1). The same functions, order and convention as src/physics/sh.rs
// (read its module docs): order L holds bands 0 .. L - 1, coefficient (l, m) at l (l + 1) + m,
// orthonormal over the sphere, no Condon-Shortley phase, evaluated as polynomials in the
// direction's components by the three-term recurrence (no trigonometry).
#ifndef SCATTERLAB_SH
#define SCATTERLAB_SH

#define SH_MAX_ORDER 8u
#define SH_MAX_COEFFS 64u

const float SH_INV_4PI = 0.07957747154594767;

// The basis of order `order` (1 .. SH_MAX_ORDER) at unit direction d into y[0 .. order^2).
void sh_basis(vec3 d, uint order, out float y[SH_MAX_COEFFS]) {
    for (uint i = 0u; i < SH_MAX_COEFFS; ++i) y[i] = 0.0;
    float c = 1.0, s = 0.0, q_mm = 1.0;   // (c, s) = (x + i y)^m, q_mm = (2m - 1)!!
    for (uint m = 0u; m < order; ++m) {
        if (m > 0u) {
            float c2 = c * d.x - s * d.y;
            s = c * d.y + s * d.x;
            c = c2;
            q_mm *= float(2u * m - 1u);
        }
        float q_prev2 = 0.0, q_prev = 0.0;
        for (uint l = m; l < order; ++l) {
            float q;
            if (l == m) q = q_mm;
            else if (l == m + 1u) q = float(2u * m + 1u) * d.z * q_mm;
            else q = (float(2u * l - 1u) * d.z * q_prev - float(l + m - 1u) * q_prev2) / float(l - m);
            // K_lm = sqrt((2l + 1) / 4pi (l - m)! / (l + m)!)
            float ratio = 1.0;
            for (uint k = l - m + 1u; k <= l + m; ++k) ratio /= float(k);
            float k_lm = sqrt(float(2u * l + 1u) * SH_INV_4PI * ratio);
            uint at = l * (l + 1u);
            if (m == 0u) {
                y[at] = k_lm * q;
            } else {
                y[at + m] = 1.41421356 * k_lm * q * c;
                y[at - m] = 1.41421356 * k_lm * q * s;
            }
            q_prev2 = q_prev;
            q_prev = q;
        }
    }
}
#endif
