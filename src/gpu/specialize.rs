//! Specialization on the host: a kernel's SPIR-V with its specialization constants made
//! ordinary constants and the branches they decide removed, before the driver sees it.
//!
//! Why: lavapipe (Mesa 22.3, Debian 12) compiles the code behind a branch a specialization
//! constant has decided as if it could run. The camera-ray march (`view/march`), specialised
//! for the cloud without a mesh, took 1.3-1.5 s to build where the same SPIR-V with those
//! branches removed (spirv-opt's `--freeze-spec-const --eliminate-dead-branches`) took 84 ms,
//! and path's tracer 2.0 s against 1.06 s; every process that renders paid it again, since
//! lavapipe's pipeline cache holds no compiled code (docs/decisions.md, "Specialization on the
//! host"). A driver that eliminates the branches itself (NVIDIA's) is given less to read and
//! the same program.
//!
//! What it does, in the order of the SPIR-V 1.6 specification's sections:
//! - 2.12 (specialization): every `OpSpecConstant{True,False,}` becomes the `OpConstant*` of the
//!   value the pipeline asks for (or its default), every `OpSpecConstantOp` the constant its
//!   operation gives, every `OpSpecConstantComposite` an `OpConstantComposite`, and the `SpecId`
//!   decorations go: the result is what the driver would have built from the specialization info.
//! - 2.11 (structured control flow): a selection (`OpSelectionMerge` + `OpBranchConditional`)
//!   whose condition is now a constant becomes a plain branch to the side taken; blocks no longer
//!   reachable go, except the merge and continue targets of constructs that remain (kept as an
//!   `OpUnreachable` block, or a branch back to its loop's header for a continue target);
//!   `OpPhi`s lose the parents that no longer branch to them.
//!
//! Anything it does not know (an `OpSpecConstantOp` operation outside its table, a module it
//! cannot parse) is an error and the caller hands the driver the kernel as compiled, with the
//! specialization info: the same program either way.

use std::collections::{HashMap, HashSet};

use rspirv::binary::Assemble;
use rspirv::dr::{self, Instruction, Operand};
use rspirv::spirv::{Decoration, Op, Word};

use super::pipeline::Spec;

/// A scalar constant's value, as far as folding needs it: a bool or 32 bits of an integer.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Value {
    Bool(bool),
    Int(u32),
}

/// The scalar types constants are folded in.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    Bool,
    Int { signed: bool },
    Float,
}

/// `words` (a whole SPIR-V module) specialised with `spec` (`(constant_id, value)`; a constant
/// not given keeps its default) and its decided branches removed. An error names what the pass
/// does not handle; the module is then to be used as it is.
pub fn specialize(words: &[u32], spec: &[(u32, Spec)]) -> Result<Vec<u32>, String> {
    if spec.is_empty() {
        // Nothing to freeze: the module as it is (its defaults are what the driver would use).
        return Ok(words.to_vec());
    }
    let mut m = dr::load_words(words).map_err(|e| format!("cannot parse the SPIR-V: {e}"))?;
    let given: HashMap<u32, Spec> = spec.iter().copied().collect();
    let spec_ids: HashMap<Word, u32> = m
        .annotations
        .iter()
        .filter(|i| i.class.opcode == Op::Decorate)
        .filter_map(|i| match i.operands.as_slice() {
            [Operand::IdRef(target), Operand::Decoration(Decoration::SpecId), Operand::LiteralBit32(id)] => {
                Some((*target, *id))
            }
            _ => None,
        })
        .collect();
    let constants = freeze(&mut m.types_global_values, &spec_ids, &given)?;
    m.annotations.retain(|i| {
        !(i.class.opcode == Op::Decorate && matches!(i.operands.get(1), Some(Operand::Decoration(Decoration::SpecId))))
    });
    let decided: HashMap<Word, bool> = constants
        .iter()
        .filter_map(|(id, v)| match v {
            Value::Bool(b) => Some((*id, *b)),
            Value::Int(_) => None,
        })
        .collect();
    for f in &mut m.functions {
        remove_decided_branches(f, &decided)?;
    }
    Ok(m.assemble())
}

/// Make every specialization constant in the module's global section an ordinary constant;
/// returns the scalar constants' values (the ones branches and folds can read).
fn freeze(
    globals: &mut [Instruction],
    spec_ids: &HashMap<Word, u32>,
    given: &HashMap<u32, Spec>,
) -> Result<HashMap<Word, Value>, String> {
    let mut types: HashMap<Word, Scalar> = HashMap::new();
    let mut values: HashMap<Word, Value> = HashMap::new();
    for inst in globals.iter_mut() {
        let id = inst.result_id;
        let ty = inst.result_type.and_then(|t| types.get(&t).copied());
        let given_for = |id: Option<Word>| id.and_then(|id| spec_ids.get(&id)).and_then(|s| given.get(s)).copied();
        match inst.class.opcode {
            Op::TypeBool => {
                types.insert(id.expect("a type has an id"), Scalar::Bool);
            }
            Op::TypeInt => {
                if let [Operand::LiteralBit32(32), Operand::LiteralBit32(s)] = inst.operands.as_slice() {
                    types.insert(id.expect("a type has an id"), Scalar::Int { signed: *s != 0 });
                }
            }
            Op::TypeFloat => {
                types.insert(id.expect("a type has an id"), Scalar::Float);
            }
            Op::ConstantTrue | Op::ConstantFalse => {
                values.insert(id.expect("a constant has an id"), Value::Bool(inst.class.opcode == Op::ConstantTrue));
            }
            Op::Constant => {
                if let (Some(Scalar::Int { .. }), [Operand::LiteralBit32(v)]) = (ty, inst.operands.as_slice()) {
                    values.insert(id.expect("a constant has an id"), Value::Int(*v));
                }
            }
            Op::SpecConstantTrue | Op::SpecConstantFalse => {
                let b = match given_for(id) {
                    Some(Spec::Bool(b)) => b,
                    Some(other) => return Err(format!("a bool specialization constant given {other:?}")),
                    None => inst.class.opcode == Op::SpecConstantTrue,
                };
                *inst = Instruction::new(
                    if b { Op::ConstantTrue } else { Op::ConstantFalse },
                    inst.result_type,
                    id,
                    vec![],
                );
                values.insert(id.expect("a constant has an id"), Value::Bool(b));
            }
            Op::SpecConstant => {
                let bits = match (given_for(id), inst.operands.as_slice()) {
                    (Some(Spec::U32(v)), _) => v,
                    (Some(Spec::I32(v)), _) => v as u32,
                    (Some(Spec::F32(v)), _) => v.to_bits(),
                    (Some(Spec::Bool(_)), _) => return Err("a numeric specialization constant given a bool".into()),
                    (None, [Operand::LiteralBit32(v)]) => *v,
                    (None, other) => return Err(format!("a specialization constant of {} words", other.len())),
                };
                *inst = Instruction::new(Op::Constant, inst.result_type, id, vec![Operand::LiteralBit32(bits)]);
                if let Some(Scalar::Int { .. }) = ty {
                    values.insert(id.expect("a constant has an id"), Value::Int(bits));
                }
            }
            Op::SpecConstantComposite => {
                *inst = Instruction::new(Op::ConstantComposite, inst.result_type, id, inst.operands.clone());
            }
            Op::SpecConstantOp => {
                let v = fold(inst, ty, &values)?;
                *inst = match v {
                    Value::Bool(b) => Instruction::new(
                        if b { Op::ConstantTrue } else { Op::ConstantFalse },
                        inst.result_type,
                        id,
                        vec![],
                    ),
                    Value::Int(bits) => {
                        Instruction::new(Op::Constant, inst.result_type, id, vec![Operand::LiteralBit32(bits)])
                    }
                };
                values.insert(id.expect("a constant has an id"), v);
            }
            _ => {}
        }
    }
    Ok(values)
}

/// The value of an `OpSpecConstantOp` over constants already frozen: the operations glslang
/// emits for our kernels' constant expressions (comparisons, logic, integer arithmetic).
fn fold(inst: &Instruction, ty: Option<Scalar>, values: &HashMap<Word, Value>) -> Result<Value, String> {
    let (op, args) = match inst.operands.split_first() {
        Some((Operand::LiteralSpecConstantOpInteger(op), rest)) => (*op, rest),
        _ => return Err("an OpSpecConstantOp without its operation".into()),
    };
    let arg = |k: usize| -> Result<Value, String> {
        match args.get(k) {
            Some(Operand::IdRef(id)) => {
                values.get(id).copied().ok_or_else(|| format!("{op:?} of a non-scalar constant"))
            }
            _ => Err(format!("{op:?} without operand {k}")),
        }
    };
    let int = |k: usize| match arg(k)? {
        Value::Int(v) => Ok(v),
        Value::Bool(_) => Err(format!("{op:?} of a bool")),
    };
    let boolean = |k: usize| match arg(k)? {
        Value::Bool(b) => Ok(b),
        Value::Int(_) => Err(format!("{op:?} of an integer")),
    };
    let result_int = || match ty {
        Some(Scalar::Int { .. }) => Ok(()),
        _ => Err(format!("{op:?} to a type other than a 32-bit integer")),
    };
    use Value::{Bool, Int};
    Ok(match op {
        Op::LogicalNot => Bool(!boolean(0)?),
        Op::LogicalAnd => Bool(boolean(0)? && boolean(1)?),
        Op::LogicalOr => Bool(boolean(0)? || boolean(1)?),
        Op::LogicalEqual => Bool(boolean(0)? == boolean(1)?),
        Op::LogicalNotEqual => Bool(boolean(0)? != boolean(1)?),
        Op::IEqual => Bool(int(0)? == int(1)?),
        Op::INotEqual => Bool(int(0)? != int(1)?),
        Op::ULessThan => Bool(int(0)? < int(1)?),
        Op::ULessThanEqual => Bool(int(0)? <= int(1)?),
        Op::UGreaterThan => Bool(int(0)? > int(1)?),
        Op::UGreaterThanEqual => Bool(int(0)? >= int(1)?),
        Op::SLessThan => Bool((int(0)? as i32) < int(1)? as i32),
        Op::SLessThanEqual => Bool(int(0)? as i32 <= int(1)? as i32),
        Op::SGreaterThan => Bool(int(0)? as i32 > int(1)? as i32),
        Op::SGreaterThanEqual => Bool(int(0)? as i32 >= int(1)? as i32),
        Op::Select => match arg(0)? {
            Bool(c) => arg(if c { 1 } else { 2 })?,
            Int(_) => return Err("OpSelect on an integer".into()),
        },
        Op::IAdd | Op::ISub | Op::IMul | Op::UDiv | Op::UMod | Op::BitwiseAnd | Op::BitwiseOr | Op::BitwiseXor => {
            result_int()?;
            let (a, b) = (int(0)?, int(1)?);
            Int(match op {
                Op::IAdd => a.wrapping_add(b),
                Op::ISub => a.wrapping_sub(b),
                Op::IMul => a.wrapping_mul(b),
                // Division by zero is undefined in SPIR-V: left to the driver.
                Op::UDiv if b != 0 => a / b,
                Op::UMod if b != 0 => a % b,
                Op::BitwiseAnd => a & b,
                Op::BitwiseOr => a | b,
                Op::BitwiseXor => a ^ b,
                _ => return Err(format!("{op:?} by zero")),
            })
        }
        Op::ShiftLeftLogical | Op::ShiftRightLogical => {
            result_int()?;
            let (a, s) = (int(0)?, int(1)?);
            if s >= 32 {
                return Err(format!("{op:?} by {s}"));
            }
            Int(if op == Op::ShiftLeftLogical { a << s } else { a >> s })
        }
        Op::Not => {
            result_int()?;
            Int(!int(0)?)
        }
        Op::SNegate => {
            result_int()?;
            Int((int(0)? as i32).wrapping_neg() as u32)
        }
        // Between the two 32-bit integer types the bits stay.
        Op::UConvert | Op::SConvert | Op::Bitcast => {
            result_int()?;
            Int(int(0)?)
        }
        other => return Err(format!("OpSpecConstantOp {other:?} is not folded on the host")),
    })
}

/// The labels a block's terminator branches to.
fn successors(block: &dr::Block) -> Vec<Word> {
    let Some(last) = block.instructions.last() else { return vec![] };
    let ids =
        |ops: &[Operand]| ops.iter().filter_map(|o| if let Operand::IdRef(w) = o { Some(*w) } else { None }).collect();
    match last.class.opcode {
        Op::Branch => ids(&last.operands),
        // The condition is the first id, the two targets follow (weights are literals).
        Op::BranchConditional => ids(&last.operands[1..]),
        // The selector is the first id; the default and each case's label follow.
        Op::Switch => ids(&last.operands[1..]),
        _ => vec![],
    }
}

/// The merge (and, for a loop, continue) target a block's merge instruction names.
fn merge_targets(block: &dr::Block) -> Option<(Op, Word, Option<Word>)> {
    let n = block.instructions.len();
    let merge = block.instructions.get(n.checked_sub(2)?)?;
    let id = |k: usize| match merge.operands.get(k) {
        Some(Operand::IdRef(w)) => Some(*w),
        _ => None,
    };
    match merge.class.opcode {
        Op::SelectionMerge => Some((Op::SelectionMerge, id(0)?, None)),
        Op::LoopMerge => Some((Op::LoopMerge, id(0)?, Some(id(1)?))),
        _ => None,
    }
}

/// Replace each selection decided by a constant with a branch to the side taken, then drop
/// the blocks no longer reachable (SPIR-V 2.11's rules kept: see the module's comment).
fn remove_decided_branches(f: &mut dr::Function, decided: &HashMap<Word, bool>) -> Result<(), String> {
    if f.blocks.is_empty() {
        return Ok(());
    }
    let mut changed = false;
    for block in &mut f.blocks {
        let n = block.instructions.len();
        if n < 2 || block.instructions[n - 2].class.opcode != Op::SelectionMerge {
            continue;
        }
        let last = &block.instructions[n - 1];
        if last.class.opcode != Op::BranchConditional {
            continue;
        }
        let (Some(Operand::IdRef(cond)), Some(Operand::IdRef(t)), Some(Operand::IdRef(e))) =
            (last.operands.first(), last.operands.get(1), last.operands.get(2))
        else {
            return Err("an OpBranchConditional without its ids".into());
        };
        let Some(&c) = decided.get(cond) else { continue };
        let taken = if c { *t } else { *e };
        block.instructions.truncate(n - 2);
        block.instructions.push(Instruction::new(Op::Branch, None, None, vec![Operand::IdRef(taken)]));
        changed = true;
    }
    if !changed {
        return Ok(());
    }
    let label = |b: &dr::Block| b.label_id().expect("a block has a label");
    let index: HashMap<Word, usize> = f.blocks.iter().enumerate().map(|(i, b)| (label(b), i)).collect();
    let mut reachable = vec![false; f.blocks.len()];
    let mut stack = vec![0usize];
    reachable[0] = true;
    while let Some(i) = stack.pop() {
        for s in successors(&f.blocks[i]) {
            let j = *index.get(&s).ok_or("a branch to a label outside the function")?;
            if !reachable[j] {
                reachable[j] = true;
                stack.push(j);
            }
        }
    }
    // The merge and continue targets of the constructs that remain must stay, even unreached.
    let mut merges: HashSet<Word> = HashSet::new();
    let mut continues: HashMap<Word, Word> = HashMap::new();
    for (i, b) in f.blocks.iter().enumerate() {
        if !reachable[i] {
            continue;
        }
        if let Some((_, merge, cont)) = merge_targets(b) {
            merges.insert(merge);
            if let Some(c) = cont {
                continues.insert(c, label(b));
            }
        }
    }
    let mut kept = Vec::with_capacity(f.blocks.len());
    for (i, mut b) in std::mem::take(&mut f.blocks).into_iter().enumerate() {
        let id = label(&b);
        if reachable[i] {
            kept.push(b);
        } else if let Some(&header) = continues.get(&id) {
            b.instructions = vec![Instruction::new(Op::Branch, None, None, vec![Operand::IdRef(header)])];
            kept.push(b);
        } else if merges.contains(&id) {
            b.instructions = vec![Instruction::new(Op::Unreachable, None, None, vec![])];
            kept.push(b);
        }
    }
    f.blocks = kept;
    // Each OpPhi keeps the parents that still branch to its block.
    let preds: HashMap<Word, HashSet<Word>> = {
        let mut p: HashMap<Word, HashSet<Word>> = HashMap::new();
        for b in &f.blocks {
            for s in successors(b) {
                p.entry(s).or_default().insert(label(b));
            }
        }
        p
    };
    for b in &mut f.blocks {
        let id = label(b);
        let empty = HashSet::new();
        let parents = preds.get(&id).unwrap_or(&empty);
        for inst in b.instructions.iter_mut().filter(|i| i.class.opcode == Op::Phi) {
            let pairs: Vec<Operand> = inst
                .operands
                .chunks(2)
                .filter(|pair| matches!(pair.get(1), Some(Operand::IdRef(p)) if parents.contains(p)))
                .flatten()
                .cloned()
                .collect();
            if pairs.is_empty() {
                return Err("an OpPhi left without a parent".into());
            }
            inst.operands = pairs;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(bytes: &[u8]) -> Vec<u32> {
        ash::util::read_spv(&mut std::io::Cursor::new(bytes)).unwrap()
    }

    /// rspirv reads and writes every word of our kernels as glslang wrote them, but for the
    /// header's generator (its own): nothing is lost on the way through the host.
    #[test]
    fn a_kernel_read_and_written_again_is_the_same_module() {
        let w = words(include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/spirv/view/march.spv")));
        let mut again = dr::load_words(&w).unwrap().assemble();
        assert_ne!(again[2], w[2], "the generator word is rspirv's");
        again[2] = w[2];
        assert_eq!(again, w);
    }
}
