//! Driving resumable kernels (glsl/include/budget.glsl): dispatch, in submissions of a few
//! rounds, until no invocation reports work left.
//!
//! llvmpipe ends every loop of an invocation silently after 65535 iterations in all
//! (LP_MAX_TGSI_LOOP_ITERATIONS, shared by every loop; docs/lavapipe.md), so every kernel
//! with data-dependent loops counts its own iterations, stops at a resumable point after
//! `budget` of them, and reports whether it has work left. Stats buffer layout shared by such
//! kernels: word 2 = most iterations one invocation ran in a dispatch (in the path kernels on
//! llvmpipe, the most one SIMD batch ran: glsl/include/batch.glsl); words 3.. = one
//! "invocations with work left" counter per round of a submission.

use crate::gpu::{Buffer, Gpu, Pass, QueueRole};

use crate::solvers::interface::{Knob, Knobs, Range, SolverError};

/// Largest budget of the view march (`single.budget` and the views of lbl and dom) for a scene
/// with an [[object]] mesh; the path kernels count their SIMD batches instead and pause them
/// (glsl/include/batch.glsl).
/// llvmpipe's loop limiter counts a SIMD batch's loop back-edges together (glsl/include/budget.glsl), at most the sum of its 8
/// lanes' own counts: 8 x (4096 + one event's overshoot) stays below 65535. Measured on the box
/// mesh (max_depth 1, 20 x 20): budgets 64, 300, 1000 and 4096 give the same image bit for bit,
/// 15000 a wrong one (one lane's count 7091 when the batch hit the limiter).
pub const MESH_MAX_BUDGET: u32 = 4096;

/// Refuse the budget knob `name` (its value `budget`) past [`MESH_MAX_BUDGET`] where the
/// scene has an [[object]] mesh: the view march, which counts each lane's loops only.
pub fn check_mesh_budget(k: &Knobs, name: &str, budget: u32, has_mesh: bool) -> Result<(), SolverError> {
    if has_mesh && budget > MESH_MAX_BUDGET {
        return Err(k.invalid(
            name,
            format!(
                "{budget} with an [[object]] mesh: its BVH traversal's divergent loops can take a SIMD batch past \
                 llvmpipe's loop limiter above {MESH_MAX_BUDGET} (measured: a wrong image at 15000); use at most \
                 {MESH_MAX_BUDGET}"
            ),
        ));
    }
    Ok(())
}

/// Whether this device ends an invocation's loops after 65535 back-edges in all: llvmpipe
/// (gallivm's LP_MAX_TGSI_LOOP_ITERATIONS; glsl/include/budget.glsl). Real GPUs have no such
/// limit.
pub fn loop_limited(gpu: &Gpu) -> bool {
    let info = gpu.info();
    info.name.starts_with("llvmpipe") || info.driver_name == "llvmpipe"
}

/// Dispatches per submission; each reports its unfinished invocations in its own counter.
pub const ROUNDS_PER_SUBMIT: u32 = 4;
/// The stats word after the rounds' counters: the most loop back-edges one SIMD batch ran in a
/// dispatch, in a kernel that counts them (the path kernels on llvmpipe: glsl/include/batch.glsl
/// STATS_BATCH_WORD); 0 elsewhere.
pub const BATCH_WORD: usize = 3 + ROUNDS_PER_SUBMIT as usize;
/// The count past which the path kernels pause a SIMD batch at its next resumable point on
/// llvmpipe by default (glsl/include/batch.glsl BATCH_PAUSE, `path.batch_pause`), [`LOOP_GUARD`]
/// less the room left for work that cannot pause (a BVH query).
pub const BATCH_PAUSE: u32 = 32768;
/// Words in a resumable kernel's stats buffer.
pub const STATS_WORDS: u64 = BATCH_WORD as u64 + 1;
/// Own-counted loop iterations past which llvmpipe's shared loop limiter (65535) may fire: the
/// kernels' `LOOP_GUARD` (glsl/include/budget.glsl), the one number both sides use (tested).
pub const LOOP_GUARD: u32 = 60000;
/// The `budget` knob of every solver with resumable kernels.
pub fn budget_knob() -> Knob {
    Knob::fixed(
        "budget",
        "4096",
        Range::int(16, (LOOP_GUARD / 4) as u64),
        "loop iterations per invocation per dispatch of a resumable kernel (llvmpipe ends loops past 65535 in a SIMD \
         batch: there the path kernels also pause a batch past 32768 of its own)",
    )
}

/// Submit rounds of `make_pass(slot)` until a round reports no work left. Returns the number
/// of dispatches and the final stats words.
///
/// `rounds` sizes the first submission (1..=[`ROUNDS_PER_SUBMIT`] dispatches) and comes back as
/// the dispatches this run needed (clamped to that range): a caller that runs the kernel again
/// over similar work (the path tracer's batches) submits no more than that the next time. A
/// round after the one that finished the work still reads and writes every invocation's state,
/// 2-4 ms each at 128 x 128 on lavapipe, where a path batch usually ends in its first dispatch
/// (the sphere: 3 such rounds a batch, about 4% of its time). Guessing short costs one more
/// submission, not a wrong result.
pub fn run_until_done(
    gpu: &Gpu,
    role: QueueRole,
    solver: &str,
    stats: &Buffer,
    rounds: &mut u32,
    make_pass: impl Fn(u32) -> Pass,
) -> Result<(u64, Vec<u32>), SolverError> {
    run_until_done_reporting(gpu, role, solver, stats, rounds, make_pass, &|_| {})
}

/// [`run_until_done`], telling `left` after each submission that leaves work: the invocations
/// with work left after its last dispatch (a progress line for a long pass).
pub fn run_until_done_reporting(
    gpu: &Gpu,
    role: QueueRole,
    solver: &str,
    stats: &Buffer,
    rounds: &mut u32,
    make_pass: impl Fn(u32) -> Pass,
    left: &dyn Fn(u64),
) -> Result<(u64, Vec<u32>), SolverError> {
    let mut dispatches = 0u64;
    let mut n = (*rounds).clamp(1, ROUNDS_PER_SUBMIT);
    loop {
        gpu.write_buffer(stats, 12, &[0u8; ROUNDS_PER_SUBMIT as usize * 4])?;
        let passes: Vec<Pass> = (0..n).map(&make_pass).collect();
        let point = gpu.submit(role, &passes, &[])?;
        gpu.wait(point)?;
        let st: Vec<u32> = gpu.read_buffer_as(stats)?;
        let most = st[2].max(st[BATCH_WORD]);
        if most >= LOOP_GUARD {
            // Every loop of a resumable kernel pauses at the budget (the path kernels inside a
            // free flight too: glsl/include/tracking.glsl), and the path kernels pause a SIMD
            // batch whose count nears the limit (glsl/include/batch.glsl), so what is left is
            // work between two pause points that cannot itself pause: a BVH query through a
            // mesh whose triangles' boxes pile up along rays, or a kernel bug. Refused rather
            // than return a wrong image.
            return Err(SolverError::Unsupported(format!(
                "{solver}: one invocation (on llvmpipe: one SIMD batch of 8) ran {} loop iterations in a dispatch, \
                    past the {LOOP_GUARD} at which llvmpipe silently ends loops, in work that cannot pause: a BVH \
                    query through an [[object]] mesh whose long thin triangles share a vertex (re-triangulate it), \
                    or a kernel loop that does not pause (please report it with the scene); a lower \
                    {solver}.budget (in path, a lower path.batch_pause) may avoid it",
                most
            )));
        }
        // Slot i counts the invocations with work left after the submission's dispatch i.
        if let Some(done) = (0..n).find(|&i| st[3 + i as usize] == 0) {
            let needed = dispatches + done as u64 + 1;
            *rounds = needed.clamp(1, ROUNDS_PER_SUBMIT as u64) as u32;
            return Ok((dispatches + n as u64, st));
        }
        dispatches += n as u64;
        left(st[3 + n as usize - 1] as u64);
        n = ROUNDS_PER_SUBMIT;
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_loop_guard_is_the_kernels() {
        let glsl = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/glsl/include/budget.glsl"));
        let want = format!("const uint LOOP_GUARD = {}u;", super::LOOP_GUARD);
        assert!(glsl.contains(&want), "glsl/include/budget.glsl does not say {want:?}");
    }

    #[test]
    fn the_batch_word_is_the_kernels() {
        let glsl = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/glsl/include/batch.glsl"));
        for want in [
            format!("const uint STATS_BATCH_WORD = {}u;", super::BATCH_WORD),
            format!("layout(constant_id = 19) const uint BATCH_PAUSE = {}u;", super::BATCH_PAUSE),
        ] {
            assert!(glsl.contains(&want), "glsl/include/batch.glsl does not say {want:?}");
        }
    }
}
