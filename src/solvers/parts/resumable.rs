//! Driving resumable kernels (glsl/include/budget.glsl): dispatch, in submissions of a few
//! rounds, until no invocation reports work left.
//!
//! llvmpipe ends every loop of an invocation silently after 65535 iterations in all
//! (LP_MAX_TGSI_LOOP_ITERATIONS, shared by every loop; docs/lavapipe.md), so every kernel
//! with data-dependent loops counts its own iterations, stops at a resumable point after
//! `budget` of them, and reports whether it has work left. Stats buffer layout shared by such
//! kernels: word 2 = most iterations one invocation ran in a dispatch; words 3.. = one
//! "invocations with work left" counter per round of a submission.

use crate::gpu::{Buffer, Gpu, Pass, QueueRole};

use crate::solvers::interface::{Knob, Knobs, Range, SolverError};

/// Largest budget (`path.budget`, `single.budget`) for a scene with an [[object]] mesh.
/// llvmpipe's loop limiter counts a SIMD batch's loop back-edges together (glsl/include/budget.glsl), at most the sum of its 8
/// lanes' own counts: 8 x (4096 + one event's overshoot) stays below 65535. Measured on the box
/// mesh (max_depth 1, 20 x 20): budgets 64, 300, 1000 and 4096 give the same image bit for bit,
/// 15000 a wrong one (one lane's count 7091 when the batch hit the limiter).
pub const MESH_MAX_BUDGET: u32 = 4096;

/// Refuse the budget knob `name` (its value `budget`) past [`MESH_MAX_BUDGET`] where the
/// scene has an [[object]] mesh: the kernels that trace it (path's, the view march) share
/// the limit.
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

/// Largest `path.budget` on a device whose loops end past 65535 back-edges ([`loop_limited`]),
/// whatever the scene. A path kernel's lanes diverge (one in a free flight, its neighbour in a
/// shadow ray), and llvmpipe counts the back-edges of the SIMD batch of 8 together, not each
/// lane's, while the kernels' guard reads each lane's own count: budgets of 16 to 8000 gave the
/// cloud (scenes/cloud.toml, 16 x 16, 512 spp) the same image bit for bit, 9000 wrong pixels
/// (27 of 256), 10000-15000 70-80 of 256, up to 6.9% each, with no lane past 12612 and so no
/// error. The mesh scenes' measured limit ([`MESH_MAX_BUDGET`]) holds there too.
pub const LIMITED_PATH_BUDGET: u32 = MESH_MAX_BUDGET;

/// Whether this device ends an invocation's loops after 65535 back-edges in all: llvmpipe
/// (gallivm's LP_MAX_TGSI_LOOP_ITERATIONS; glsl/include/budget.glsl). Real GPUs have no such
/// limit.
pub fn loop_limited(gpu: &Gpu) -> bool {
    let info = gpu.info();
    info.name.starts_with("llvmpipe") || info.driver_name == "llvmpipe"
}

/// Refuse `path.budget` past [`LIMITED_PATH_BUDGET`] on a [`loop_limited`] device: its
/// divergent lanes' loops add up in one SIMD batch.
pub fn check_path_budget(gpu: &Gpu, k: &Knobs, name: &str, budget: u32) -> Result<(), SolverError> {
    if loop_limited(gpu) && budget > LIMITED_PATH_BUDGET {
        return Err(k.invalid(
            name,
            format!(
                "{budget} on llvmpipe: its loop limiter counts the 8 lanes of a SIMD batch together, and path's \
                 lanes run different loops, so above {LIMITED_PATH_BUDGET} their loops could end silently \
                 (measured: wrong pixels from 9000 on scenes/cloud.toml); use at most {LIMITED_PATH_BUDGET}"
            ),
        ));
    }
    Ok(())
}

/// Dispatches per submission; each reports its unfinished invocations in its own counter.
pub const ROUNDS_PER_SUBMIT: u32 = 4;
/// Words in a resumable kernel's stats buffer.
pub const STATS_WORDS: u64 = 3 + ROUNDS_PER_SUBMIT as u64;
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
         batch: there path takes at most 4096)",
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
        if st[2] >= LOOP_GUARD {
            // Every loop of a resumable kernel pauses at the budget (the path kernels inside a
            // free flight too: glsl/include/tracking.glsl), so this is a kernel bug, not a scene
            // the user could have avoided; it is still refused rather than return a wrong image.
            return Err(SolverError::Unsupported(format!(
                "{solver}: one invocation ran {} loop iterations in a dispatch, past the {LOOP_GUARD} at which \
                    llvmpipe silently ends loops: a kernel loop that does not pause at its budget (please report it \
                    with the scene); a lower {solver}.budget may avoid it",
                st[2]
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
}
