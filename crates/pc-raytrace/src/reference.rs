//! Comparison of a render with a reference render (two EXRs, and optionally a JSON file of
//! pixel regions such as `../shared/reference/<scene>/*.stats.json`). Used by `pc-compare`,
//! `cargo xtask compare` and the end-to-end reference test.
//!
//! Per region: our mean RGB over the region's pixels against the reference's mean over the
//! same pixels, as the
//! relative error of each channel and as `‖ours − ref‖₁ / ‖ref‖₁` over RGB (the figure the
//! 3 % target is about: tiny channels, such as the red wall's green, cannot blow it up).
//! Whole image: `rel_rmse = sqrt(Σ (o − r)² / Σ r²)` over every pixel and channel.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use crate::image::{read_exr, Image};

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
        s
    }
}

/// Find the stats file (`*.stats.json`) of a reference folder.
pub fn stats_file(dir: &Path) -> anyhow::Result<PathBuf> {
    let mut found = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("{}: cannot read", dir.display()))? {
        let p = e?.path();
        if p.to_string_lossy().ends_with(".stats.json") {
            found.push(p);
        }
    }
    match found.len() {
        1 => Ok(found.pop().unwrap()),
        0 => bail!("{}: no *.stats.json reference stats", dir.display()),
        _ => bail!("{}: several *.stats.json files: {found:?}", dir.display()),
    }
}

/// Compare `ours` with the reference in `dir` (its stats JSON, and the EXR it names, over the
/// stats' regions).
pub fn compare(ours: &Image, dir: &Path) -> anyhow::Result<(Report, Image)> {
    let stats_path = stats_file(dir)?;
    let stats = read_json(&stats_path)?;
    let exr_name = stats["image"]
        .as_str()
        .with_context(|| format!("{}: no `image`", stats_path.display()))?;
    let exr = dir.join(exr_name);
    let reference = read_exr(&exr)?;
    let report = compare_images(ours, &reference, &exr, Some(&stats_path))?;
    Ok((report, reference))
}

fn read_json(path: &Path) -> anyhow::Result<serde_json::Value> {
    serde_json::from_str(
        &std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?,
    )
    .with_context(|| format!("{}: not JSON", path.display()))
}

/// The regions of a regions file: a JSON object whose `regions` maps each name to
/// `{"rect": [x0, y0, x1, y1], "description": "..."}` (pixels from the top left, `[x0, x1) ×
/// [y0, y1)`), as the reference's `*.stats.json` does; other keys are ignored.
pub fn read_regions(
    path: &Path,
    width: u32,
    height: u32,
) -> anyhow::Result<Vec<(String, String, [u32; 4])>> {
    let json = read_json(path)?;
    let regions = json["regions"]
        .as_object()
        .with_context(|| format!("{}: no `regions` object", path.display()))?;
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
            bail!(
                "{}: region `{name}` needs a rect [x0, y0, x1, y1] with x0 < x1 and y0 < y1",
                path.display()
            );
        }
        if rect[2] > width || rect[3] > height {
            bail!(
                "{}: region `{name}` ({rect:?}) reaches outside the {width}x{height} image",
                path.display()
            );
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
) -> anyhow::Result<Report> {
    if (reference.width, reference.height) != (ours.width, ours.height) {
        bail!(
            "{}: the reference is {}x{}, the render {}x{}: render at the reference's size",
            reference_path.display(),
            reference.width,
            reference.height,
            ours.width,
            ours.height
        );
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
    Ok(Report {
        reference_exr: reference_path.to_path_buf(),
        regions,
        rel_rmse: (d2 / r2.max(1e-300)).sqrt(),
        mean_ours: ours.mean(),
        mean_reference: reference.mean(),
    })
}

/// A pipeline config that renders the reference scene in `dir` (`../shared/reference/cornell`)
/// from its sampled points: one material per shape (reflectance, emitted radiance) from
/// `points-100k/cornell.materials.json`, the camera from `cornell.scene.json`.
pub fn config_toml(dir: &Path) -> anyhow::Result<String> {
    let dir = dir
        .canonicalize()
        .with_context(|| format!("{}: the reference data is missing", dir.display()))?;
    let mpath = dir.join("points-100k/cornell.materials.json");
    let spath = dir.join("cornell.scene.json");
    let m: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&mpath).with_context(|| mpath.display().to_string())?,
    )?;
    let s: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&spath).with_context(|| spath.display().to_string())?,
    )?;
    let mut materials = String::new();
    let mut models = String::new();
    let files = m["files"]
        .as_object()
        .context("materials.json has no `files`")?;
    for (file, desc) in files {
        let name = desc["shape"]
            .as_str()
            .context("shape name")?
            .replace('-', "_");
        let refl = toml_vec(&desc["bsdf"]["reflectance"])?;
        if desc["emitter"].is_object() {
            let rad = toml_vec(&desc["emitter"]["radiance"])?;
            materials.push_str(&format!(
                "[materials.{name}]\ntype = \"emitter\"\nradiance = {rad}\nalbedo = {refl}\n\n"
            ));
        } else {
            materials.push_str(&format!(
                "[materials.{name}]\ntype = \"diffuse\"\nalbedo = {refl}\n\n"
            ));
        }
        models.push_str(&format!(
            "[[models]]\nfile = \"{}\"\nmaterial = \"{name}\"\n\n",
            dir.join("points-100k").join(file).display()
        ));
    }
    let sensor = &s["sensor"];
    let camera = format!(
        "[camera]\norigin = {}\ntarget = {}\nup = {}\nfov = {}\nfov_axis = \"{}\"\nwidth = {}\nheight = {}\n",
        toml_vec(&sensor["origin"])?,
        toml_vec(&sensor["target"])?,
        toml_vec(&sensor["up"])?,
        sensor["fov_deg"].as_f64().context("fov_deg")?,
        sensor["fov_axis"].as_str().context("fov_axis")?,
        sensor["film"]["width"],
        sensor["film"]["height"],
    );
    Ok(format!(
        "# Generated by `pc-compare --write-config` (`cargo xtask reference-config`) from {}\n# (the reference Cornell box of Mitsuba 3; materials and camera read from its JSON).\n\n[output]\ndir = \".\"\n\n{materials}{models}{camera}",
        dir.display()
    ))
}

fn toml_vec(v: &serde_json::Value) -> anyhow::Result<String> {
    let a = v.as_array().context("expected an array of numbers")?;
    let parts: Vec<String> = a
        .iter()
        .map(|x| x.as_f64().map(|f| format!("{f}")))
        .collect::<Option<_>>()
        .context("expected numbers")?;
    Ok(format!("[{}]", parts.join(", ")))
}
