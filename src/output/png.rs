//! Tone-mapped 8-bit PNG previews of linear HDR images.

use std::path::Path;

use super::{write_atomically, Image, OutputError};

/// The tone-mapping operator of [`write_png_tonemapped`], as printed by the CLI.
pub const TONEMAP_DESCRIPTION: &str =
    "exposure 2^e, ACES filmic (Narkowicz 2015 fit), sRGB OETF, 8-bit; NaN/Inf pixels magenta";

/// Colour of a pixel with any NaN or infinite channel, so it cannot go unnoticed.
pub const NON_FINITE_RGB8: [u8; 3] = [255, 0, 255];

/// Write `image` as an 8-bit sRGB PNG, atomically.
///
/// Per channel: `x = max(v, 0) * 2^exposure`, then the ACES filmic curve fit of
/// K. Narkowicz ("ACES Filmic Tone Mapping Curve", 2015)
/// `(x (2.51 x + 0.03)) / (x (2.43 x + 0.59) + 0.14)` clamped to [0, 1], then the sRGB
/// OETF (IEC 61966-2-1), rounded to 8 bits. Pixels with any non-finite channel are
/// written magenta (255, 0, 255). See [`TONEMAP_DESCRIPTION`].
pub fn write_png_tonemapped(path: &Path, image: &Image, exposure: f32) -> Result<(), OutputError> {
    write_png_tonemapped_with_metadata(path, image, exposure, &[])
}

/// [`write_png_tonemapped`] with text chunks (`metadata`: keyword, text; the render's
/// [`super::Provenance`] and the exposure), as `exiftool` or `identify -verbose` show them.
pub fn write_png_tonemapped_with_metadata(
    path: &Path,
    image: &Image,
    exposure: f32,
    metadata: &[(String, String)],
) -> Result<(), OutputError> {
    check_writable(path, image)?;
    let rgb8 = tonemap_rgb8(image, exposure);
    let mut text = metadata.to_vec();
    text.push(("scatterlab.exposure".into(), format!("{exposure}")));
    text.push(("scatterlab.tonemap".into(), TONEMAP_DESCRIPTION.into()));
    write_rgb8_with_text(path, image.width, image.height, &rgb8, &text)
}

/// `image` tone-mapped as [`write_png_tonemapped`] writes it: 8-bit sRGB RGB, rows top-down
/// (what `scatterlab view` shows).
pub fn tonemap_rgb8(image: &Image, exposure: f32) -> Vec<u8> {
    let scale = exposure.exp2();
    let mut rgb8 = Vec::with_capacity(3 * image.pixel_count());
    for p in image.pixels() {
        if p.iter().any(|v| !v.is_finite()) {
            rgb8.extend_from_slice(&NON_FINITE_RGB8);
        } else {
            rgb8.extend(p.iter().map(|&v| to_u8(srgb_oetf(aces_narkowicz(v.max(0.0) * scale)))));
        }
    }
    rgb8
}

/// 8-bit sRGB RGB pixels (`width` x `height`, rows top-down) as a PNG with text chunks, atomically
/// (a `scatterlab view` screenshot).
pub fn write_rgb8_png(
    path: &Path,
    width: u32,
    height: u32,
    rgb8: &[u8],
    text: &[(String, String)],
) -> Result<(), OutputError> {
    write_rgb8_with_text(path, width, height, rgb8, text)
}

/// 8-bit RGB as PNG with text chunks at `path`, atomically: tEXt where the text is Latin-1
/// (what most viewers show), iTXt (UTF-8) otherwise.
pub(super) fn write_rgb8_with_text(
    path: &Path,
    width: u32,
    height: u32,
    rgb8: &[u8],
    text: &[(String, String)],
) -> Result<(), OutputError> {
    let encoding = |source: ::png::EncodingError| OutputError::PngEncode { path: path.to_owned(), source };
    write_atomically(path, |tmp| {
        let file = std::fs::File::create(tmp).map_err(|source| OutputError::Io {
            path: path.to_owned(),
            action: "create",
            source,
        })?;
        let mut encoder = ::png::Encoder::new(std::io::BufWriter::new(file), width, height);
        encoder.set_color(::png::ColorType::Rgb);
        encoder.set_depth(::png::BitDepth::Eight);
        encoder.set_source_srgb(::png::SrgbRenderingIntent::Perceptual);
        for (key, value) in text {
            let latin1 = value.chars().all(|c| (c as u32) < 256 && c != '\0');
            if latin1 {
                encoder.add_text_chunk(key.clone(), value.clone()).map_err(encoding)?;
            } else {
                encoder.add_itxt_chunk(key.clone(), value.clone()).map_err(encoding)?;
            }
        }
        let mut writer = encoder.write_header().map_err(encoding)?;
        writer.write_image_data(rgb8).map_err(encoding)?;
        writer.finish().map_err(encoding)
    })
}

/// The text chunks (tEXt, zTXt and iTXt) of the PNG file at `path`, in file order.
pub fn read_png_text(path: &Path) -> Result<Vec<(String, String)>, OutputError> {
    let io = |source| OutputError::Io { path: path.to_owned(), action: "read", source };
    let file = std::fs::File::open(path).map_err(io)?;
    let decoder = ::png::Decoder::new(std::io::BufReader::new(file));
    let reader = decoder.read_info().map_err(|e| OutputError::PngDecode { path: path.to_owned(), source: e })?;
    let info = reader.info();
    let mut out: Vec<(String, String)> =
        info.uncompressed_latin1_text.iter().map(|t| (t.keyword.clone(), t.text.clone())).collect();
    for t in &info.utf8_text {
        if let Ok(text) = t.get_text() {
            out.push((t.keyword.clone(), text));
        }
    }
    Ok(out)
}

/// ACES filmic tone curve, Narkowicz's fit; maps [0, inf) to [0, 1).
pub fn aces_narkowicz(x: f32) -> f32 {
    let (a, b, c, d, e) = (2.51, 0.03, 2.43, 0.59, 0.14);
    ((x * (a * x + b)) / (x * (c * x + d) + e)).clamp(0.0, 1.0)
}

/// sRGB opto-electronic transfer function (linear [0, 1] to encoded [0, 1]).
pub fn srgb_oetf(linear: f32) -> f32 {
    let l = linear.clamp(0.0, 1.0);
    if l <= 0.003_130_8 {
        12.92 * l
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    }
}

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

pub(super) fn check_writable(path: &Path, image: &Image) -> Result<(), OutputError> {
    if !image.is_consistent() {
        return Err(OutputError::InvalidImage {
            path: path.to_owned(),
            reason: format!(
                "{} values for {}x{} pixels (need {})",
                image.data.len(),
                image.width,
                image.height,
                3 * image.pixel_count()
            ),
        });
    }
    if image.width == 0 || image.height == 0 {
        return Err(OutputError::InvalidImage {
            path: path.to_owned(),
            reason: "image has zero width or height".to_owned(),
        });
    }
    Ok(())
}

/// Encode 8-bit RGB as PNG at `path`, atomically.
pub(super) fn write_rgb8(path: &Path, width: u32, height: u32, rgb8: &[u8]) -> Result<(), OutputError> {
    write_atomically(path, |tmp| {
        ::image::save_buffer_with_format(
            tmp,
            rgb8,
            width,
            height,
            ::image::ExtendedColorType::Rgb8,
            ::image::ImageFormat::Png,
        )
        .map_err(|source| OutputError::Png { path: path.to_owned(), source })
    })
}
