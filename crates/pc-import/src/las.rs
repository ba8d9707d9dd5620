//! LAS 1.0 to 1.4 and LAZ, through the `las` crate (its pure-Rust `laz` decoder, in parallel).
//!
//! Read: x y z (f64, the header's scale and offset applied, kept as f32 offsets from the first
//! point rounded to a metre), RGB when the point format has it, intensity, and the
//! classification code. Before any point is decoded, the header's point count is checked
//! against the size of an uncompressed body; a compressed body that ends early, or any record
//! the decoder refuses, is an error naming the point it stopped at.

use std::fs::File;
use std::io::{BufReader, Seek, SeekFrom};
use std::path::Path;

use glam::{DVec3, Vec3};

use crate::points::{offset, round_origin, srgb_to_linear, PlyOptions, PointSet};
use crate::ImportError;

/// Points decoded per call into the `las` reader.
const CHUNK: u64 = 1 << 16;

/// Read a LAS or LAZ file.
pub fn read_las(path: &Path, _opts: &PlyOptions) -> Result<PointSet, ImportError> {
    crate::check_regular_file(path)?;
    let mut file = File::open(path).map_err(|e| ImportError::io(path, e))?;
    let raw = las::raw::Header::read_from(BufReader::new(&mut file))
        .map_err(|e| ImportError::scan(path, "LAS", format!("header: {e}")))?;
    let compressed = raw.point_data_record_format & 0x80 != 0;
    let format = if compressed { "LAZ" } else { "LAS" };
    let announced = announced_points(&raw);
    check_transform(path, format, &raw)?;
    let len = file.metadata().map_err(|e| ImportError::io(path, e))?.len();
    // The `las` and `laz` crates trust the sizes a file gives and allocate them: checked here
    // first, so a damaged file is an error, not an abort.
    crate::las_guard::check_evlrs(path, &mut file, &raw, len)?;
    if compressed {
        crate::las_guard::check_laz_tables(path, &mut file, &raw, announced, len)?;
    } else {
        check_body_size(path, &raw, announced, len)?;
    }
    file.seek(SeekFrom::Start(0))
        .map_err(|e| ImportError::io(path, e))?;
    let options = las::ReaderOptions::default().with_laz_parallelism(las::LazParallelism::Yes);
    let mut reader = las::Reader::with_options(BufReader::new(file), options).map_err(|e| {
        let what = if compressed {
            "the compressed body cannot be opened (cut short, or not LAZ?)"
        } else {
            "the body cannot be opened"
        };
        ImportError::scan(path, format, format!("{what}: {e}"))
    })?;
    let has_color = reader.header().point_format().has_color;
    let n = usize::try_from(announced)
        .map_err(|_| ImportError::scan(path, format, "more points than this machine can hold"))?;
    let mut acc = Accumulator::new(n, has_color);
    let mut buf = Vec::with_capacity(CHUNK as usize);
    while acc.read < announced {
        buf.clear();
        let want = CHUNK.min(announced - acc.read);
        let got = reader.read_points_into(want, &mut buf).map_err(|e| {
            ImportError::scan(
                path,
                format,
                format!("point {} of {announced}: {e}", acc.read),
            )
        })?;
        if got == 0 {
            return Err(ImportError::scan(
                path,
                format,
                format!(
                    "the body ends after {} of the {announced} points the header announces",
                    acc.read
                ),
            ));
        }
        if let Some((i, p)) = acc.push(&buf) {
            return Err(ImportError::scan(
                path,
                format,
                format!(
                    "point {i}: coordinates ({}, {}, {}) are not finite numbers of metres: the header's scale or offset is damaged",
                    p.x, p.y, p.z
                ),
            ));
        }
    }
    Ok(acc.finish())
}

/// The point count of the header (LAS 1.4's 64-bit count when present).
fn announced_points(raw: &las::raw::Header) -> u64 {
    match &raw.large_file {
        Some(l) if l.number_of_point_records > 0 => l.number_of_point_records,
        _ => u64::from(raw.number_of_point_records),
    }
}

/// Scale factors must be finite and non-zero, offsets finite: else every coordinate is.
fn check_transform(
    path: &Path,
    format: &'static str,
    raw: &las::raw::Header,
) -> Result<(), ImportError> {
    let scales = [raw.x_scale_factor, raw.y_scale_factor, raw.z_scale_factor];
    let offsets = [raw.x_offset, raw.y_offset, raw.z_offset];
    for (axis, (s, o)) in ["x", "y", "z"]
        .into_iter()
        .zip(scales.into_iter().zip(offsets))
    {
        if !s.is_finite() || s == 0.0 || !o.is_finite() {
            return Err(ImportError::scan(
                path,
                format,
                format!("header: {axis} scale {s} and offset {o}: a finite, non-zero scale and a finite offset are required"),
            ));
        }
    }
    Ok(())
}

/// An uncompressed body holds exactly the announced records: from the point data offset to
/// the first extended VLR (LAS 1.4) or the end of the file.
fn check_body_size(
    path: &Path,
    raw: &las::raw::Header,
    announced: u64,
    file_len: u64,
) -> Result<(), ImportError> {
    let start = u64::from(raw.offset_to_point_data);
    let record = u64::from(raw.point_data_record_length);
    let end = match &raw.evlr {
        Some(e) if e.start_of_first_evlr > 0 => e.start_of_first_evlr.min(file_len),
        _ => file_len,
    };
    if record == 0 {
        return Err(ImportError::scan(
            path,
            "LAS",
            "header: point records of 0 bytes",
        ));
    }
    let body = end.saturating_sub(start);
    let held = body / record;
    if held != announced {
        let more = if held < announced {
            "the file ends early: truncated?"
        } else {
            "the header's count is wrong"
        };
        return Err(ImportError::scan(
            path,
            "LAS",
            format!(
                "the header announces {announced} points of {record} bytes, the body holds {held} ({body} bytes from offset {start}): {more}"
            ),
        ));
    }
    Ok(())
}

/// The arrays of a LAS file as its chunks are decoded.
struct Accumulator {
    /// The first point, rounded: the origin of the f32 offsets (the header's bounds are not
    /// trusted: a damaged header would put it anywhere).
    origin: Option<DVec3>,
    read: u64,
    positions: Vec<Vec3>,
    intensity: Vec<u16>,
    classes: Vec<u8>,
    sources: Vec<u16>,
    colors: Option<Vec<[u16; 3]>>,
}

impl Accumulator {
    fn new(n: usize, has_color: bool) -> Self {
        let n = n.min(1 << 24); // grown as points come: the count is not proof of them
        Self {
            origin: None,
            read: 0,
            positions: Vec::with_capacity(n),
            intensity: Vec::with_capacity(n),
            classes: Vec::with_capacity(n),
            sources: Vec::with_capacity(n),
            colors: has_color.then(|| Vec::with_capacity(n)),
        }
    }

    /// Appends decoded points; the index and coordinates of the first whose offset is not a
    /// finite f32, if any.
    fn push(&mut self, points: &[las::Point]) -> Option<(u64, DVec3)> {
        for (k, p) in points.iter().enumerate() {
            let world = DVec3::new(p.x, p.y, p.z);
            let origin = *self.origin.get_or_insert_with(|| round_origin(world));
            let o = offset(world, origin);
            if !world.is_finite() || !o.is_finite() {
                return Some((self.read + k as u64, world));
            }
            self.positions.push(o);
            self.intensity.push(p.intensity);
            self.classes.push(u8::from(p.classification));
            self.sources.push(p.point_source_id);
            if let Some(c) = &mut self.colors {
                let rgb = p.color.map_or([0; 3], |c| [c.red, c.green, c.blue]);
                c.push(rgb);
            }
        }
        self.read += points.len() as u64;
        None
    }

    fn finish(self) -> PointSet {
        let max_i = self.intensity.iter().copied().max().unwrap_or(0);
        let intensity = (max_i > 0).then(|| {
            let s = 1.0 / f32::from(max_i);
            self.intensity.iter().map(|&i| f32::from(i) * s).collect()
        });
        PointSet {
            positions: self.positions,
            origin: self.origin.unwrap_or(DVec3::ZERO),
            colors: self.colors.map(|c| linear_colors(&c)),
            intensity,
            classes: Some(self.classes),
            source_ids: Some(self.sources),
            ..PointSet::default()
        }
    }
}

/// LAS colors are 16-bit, but many writers store 8-bit values in them: when no channel of the
/// file exceeds 255 the values are taken as 8-bit. sRGB-decoded to linear.
fn linear_colors(raw: &[[u16; 3]]) -> Vec<Vec3> {
    let max = raw.iter().flatten().copied().max().unwrap_or(0);
    let full = if max <= 255 { 255.0 } else { 65535.0 };
    let table: Vec<f32> = (0..=max as u32)
        .map(|v| srgb_to_linear(f64::from(v) / full) as f32)
        .collect();
    raw.iter()
        .map(|c| {
            Vec3::new(
                table[c[0] as usize],
                table[c[1] as usize],
                table[c[2] as usize],
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_bit_colors_in_sixteen_bit_fields_are_recognised() {
        let c = linear_colors(&[[255, 0, 128]]);
        assert!((c[0].x - 1.0).abs() < 1e-6 && c[0].y == 0.0);
        assert!((c[0].z - 0.2158).abs() < 1e-3, "{}", c[0].z);
        let c = linear_colors(&[[65535, 256, 0]]);
        assert!((c[0].x - 1.0).abs() < 1e-6 && c[0].y < 0.01);
    }
}
