// quantize.glsl: a deposit into a 32-bit fixed-point sum (integer atomics: the same bits in any
// order of the adds), rounded without bias.
//
// Rounding each deposit to the nearest quantum drops every deposit under half a quantum, and a
// medium thin enough makes them all that small: measured on the homogeneous sphere at sigma_t
// 1e-3 (lbl, fixed-point transfer, 2^30 quanta for the light's power, 65536 rays), the whole
// multiply scattered term was lost (the image equalled `single`'s; the float transfer's was 2.9e-4
// above it). Rounding down after adding u, uniform in [0, 1), has expectation x exactly
// (E[floor(x + u)] = x), so a sum of many deposits is unbiased; u is a hash of the deposit's own
// bits and of its slot, never of the order it is added in, so the sums stay deterministic.
// A value past 2^24 quanta is an integer in float already, and u changes nothing.
#ifndef SCATTERLAB_QUANTIZE
#define SCATTERLAB_QUANTIZE
#include "rng.glsl"

// u in [0, 1) for the value x (in quanta) of slot `slot` (an entry and which of its sums).
float quantum_dither(float x, uint slot) {
    return float(pcg_hash(pcg_hash(slot) ^ floatBitsToUint(x)) >> 8u) * (1.0 / 16777216.0);
}

// x >= 0 quanta as an unsigned deposit.
uint quantize(float x, uint slot) { return uint(floor(x + quantum_dither(x, slot))); }

// x quanta of either sign, as the two's-complement bits that an unsigned atomicAdd wraps
// the same way in any order.
uint quantize_signed(float x, uint slot) { return uint(int(floor(x + quantum_dither(x, slot)))); }
#endif
