//! Comparison of a render with a reference render (two EXRs, and optionally a JSON file of
//! pixel regions such as `../shared/reference/<scene>/*.stats.json`). Used by `pc-compare`,
//! `cargo xtask compare` and the end-to-end reference test.
//!
//! Per region: our mean RGB over the region's pixels against the reference's mean over the
//! same pixels, as the
//! relative error of each channel and as `‖ours − ref‖₁ / ‖ref‖₁` over RGB (the figure the
//! 3 % target is about: tiny channels, such as the red wall's green, cannot blow it up).
//! Whole image: `rel_rmse = sqrt(Σ (o − r)² / Σ r²)` over every pixel and channel, and the
//! per-pixel relative error ([`crate::per_pixel`]) over every pixel and outside the band around
//! the light's border.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use pc_config::{Albedo, CameraConfig, FovAxis, MaterialConfig, ModelConfig};

use crate::image::{read_exr, Image, ImageError};

/// One region of the reference's stats.
#[derive(Clone, Debug)]
pub struct Region {
    pub name: String,
    pub description: String,
    /// [x0, y0, x1, y1), pixels from the top left.
    pub rect: [u32; 4],
    pub reference: [f64; 3],
    pub ours: [f64; 3],
}

impl Region {
    /// `‖ours − ref‖₁ / ‖ref‖₁` over RGB.
    pub fn error(&self) -> f64 {
        let d: f64 = (0..3)
            .map(|c| (self.ours[c] - self.reference[c]).abs())
            .sum();
        d / self
            .reference
            .iter()
            .map(|x| x.abs())
            .sum::<f64>()
            .max(1e-12)
    }

    /// Signed relative error per channel.
    pub fn channel_errors(&self) -> [f64; 3] {
        std::array::from_fn(|c| {
            (self.ours[c] - self.reference[c]) / self.reference[c].abs().max(1e-12)
        })
    }
}

/// The comparison of one render.
#[derive(Clone, Debug)]
pub struct Report {
    pub reference_exr: PathBuf,
    pub regions: Vec<Region>,
    /// sqrt(Σ (o − r)² / Σ r²) over the whole image.
    pub rel_rmse: f64,
    /// The per-pixel relative error ([`crate::per_pixel::error`]) over the whole image.
    pub per_pixel: f64,
    /// The same outside the band around the light's border ([`crate::per_pixel::light_band`]).
    pub per_pixel_outside_band: f64,
    /// Pixels in that band.
    pub band_pixels: usize,
    pub mean_ours: [f64; 3],
    pub mean_reference: [f64; 3],
}

impl Report {
    /// The largest region error.
    pub fn worst(&self) -> Option<&Region> {
        self.regions
            .iter()
            .max_by(|a, b| a.error().total_cmp(&b.error()))
    }

    /// A text table.
    pub fn table(&self) -> String {
        let mut s = format!(
            "{:<18} {:>28} {:>28} {:>8}  {}\n",
            "region", "ours (RGB)", "reference (RGB)", "error", "per channel"
        );
        for r in &self.regions {
            let ce = r.channel_errors();
            s.push_str(&format!(
                "{:<18} {:>8.4} {:>8.4} {:>8.4}   {:>8.4} {:>8.4} {:>8.4}   {:>6.2} %  ({:+.1} {:+.1} {:+.1}) %\n",
                r.name,
                r.ours[0],
                r.ours[1],
                r.ours[2],
                r.reference[0],
                r.reference[1],
                r.reference[2],
                100.0 * r.error(),
                100.0 * ce[0],
                100.0 * ce[1],
                100.0 * ce[2]
            ));
        }
        s.push_str(&format!(
            "whole image: mean ours ({:.4} {:.4} {:.4}), reference ({:.4} {:.4} {:.4}); relative RMSE {:.2} %\n",
            self.mean_ours[0],
            self.mean_ours[1],
            self.mean_ours[2],
            self.mean_reference[0],
            self.mean_reference[1],
            self.mean_reference[2],
            100.0 * self.rel_rmse
        ));
        s.push_str(&format!(
            "per-pixel relative error: {:.4} whole image, {:.4} outside the {} pixels within {} of the light's border\n",
            self.per_pixel,
            self.per_pixel_outside_band,
            self.band_pixels,
            crate::per_pixel::LIGHT_BAND
        ));
        s
    }
}

/// What can be wrong with a reference folder or a regions file; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    #[error("{}: cannot read", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is not what a reference folder holds (not JSON, a key missing or malformed).
    #[error("{}: {msg}", path.display())]
    Bad { path: PathBuf, msg: String },
    #[error(transparent)]
    Image(#[from] ImageError),
}

fn bad(path: &Path, msg: impl Into<String>) -> ReferenceError {
    ReferenceError::Bad {
        path: path.to_path_buf(),
        msg: msg.into(),
    }
}

/// The one file of `dir` whose name ends with `suffix` (`.stats.json`).
fn file_ending(dir: &Path, suffix: &str) -> Result<PathBuf, ReferenceError> {
    let io = |source| ReferenceError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut found = Vec::new();
    for e in std::fs::read_dir(dir).map_err(io)? {
        let p = e.map_err(io)?.path();
        if p.to_string_lossy().ends_with(suffix) {
            found.push(p);
        }
    }
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => Err(bad(dir, format!("no *{suffix} file"))),
        _ => Err(bad(dir, format!("several *{suffix} files: {found:?}"))),
    }
}

/// Find the stats file (`*.stats.json`) of a reference folder.
pub fn stats_file(dir: &Path) -> Result<PathBuf, ReferenceError> {
    file_ending(dir, ".stats.json")
}

/// Compare `ours` with the reference in `dir` (its stats JSON, and the EXR it names, over the
/// stats' regions).
pub fn compare(ours: &Image, dir: &Path) -> Result<(Report, Image), ReferenceError> {
    let stats_path = stats_file(dir)?;
    let stats = read_json(&stats_path)?;
    let exr_name = stats["image"]
        .as_str()
        .ok_or_else(|| bad(&stats_path, "no `image`"))?;
    let exr = dir.join(exr_name);
    let reference = read_exr(&exr)?;
    let report = compare_images(ours, &reference, &exr, Some(&stats_path))?;
    Ok((report, reference))
}

fn read_json(path: &Path) -> Result<serde_json::Value, ReferenceError> {
    let text = std::fs::read_to_string(path).map_err(|source| ReferenceError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|e| bad(path, format!("not JSON: {e}")))
}

/// The regions of a regions file: a JSON object whose `regions` maps each name to
/// `{"rect": [x0, y0, x1, y1], "description": "..."}` (pixels from the top left, `[x0, x1) ×
/// [y0, y1)`), as the reference's `*.stats.json` does; other keys are ignored.
pub fn read_regions(
    path: &Path,
    width: u32,
    height: u32,
) -> Result<Vec<(String, String, [u32; 4])>, ReferenceError> {
    let json = read_json(path)?;
    let regions = json["regions"]
        .as_object()
        .ok_or_else(|| bad(path, "no `regions` object"))?;
    let mut out = Vec::new();
    for (name, r) in regions {
        let rect: Vec<u32> = r["rect"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|v| v.as_u64().and_then(|x| u32::try_from(x).ok()))
                    .collect()
            })
            .unwrap_or_default();
        if rect.len() != 4 || rect[0] >= rect[2] || rect[1] >= rect[3] {
            return Err(bad(
                path,
                format!("region `{name}` needs a rect [x0, y0, x1, y1] with x0 < x1 and y0 < y1"),
            ));
        }
        if rect[2] > width || rect[3] > height {
            return Err(bad(
                path,
                format!("region `{name}` ({rect:?}) reaches outside the {width}x{height} image"),
            ));
        }
        let description = r["description"].as_str().unwrap_or("").to_string();
        out.push((
            name.clone(),
            description,
            [rect[0], rect[1], rect[2], rect[3]],
        ));
    }
    Ok(out)
}
/// The mean RGB of `img` over `rect` ([x0, y0, x1, y1)).
fn region_mean(img: &Image, rect: [u32; 4]) -> [f64; 3] {
    let mut sum = [0.0f64; 3];
    for y in rect[1]..rect[3] {
        for x in rect[0]..rect[2] {
            let p = img.get(x, y);
            for c in 0..3 {
                sum[c] += p[c] as f64;
            }
        }
    }
    let n = ((rect[2] - rect[0]) * (rect[3] - rect[1])) as f64;
    sum.map(|s| s / n)
}

/// Compare `ours` with `reference` (read from `reference_path`, named in the report): the
/// relative RMSE over the whole image, and the mean of both images over each region of the
/// `regions` file when given.
pub fn compare_images(
    ours: &Image,
    reference: &Image,
    reference_path: &Path,
    regions: Option<&Path>,
) -> Result<Report, ReferenceError> {
    if (reference.width, reference.height) != (ours.width, ours.height) {
        return Err(bad(
            reference_path,
            format!(
                "the reference is {}x{}, the render {}x{}: render at the reference's size",
                reference.width, reference.height, ours.width, ours.height
            ),
        ));
    }
    let regions = match regions {
        Some(path) => read_regions(path, ours.width, ours.height)?
            .into_iter()
            .map(|(name, description, rect)| Region {
                name,
                description,
                rect,
                reference: region_mean(reference, rect),
                ours: region_mean(ours, rect),
            })
            .collect(),
        None => Vec::new(),
    };
    let (mut d2, mut r2) = (0.0f64, 0.0f64);
    for (o, r) in ours.rgb.iter().zip(&reference.rgb) {
        for c in 0..3 {
            d2 += ((o[c] - r[c]) as f64).powi(2);
            r2 += (r[c] as f64).powi(2);
        }
    }
    let band = crate::per_pixel::light_band(reference);
    Ok(Report {
        reference_exr: reference_path.to_path_buf(),
        regions,
        rel_rmse: (d2 / r2.max(1e-300)).sqrt(),
        per_pixel: crate::per_pixel::error(ours, reference, None),
        per_pixel_outside_band: crate::per_pixel::error(ours, reference, Some(&band)),
        band_pixels: band.iter().filter(|&&b| b).count(),
        mean_ours: ours.mean(),
        mean_reference: reference.mean(),
    })
}

/// What `--write-config` writes: the scene's tables of pipeline.toml.
#[derive(serde::Serialize)]
struct ReferenceConfig {
    output: pc_config::OutputConfig,
    materials: BTreeMap<String, MaterialConfig>,
    models: Vec<ModelConfig>,
    camera: CameraConfig,
}

/// A pipeline config that renders the reference scene in `dir` (a folder of
/// `../shared/reference/`) from its sampled points: one material per shape from
/// `points-100k/*.materials.json` (Mitsuba's `diffuse` with or without an area emitter, its
/// `conductor` as a mirror, its `dielectric` with the ratio of its indices of refraction), the
/// camera from `*.scene.json`. Nothing is copied into code: every number is read from the
/// reference's own files.
pub fn config_toml(dir: &Path) -> Result<String, ReferenceError> {
    let dir = dir.canonicalize().map_err(|source| ReferenceError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let points = dir.join("points-100k");
    let mpath = file_ending(&points, ".materials.json")?;
    let spath = file_ending(&dir, ".scene.json")?;
    let (m, s) = (read_json(&mpath)?, read_json(&spath)?);
    let files = m["files"]
        .as_object()
        .ok_or_else(|| bad(&mpath, "no `files` object"))?;
    let mut materials = BTreeMap::new();
    let mut models = Vec::new();
    for (file, desc) in files {
        let name = desc["shape"]
            .as_str()
            .ok_or_else(|| bad(&mpath, format!("`files.{file}` has no `shape`")))?
            .replace('-', "_");
        let key = |k: &str| format!("files.{file}.{k}");
        materials.insert(name.clone(), material(desc, &mpath, &key)?);
        models.push(ModelConfig {
            file: points.join(file),
            material: name,
            ..ModelConfig::default()
        });
    }
    let sensor = &s["sensor"];
    let fov_axis = match sensor["fov_axis"].as_str() {
        Some("x") => FovAxis::X,
        Some("y") => FovAxis::Y,
        Some("smaller") => FovAxis::Smaller,
        Some("larger") => FovAxis::Larger,
        other => return Err(bad(&spath, format!("`sensor.fov_axis` is {other:?}"))),
    };
    let size = |k: &str| {
        sensor["film"][k]
            .as_u64()
            .and_then(|x| u32::try_from(x).ok())
            .ok_or_else(|| bad(&spath, format!("`sensor.film.{k}` is not a size")))
    };
    let camera = CameraConfig {
        origin: rgb(&sensor["origin"], &spath, "sensor.origin")?,
        target: rgb(&sensor["target"], &spath, "sensor.target")?,
        up: rgb(&sensor["up"], &spath, "sensor.up")?,
        fov: sensor["fov_deg"]
            .as_f64()
            .ok_or_else(|| bad(&spath, "`sensor.fov_deg` is not a number"))? as f32,
        fov_axis,
        width: size("width")?,
        height: size("height")?,
    };
    let config = ReferenceConfig {
        output: pc_config::OutputConfig {
            dir: PathBuf::from("."),
        },
        materials,
        models,
        camera,
    };
    let body = pc_config::to_toml(&config).map_err(|e| bad(&dir, e.to_string()))?;
    Ok(format!(
        "# Generated by `pc-compare --write-config` (`cargo xtask reference-config`) from {}\n# (a Mitsuba 3 reference; materials and camera read from its JSON).\n\n{body}",
        dir.display()
    ))
}

/// The material of one shape of a reference's materials file.
fn material(
    desc: &serde_json::Value,
    path: &Path,
    key: &dyn Fn(&str) -> String,
) -> Result<MaterialConfig, ReferenceError> {
    let bsdf = &desc["bsdf"];
    let unit = |v: &serde_json::Value| v.as_f64().map(|x| [x as f32; 3]);
    Ok(match bsdf["type"].as_str() {
        Some("diffuse") => {
            let albedo = rgb(&bsdf["reflectance"], path, &key("bsdf.reflectance"))?;
            if desc["emitter"].is_object() {
                MaterialConfig::Emitter {
                    radiance: rgb(&desc["emitter"]["radiance"], path, &key("emitter.radiance"))?,
                    albedo: Some(albedo),
                }
            } else {
                MaterialConfig::Diffuse {
                    albedo: Albedo::Rgb(albedo),
                }
            }
        }
        Some("conductor") => MaterialConfig::Mirror {
            reflectance: match &bsdf["reflectance"] {
                serde_json::Value::Null => [1.0; 3],
                v => rgb(v, path, &key("bsdf.reflectance"))?,
            },
            phong: None,
        },
        Some("dielectric") => {
            let ior = |k: &str| {
                bsdf[k].as_f64().ok_or_else(|| {
                    bad(
                        path,
                        format!("`{}` is not a number", key(&format!("bsdf.{k}"))),
                    )
                })
            };
            MaterialConfig::Dielectric {
                ior: (ior("int_ior")? / ior("ext_ior")?) as f32,
                tint: unit(&bsdf["specular_transmittance"]).filter(|t| *t != [1.0; 3]),
                phong: None,
            }
        }
        other => {
            return Err(bad(
                path,
                format!(
                    "`{}` is {other:?}, not diffuse, conductor or dielectric",
                    key("bsdf.type")
                ),
            ))
        }
    })
}

/// Three numbers of a JSON array.
fn rgb(v: &serde_json::Value, path: &Path, key: &str) -> Result<[f32; 3], ReferenceError> {
    let a: Vec<f32> = v
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|x| x.as_f64().map(|f| f as f32))
                .collect()
        })
        .unwrap_or_default();
    <[f32; 3]>::try_from(a).map_err(|_| bad(path, format!("`{key}` is not three numbers")))
}
