//! The PNG previews of renders: 8-bit sRGB, the render's key in a text chunk.

use std::fs;
use std::path::Path;

use super::{write_atomically, Image, ImageError, KEY_ATTRIBUTE};
use crate::srgb::to_srgb8;

/// Encodes 8-bit RGB pixels (row-major, top row first) as PNG, with the render's key in a
/// `tEXt` chunk ([`KEY_ATTRIBUTE`]) when given, and writes it atomically.
pub(super) fn write_png_bytes(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[u8],
    key: Option<&pc_artifact::Key>,
) -> Result<(), ImageError> {
    let err = |e: png::EncodingError| ImageError::png(path, e);
    let mut bytes = Vec::new();
    let mut enc = png::Encoder::new(&mut bytes, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    // fdeflate: a 1024×1024 frame in 9 ms instead of 214 (`Balanced`), 19 % larger. The PNG is
    // the preview; the EXR holds the render.
    enc.set_compression(png::Compression::Fast);
    if let Some(key) = key {
        enc.add_text_chunk(KEY_ATTRIBUTE.to_string(), key.to_string())
            .map_err(err)?;
    }
    let mut w = enc.write_header().map_err(err)?;
    w.write_image_data(pixels).map_err(err)?;
    w.finish().map_err(err)?;
    write_atomically(path, &bytes)
}

/// Writes `img` as an 8-bit sRGB PNG:
/// each channel is `round(255 * srgb_encode(linear * exposure))` ([`crate::srgb::to_srgb8`]).
pub fn write_png(path: &Path, img: &Image, exposure: f32) -> Result<(), ImageError> {
    write_png_keyed(path, img, exposure, None)
}

/// [`write_png`], with the render's key in a `tEXt` chunk ([`KEY_ATTRIBUTE`]) when given.
pub fn write_png_keyed(
    path: &Path,
    img: &Image,
    exposure: f32,
    key: Option<&pc_artifact::Key>,
) -> Result<(), ImageError> {
    img.check_sizes()
        .map_err(|m| ImageError::format(path, m.0))?;
    let pixels: Vec<u8> = img
        .rgb
        .iter()
        .flat_map(|p| p.map(|v| to_srgb8(v * exposure)))
        .collect();
    write_png_bytes(path, img.width, img.height, &pixels, key)
}

/// The key a render wrote into the PNG at `path` ([`KEY_ATTRIBUTE`] text chunk), when the file
/// decodes as a whole; `None` when it is missing, damaged or has no key.
pub fn png_key(path: &Path) -> Option<pc_artifact::Key> {
    let file = std::io::BufReader::new(fs::File::open(path).ok()?);
    let mut reader = png::Decoder::new(file).read_info().ok()?;
    let text = reader
        .info()
        .uncompressed_latin1_text
        .iter()
        .find(|t| t.keyword == KEY_ATTRIBUTE)?
        .text
        .clone();
    let mut buf = vec![0; reader.output_buffer_size()?];
    reader.next_frame(&mut buf).ok()?;
    pc_artifact::Key::from_hex(&text)
}
