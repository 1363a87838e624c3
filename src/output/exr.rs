//! OpenEXR files: linear f32 RGB, with optional extra layers in the same part.
//!
//! Layout: one scan-line part, ZIP-compressed (lossless, so a round trip is bit exact),
//! 32-bit float channels. The main layer is the plain channels `R`, `G`, `B`; an extra
//! layer `name` is stored as `name.R`, `name.G`, `name.B`, the naming convention that
//! OpenEXR viewers, Nuke and Blender show as layers.

use std::path::Path;

use ::exr::prelude::traits::{ReadChannels, ReadLayers, WritableImage};
use ::exr::prelude::{
    read, AnyChannel, AnyChannels, Encoding, FlatSamples, Image as ExrImage, Layer, LayerAttributes, SmallVec,
};

use super::{write_atomically, Image, OutputError};

/// Write `layers` to one EXR file at `path`, atomically.
///
/// Each entry is `(layer name, image)`; the name `""` is the main RGB layer (channels
/// `R`, `G`, `B`), any other name `n` becomes channels `n.R`, `n.G`, `n.B` (e.g. a
/// `"variance"` layer beside the radiance). All layers must have one size.
pub fn write_exr(path: &Path, layers: &[(&str, &Image)]) -> Result<(), OutputError> {
    let Some((_, first)) = layers.first() else {
        return Err(invalid(path, "no layers given"));
    };
    let (width, height) = (first.width, first.height);
    for (name, image) in layers {
        if !image.is_consistent() {
            return Err(invalid(
                path,
                &format!(
                    "layer '{name}' has {} values for {}x{} pixels (need {})",
                    image.data.len(),
                    image.width,
                    image.height,
                    3 * image.pixel_count()
                ),
            ));
        }
        if (image.width, image.height) != (width, height) {
            return Err(OutputError::SizeMismatch {
                what: format!("EXR '{}', layer '{name}'", path.display()),
                size: (image.width, image.height),
                reference_size: (width, height),
            });
        }
    }
    if width == 0 || height == 0 {
        return Err(invalid(path, "image has zero width or height"));
    }

    let mut channels: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    for (name, image) in layers {
        for (c, suffix) in ["R", "G", "B"].iter().enumerate() {
            let channel_name = if name.is_empty() { (*suffix).to_owned() } else { format!("{name}.{suffix}") };
            let samples: Vec<f32> = image.data.iter().skip(c).step_by(3).copied().collect();
            channels.push(AnyChannel::new(channel_name.as_str(), FlatSamples::F32(samples)));
        }
    }
    let layer = Layer::new(
        (width as usize, height as usize),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(channels),
    );
    let exr_image = ExrImage::from_layer(layer);

    write_atomically(path, |tmp| {
        exr_image.write().to_file(tmp).map_err(|source| OutputError::Exr {
            path: path.to_owned(),
            action: "write",
            source,
        })
    })
}

/// Read the main RGB layer (channels `R`, `G`, `B`) of the EXR file at `path`.
pub fn read_exr(path: &Path) -> Result<Image, OutputError> {
    read_exr_layer(path, "")
}

/// Read layer `name` (channels `name.R`, `name.G`, `name.B`; `""` = main `R`, `G`, `B`)
/// of the EXR file at `path`, from whichever part holds it. Half and u32 channels are
/// converted to f32.
pub fn read_exr_layer(path: &Path, name: &str) -> Result<Image, OutputError> {
    let exr_image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .map_err(|source| OutputError::Exr { path: path.to_owned(), action: "read", source })?;

    let wanted = |suffix: &str| -> String {
        if name.is_empty() {
            suffix.to_owned()
        } else {
            format!("{name}.{suffix}")
        }
    };
    let mut available = Vec::new();
    for layer in &exr_image.layer_data {
        // A named part prefixes its channels with the part name, as OpenEXR 2 does.
        let prefix = layer.attributes.layer_name.as_ref().map(|n| format!("{n}.")).unwrap_or_default();
        let full_name = |channel: &AnyChannel<FlatSamples>| format!("{prefix}{}", channel.name);
        let find = |suffix: &str| {
            let target = wanted(suffix);
            layer.channel_data.list.iter().find(|ch| full_name(ch) == target)
        };
        if let (Some(r), Some(g), Some(b)) = (find("R"), find("G"), find("B")) {
            let (w, h) = (layer.size.width(), layer.size.height());
            let mut data = Vec::with_capacity(3 * w * h);
            let (r, g, b) = (&r.sample_data, &g.sample_data, &b.sample_data);
            for i in 0..w * h {
                data.push(r.value_by_flat_index(i).to_f32());
                data.push(g.value_by_flat_index(i).to_f32());
                data.push(b.value_by_flat_index(i).to_f32());
            }
            return Ok(Image { width: w as u32, height: h as u32, data });
        }
        available.extend(layer.channel_data.list.iter().map(full_name));
    }
    Err(OutputError::MissingLayer { path: path.to_owned(), layer: name.to_owned(), available: available.join(", ") })
}

fn invalid(path: &Path, reason: &str) -> OutputError {
    OutputError::InvalidImage { path: path.to_owned(), reason: reason.to_owned() }
}
