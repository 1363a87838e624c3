//! Measurement: what the GPU did and how long it took (timelines, overlap, serial baseline).

pub mod bench;
pub mod stability;
pub mod timeline;
