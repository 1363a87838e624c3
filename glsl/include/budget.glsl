// budget.glsl: a per-invocation loop budget, so no kernel ever meets llvmpipe's loop limiter.
//
// Measured (docs/lavapipe.md): llvmpipe (gallivm) gives every shader invocation one counter,
// LP_MAX_TGSI_LOOP_ITERATIONS = 65535, "shared between every loop", decremented on each loop
// back-edge of the 8-wide SIMD batch; when it reaches 0 *every loop exits silently* and the
// shader runs on with wrong values. Kernels here therefore count their own loop iterations
// in `iters`, stop at a resumable point once `budget` is spent, keep their state in a buffer,
// and are dispatched again until no invocation has work left. Real GPUs have no such limiter;
// there the budget bounds the time one dispatch may run (watchdog/TDR).
#ifndef SCATTERLAB_BUDGET
#define SCATTERLAB_BUDGET

uint iters = 0u;

// Past this many own-counted iterations in one dispatch the limiter could have fired
// (divergent lanes may add up); the kernel reports it and the host fails loudly.
const uint LOOP_GUARD = 60000u;

// A loop whose trips count into the lane's `iters` counts into its batch's too (batch.glsl):
// LOOP_EDGE(w) at the top of its body, w = 1 + the loop constructs nested in it.
#include "batch.glsl"
#define LOOP_EDGE(w) { iters++; BATCH_EDGE(w); }

// Whether the dispatch's work is spent at a resumable point: the lane's own `limit`, or, in a
// kernel that pauses on its batch's count (batch.glsl), the batch's past BATCH_PAUSE once this
// lane has counted an iteration in the dispatch (iters > 0). A batch's count starts every
// dispatch at main's prepayment, far below BATCH_PAUSE, so the first lane to reach a pause
// point goes on, and every dispatch moves some lane of every unfinished batch on: the
// dispatches end. (A lane can still pause without progress where its neighbours' work that
// cannot pause filled the batch first; the next dispatch finds that work done.)
#ifdef SCATTERLAB_BATCH_PAUSE
#define SPENT(limit) (iters >= (limit) || (BATCH_SPENT && iters > 0u))
#else
#define SPENT(limit) (iters >= (limit))
#endif
#endif
