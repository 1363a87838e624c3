//! Queue roles and their mapping onto the device's queue families.
//!
//! Solvers name a *role* (`trace`, `diffuse`, `transfer`); the mapping to real queues is decided once, when
//! the device is created, by [`map_roles`], a pure function of the queue-family table so it can
//! be tested against the tables of real GPUs without owning one (see docs/design.md, "Vulkan facts").

use serde::Serialize;

/// The queue roles of the engine. Tracing-like work runs on `Trace`, stencil/diffusion work on
/// `Diffuse`; on a device with one queue both roles share it and the same graph runs serialised.
/// `Transfer` carries buffer copies only (dom's block streaming): a transfer-only family's
/// queue (the copy engines) where the device has one, else the `Trace` queue.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum QueueRole {
    Trace,
    Diffuse,
    Transfer,
}

impl QueueRole {
    pub const ALL: [QueueRole; 3] = [QueueRole::Trace, QueueRole::Diffuse, QueueRole::Transfer];

    pub fn name(self) -> &'static str {
        match self {
            QueueRole::Trace => "trace",
            QueueRole::Diffuse => "diffuse",
            QueueRole::Transfer => "transfer",
        }
    }

    pub(crate) fn index(self) -> usize {
        self as usize
    }
}

impl std::fmt::Display for QueueRole {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What the mapping needs to know about one queue family.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct FamilyInfo {
    pub index: u32,
    pub queue_count: u32,
    pub graphics: bool,
    pub compute: bool,
    pub transfer: bool,
    pub timestamp_valid_bits: u32,
}

/// A queue a role runs on: (family, index within family).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct QueueSlot {
    pub family: u32,
    pub index: u32,
}

/// How the two compute roles were placed, strongest concurrency first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum MappingKind {
    /// Two queues of one compute-only family (NVIDIA family 2, AMD's compute family).
    TwoComputeOnly,
    /// Two queues of one compute-capable family that also does graphics.
    TwoComputeCapable,
    /// One queue in each of two compute-capable families (needs care with buffer sharing).
    TwoFamilies,
    /// One queue shared by both roles (lavapipe, many Intel GPUs): no overlap is possible.
    Shared,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct RoleMapping {
    pub kind: MappingKind,
    pub trace: QueueSlot,
    pub diffuse: QueueSlot,
    /// The copy role: a transfer-only family's first queue, or the trace queue.
    pub transfer: QueueSlot,
}

impl RoleMapping {
    pub fn slot(&self, role: QueueRole) -> QueueSlot {
        match role {
            QueueRole::Trace => self.trace,
            QueueRole::Diffuse => self.diffuse,
            QueueRole::Transfer => self.transfer,
        }
    }

    /// Whether the two compute roles share one queue (no compute overlap possible).
    pub fn shared(&self) -> bool {
        self.trace == self.diffuse
    }

    /// Whether copies have a queue of their own (a transfer-only family).
    pub fn own_transfer(&self) -> bool {
        self.transfer != self.trace && self.transfer != self.diffuse
    }

    /// Distinct families used, for `VK_SHARING_MODE_CONCURRENT` and queue creation.
    pub fn families(&self) -> Vec<u32> {
        distinct(vec![self.trace.family, self.diffuse.family, self.transfer.family])
    }

    /// Distinct families of the two compute roles (what ordinary buffers are shared among).
    pub fn compute_families(&self) -> Vec<u32> {
        distinct(vec![self.trace.family, self.diffuse.family])
    }

    pub fn describe(&self) -> String {
        let transfer = if self.own_transfer() {
            format!("family {} queue {}", self.transfer.family, self.transfer.index)
        } else {
            "the trace queue".to_string()
        };
        format!(
            "{:?}: trace -> family {} queue {}, diffuse -> family {} queue {}, transfer -> {transfer}",
            self.kind, self.trace.family, self.trace.index, self.diffuse.family, self.diffuse.index
        )
    }
}

fn distinct(mut f: Vec<u32>) -> Vec<u32> {
    f.sort_unstable();
    f.dedup();
    f
}

/// Map the roles onto queues: two compute-only queues, else two compute-capable queues of
/// one family, else queues of two families, else one shared queue (docs/design.md, "Queues and
/// schedule"). Returns `None` when no family can run compute at all. Families whose
/// timestamps are not valid are avoided where an alternative exists, since every pass is timed.
pub fn map_roles(families: &[FamilyInfo]) -> Option<RoleMapping> {
    let mut m = map_compute_roles(families)?;
    // Copies: a timed transfer-only family (the DMA engines beside the compute queues: NVIDIA
    // families 1, 3 and 4, AMD's SDMA), the widest timestamps first; else the trace queue.
    let copy = families
        .iter()
        .filter(|f| f.transfer && !f.compute && !f.graphics && f.queue_count > 0 && f.timestamp_valid_bits > 0)
        .max_by_key(|f| (f.timestamp_valid_bits, std::cmp::Reverse(f.index)));
    m.transfer = copy.map_or(m.trace, |f| QueueSlot { family: f.index, index: 0 });
    Some(m)
}

fn map_compute_roles(families: &[FamilyInfo]) -> Option<RoleMapping> {
    let compute: Vec<&FamilyInfo> = families.iter().filter(|f| f.compute && f.queue_count > 0).collect();
    if compute.is_empty() {
        return None;
    }
    let slot = |f: &FamilyInfo, index: u32| QueueSlot { family: f.index, index };
    let two = |kind, f: &FamilyInfo| RoleMapping { kind, trace: slot(f, 0), diffuse: slot(f, 1), transfer: slot(f, 0) };
    let timed = |f: &&&FamilyInfo| f.timestamp_valid_bits > 0;

    if let Some(f) = compute.iter().filter(timed).find(|f| !f.graphics && f.queue_count >= 2) {
        return Some(two(MappingKind::TwoComputeOnly, f));
    }
    if let Some(f) = compute.iter().filter(timed).find(|f| f.queue_count >= 2) {
        return Some(two(MappingKind::TwoComputeCapable, f));
    }
    let timed_families: Vec<&&FamilyInfo> = compute.iter().filter(timed).collect();
    if timed_families.len() >= 2 {
        // Prefer a compute-only family for tracing (the heavier role), a general one for diffusion.
        let mut sorted = timed_families.clone();
        sorted.sort_by_key(|f| f.graphics);
        return Some(RoleMapping {
            kind: MappingKind::TwoFamilies,
            trace: slot(sorted[0], 0),
            diffuse: slot(sorted[1], 0),
            transfer: slot(sorted[0], 0),
        });
    }
    let best = timed_families.first().copied().unwrap_or(&compute[0]);
    Some(RoleMapping {
        kind: MappingKind::Shared,
        trace: slot(best, 0),
        diffuse: slot(best, 0),
        transfer: slot(best, 0),
    })
}

/// A queue mapping asked for by the user (`--queues`, env `SCATTERLAB_QUEUES`), for queue
/// concurrency experiments: the same work under each mapping the device offers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum QueueChoice {
    /// The strongest concurrency the device offers ([`map_roles`]).
    #[default]
    Auto,
    /// Every role on one queue (copies included): no overlap possible.
    Shared,
    /// Trace and diffuse on two queues of one compute family; copies on a transfer-only family
    /// where there is one.
    SameFamily,
    /// Trace and diffuse on queues of two different compute families; copies as above.
    SeparateFamilies,
}

impl QueueChoice {
    pub const NAMES: [&'static str; 4] = ["auto", "shared", "same-family", "separate-families"];

    pub fn parse(s: &str) -> Option<QueueChoice> {
        Some(match s {
            "auto" => QueueChoice::Auto,
            "shared" => QueueChoice::Shared,
            "same-family" => QueueChoice::SameFamily,
            "separate-families" => QueueChoice::SeparateFamilies,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }
}

/// The mapping `choice` asks for on this queue-family table, or why the device cannot give it
/// (one line, naming the families it has).
pub fn map_roles_as(families: &[FamilyInfo], choice: QueueChoice) -> Result<RoleMapping, String> {
    let auto = map_roles(families).ok_or("no queue family can run compute")?;
    let table = || {
        families
            .iter()
            .map(|f| {
                let what = match (f.graphics, f.compute) {
                    (true, true) => "graphics+compute",
                    (false, true) => "compute",
                    _ => "transfer",
                };
                format!("{}: {} x{}", f.index, what, f.queue_count)
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    let timed: Vec<&FamilyInfo> =
        families.iter().filter(|f| f.compute && f.queue_count > 0 && f.timestamp_valid_bits > 0).collect();
    let slot = |f: &FamilyInfo, index: u32| QueueSlot { family: f.index, index };
    // Copies on the transfer-only family the automatic mapping found, else on the trace queue.
    let with_copies = |kind, trace: QueueSlot, diffuse| {
        let transfer = if auto.own_transfer() { auto.transfer } else { trace };
        RoleMapping { kind, trace, diffuse, transfer }
    };
    match choice {
        QueueChoice::Auto => Ok(auto),
        QueueChoice::Shared => {
            let q = auto.trace;
            Ok(RoleMapping { kind: MappingKind::Shared, trace: q, diffuse: q, transfer: q })
        }
        QueueChoice::SameFamily => {
            let f = timed
                .iter()
                .filter(|f| f.queue_count >= 2)
                .min_by_key(|f| f.graphics)
                .ok_or_else(|| format!("no compute family offers two queues (families {})", table()))?;
            let kind = if f.graphics { MappingKind::TwoComputeCapable } else { MappingKind::TwoComputeOnly };
            Ok(with_copies(kind, slot(f, 0), slot(f, 1)))
        }
        QueueChoice::SeparateFamilies => {
            let mut two = timed.clone();
            two.sort_by_key(|f| f.graphics);
            if two.len() < 2 {
                return Err(format!("only one compute family (families {})", table()));
            }
            Ok(with_copies(MappingKind::TwoFamilies, slot(two[0], 0), slot(two[1], 0)))
        }
    }
}

/// [`map_roles_as`] for a mapping named as `--queues` takes it (an unknown name is an error
/// listing the names).
pub fn map_roles_named(families: &[FamilyInfo], name: &str) -> Result<RoleMapping, String> {
    let choice =
        QueueChoice::parse(name).ok_or_else(|| format!("unknown mapping; one of {}", QueueChoice::NAMES.join(", ")))?;
    map_roles_as(families, choice)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fam(index: u32, queue_count: u32, graphics: bool, compute: bool) -> FamilyInfo {
        FamilyInfo { index, queue_count, graphics, compute, transfer: true, timestamp_valid_bits: 64 }
    }

    #[test]
    fn nvidia_uses_compute_only_family() {
        let t = [fam(0, 16, true, true), fam(1, 2, false, false), fam(2, 8, false, true)];
        let m = map_roles(&t).unwrap();
        assert_eq!(m.kind, MappingKind::TwoComputeOnly);
        assert_eq!((m.trace, m.diffuse), (QueueSlot { family: 2, index: 0 }, QueueSlot { family: 2, index: 1 }));
        assert_eq!(m.transfer, QueueSlot { family: 1, index: 0 });
        assert!(m.own_transfer());
        assert_eq!(m.families(), vec![1, 2]);
    }

    /// The H100's table as the driver reports it (docs/devices/nvidia-h100-2026-11-25): copies go
    /// to family 1 (64-bit timestamps), not family 3 (32-bit) or 4 (one queue, 64-bit, later).
    #[test]
    fn h100_copies_on_a_transfer_family() {
        let mut t = [
            fam(0, 16, true, true),
            fam(1, 2, false, false),
            fam(2, 8, false, true),
            fam(3, 7, false, false),
            fam(4, 1, false, false),
        ];
        t[3].timestamp_valid_bits = 32;
        let m = map_roles(&t).unwrap();
        assert_eq!(m.transfer, QueueSlot { family: 1, index: 0 });
    }

    #[test]
    fn radv_with_single_compute_queue_uses_two_families() {
        let t = [fam(0, 1, true, true), fam(1, 1, false, true)];
        let m = map_roles(&t).unwrap();
        assert_eq!(m.kind, MappingKind::TwoFamilies);
        assert_eq!(m.trace.family, 1);
        assert_eq!(m.diffuse.family, 0);
        assert!(!m.shared());
    }

    #[test]
    fn general_family_with_two_queues() {
        let m = map_roles(&[fam(0, 4, true, true)]).unwrap();
        assert_eq!(m.kind, MappingKind::TwoComputeCapable);
    }

    #[test]
    fn forced_mappings_on_the_h100_table() {
        let t = [
            fam(0, 16, true, true),
            fam(1, 2, false, false),
            fam(2, 8, false, true),
            fam(3, 7, false, false),
            fam(4, 1, false, false),
        ];
        let shared = map_roles_as(&t, QueueChoice::Shared).unwrap();
        assert!(shared.shared() && !shared.own_transfer());
        assert_eq!((shared.trace, shared.transfer), (QueueSlot { family: 2, index: 0 }, shared.trace));
        let same = map_roles_as(&t, QueueChoice::SameFamily).unwrap();
        assert_eq!(same.kind, MappingKind::TwoComputeOnly);
        assert_eq!((same.trace.family, same.diffuse.family, same.diffuse.index), (2, 2, 1));
        assert_eq!(same.transfer, QueueSlot { family: 1, index: 0 });
        let sep = map_roles_as(&t, QueueChoice::SeparateFamilies).unwrap();
        assert_eq!(sep.kind, MappingKind::TwoFamilies);
        assert_eq!((sep.trace.family, sep.diffuse.family, sep.transfer.family), (2, 0, 1));
        assert_eq!(map_roles_as(&t, QueueChoice::Auto).unwrap(), map_roles(&t).unwrap());
    }

    #[test]
    fn lavapipe_refuses_what_it_cannot_map() {
        let t = [fam(0, 1, true, true)];
        assert!(map_roles_as(&t, QueueChoice::Shared).unwrap().shared());
        let e = map_roles_as(&t, QueueChoice::SameFamily).unwrap_err();
        assert!(e.contains("two queues") && e.contains("0: graphics+compute x1"), "{e}");
        let e = map_roles_as(&t, QueueChoice::SeparateFamilies).unwrap_err();
        assert!(e.contains("one compute family"), "{e}");
        for n in QueueChoice::NAMES {
            assert_eq!(QueueChoice::parse(n).unwrap().name(), n);
        }
        assert!(QueueChoice::parse("both").is_none());
    }

    #[test]
    fn lavapipe_shares_one_queue() {
        let m = map_roles(&[fam(0, 1, true, true)]).unwrap();
        assert_eq!(m.kind, MappingKind::Shared);
        assert!(m.shared());
        assert_eq!(m.transfer, m.trace);
        assert!(!m.own_transfer());
        assert_eq!(m.families(), vec![0]);
    }

    #[test]
    fn no_compute_no_mapping() {
        assert!(map_roles(&[fam(0, 1, true, false)]).is_none());
    }

    #[test]
    fn untimed_family_avoided() {
        let mut only = fam(1, 8, false, true);
        only.timestamp_valid_bits = 0;
        let m = map_roles(&[fam(0, 1, true, true), only]).unwrap();
        assert_eq!(m.kind, MappingKind::Shared);
        assert_eq!(m.trace.family, 0);
    }
}
