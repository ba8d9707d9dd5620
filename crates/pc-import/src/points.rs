//! What every reader gives back: one file's points ([`PointSet`]), whatever its format, and
//! the choice of reader by file extension ([`read_points`]). docs/import.md lists what is read
//! from each format.

use std::path::Path;

use glam::{DVec3, Vec3};

use crate::ImportError;

/// How to treat invalid points.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlyOptions {
    /// Drop invalid points (non-finite values, zero normals, bad radii) and count them in
    /// [`PointSet::dropped`] instead of failing on the first one.
    pub drop_invalid: bool,
}

/// The points of one file. Optional attributes are `Some` when the file has them.
///
/// Positions are f32 offsets from [`PointSet::origin`], an f64 point of the file's own frame:
/// a georeferenced scan (coordinates in the hundreds of thousands of metres, where f32 steps
/// are centimetres) keeps its precision as long as the cloud itself spans less than a few
/// kilometres. PLY files are read as they are (origin zero).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointSet {
    /// Offsets from `origin`.
    pub positions: Vec<Vec3>,
    /// The file-frame point the positions are relative to: `origin + position` is the point
    /// as the file gives it, computed in f64.
    pub origin: DVec3,
    /// Unit normals (normalized on import).
    pub normals: Option<Vec<Vec3>>,
    /// Positive finite radii.
    pub radii: Option<Vec<f32>>,
    /// Linear RGB in [0, 1].
    pub colors: Option<Vec<Vec3>>,
    /// Return intensity in [0, 1], normalized per file.
    pub intensity: Option<Vec<f32>>,
    /// LAS classification codes (0 to 255).
    pub classes: Option<Vec<u8>>,
    /// LAS point source ids (the scan or flight line a point came from).
    pub source_ids: Option<Vec<u16>>,
    /// Scanner positions in the file's frame (E57 scans with a pose or spherical coordinates),
    /// and for each point the index of the station that saw it.
    pub stations: Vec<DVec3>,
    pub station_of: Option<Vec<u32>>,
    /// Points dropped as invalid (only with [`PlyOptions::drop_invalid`]) or left out because
    /// the file marks them as no return (E57).
    pub dropped: usize,
    /// Dropped points per reason, e.g. `("zero-length normal", 3)`; only reasons that occurred,
    /// in a fixed order. Each dropped point counts once, for the first problem found.
    pub drop_reasons: Vec<(String, usize)>,
}

impl PointSet {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// The axis-aligned bounds of the points in the file's frame (f64), `None` when empty.
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        let first = *self.positions.first()?;
        let (lo, hi) = self
            .positions
            .iter()
            .fold((first, first), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        Some((self.origin + lo.as_dvec3(), self.origin + hi.as_dvec3()))
    }
}

/// The point-cloud formats pcgi reads, chosen by the file's extension (case-insensitive).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Ply,
    /// LAS 1.0 to 1.4, and LAZ (compressed LAS) through the same reader.
    Las,
    E57,
}

impl Format {
    /// The format of `path`, from its extension.
    pub fn of(path: &Path) -> Result<Format, ImportError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        match ext.as_str() {
            "ply" => Ok(Format::Ply),
            "las" | "laz" => Ok(Format::Las),
            "e57" => Ok(Format::E57),
            _ => Err(ImportError::UnknownFormat {
                path: path.to_path_buf(),
                ext,
            }),
        }
    }

    /// The format's name, for messages.
    pub fn name(self) -> &'static str {
        match self {
            Format::Ply => "PLY",
            Format::Las => "LAS/LAZ",
            Format::E57 => "E57",
        }
    }

    /// True for the formats scanners write, whose coordinates may be georeferenced.
    pub fn is_scan(self) -> bool {
        !matches!(self, Format::Ply)
    }
}

/// Read the points of `path` with the reader its extension names.
pub fn read_points(path: &Path, opts: &PlyOptions) -> Result<PointSet, ImportError> {
    let pts = match Format::of(path)? {
        Format::Ply => crate::ply::read_ply(path, opts)?,
        Format::Las => decoder_guard(path, "LAS", || crate::las::read_las(path, opts))?,
        Format::E57 => decoder_guard(path, "E57", || crate::e57::read_e57(path, opts))?,
    };
    if pts.is_empty() {
        return Err(ImportError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok(pts)
}

/// Runs a third-party decoder: a panic inside it (a damaged file it did not expect) becomes an
/// error naming the file, not the end of the process. pcgi's own checks come first (see
/// `las_guard`); this is the backstop.
fn decoder_guard(
    path: &Path,
    format: &'static str,
    read: impl FnOnce() -> Result<PointSet, ImportError>,
) -> Result<PointSet, ImportError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(read)).unwrap_or_else(|payload| {
        let why = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "no message".into());
        Err(ImportError::scan(
            path,
            format,
            format!("the decoder failed ({why}): the file is damaged"),
        ))
    })
}

/// The sRGB transfer function undone: an sRGB-encoded value in [0, 1] to linear.
pub fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// A point rounded to whole units: the origin a reader (and the scene) picks for its f32
/// offsets (any point of the cloud keeps them small; a round one reads well in reports).
pub fn round_origin(p: DVec3) -> DVec3 {
    p.round()
}

/// `p` (file frame, f64) as an f32 offset from `origin`.
#[inline]
pub fn offset(p: DVec3, origin: DVec3) -> Vec3 {
    (p - origin).as_vec3()
}
