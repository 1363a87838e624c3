#version 460
// lattice/check: the convergence test of the lattice iteration, on the device, after every chunk
// of steps (src/solvers/lattice.rs, Diffuser::iterate, which documents the criterion; this is
// the same arithmetic in double precision, in the same order, so that the device stops where
// the host-side test stopped). One workgroup. When the iteration has converged it sets
// control word 0, and every later lattice step, reduction and check of the submission returns
// at once: a batch of chunks is one submission and the host waits once per batch.
//
// Plain: converged when the largest relative change per step of the field at the probe voxels
// falls under tol, channel by channel (a slow channel holding little of the sum is judged on its
// own: summed over channels, a chromatic emitter's albedo-0.99 channel stopped at 0.988 of Le).
// Extrapolated (pc.extrapolate): the chunks' increments per channel D_n (lattice/reduce.comp)
// give r = D_n / D_(n-1) where both chunks had the same length and 0 < r < 1 in every channel
// that moves; then the probes' field (per channel)
// extrapolated to the end of the geometric tail, F + D r / (1 - r), is tested the same way
// against its value a chunk before, and at convergence the host adds the tail to the whole
// field (Diffuser::extrapolate_tail) with the q = r / (1 - r) recorded here.

layout(local_size_x = 256, local_size_y = 1, local_size_z = 1) in;

layout(constant_id = 3) const uint NCH = 3u;

layout(std430, binding = 0) readonly buffer Irradiance { float irr[]; };   // [c * V + v] first
layout(std430, binding = 1) readonly buffer Snapshot { float snap[]; };    // extrapolated: the chunk's start
layout(std430, binding = 2) readonly buffer Partials { double partial[]; }; // lattice/reduce.comp
layout(std430, binding = 3) readonly buffer Probes { uint probe[]; };      // voxel indices
// Per channel and probe: [c P + i] its field at the last check, [(NCH + c) P + i] its
// extrapolated value then.
layout(std430, binding = 4) buffer ProbeState { double pstate[]; };
// The iteration's state, read by the host once per batch (src/solvers/lattice.rs, Control).
layout(std430, binding = 5) buffer Control {
    uint stopped;        // 1: converged (later steps, reductions and checks return)
    uint checks;         // chunks judged since the iteration started
    uint have_inc;       // prev_inc holds the last chunk's increments
    uint prev_n;         // ... of a chunk of this many steps
    uint have_x;         // the probes' extrapolated values of the last check are in pstate
    uint tail;           // converged on the extrapolated field: the host adds the tail
    uint measured;       // x_change holds a measure of the extrapolated field
    uint prev_measured;  // the check before: 1 measured x_change, 0 change only, 2 none
    double change;       // the last check's largest change per step (plain)
    double x_change;     // the last check's largest change of the extrapolated field
    double prev_measure; // the check before's measure (x_change where it had one, else change)
    double prev_inc[4];
    double r[4];         // the chunk ratio per channel at the last extrapolated check
    double q[4];         // r / (1 - r)
} ctl;

layout(push_constant) uniform Push {
    uint voxels;         // V
    uint probes;         // P
    uint parts;          // workgroups of lattice/reduce.comp
    uint steps;          // steps in this chunk (n)
    uint extrapolate;    // 1: the tail extrapolation's criterion
    uint init;           // 1: only record the probes' field (the iteration's start)
    float tol;
    uint pad;
} pc;

shared double sh[256];
shared double sh2[256];
shared double inc_s[3];
shared double q_s[3];
shared uint ratio_ok;

// The probe's field in channel c.
double probe_now(uint c, uint p) {
    return double(irr[c * pc.voxels + p]);
}

void main() {
    if (ctl.stopped != 0u) return;
    uint l = gl_LocalInvocationIndex;
    uint P = pc.probes;
    if (pc.init != 0u) {
        for (uint i = l; i < P; i += 256u) {
            for (uint c = 0u; c < NCH; ++c) pstate[c * P + i] = probe_now(c, probe[i]);
        }
        return;
    }
    double done = double(pc.steps);

    // The chunk's increment per channel: the workgroups' sums, strided per invocation, then a
    // fixed tree (the order is the same every run: deterministic).
    if (pc.extrapolate != 0u) {
        for (uint c = 0u; c < NCH; ++c) {
            double s = 0.0lf;
            for (uint k = l; k < pc.parts; k += 256u) s += partial[k * NCH + c];
            sh[l] = s;
            barrier();
            for (uint t = 128u; t > 0u; t >>= 1) {
                if (l < t) sh[l] += sh[l + t];
                barrier();
            }
            if (l == 0u) inc_s[c] = sh[0];
            barrier();
        }
        if (l == 0u) {
            // The ratio where both chunks had the same length and it is a decay in every
            // channel that moves.
            bool ok = ctl.have_inc != 0u && ctl.prev_n == pc.steps;
            for (uint c = 0u; c < NCH && ok; ++c) {
                double inc = inc_s[c], p = ctl.prev_inc[c];
                if (inc == 0.0lf && p == 0.0lf) {
                    ctl.r[c] = 0.0lf;
                    ctl.q[c] = 0.0lf;
                    continue;
                }
                precise double r = inc / p;
                if (!(r > 0.0lf && r < 1.0lf)) ok = false;
                ctl.r[c] = r;
                precise double q = r / (1.0lf - r);
                ctl.q[c] = q;
            }
            for (uint c = 0u; c < 3u; ++c) q_s[c] = c < NCH ? ctl.q[c] : 0.0lf;
            ratio_ok = ok ? 1u : 0u;
            for (uint c = 0u; c < NCH; ++c) ctl.prev_inc[c] = inc_s[c];
            ctl.prev_n = pc.steps;
            ctl.have_inc = 1u;
        }
        barrier();
    }
    bool ratio = pc.extrapolate != 0u && ratio_ok != 0u;
    bool had_x = ctl.have_x != 0u;

    // Per probe: the change of the field and of its extrapolation since the last check.
    double change = 0.0lf, x_change = 0.0lf;
    for (uint i = l; i < P; i += 256u) {
        uint p = probe[i];
        for (uint c = 0u; c < NCH; ++c) {
            double now = probe_now(c, p);
            double prev = pstate[c * P + i];
            if (now > 0.0lf) change = max(change, abs(now - prev) / now / done);
            if (ratio) {
                double w = double(snap[c * pc.voxels + p]);
                precise double x = now + (now - w) * q_s[c];
                uint k = (NCH + c) * P + i;
                if (had_x && x > 0.0lf) x_change = max(x_change, abs(x - pstate[k]) / x / done);
                pstate[k] = x;
            }
            pstate[c * P + i] = now;
        }
    }
    sh[l] = change;
    sh2[l] = x_change;
    barrier();
    for (uint t = 128u; t > 0u; t >>= 1) {
        if (l < t) {
            sh[l] = max(sh[l], sh[l + t]);
            sh2[l] = max(sh2[l], sh2[l + t]);
        }
        barrier();
    }
    if (l == 0u) {
        // The last check's measure, kept so the host sees two per batch (its estimate of the
        // iterations left).
        ctl.prev_measured = ctl.checks == 0u ? 2u : ctl.measured;
        ctl.prev_measure = ctl.measured != 0u ? ctl.x_change : ctl.change;
        ctl.checks += 1u;
        ctl.change = sh[0];
        ctl.measured = (ratio && had_x) ? 1u : 0u;
        ctl.x_change = sh2[0];
        ctl.have_x = ratio ? 1u : 0u;
        double tol = double(pc.tol);
        if (ratio && had_x && sh2[0] < tol) {
            ctl.tail = 1u;
            ctl.stopped = 1u;
        } else if (sh[0] < tol) {
            ctl.tail = 0u;
            ctl.stopped = 1u;
        }
    }
}
