//! All integration tests in one binary (ripgrep style) so ash and gpu-allocator link once.
//! GPU tests run on whatever Vulkan device the loader finds (lavapipe in CI) with the
//! validation layer on; a missing device is a failure, never a skip.
mod animate_tests;
mod bench_tests;
mod cli_tests;
mod common;
mod dom_streaming;
mod dom_tests;
mod equiangular_tests;
mod export_tests;
mod gpu_core;
mod lbl;
mod lbl_refraction_tests;
mod light_tracing_tests;
mod material_tests;
mod mesh_tests;
mod mitsuba_crosscheck;
mod mnee_tests;
mod networks_tests;
mod object_set_tests;
mod octaves_tests;
mod output_tests;
mod path_extremes_tests;
mod phase_gpu;
mod physics_tests;
mod refraction_tests;
mod registry_tests;
mod report_tests;
mod scene_tests;
mod sh_tests;
mod single_refraction_tests;
mod slab_reference;
mod solvers;
mod stability_tests;
mod timeline_tests;
mod vdb_tests;
mod wavefront_tests;
