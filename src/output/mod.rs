//! Output: HDR images, EXR and PNG files, error metrics, JSON reports, and the Mitsuba 3
//! export of a scene.
//!
//! Every writer here is atomic ([`write_atomically`]): it writes a temporary file in the
//! destination directory and renames it over the final name only on success, so a failed
//! or interrupted write never leaves a truncated file under the name a user asked for.

mod atomic;
mod error;
pub mod exr;
mod image;
pub mod metrics;
mod pfm;
pub mod png;
mod provenance;
pub mod report;

pub use self::atomic::{write_atomically, Staging};
pub use self::error::OutputError;
pub use self::exr::{read_exr, read_exr_layer, read_exr_layers, read_exr_metadata, write_exr, write_exr_with_metadata};
pub use self::image::Image;
pub use self::metrics::{compare, error_png, Metrics};
pub use self::pfm::{read_pfm, write_pfm};
pub use self::png::{
    read_png_text, tonemap_rgb8, write_png_tonemapped, write_png_tonemapped_with_metadata, write_rgb8_png,
    TONEMAP_DESCRIPTION,
};
pub use self::provenance::{engine, parse_range, Provenance, KEY_PREFIX};
pub use self::report::{write_json, write_text};
