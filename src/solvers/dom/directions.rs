//! How many directions dom sweeps for a medium's anisotropy, and how far to trust a render's
//! directions (issue 44, item 2: "directions against g for dom"): one table serves the `auto`
//! choice and the trust line, so the two cannot drift apart.

use serde::Serialize;

use crate::physics::quadrature::Quadrature;

/// The fewest directions dom was validated with at |g| from each threshold up, and the set
/// `dom.directions=auto` picks there, most peaked first. Measured (docs/dom.md, "Directions"):
/// on the thin cube (sigma_t 1, albedo 0.5) at g 0.9 the twice-scattered light is 1.51x
/// path's at s6 (48 directions), 1.16x at s8 (80), 1.04x at product-8x16 (128), at g -0.9 1.50x
/// / 1.14x / 1.00x; at g 0.99 product-8x16 put `stability`'s case 0.8% over the lossless bound
/// and product-16x32 (512) did not; s6 carries the g 0.75 slab (DISORT's problem 3) to 0.5%
/// and the g 0.7 cube to 0.6% of path's energy.
pub const DIRECTIONS_FOR_G: [(f32, usize, &str); 3] =
    [(0.95, 512, "product-16x32"), (0.8, 128, "product-8x16"), (0.0, 48, "s6")];

/// From this g up the full sweeps were measured far off path's energy at every set (docs/dom.md,
/// "The forward peak truncated"): untruncated, the trust line says OUTSIDE and the render warns.
pub const DIRECTIONS_PAST: f32 = 0.95;

/// What dom gave past g -0.95 ([`DirectionsTrust`]'s backward peak), as the warning says it.
const BACKWARD_FIGURES: &str = "on the front-lit cube at g -0.99 it gave 1.22x path's energy (relL2 0.46) at \
     product-16x32, at g -0.95 1.04x (0.18), where the isotropic medium is within 1.3%";

/// The row of [`DIRECTIONS_FOR_G`] for a medium of asymmetry `g`.
fn row(g: f32) -> (f32, usize, &'static str) {
    DIRECTIONS_FOR_G.iter().copied().find(|r| g.abs() >= r.0).unwrap_or(DIRECTIONS_FOR_G[2])
}

/// The set `dom.directions=auto` sweeps for a medium of asymmetry `g`.
pub fn auto_set(g: f32) -> &'static str {
    row(g).2
}

/// How the swept and stored directions resolve the medium's phase function, against what dom
/// was validated with: the `directions` half of dom's trust line (the grid's is
/// [`GridTrust`](crate::solvers::parts::lattice::GridTrust)).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DirectionsTrust {
    /// The medium's Henyey-Greenstein asymmetry g (dimensionless, -1..1).
    pub g: f32,
    /// The swept set and its size N.
    pub set: String,
    pub directions: usize,
    /// The storage set and its size M (1: isotropic).
    pub storage: String,
    pub stored: usize,
    /// The fewest directions dom was validated with at this |g| ([`DIRECTIONS_FOR_G`]), and
    /// the set `auto` sweeps.
    pub needed: usize,
    pub auto: &'static str,
    /// The forward peak is truncated (dom.delta_m): from g 0.95 dom matches path only so.
    pub truncated: bool,
}

impl DirectionsTrust {
    pub fn new(g: f32, swept: &Quadrature, storage: &Quadrature, truncated: bool) -> DirectionsTrust {
        let (_, needed, auto) = row(g);
        DirectionsTrust {
            g,
            set: swept.name.clone(),
            directions: swept.len(),
            storage: storage.name.clone(),
            stored: storage.len(),
            needed,
            auto,
            truncated,
        }
    }

    /// Fewer swept directions than validated at this |g|.
    fn too_few(&self) -> bool {
        self.directions < self.needed
    }

    /// Too few for a peaked phase function (|g| >= 0.8), where the error was measured large.
    fn too_few_peaked(&self) -> bool {
        self.too_few() && self.g.abs() >= DIRECTIONS_FOR_G[1].0
    }

    /// An anisotropic medium's source stored at one direction.
    fn stored_isotropically(&self) -> bool {
        self.g != 0.0 && self.stored == 1
    }

    /// An anisotropic medium's source stored at fewer directions than swept: the upsampling
    /// smears the lobe (the g 0.75 slab: product-16x8 stored at product-8x8 reflects 1.4% too
    /// little, s8 stored at s6 6.7%; stored isotropically the cloud loses 10% of its energy and
    /// the g 0.7 cube 21%).
    fn smeared(&self) -> bool {
        self.g != 0.0 && self.stored < self.directions
    }

    /// A forward peak past what dom matches path at without the truncation: from g 0.95
    /// (DIRECTIONS_PAST) the back-lit cube was 1.5-2.5x path's energy at product-16x32 with the
    /// full sweeps, 0.93-1.10x with the peak truncated (dom.delta_m; docs/dom.md, "The forward
    /// peak truncated").
    fn past_validated(&self) -> bool {
        self.g >= DIRECTIONS_PAST && !self.truncated
    }

    /// A backward peak past what dom matches path at: from g -0.95 on the front-lit cube
    /// (sigma_t 5, albedo 0.95, dom.grid 16 at product-16x32 against path at 2048 spp, where
    /// the isotropic medium is 0.99x path's energy, relL2 0.045) g -0.95 gave 1.04x and relL2
    /// 0.18, g -0.99 1.22x and 0.46 (BACKWARD_FIGURES; at grid 32 1.22x and 0.45: the set's
    /// error, not the grid's). The truncation does not apply: a
    /// backward delta is not light going on unscattered.
    fn backward_past(&self) -> bool {
        self.g <= -DIRECTIONS_PAST
    }

    /// The directions resolve the phase function as dom was validated.
    pub fn within(&self) -> bool {
        !self.too_few() && !self.smeared() && !self.past_validated() && !self.backward_past()
    }

    /// Outside by enough to warn, where the error was measured large: a peaked phase function
    /// (|g| >= 0.8) swept at fewer directions than validated (1.14-1.51x path's twice-scattered
    /// light), or an anisotropic medium's source stored isotropically (10-21% of the energy
    /// lost). Fewer directions than s6 at milder g, or a storage set between, only show in the
    /// trust line (OUTSIDE): not measured large.
    pub fn warns(&self) -> bool {
        self.too_few_peaked() || self.stored_isotropically() || self.past_validated() || self.backward_past()
    }

    /// The one-line figure for a render's summary.
    pub fn line(&self) -> String {
        format!(
            "directions trust: g {} swept at {} ({} directions), stored at {} ({}) (validated at >= {} swept{}){}",
            self.g,
            self.set,
            self.directions,
            self.storage,
            self.stored,
            self.needed,
            if self.g != 0.0 { " and stored at as many" } else { "" },
            if self.within() { "" } else { ": OUTSIDE" }
        )
    }

    /// The warning a render outside the range carries (None within it or near enough): what
    /// falls short, the error measured there, and the knob's value that fixes it.
    pub fn warning(&self) -> Option<String> {
        if !self.warns() {
            return None;
        }
        let mut parts = Vec::new();
        if self.too_few_peaked() {
            parts.push(format!(
                "g {} swept at {} ({} directions), below the {} dom was validated with at |g| >= {} (on the thin cube at \
                 g 0.9 the twice-scattered light was 1.51x path's at s6, 1.16x at s8, 1.04x at product-8x16); set \
                 dom.directions={} (or auto)",
                self.g,
                self.set,
                self.directions,
                self.needed,
                row(self.g).0,
                self.auto
            ));
        }
        if self.stored_isotropically() {
            parts.push(format!(
                "an anisotropic medium (g {}) with its source stored isotropically (dom.storage=1) loses its lobe (the \
                 g 0.6 cloud lost 10% of path's energy, the g 0.7 cube 21%); set dom.storage=auto",
                self.g
            ));
        }
        if self.past_validated() {
            parts.push(format!(
                "g {} is past the forward peaks dom matches path at with the full sweeps: on the back-lit cube at g \
                 0.99 they gave 1.5-2.5x path's energy at product-16x32, 0.93-1.10x with the peak truncated; set \
                 dom.delta_m=auto (with dom.block=0)",
                self.g
            ));
        }
        if self.backward_past() {
            parts.push(format!(
                "g {} is past the backward peaks dom matches path at: {BACKWARD_FIGURES}, and no truncation applies to a \
                 backward peak; use path for this medium",
                self.g
            ));
        }
        Some(format!("dom: {}", parts.join("; and ")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trust(g: f32, swept: &str, stored: &str) -> DirectionsTrust {
        let q = |n: &str| if n == "1" { Quadrature::isotropic() } else { Quadrature::named(n).expect("a set") };
        DirectionsTrust::new(g, &q(swept), &q(stored), false)
    }

    #[test]
    fn auto_sweeps_what_the_trust_line_asks_and_short_sets_warn_where_measured() {
        for g in [-0.94f32, -0.9, -0.5, 0.0, 0.6, 0.79, 0.8, 0.9, 0.94] {
            let t = trust(g, auto_set(g), auto_set(g));
            assert!(t.within() && t.warning().is_none(), "g {g}: auto is within: {t:?}");
        }
        // From g 0.95 the full sweeps did not match path: warned, naming the truncation, which did.
        for g in [0.95f32, 0.99] {
            let t = trust(g, auto_set(g), auto_set(g));
            assert!(!t.within() && t.warning().is_some_and(|w| w.contains("dom.delta_m=auto")), "g {g}: {t:?}");
            let t = DirectionsTrust { truncated: true, ..t };
            assert!(t.within() && t.warning().is_none(), "g {g}: {t:?}");
        }
        // Past g -0.95 no set or truncation matched path: warned, naming path.
        for g in [-0.95f32, -0.99] {
            let t = trust(g, auto_set(g), auto_set(g));
            assert!(!t.within() && t.warning().is_some_and(|w| w.contains("use path")), "g {g}: {t:?}");
        }
        // Measured large: a peaked phase function at s6 / s8, and isotropic storage.
        assert!(trust(0.9, "s6", "s6").warning().is_some_and(|w| w.contains("dom.directions=product-8x16")));
        assert!(trust(-0.9, "s8", "s8").warns());
        assert!(trust(0.99, "product-8x16", "product-8x16").warns());
        let iso = trust(0.6, "s6", "1");
        assert!(iso.warning().is_some_and(|w| w.contains("dom.storage=auto")), "{iso:?}");
        // Outside but not measured large: the line says so, no warning.
        let s4 = trust(0.6, "s4", "s4");
        assert!(!s4.within() && !s4.warns() && s4.line().ends_with("OUTSIDE"), "{s4:?}");
        let s8_at_s6 = trust(0.75, "s8", "s6");
        assert!(!s8_at_s6.within() && !s8_at_s6.warns());
        // An isotropic medium needs one storage direction.
        assert!(trust(0.0, "s6", "1").within());
    }
}
