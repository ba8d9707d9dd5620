//! The EXR files of renders (the layout is in [`super`]'s documentation): written with the
//! render's key in the header, read back whole or not at all.

use std::fs;
use std::io::Cursor;
use std::path::Path;

use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image as ExrImage, Layer, LayerAttributes,
    ReadChannels, ReadLayers, SmallVec, WritableImage,
};

use super::{write_atomically, Aovs, Image, ImageError, KEY_ATTRIBUTE};

/// Names of the `f32` AOV channels, in the order of [`Aovs`] fields (depth, normal, albedo).
const AOV_FLOAT_CHANNELS: [&str; 7] = [
    "depth.Z", "normal.X", "normal.Y", "normal.Z", "albedo.R", "albedo.G", "albedo.B",
];
/// Name of the `u32` splat id channel.
const AOV_SPLAT_CHANNEL: &str = "splat.id";

/// Writes `img` as an OpenEXR file (see the module documentation for the layout).
pub fn write_exr(path: &Path, img: &Image) -> Result<(), ImageError> {
    write_exr_keyed(path, img, None)
}

/// The key a render wrote into the EXR at `path` ([`KEY_ATTRIBUTE`]), when the file reads as a
/// whole; `None` when it is missing, damaged or has no key.
pub fn exr_key(path: &Path) -> Option<pc_artifact::Key> {
    let meta = exr::meta::MetaData::read_from_file(path, false).ok()?;
    let header = meta.headers.first()?;
    let value = header
        .own_attributes
        .other
        .get(&exr::meta::attribute::Text::new_or_panic(KEY_ATTRIBUTE))?;
    let exr::meta::attribute::AttributeValue::Text(text) = value else {
        return None;
    };
    let key = pc_artifact::Key::from_hex(&text.to_string())?;
    read_exr(path).ok()?;
    Some(key)
}

/// [`write_exr`], with the render's key in the header ([`KEY_ATTRIBUTE`]) when given.
pub fn write_exr_keyed(
    path: &Path,
    img: &Image,
    key: Option<&pc_artifact::Key>,
) -> Result<(), ImageError> {
    img.check_sizes()
        .map_err(|m| ImageError::format(path, m.0))?;
    if img.width == 0 || img.height == 0 {
        return Err(ImageError::format(
            path,
            format!("cannot write an empty {}x{} image", img.width, img.height),
        ));
    }

    let channel = |name: &str, samples: FlatSamples| AnyChannel::new(name, samples);
    let component = |v: &[[f32; 3]], c: usize| FlatSamples::F32(v.iter().map(|p| p[c]).collect());

    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    for (c, name) in ["R", "G", "B"].into_iter().enumerate() {
        list.push(channel(name, component(&img.rgb, c)));
    }
    if let Some(aovs) = &img.aovs {
        list.push(channel(
            AOV_FLOAT_CHANNELS[0],
            FlatSamples::F32(aovs.depth.clone()),
        ));
        for c in 0..3 {
            list.push(channel(
                AOV_FLOAT_CHANNELS[1 + c],
                component(&aovs.normal, c),
            ));
            list.push(channel(
                AOV_FLOAT_CHANNELS[4 + c],
                component(&aovs.albedo, c),
            ));
        }
        list.push(channel(
            AOV_SPLAT_CHANNEL,
            FlatSamples::U32(aovs.splat.clone()),
        ));
    }

    let size = (img.width as usize, img.height as usize);
    // ZIP16 compression, scan lines, increasing line order (y down), a single resolution level.
    let mut attributes = LayerAttributes::default();
    if let Some(key) = key {
        attributes.other.insert(
            exr::meta::attribute::Text::new_or_panic(KEY_ATTRIBUTE),
            exr::meta::attribute::AttributeValue::Text(exr::meta::attribute::Text::new_or_panic(
                key.to_string(),
            )),
        );
    }
    let layer = Layer::new(
        size,
        attributes,
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list),
    );
    let mut bytes = Vec::new();
    ExrImage::from_layer(layer)
        .write()
        .to_buffered(Cursor::new(&mut bytes))
        .map_err(|e| ImageError::exr(path, e))?;
    write_atomically(path, &bytes)
}

/// Reads the first layer of an OpenEXR file: `R`, `G`, `B` (`f16` or `f32`, any channel order)
/// and, when present, all AOV channels written by [`write_exr`].
///
/// Fails with [`ImageError::Format`] if `R`, `G` or `B` is missing or only some AOV channels are
/// present, with [`ImageError::Io`] if it cannot be opened, and with [`ImageError::Exr`] if it is
/// damaged or truncated. Files are read pedantically (like the reference C++ library would), so
/// that inconsistent data is an error rather than silently tolerated.
pub fn read_exr(path: &Path) -> Result<Image, ImageError> {
    if let Err(source) = fs::metadata(path) {
        return Err(ImageError::Io {
            path: path.to_path_buf(),
            source,
        });
    }
    let exr = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .pedantic()
        .from_file(path)
        .map_err(|e| ImageError::exr(path, e))?;
    let layer = exr.layer_data;
    let (w, h) = (layer.size.0, layer.size.1);
    let (width, height) = match (u32::try_from(w), u32::try_from(h)) {
        (Ok(width), Ok(height)) => (width, height),
        _ => {
            return Err(ImageError::format(
                path,
                format!("{w}x{h} image is too large"),
            ))
        }
    };
    let n = w * h;
    let channels = Channels {
        path,
        list: &layer.channel_data.list,
        n,
    };
    let (r, g, b) = (
        channels.required("R")?,
        channels.required("G")?,
        channels.required("B")?,
    );
    let rgb = (0..n).map(|i| [r[i], g[i], b[i]]).collect();
    Ok(Image {
        width,
        height,
        rgb,
        aovs: channels.aovs()?,
    })
}

/// The channels of an EXR file's first layer, `n` samples each, as [`read_exr`] reads them.
struct Channels<'a> {
    path: &'a Path,
    list: &'a [AnyChannel<FlatSamples>],
    n: usize,
}

impl Channels<'_> {
    fn find(&self, name: &str) -> Option<&AnyChannel<FlatSamples>> {
        self.list.iter().find(|c| c.name.eq(name))
    }

    /// The channels' names, for messages.
    fn names(&self) -> String {
        let names: Vec<String> = self.list.iter().map(|c| c.name.to_string()).collect();
        names.join(", ")
    }

    /// The f16 or f32 samples of channel `name`, if it is there.
    fn floats(&self, name: &str) -> Result<Option<Vec<f32>>, ImageError> {
        let Some(channel) = self.find(name) else {
            return Ok(None);
        };
        let values: Vec<f32> = match &channel.sample_data {
            FlatSamples::F32(v) => v.clone(),
            FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
            FlatSamples::U32(_) => {
                return Err(ImageError::format(
                    self.path,
                    format!("channel {name} holds u32 samples, expected f16 or f32"),
                ))
            }
        };
        if values.len() != self.n {
            return Err(ImageError::format(
                self.path,
                format!(
                    "channel {name} has {} samples, expected {}",
                    values.len(),
                    self.n
                ),
            ));
        }
        Ok(Some(values))
    }

    /// [`Self::floats`] of a channel that must be there.
    fn required(&self, name: &str) -> Result<Vec<f32>, ImageError> {
        self.floats(name)?.ok_or_else(|| {
            ImageError::format(
                self.path,
                format!(
                    "no {name} channel in the first layer (channels: {})",
                    self.names()
                ),
            )
        })
    }

    /// The AOVs: none where no AOV channel is there, all of them, or an error naming the ones
    /// there where only some are.
    fn aovs(&self) -> Result<Option<Aovs>, ImageError> {
        let present: Vec<&str> = AOV_FLOAT_CHANNELS
            .iter()
            .chain(std::iter::once(&AOV_SPLAT_CHANNEL))
            .copied()
            .filter(|name| self.find(name).is_some())
            .collect();
        if present.is_empty() {
            return Ok(None);
        }
        if present.len() < AOV_FLOAT_CHANNELS.len() + 1 {
            return Err(ImageError::format(
                self.path,
                format!(
                    "incomplete AOV channels: has {}, expected all of {}, {AOV_SPLAT_CHANNEL}",
                    present.join(", "),
                    AOV_FLOAT_CHANNELS.join(", ")
                ),
            ));
        }
        let f: Vec<Vec<f32>> = AOV_FLOAT_CHANNELS
            .iter()
            .map(|name| self.required(name))
            .collect::<Result<_, _>>()?;
        let n = self.n;
        let splat = match &self
            .find(AOV_SPLAT_CHANNEL)
            .expect("checked above")
            .sample_data
        {
            FlatSamples::U32(v) if v.len() == n => v.clone(),
            FlatSamples::U32(v) => {
                return Err(ImageError::format(
                    self.path,
                    format!(
                        "channel {AOV_SPLAT_CHANNEL} has {} samples, expected {n}",
                        v.len()
                    ),
                ))
            }
            _ => {
                return Err(ImageError::format(
                    self.path,
                    format!("channel {AOV_SPLAT_CHANNEL} must hold u32 samples"),
                ))
            }
        };
        Ok(Some(Aovs {
            depth: f[0].clone(),
            normal: (0..n).map(|i| [f[1][i], f[2][i], f[3][i]]).collect(),
            albedo: (0..n).map(|i| [f[4][i], f[5][i], f[6][i]]).collect(),
            splat,
        }))
    }
}
