// batch.glsl: counting loop back-edges as llvmpipe's loop limiter counts them, per SIMD batch.
//
// llvmpipe (gallivm) gives every SIMD batch of a shader one counter of 65535 loop back-edges
// in all (docs/lavapipe.md: LP_MAX_TGSI_LOOP_ITERATIONS, decremented at every loop's end block
// the batch runs). The batch is the subgroup (8 lanes at 256 bits), and it runs *every* branch
// of every `if` (masked, never skipped), so every loop construct the code passes costs the
// batch its body's runs even when no lane is inside: once, with an empty mask. A lane's own
// count (`iters`, budget.glsl) sees none of that, nor its neighbours' trips: lanes' own
// counts of 36721 hid batches past the limit, and an image 15% wrong (lbl's march through a
// cone fanned from its apex).
//
// The count, exact under that model: a loop L whose body holds loop constructs C (directly,
// or in functions it calls, not inside a deeper loop) charges, at the top of each body run
// that some lane makes, W(L) = 1 + sum S(C), where S(C) is the number of loop constructs in
// C's subtree (C's own run, with its nested loops each once, whether or not lanes enter); a
// construct outside every loop is charged S once at the kernel's start. A child's first run is
// then prepaid, and its further runs charge themselves. subgroupElect() is true for exactly
// one active lane, so `batch_iters` summed over the subgroup (subgroupAdd at a point every lane
// reaches) is the batch's count. Loops the compiler unrolls are counted anyway (an
// over-count), and a while (true) loop's exit run twice (the same). Measured, the count is at
// least llvmpipe's: no image went wrong below 65535, lbl's march within 8% of where it did,
// path's 1.1-1.4 times over or more (docs/lavapipe.md); code that only a variable or an early
// return makes dead is counted as live.
//
// A kernel asks for it by defining SCATTERLAB_BATCH_LOOPS (with GL_KHR_shader_subgroup_basic
// enabled) before its includes; LOOP_LIMITED, set by the host on llvmpipe only, leaves real
// GPUs' loops as they were. Elsewhere BATCH_EDGE is empty and a kernel's SPIR-V is unchanged.
//
// A kernel that pauses on its batch's count (the path kernels) defines SCATTERLAB_BATCH_PAUSE
// as its workgroup's invocation count as well: the count then lives in shared memory, one word
// per subgroup, which every lane of the batch reads at its pause points (BATCH_SPENT, through
// budget.glsl's SPENT). llvmpipe runs a subgroup as one SIMD thread, so the elected lane's add
// is seen by its neighbours' next read. Weights that depend on the specialisation are the
// W_... macros tools/glsl-loop-counts --write generates into the kernel's <name>.loops.glsl.
#ifndef SCATTERLAB_BATCH
#define SCATTERLAB_BATCH
#ifdef SCATTERLAB_BATCH_LOOPS
layout(constant_id = 18) const bool LOOP_LIMITED = false;
#ifdef SCATTERLAB_BATCH_PAUSE
// The batch pauses at its resumable points past this count (path.batch_pause), by default
// leaving 27232 below the guard (LOOP_GUARD, budget.glsl) for the work between two of them
// that cannot pause (a BVH query).
layout(constant_id = 19) const uint BATCH_PAUSE = 32768u;
shared uint batch_count[SCATTERLAB_BATCH_PAUSE];
#define BATCH_EDGE(w) { if (LOOP_LIMITED && subgroupElect()) batch_count[gl_SubgroupID] += (w); }
// At the kernel's start: the batch's count from zero, with main's prepayment w.
#define BATCH_BEGIN(w) { if (LOOP_LIMITED && subgroupElect()) batch_count[gl_SubgroupID] = 0u; } BATCH_EDGE(w)
#define BATCH_SPENT (LOOP_LIMITED && batch_count[gl_SubgroupID] >= BATCH_PAUSE)
#define BATCH_COUNT (LOOP_LIMITED ? batch_count[gl_SubgroupID] : 0u)
// The resumable kernels' stats word (src/solvers/parts/resumable.rs BATCH_WORD) for the most
// any batch ran in a dispatch.
const uint STATS_BATCH_WORD = 7u;
#else
uint batch_iters = 0u;
#define BATCH_EDGE(w) { if (LOOP_LIMITED && subgroupElect()) batch_iters += (w); }
#endif
#else
#define BATCH_EDGE(w) {}
#endif
#endif
