#version 460
// ordinates/converge: dom's convergence test on the device (src/solvers/dom.rs documents the
// criterion and its tail; this is the same arithmetic, f32 where the host's was f32 and double
// where it was f64, so the device stops at the iteration the host-side test stopped at).
// After each scattering iteration n (1-based) four dispatches, by pc.mode:
//   0  every element k = c V + v: the bounce b = the octants' fluence slices added in order,
//      the summed fluence t += b, the bounce kept (two buffers, this one and the last), and
//      per workgroup in double: sum b, max b, max t, sum t, and (extrapolating, n >= 3) the sum
//      of the light toward the camera minus its value two iterations back (a ring of three);
//   1  one workgroup: the workgroups' figures in a fixed order; change = max b / max t; the
//      pair sums P_n = sum b_n + sum b_(n-1) and the camera's; rho^2 = P_n / P_(n-2) where
//      that is a decay, and f = rho^2 / (1 - rho^2) in f32;
//   2  (with rho^2) every element: the extrapolated fluence e = t + (b + b_last) f, its
//      largest change since the last iteration's e and its largest value;
//   3  one workgroup: the extrapolated change, then the verdict (change <= tol, or the
//      extrapolated change <= tol with the tail's share and the camera's decay).
// A verdict sets control word 0: every later sweep, scatter and test of the submission returns
// at once (a batch of iterations is one submission; the host waits once per batch).

layout(local_size_x = 256, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Slices { float slices[]; };  // [c][octant][v]
layout(std430, binding = 1) readonly buffer Camera { float camera[]; };  // [c][v]
layout(std430, binding = 2) buffer Accum { float accum[]; };             // [c][v]: the bounces summed
layout(std430, binding = 3) buffer Bounce { float bounce[]; };           // [2][c][v]: b_n at n % 2
layout(std430, binding = 4) buffer Extrap { float extrap[]; };           // [c][v]: the last e
layout(std430, binding = 5) buffer CamHist { float cam_hist[]; };        // [3][c][v]: camera_n at n % 3
layout(std430, binding = 6) buffer Partials { double partial[]; };       // [workgroup][8]
layout(std430, binding = 7) buffer Control {
    uint stopped;        // 1: converged
    uint iterations;     // iterations judged
    uint pairs;          // pair sums pushed (the last three kept, newest last)
    uint cam_pairs;      // the camera's
    uint have_e;         // extrap holds the last iteration's e
    uint ratio_ok;       // this iteration has rho^2
    uint ext_ok;         // this iteration has an extrapolated change
    uint tail;           // converged on the extrapolated fluence
    float f;             // rho^2 / (1 - rho^2), f32
    uint pad0;
    uint pad1;
    uint pad2;
    double change;
    double ext_change;
    double r2;
    double prev_sum_b;
    double pair[3];
    double cam_pair[3];
    double total;        // sum t
    double camera_ratio2;
    double share;
} ctl;

layout(push_constant) uniform Push {
    uint voxels;         // V
    uint elements;       // NCH V
    uint mode;
    uint n;              // this iteration, from 1
    uint parts;          // workgroups of modes 0 and 2
    uint extrapolate;
    uvec2 tol;           // dom.tol, a double's two halves (low first)
} pc;

shared double s0[256];
shared double s1[256];
shared double s2[256];
shared double s3[256];
shared double s4[256];

// The sum (or max) of the workgroup's values, by a fixed tree.
void tree(bool sum5) {
    uint l = gl_LocalInvocationIndex;
    for (uint t = 128u; t > 0u; t >>= 1) {
        if (l < t) {
            s0[l] += s0[l + t];
            s1[l] = max(s1[l], s1[l + t]);
            s2[l] = max(s2[l], s2[l + t]);
            if (sum5) {
                s3[l] += s3[l + t];
                s4[l] += s4[l + t];
            }
        }
        barrier();
    }
}

// rho^2 from the last three pair sums a, _, c (newest last) where it is a decay.
bool decay2(double a, double c, out double r) {
    r = 0.0lf;
    if (!(a > 0.0lf && c > 0.0lf)) return false;
    r = c / a;
    return r < 1.0lf;
}

void push3(inout double h[3], uint count, double x) {
    if (count >= 3u) {
        h[0] = h[1];
        h[1] = h[2];
        h[2] = x;
    } else {
        h[count] = x;
    }
}

void main() {
    if (ctl.stopped != 0u) return;
    uint l = gl_LocalInvocationIndex;
    uint k = gl_GlobalInvocationID.x;
    uint V = pc.voxels, NV = pc.elements;
    uint cur = pc.n % 2u;
    if (pc.mode == 0u) {
        double sb = 0.0lf, mb = 0.0lf, mt = 0.0lf, st = 0.0lf, cd = 0.0lf;
        if (k < NV) {
            uint c = k / V, v = k % V;
            precise float b = slices[(c * 8u) * V + v];
            for (uint o = 1u; o < 8u; ++o) b += slices[(c * 8u + o) * V + v];
            precise float t = accum[k] + b;
            accum[k] = t;
            bounce[cur * NV + k] = b;
            // Magnitudes: a warm-started frame's bounces are signed (src/solvers/dom/mod.rs,
            // DomCarry). Summed signed they can cancel (a light turned about a symmetric medium
            // moves little energy in total) and their ratio is not the decay; the magnitudes, as
            // lbl's chunk increments, still decay at the slowest surviving mode's rate. A cold
            // start's bounces are never negative: the same numbers.
            sb = abs(double(b));
            mb = abs(double(b));
            mt = max(0.0lf, double(t));
            st = double(t);
            if (pc.extrapolate != 0u) {
                float cam = camera[k];
                if (pc.n >= 3u) cd = abs(double(cam) - double(cam_hist[((pc.n - 2u) % 3u) * NV + k]));
                cam_hist[(pc.n % 3u) * NV + k] = cam;
            }
        }
        s0[l] = sb; s1[l] = mb; s2[l] = mt; s3[l] = st; s4[l] = cd;
        barrier();
        tree(true);
        if (l == 0u) {
            uint w = gl_WorkGroupID.x * 8u;
            partial[w] = s0[0]; partial[w + 1u] = s1[0]; partial[w + 2u] = s2[0];
            partial[w + 3u] = s3[0]; partial[w + 4u] = s4[0];
        }
    } else if (pc.mode == 1u) {
        double sb = 0.0lf, mb = 0.0lf, mt = 0.0lf, st = 0.0lf, cd = 0.0lf;
        for (uint w = l; w < pc.parts; w += 256u) {
            sb += partial[w * 8u];
            mb = max(mb, partial[w * 8u + 1u]);
            mt = max(mt, partial[w * 8u + 2u]);
            st += partial[w * 8u + 3u];
            cd += partial[w * 8u + 4u];
        }
        s0[l] = sb; s1[l] = mb; s2[l] = mt; s3[l] = st; s4[l] = cd;
        barrier();
        tree(true);
        if (l == 0u) {
            sb = s0[0]; mb = s1[0]; mt = s2[0]; st = s3[0]; cd = s4[0];
            ctl.change = mb / (mt > 0.0lf ? mt : 1.0lf);
            ctl.total = st;
            ctl.ratio_ok = 0u;
            if (pc.extrapolate != 0u) {
                if (pc.n >= 3u) {
                    push3(ctl.cam_pair, ctl.cam_pairs, cd);
                    ctl.cam_pairs += 1u;
                }
                if (pc.n >= 2u) {
                    push3(ctl.pair, ctl.pairs, sb + ctl.prev_sum_b);
                    ctl.pairs += 1u;
                }
                ctl.prev_sum_b = sb;
                double r;
                if (ctl.pairs >= 3u && decay2(ctl.pair[0], ctl.pair[2], r)) {
                    ctl.ratio_ok = 1u;
                    ctl.r2 = r;
                    precise double q = r / (1.0lf - r);
                    ctl.f = float(q);
                }
            }
        }
    } else if (pc.mode == 2u) {
        if (ctl.ratio_ok == 0u) return;
        double md = 0.0lf, me = 0.0lf;
        if (k < NV) {
            float b = bounce[cur * NV + k], last = bounce[(1u - cur) * NV + k];
            precise float e = accum[k] + (b + last) * ctl.f;
            if (ctl.have_e != 0u) md = abs(double(e) - double(extrap[k]));
            me = max(0.0lf, double(e));
            extrap[k] = e;
        }
        s0[l] = 0.0lf; s1[l] = md; s2[l] = me;
        barrier();
        tree(false);
        if (l == 0u) {
            partial[gl_WorkGroupID.x * 8u + 5u] = s1[0];
            partial[gl_WorkGroupID.x * 8u + 6u] = s2[0];
        }
    } else {
        double md = 0.0lf, me = 0.0lf;
        if (ctl.ratio_ok != 0u) {
            for (uint w = l; w < pc.parts; w += 256u) {
                md = max(md, partial[w * 8u + 5u]);
                me = max(me, partial[w * 8u + 6u]);
            }
        }
        s0[l] = 0.0lf; s1[l] = md; s2[l] = me;
        barrier();
        tree(false);
        if (l == 0u) {
            ctl.ext_ok = 0u;
            if (ctl.ratio_ok != 0u) {
                if (ctl.have_e != 0u) {
                    ctl.ext_change = s1[0] / max(s2[0], 2.2250738585072014e-308lf);
                    ctl.ext_ok = 1u;
                }
                ctl.have_e = 1u;
            } else {
                ctl.have_e = 0u;
            }
            ctl.iterations = pc.n;
            double tol = packDouble2x32(pc.tol);
            if (ctl.change <= tol) {
                ctl.stopped = 1u;
                ctl.tail = 0u;
            } else if (ctl.ext_ok != 0u && ctl.ext_change <= tol) {
                ctl.stopped = 1u;
                ctl.tail = 1u;
                ctl.change = ctl.ext_change;
                double r2 = ctl.r2;
                double added = ctl.pair[2] * r2 / (1.0lf - r2);
                ctl.share = added / max(ctl.total + added, 2.2250738585072014e-308lf);
                double c;
                ctl.camera_ratio2 = (pc.n >= 3u && ctl.cam_pairs >= 3u && decay2(ctl.cam_pair[0], ctl.cam_pair[2], c))
                    ? min(c, r2) : 0.0lf;
            }
        }
    }
}
