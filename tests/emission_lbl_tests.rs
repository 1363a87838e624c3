//! Emissive media in `lbl` (issue 47): the emitted light the medium scatters, against `path`
//! and the 1D emitting-slab reference (tests/slab_reference.rs, `slab_emission`).
