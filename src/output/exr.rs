//! OpenEXR files: linear f32 RGB, with optional extra layers in the same part.
//!
//! Layout: one scan-line part, ZIP-compressed (lossless, so a round trip is bit exact),
//! 32-bit float channels. The main layer is the plain channels `R`, `G`, `B`; an extra
//! layer `name` is stored as `name.R`, `name.G`, `name.B`, the naming convention that
//! OpenEXR viewers, Nuke and Blender show as layers.

use std::path::Path;

use ::exr::prelude::traits::{ReadChannels, ReadLayers, WritableImage};
use ::exr::prelude::{
    read, AnyChannel, AnyChannels, AttributeValue, Encoding, FlatSamples, Image as ExrImage, Layer, LayerAttributes,
    SmallVec, Text,
};

use super::{write_atomically, Image, OutputError};

/// Write `layers` to one EXR file at `path`, atomically.
///
/// Each entry is `(layer name, image)`; the name `""` is the main RGB layer (channels
/// `R`, `G`, `B`), any other name `n` becomes channels `n.R`, `n.G`, `n.B` (e.g. a
/// `"variance"` layer beside the radiance). All layers must have one size.
pub fn write_exr(path: &Path, layers: &[(&str, &Image)]) -> Result<(), OutputError> {
    write_exr_with_metadata(path, layers, &[])
}

/// [`write_exr`] with text attributes in the header (`metadata`: name, value; the render's
/// [`super::Provenance`]), readable with [`read_exr_metadata`] or any OpenEXR tool
/// (`exrheader`). A value outside the attribute's byte-string range is written escaped.
pub fn write_exr_with_metadata(
    path: &Path,
    layers: &[(&str, &Image)],
    metadata: &[(String, String)],
) -> Result<(), OutputError> {
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
    let mut attributes = LayerAttributes::default();
    for (name, value) in metadata {
        let text = Text::new_or_none(value).or_else(|| Text::new_or_none(value.escape_default().to_string()));
        if let (Some(key), Some(text)) = (Text::new_or_none(name), text) {
            attributes.other.insert(key, AttributeValue::Text(text));
        }
    }
    let layer = Layer::new(
        (width as usize, height as usize),
        attributes,
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

/// The text attributes of an EXR file's header (every part's, in file order): what
/// [`write_exr_with_metadata`] wrote, sorted by name within a part.
pub fn read_exr_metadata(path: &Path) -> Result<Vec<(String, String)>, OutputError> {
    let meta = ::exr::meta::MetaData::read_from_file(path, false).map_err(|source| OutputError::Exr {
        path: path.to_owned(),
        action: "read",
        source,
    })?;
    let mut out = Vec::new();
    for header in &meta.headers {
        let mut part: Vec<(String, String)> = header
            .own_attributes
            .other
            .iter()
            .filter_map(|(k, v)| match v {
                AttributeValue::Text(t) => Some((k.to_string(), t.to_string())),
                _ => None,
            })
            .collect();
        part.sort();
        out.extend(part);
    }
    Ok(out)
}

/// Read the main RGB layer (channels `R`, `G`, `B`) of the EXR file at `path`.
pub fn read_exr(path: &Path) -> Result<Image, OutputError> {
    read_exr_layer(path, "")
}

/// Read layer `name` (channels `name.R`, `name.G`, `name.B`; `""` = main `R`, `G`, `B`)
/// of the EXR file at `path`, from whichever part holds it. Half and u32 channels are
/// converted to f32.
pub fn read_exr_layer(path: &Path, name: &str) -> Result<Image, OutputError> {
    let mut layers = read_exr_layers(path, &[name])?;
    Ok(layers.remove(0))
}

/// Read the layers `names` (as [`read_exr_layer`]) from one read of the file.
pub fn read_exr_layers(path: &Path, names: &[&str]) -> Result<Vec<Image>, OutputError> {
    let exr_image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .map_err(|source| OutputError::Exr { path: path.to_owned(), action: "read", source })?;

    names.iter().map(|name| find_layer(&exr_image, path, name)).collect()
}

type AnyExr = ::exr::image::Image<::exr::image::Layers<::exr::image::AnyChannels<FlatSamples>>>;

/// Layer `name` of a read file (any part), or the error listing the channels there are.
fn find_layer(exr_image: &AnyExr, path: &Path, name: &str) -> Result<Image, OutputError> {
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
