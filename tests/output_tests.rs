//! Pure-Rust tests of `scatterlab::output`.
