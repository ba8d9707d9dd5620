//! Writing the lit cloud: PLY (binary little-endian) or LAS/LAZ, atomically, with the stage's
//! key inside (a PLY `comment pcgiKey`, a LAS VLR of user `pcgi`) so that the next run can tell
//! it is up to date.

use std::fs::File;
use std::io::{self, BufWriter, Read, Write};
use std::path::Path;

use pc_artifact::atomic::AtomicFile;
use pc_artifact::Key;

use crate::lit::{tone_map, LitPoint};

/// The formats of the lit cloud.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LitFormat {
    Ply,
    Las,
    Laz,
}

impl LitFormat {
    /// The format `path`'s extension names (pc-config checked `bake.file`; an `--output` path
    /// with another extension is written as PLY).
    pub fn of(path: &Path) -> LitFormat {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("las") => LitFormat::Las,
            Some("laz") => LitFormat::Laz,
            _ => LitFormat::Ply,
        }
    }
}

/// The names of the linear radiance fields, in both formats.
pub const RADIANCE_FIELDS: [&str; 3] = ["radiance_r", "radiance_g", "radiance_b"];
/// LAS coordinates of the lit cloud are integers of this many metres.
pub const LAS_SCALE: f64 = 1e-4;
/// The LAS VLR that holds the key.
const KEY_VLR_USER: &str = "pcgi";
const KEY_VLR_RECORD: u16 = 1;

/// Writes `points` to `path` in the format its extension names.
pub fn write_lit(path: &Path, points: &[LitPoint], exposure: f32, key: &Key) -> io::Result<()> {
    match LitFormat::of(path) {
        LitFormat::Ply => write_ply(path, points, exposure, key),
        f => write_las(path, points, exposure, key, f == LitFormat::Laz),
    }
}

/// The key written into the lit cloud at `path`, `None` when it is missing or unreadable.
pub fn existing_key(path: &Path) -> Option<Key> {
    match LitFormat::of(path) {
        LitFormat::Ply => {
            let mut head = vec![0u8; 4096];
            let n = File::open(path).ok()?.read(&mut head).ok()?;
            let text = String::from_utf8_lossy(&head[..n]);
            let line = text
                .lines()
                .find_map(|l| l.strip_prefix("comment pcgiKey "))?;
            Key::from_hex(line.trim())
        }
        _ => {
            let r = las::Reader::from_path(path).ok()?;
            let vlr = r
                .header()
                .vlrs()
                .iter()
                .find(|v| v.user_id == KEY_VLR_USER && v.record_id == KEY_VLR_RECORD)?;
            Key::from_hex(std::str::from_utf8(&vlr.data).ok()?)
        }
    }
}

fn write_ply(path: &Path, points: &[LitPoint], exposure: f32, key: &Key) -> io::Result<()> {
    let mut file = AtomicFile::create(path)?;
    {
        let mut w = BufWriter::with_capacity(1 << 20, file.file());
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\ncomment pcgiKey {key}\n\
             comment lit by pcgi pc-bake: red green blue are sRGB after exposure {exposure}; \
             radiance_r/g/b the linear radiance\n\
             element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
             property float nx\nproperty float ny\nproperty float nz\n\
             property uchar red\nproperty uchar green\nproperty uchar blue\n",
            points.len()
        )?;
        for f in RADIANCE_FIELDS {
            writeln!(w, "property float {f}")?;
        }
        writeln!(w, "end_header")?;
        for p in points {
            for v in p.position.to_array() {
                w.write_all(&v.to_le_bytes())?;
            }
            for v in p.normal.to_array() {
                w.write_all(&v.to_le_bytes())?;
            }
            let c = tone_map(p.radiance, exposure).map(|v| (v * 255.0).round() as u8);
            w.write_all(&c)?;
            for v in p.radiance.to_array() {
                w.write_all(&v.to_le_bytes())?;
            }
        }
        w.flush()?;
    }
    file.commit()
}

/// The Extra Bytes VLR (LAS 1.4 R15, table 24) describing three `float` fields.
fn extra_bytes_vlr() -> las::Vlr {
    let mut data = Vec::with_capacity(192 * 3);
    for (name, desc) in RADIANCE_FIELDS.iter().zip([
        "linear radiance, red",
        "linear radiance, green",
        "linear radiance, blue",
    ]) {
        let mut rec = [0u8; 192];
        rec[2] = 9; // data type: float
        rec[4..4 + name.len()].copy_from_slice(name.as_bytes());
        rec[160..160 + desc.len()].copy_from_slice(desc.as_bytes());
        data.extend_from_slice(&rec);
    }
    las::Vlr {
        user_id: "LASF_Spec".into(),
        record_id: 4,
        description: "pcgi radiance".into(),
        data,
    }
}

fn write_las(
    path: &Path,
    points: &[LitPoint],
    exposure: f32,
    key: &Key,
    laz: bool,
) -> io::Result<()> {
    let err = |e: las::Error| io::Error::other(e.to_string());
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(2).map_err(err)?;
    b.point_format.extra_bytes = 12;
    b.point_format.is_compressed = laz;
    b.generating_software = "pcgi pc-bake".into();
    let first = points
        .first()
        .map_or(glam::DVec3::ZERO, |p| p.position.round());
    let t = |offset: f64| las::Transform {
        scale: LAS_SCALE,
        offset,
    };
    b.transforms = las::Vector {
        x: t(first.x),
        y: t(first.y),
        z: t(first.z),
    };
    b.vlrs.push(extra_bytes_vlr());
    b.vlrs.push(las::Vlr {
        user_id: KEY_VLR_USER.into(),
        record_id: KEY_VLR_RECORD,
        description: "pcgi key".into(),
        data: key.to_string().into_bytes(),
    });
    let header = b.into_header().map_err(err)?;
    pc_artifact::atomic::publish_with(path, |tmp| {
        let mut w = las::Writer::new(BufWriter::new(File::create(tmp)?), header).map_err(err)?;
        let written = points.iter().try_for_each(|p| {
            let c = tone_map(p.radiance, exposure).map(|v| (v * 65535.0).round() as u16);
            let mut extra = Vec::with_capacity(12);
            for v in p.radiance.to_array() {
                extra.extend_from_slice(&v.to_le_bytes());
            }
            w.write_point(las::Point {
                x: p.position.x,
                y: p.position.y,
                z: p.position.z,
                color: Some(las::Color::new(c[0], c[1], c[2])),
                extra_bytes: extra,
                ..Default::default()
            })
            .map_err(err)
        });
        match written.and_then(|()| w.close().map_err(err)) {
            Ok(()) => Ok(()),
            Err(e) => {
                // The writer's Drop would close again and panic on a second failure.
                std::mem::forget(w);
                Err(e)
            }
        }
    })
}
