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

// The SIMD batch's own count, where a kernel asks for it (SCATTERLAB_BATCH_LOOPS, with
// GL_KHR_shader_subgroup_basic enabled first). A lane's `iters` is not what llvmpipe counts:
// its counter belongs to the batch (its subgroup: 8 lanes at 256 bits), and an inner loop
// costs the batch its longest lane's trip each time the outer loop runs it, so when lanes'
// long traversals fall in different outer iterations the batch's count is up to 8 times any
// lane's (a cone of 8192 fan triangles: lanes' own counts of 36721 at lbl.k 64, an image 15%
// wrong). LOOP_EDGE() at the top of a loop's body counts the batch once for each trip any
// lane makes (subgroupElect picks one active lane), LOOP_ENTRY() before the loop the one more
// back-edge the batch takes leaving it; subgroupAdd(batch_iters) at a point all lanes reach is
// the batch's count. Without SCATTERLAB_BATCH_LOOPS both only count the lane's `iters`, and a
// kernel's SPIR-V is what it was.
#ifdef SCATTERLAB_BATCH_LOOPS
uint batch_iters = 0u;
#define LOOP_EDGE() { iters++; if (subgroupElect()) batch_iters++; }
#define LOOP_ENTRY() { if (subgroupElect()) batch_iters++; }
#else
#define LOOP_EDGE() { iters++; }
#define LOOP_ENTRY() {}
#endif
#endif
