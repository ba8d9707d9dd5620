//! Rendered images: linear RGB with optional AOVs, EXR and PNG output, EXR input, comparison.
//!
//! Pixels are stored row-major with pixel (0, 0) at the top left (y grows downwards), which is
//! also the line order of the EXR and PNG files written here.
//!
//! EXR files hold the standard unnamed layer with linear `f32` channels `R`, `G`, `B` (scan lines,
//! ZIP compression, one resolution level). When [`Image::aovs`] is set, the same layer also holds
//! `depth.Z`, `normal.X`, `normal.Y`, `normal.Z`, `albedo.R`, `albedo.G`, `albedo.B` (`f32`) and
//! `splat.id` (`u32`). All files are written atomically ([`pc_artifact::atomic`]): the data goes
//! to a temporary file in the same folder, which is then renamed onto `<path>` (and removed if
//! anything fails).
//!
//! Here the image, its errors and the EXR-PNG pair's key; `image/exr_io.rs` the EXR files,
//! `image/png_io.rs` the PNG previews, `image/compare.rs` the comparison against a reference.

use std::path::{Path, PathBuf};

mod compare;
mod exr_io;
mod png_io;

pub use compare::{compare, write_diff_png, Comparison, SizeMismatch, RELATIVE_FLOOR};
pub use exr_io::{exr_key, read_exr, write_exr, write_exr_keyed};
pub use png_io::{png_key, write_png, write_png_keyed};

/// Arbitrary output variables: one entry per pixel each, row-major like [`Image::rgb`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Aovs {
    /// Distance along the primary ray (or whatever depth the renderer defines); `inf` for misses.
    pub depth: Vec<f32>,
    /// Shading normal of the first hit.
    pub normal: Vec<[f32; 3]>,
    /// Albedo of the first hit.
    pub albedo: Vec<[f32; 3]>,
    /// Id of the splat hit first (renderer-defined sentinel for misses).
    pub splat: Vec<u32>,
}

impl Aovs {
    /// Zero-filled AOVs for a `width` x `height` image.
    pub fn zeros(width: u32, height: u32) -> Aovs {
        let n = width as usize * height as usize;
        Aovs {
            depth: vec![0.0; n],
            normal: vec![[0.0; 3]; n],
            albedo: vec![[0.0; 3]; n],
            splat: vec![0; n],
        }
    }
}

/// A linear RGB image, row-major, pixel (0, 0) at the top left.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    /// `width * height` linear RGB pixels, row after row from the top.
    pub rgb: Vec<[f32; 3]>,
    pub aovs: Option<Aovs>,
}

impl Image {
    /// A black image without AOVs.
    pub fn new(width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            rgb: vec![[0.0; 3]; width as usize * height as usize],
            aovs: None,
        }
    }

    /// Mean of each channel over all pixels (zero for an empty image).
    pub fn mean(&self) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        for p in &self.rgb {
            for c in 0..3 {
                sum[c] += f64::from(p[c]);
            }
        }
        let n = self.rgb.len().max(1) as f64;
        sum.map(|s| s / n)
    }

    /// Index of pixel (x, y) in [`Image::rgb`] and the AOV vectors.
    ///
    /// # Panics
    /// If (x, y) lies outside the image.
    pub fn index(&self, x: u32, y: u32) -> usize {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside {}x{} image",
            self.width,
            self.height
        );
        y as usize * self.width as usize + x as usize
    }

    /// The pixel at (x, y).
    ///
    /// # Panics
    /// If (x, y) lies outside the image.
    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        self.rgb[self.index(x, y)]
    }

    /// Sets the pixel at (x, y).
    ///
    /// # Panics
    /// If (x, y) lies outside the image.
    pub fn set(&mut self, x: u32, y: u32, rgb: [f32; 3]) {
        let i = self.index(x, y);
        self.rgb[i] = rgb;
    }

    fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Checks that all buffers have `width * height` entries.
    fn check_sizes(&self) -> Result<(), SizeMismatch> {
        let n = self.pixel_count();
        let mut lens = vec![("rgb", self.rgb.len())];
        if let Some(a) = &self.aovs {
            lens.extend([
                ("depth", a.depth.len()),
                ("normal", a.normal.len()),
                ("albedo", a.albedo.len()),
                ("splat", a.splat.len()),
            ]);
        }
        for (name, len) in lens {
            if len != n {
                return Err(SizeMismatch(format!(
                    "{name} buffer has {len} pixels, but the image is {}x{} = {n}",
                    self.width, self.height
                )));
            }
        }
        Ok(())
    }
}

/// Errors of image input and output. The message starts with the path of the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{}: I/O error", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: OpenEXR error: {msg}", path.display())]
    Exr { path: PathBuf, msg: String },
    #[error("{}: PNG error: {msg}", path.display())]
    Png { path: PathBuf, msg: String },
    #[error("{}: {msg}", path.display())]
    Format { path: PathBuf, msg: String },
}

impl ImageError {
    fn format(path: &Path, msg: impl Into<String>) -> ImageError {
        ImageError::Format {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    fn exr(path: &Path, err: impl std::fmt::Display) -> ImageError {
        ImageError::Exr {
            path: path.to_path_buf(),
            msg: err.to_string(),
        }
    }

    fn png(path: &Path, err: impl std::fmt::Display) -> ImageError {
        ImageError::Png {
            path: path.to_path_buf(),
            msg: err.to_string(),
        }
    }

    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            ImageError::Io { path, .. }
            | ImageError::Exr { path, .. }
            | ImageError::Png { path, .. }
            | ImageError::Format { path, .. } => path,
        }
    }
}

/// Writes `bytes` to `path` atomically ([`pc_artifact::write_file_atomically`]), creating the
/// parent folder.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), ImageError> {
    pc_artifact::write_file_atomically(path, bytes).map_err(|source| ImageError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The name of the EXR header attribute (text), and of the PNG's `tEXt` chunk, that holds the
/// key of the render: the stage's version, its parameters, the camera, and the keys of the
/// artifacts it read.
pub const KEY_ATTRIBUTE: &str = "pcgiKey";

/// The key of the image pair at `exr` (the EXR and the PNG beside it, [`png_path`]) when both
/// read whole and carry the same key; `None` otherwise, so a pair left mismatched by a run
/// killed between its two writes is redone.
pub fn rendered_key(exr: &Path) -> Option<pc_artifact::Key> {
    let key = exr_key(exr)?;
    (png_key(&png_path(exr)) == Some(key)).then_some(key)
}

/// The PNG preview written beside the EXR `exr`.
pub fn png_path(exr: &Path) -> PathBuf {
    exr.with_extension("png")
}

#[cfg(test)]
mod tests {
    use std::fs;

    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Image as ExrImage, Layer, LayerAttributes,
        SmallVec, WritableImage,
    };

    use super::*;

    const REFERENCE: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/reference/cornell/cornell.exr"
    );

    /// A 5x3 image with distinct, awkward values (negative, tiny, huge, inf, NaN payloads aside).
    fn test_image(aovs: bool) -> Image {
        let (w, h) = (5u32, 3u32);
        let mut img = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as f32;
                img.set(x, y, [i * 0.1 + 1e-7, -i / 3.0, 1.0e30 / (i + 1.0)]);
            }
        }
        img.rgb[7] = [f32::INFINITY, f32::MIN_POSITIVE / 4.0, 0.0];
        if aovs {
            let n = (w * h) as usize;
            img.aovs = Some(Aovs {
                depth: (0..n)
                    .map(|i| {
                        if i == 4 {
                            f32::INFINITY
                        } else {
                            i as f32 * 1.5
                        }
                    })
                    .collect(),
                normal: (0..n).map(|i| [i as f32, -(i as f32), 0.25]).collect(),
                albedo: (0..n).map(|i| [0.1, 0.2 * i as f32, 1.0 / 3.0]).collect(),
                splat: (0..n as u32)
                    .map(|i| if i == 2 { u32::MAX } else { i * 1_000_003 })
                    .collect(),
            });
        }
        img
    }

    fn bits(v: &[[f32; 3]]) -> Vec<[u32; 3]> {
        v.iter().map(|p| p.map(f32::to_bits)).collect()
    }

    fn file_names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn new_get_mean() {
        let mut img = Image::new(4, 2);
        assert_eq!(img.rgb.len(), 8);
        assert!(img.aovs.is_none());
        assert_eq!(img.mean(), [0.0; 3]);
        img.set(3, 1, [8.0, 4.0, -8.0]);
        assert_eq!(img.get(3, 1), [8.0, 4.0, -8.0]);
        assert_eq!(img.rgb[7], [8.0, 4.0, -8.0]);
        assert_eq!(img.get(0, 1), [0.0; 3]);
        assert_eq!(img.mean(), [1.0, 0.5, -1.0]);
        assert_eq!(Image::new(0, 0).mean(), [0.0; 3]);
    }

    #[test]
    #[should_panic(expected = "outside")]
    fn get_out_of_bounds_panics() {
        Image::new(4, 2).get(4, 0);
    }

    #[test]
    fn exr_round_trip_without_aovs() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("nested/folder/a.exr");
        let img = test_image(false);
        write_exr(&path, &img).unwrap();
        let back = read_exr(&path).unwrap();
        assert_eq!((back.width, back.height), (5, 3));
        assert_eq!(bits(&back.rgb), bits(&img.rgb));
        assert!(back.aovs.is_none());
        assert_eq!(file_names(&dir.path().join("nested/folder")), ["a.exr"]);
    }

    #[test]
    fn exr_round_trip_with_aovs() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.exr");
        let img = test_image(true);
        write_exr(&path, &img).unwrap();
        // Overwriting an existing file works too.
        write_exr(&path, &img).unwrap();
        let back = read_exr(&path).unwrap();
        assert_eq!((back.width, back.height), (5, 3));
        assert_eq!(bits(&back.rgb), bits(&img.rgb));
        let (a, b) = (img.aovs.as_ref().unwrap(), back.aovs.as_ref().unwrap());
        let depth_bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(depth_bits(&b.depth), depth_bits(&a.depth));
        assert_eq!(bits(&b.normal), bits(&a.normal));
        assert_eq!(bits(&b.albedo), bits(&a.albedo));
        assert_eq!(b.splat, a.splat);
        assert_eq!(b.splat[2], u32::MAX);
        assert_eq!(file_names(dir.path()), ["b.exr"]);

        // The file has the documented channels and types, in a single scan-line level.
        let raw = exr::prelude::read_first_flat_layer_from_file(&path).unwrap();
        let layer = &raw.layer_data;
        let mut names: Vec<String> = layer
            .channel_data
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        names.sort();
        assert_eq!(
            names,
            [
                "B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "depth.Z", "normal.X",
                "normal.Y", "normal.Z", "splat.id"
            ]
        );
        for c in &layer.channel_data.list {
            let is_u32 = matches!(c.sample_data, FlatSamples::U32(_));
            assert_eq!(is_u32, c.name.eq("splat.id"), "{}", c.name);
            if !is_u32 {
                assert!(matches!(c.sample_data, FlatSamples::F32(_)), "{}", c.name);
            }
        }
        assert_eq!(layer.encoding.compression, exr::prelude::Compression::ZIP16);
        assert_eq!(layer.encoding.blocks, exr::prelude::Blocks::ScanLines);
        // Pixel (x, y) = (1, 2) is sample 2 * 5 + 1 of the R channel: top-left origin, y down.
        let r = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.eq("R"))
            .unwrap();
        let FlatSamples::F32(r) = &r.sample_data else {
            panic!("R is not f32")
        };
        assert_eq!(r[11].to_bits(), img.get(1, 2)[0].to_bits());
    }

    #[test]
    fn reads_f16_channels_in_any_order_and_rejects_missing_rgb() {
        use exr::prelude::f16;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("half.exr");
        let size = (2usize, 2usize);
        let half = |v: [f32; 4]| FlatSamples::F16(v.map(f16::from_f32).to_vec());
        // Unsorted on purpose; `AnyChannels::sort` orders them as the format requires.
        let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::from_vec(vec![
            AnyChannel::new("G", half([0.5, 1.0, 1.5, 2.0])),
            AnyChannel::new("R", half([0.25, 0.0, 4.0, 8.0])),
            AnyChannel::new("A", half([1.0; 4])),
            AnyChannel::new("B", FlatSamples::F32(vec![0.1, 0.2, 0.3, 0.4])),
        ]);
        let layer = Layer::new(
            size,
            LayerAttributes::default(),
            Encoding::UNCOMPRESSED,
            AnyChannels::sort(list),
        );
        ExrImage::from_layer(layer).write().to_file(&path).unwrap();
        let img = read_exr(&path).unwrap();
        assert_eq!((img.width, img.height), (2, 2));
        assert_eq!(img.get(0, 0), [0.25, 0.5, 0.1]);
        assert_eq!(img.get(1, 1), [8.0, 2.0, 0.4]);
        assert!(img.aovs.is_none());

        let path = dir.path().join("luma.exr");
        let list: SmallVec<[AnyChannel<FlatSamples>; 4]> =
            SmallVec::from_vec(vec![AnyChannel::new("Y", FlatSamples::F32(vec![1.0; 4]))]);
        let layer = Layer::new(
            size,
            LayerAttributes::default(),
            Encoding::UNCOMPRESSED,
            AnyChannels::sort(list),
        );
        ExrImage::from_layer(layer).write().to_file(&path).unwrap();
        let err = read_exr(&path).unwrap_err();
        assert!(matches!(err, ImageError::Format { .. }), "{err:?}");
        let msg = err.to_string();
        assert!(msg.starts_with(&format!("{}: ", path.display())), "{msg}");
        assert!(msg.contains("no R channel"), "{msg}");
    }

    #[test]
    fn incomplete_aovs_are_a_format_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("partial.exr");
        let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::from_vec(vec![
            AnyChannel::new("R", FlatSamples::F32(vec![1.0])),
            AnyChannel::new("G", FlatSamples::F32(vec![1.0])),
            AnyChannel::new("B", FlatSamples::F32(vec![1.0])),
            AnyChannel::new("depth.Z", FlatSamples::F32(vec![1.0])),
        ]);
        let layer = Layer::new(
            (1, 1),
            LayerAttributes::default(),
            Encoding::UNCOMPRESSED,
            AnyChannels::sort(list),
        );
        ExrImage::from_layer(layer).write().to_file(&path).unwrap();
        let err = read_exr(&path).unwrap_err();
        assert!(matches!(err, ImageError::Format { .. }), "{err:?}");
        assert!(err.to_string().contains("incomplete AOV"), "{err}");
    }

    #[test]
    fn reads_reference_render() {
        let path = Path::new(REFERENCE);
        let img = read_exr(path).unwrap();
        assert_eq!((img.width, img.height), (256, 256));
        assert_eq!(img.rgb.len(), 256 * 256);
        assert!(img.rgb.iter().flatten().all(|v| v.is_finite()));
        let mean = img.mean();
        assert!(mean.iter().all(|&m| m > 0.0), "{mean:?}");
        assert!(img.aovs.is_none());
        // Identical images compare as equal.
        let c = compare(&img, &img).unwrap();
        assert_eq!(
            (c.mean_relative, c.max_abs, c.rmse_relative),
            (0.0, 0.0, 0.0)
        );
    }

    #[test]
    fn truncated_exr_is_an_error_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("full.exr");
        // Large enough for several compressed blocks.
        let img = Image {
            width: 64,
            height: 64,
            rgb: (0..64 * 64)
                .map(|i| [i as f32, (i * 7 % 13) as f32, 0.5])
                .collect(),
            aovs: None,
        };
        write_exr(&path, &img).unwrap();
        let bytes = fs::read(&path).unwrap();
        for keep in [0, 3, 40, bytes.len() / 2, bytes.len() - 1] {
            let cut = dir.path().join(format!("cut{keep}.exr"));
            fs::write(&cut, &bytes[..keep]).unwrap();
            let err = read_exr(&cut).expect_err("truncated file must not read");
            let msg = err.to_string();
            assert_eq!(err.path(), cut.as_path());
            assert!(msg.starts_with(&format!("{}: ", cut.display())), "{msg}");
        }
        let missing = dir.path().join("missing.exr");
        let err = read_exr(&missing).unwrap_err();
        assert!(matches!(err, ImageError::Io { .. }), "{err:?}");
        assert!(err
            .to_string()
            .starts_with(&format!("{}: ", missing.display())));
    }

    #[test]
    fn write_errors_leave_no_tmp() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = test_image(true);
        img.aovs.as_mut().unwrap().splat.pop();
        let err = write_exr(&dir.path().join("bad.exr"), &img).unwrap_err();
        assert!(matches!(err, ImageError::Format { .. }), "{err:?}");
        assert!(err.to_string().contains("splat buffer"), "{err}");
        let err = write_exr(&dir.path().join("empty.exr"), &Image::new(0, 4)).unwrap_err();
        assert!(matches!(err, ImageError::Format { .. }), "{err:?}");
        // The target is a folder: the rename fails and the tmp file is removed.
        let target = dir.path().join("folder.png");
        fs::create_dir(&target).unwrap();
        fs::write(target.join("x"), b"x").unwrap();
        let err = write_png(&target, &Image::new(2, 2), 1.0).unwrap_err();
        assert!(matches!(err, ImageError::Io { .. }), "{err:?}");
        assert!(err
            .to_string()
            .starts_with(&format!("{}: ", target.display())));
        assert_eq!(file_names(dir.path()), ["folder.png"]);
    }

    #[test]
    fn png_size_and_values() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out/a.png");
        let mut img = Image::new(3, 2);
        img.set(2, 1, [0.25, 0.0031308 / 2.0, 4.0]);
        img.set(0, 0, [0.0, 0.5, 1.0]);
        write_png(&path, &img, 2.0).unwrap();
        assert_eq!(file_names(&dir.path().join("out")), ["a.png"]);
        let png = ::image::open(&path).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (3, 2));
        // 0.25 * 2 = 0.5 -> 0.735357 * 255 = 187.52 -> 188;
        // 0.0031308 -> 0.040450 * 255 = 10.31 -> 10.
        assert_eq!(png.get_pixel(2, 1).0, [188, 10, 255]);
        assert_eq!(png.get_pixel(0, 0).0, [0, 255, 255]);
        assert_eq!(png.get_pixel(1, 0).0, [0, 0, 0]);
    }

    fn constant(w: u32, h: u32, v: f32) -> Image {
        Image {
            rgb: vec![[v; 3]; (w * h) as usize],
            ..Image::new(w, h)
        }
    }

    #[test]
    fn compare_statistics() {
        let b = constant(2, 2, 1.0);
        let c = compare(&b, &b).unwrap();
        assert_eq!(
            c,
            Comparison {
                mean_relative: 0.0,
                max_abs: 0.0,
                rmse_relative: 0.0
            }
        );

        // One of 12 values off by 0.5: relative 0.5 / 12, rmse sqrt(0.25 / 12) / 1.
        let mut a = b.clone();
        a.rgb[3][1] = 1.5;
        let c = compare(&a, &b).unwrap();
        assert!((c.mean_relative - 0.5 / 12.0).abs() < 1e-12, "{c}");
        assert_eq!(c.max_abs, 0.5);
        assert!(
            (c.rmse_relative - (0.25f64 / 12.0).sqrt()).abs() < 1e-12,
            "{c}"
        );

        // A black reference pixel: its difference is relative to the floor, 1 % of mean |b|.
        let mut b2 = constant(2, 2, 2.0);
        b2.rgb[0] = [0.0; 3];
        let mut a2 = b2.clone();
        a2.rgb[0][0] = 0.015; // mean |b| = 1.5, floor = 0.015 + 1e-6
        let c = compare(&a2, &b2).unwrap();
        let d = f64::from(0.015f32);
        let expected = d / (0.01 * 1.5 + 1e-6) / 12.0;
        assert!((c.mean_relative - expected).abs() < 1e-9, "{c}");
        assert_eq!(c.max_abs, 0.015);
        let expected_rmse = (d * d / 12.0).sqrt() / 1.5;
        assert!((c.rmse_relative - expected_rmse).abs() < 1e-9, "{c}");

        // NaN is never hidden.
        a2.rgb[3][2] = f32::NAN;
        let c = compare(&a2, &b2).unwrap();
        assert!(c.max_abs.is_nan() && c.mean_relative.is_nan() && c.rmse_relative.is_nan());

        assert!(compare(&constant(2, 2, 1.0), &constant(2, 3, 1.0)).is_err());
        let empty = compare(&Image::new(0, 0), &Image::new(0, 0)).unwrap();
        assert_eq!(empty.mean_relative, 0.0);
    }

    #[test]
    fn diff_png() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("diff.png");
        let b = constant(2, 1, 0.5);
        let mut a = b.clone();
        a.rgb[1] = [0.75, 0.5, f32::NAN];
        write_diff_png(&path, &a, &b, 2.0).unwrap();
        let png = ::image::open(&path).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (2, 1));
        assert_eq!(png.get_pixel(0, 0).0, [0, 0, 0]);
        // |0.25| * 2 = 0.5 -> 188; NaN -> 255.
        assert_eq!(png.get_pixel(1, 0).0, [188, 0, 255]);
        let err = write_diff_png(&path, &a, &constant(1, 1, 0.0), 1.0).unwrap_err();
        assert!(matches!(err, ImageError::Format { .. }));
        assert_eq!(file_names(dir.path()), ["diff.png"]);
    }
}
