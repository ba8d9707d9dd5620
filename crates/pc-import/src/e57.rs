//! E57 (ASTM E2807), through the `e57` crate: every scan of the file, each with its pose.
//!
//! Read: cartesian or spherical coordinates (spherical converted), each scan's pose applied,
//! in f64, kept as f32 offsets from an origin at the first point (rounded to a metre); color
//! and intensity, normalized by the scan's limits; the scanner position of each scan that has
//! a pose or spherical coordinates (the origin of a scan's own frame is its scanner). Points
//! the scanner marks as having no return (an invalid coordinate) are left out and counted.
//! Every page's checksum is verified as it is read.

use std::path::Path;

use glam::{DVec3, Vec3};

use crate::points::{offset, round_origin, srgb_to_linear, PlyOptions, PointSet};
use crate::ImportError;

/// Read an E57 file.
pub fn read_e57(path: &Path, _opts: &PlyOptions) -> Result<PointSet, ImportError> {
    crate::check_regular_file(path)?;
    let err = |what: String| ImportError::scan(path, "E57", what);
    let mut reader = e57::E57Reader::from_file(path).map_err(|e| err(chain(&e)))?;
    let clouds = reader.pointclouds();
    let mut acc = Accumulator::default();
    for (index, pc) in clouds.iter().enumerate() {
        let station = station_of(pc);
        let mut points = reader
            .pointcloud_simple(pc)
            .map_err(|e| err(format!("scan {index}: {}", chain(&e))))?;
        points.apply_pose(true);
        points.spherical_to_cartesian(true);
        points.intensity_to_color(false);
        acc.begin_scan(station, pc.has_color(), pc.has_intensity());
        for (i, p) in points.enumerate() {
            let p = p.map_err(|e| err(format!("scan {index}, point {i}: {}", chain(&e))))?;
            acc.push(&p)
                .map_err(|why| err(format!("scan {index}, point {i}: {why}")))?;
        }
    }
    Ok(acc.finish())
}

/// The scanner position of a scan in the file's frame, when the file says where it was: the
/// pose's translation, or the origin of a scan in spherical coordinates without a pose.
fn station_of(pc: &e57::PointCloud) -> Option<DVec3> {
    match &pc.transform {
        Some(t) => Some(DVec3::new(
            t.translation.x,
            t.translation.y,
            t.translation.z,
        )),
        None => pc.has_spherical().then_some(DVec3::ZERO),
    }
}

/// An error with its causes, one after the other (the crate's `Display` shows only the first).
fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let c_text = c.to_string();
        // Some causes repeat what their parent already printed.
        if !s.ends_with(&c_text) {
            s.push_str(": ");
            s.push_str(&c_text);
        }
        cause = c.source();
    }
    s
}

/// The points of every scan as they are read, and what is known of each attribute.
#[derive(Default)]
struct Accumulator {
    origin: Option<DVec3>,
    positions: Vec<Vec3>,
    colors: Vec<Vec3>,
    intensity: Vec<f32>,
    station_of: Vec<u32>,
    stations: Vec<DVec3>,
    /// The current scan's station slot, `u32::MAX` when it has none.
    station: u32,
    /// Every scan so far had color / intensity / a station.
    all_color: bool,
    all_intensity: bool,
    all_stations: bool,
    scans: usize,
    no_return: usize,
}

impl Accumulator {
    fn begin_scan(&mut self, station: Option<DVec3>, color: bool, intensity: bool) {
        let first = self.scans == 0;
        self.all_color = color && (first || self.all_color);
        self.all_intensity = intensity && (first || self.all_intensity);
        self.all_stations = station.is_some() && (first || self.all_stations);
        self.station = match station {
            Some(s) => {
                self.stations.push(s);
                self.stations.len() as u32 - 1
            }
            None => u32::MAX,
        };
        self.scans += 1;
    }

    /// Appends a point; why it cannot be, if it cannot.
    fn push(&mut self, p: &e57::Point) -> Result<(), String> {
        let e57::CartesianCoordinate::Valid { x, y, z } = p.cartesian else {
            self.no_return += 1;
            return Ok(());
        };
        let world = DVec3::new(x, y, z);
        let origin = *self.origin.get_or_insert_with(|| round_origin(world));
        let o = offset(world, origin);
        if !world.is_finite() || !o.is_finite() {
            return Err(format!(
                "coordinates ({x}, {y}, {z}) are not finite numbers of metres"
            ));
        }
        self.positions.push(o);
        let rgb = p.color.as_ref().map_or(Vec3::ZERO, |c| {
            Vec3::new(c.red, c.green, c.blue).clamp(Vec3::ZERO, Vec3::ONE)
        });
        self.colors.push(
            rgb.to_array()
                .map(|v| srgb_to_linear(f64::from(v)) as f32)
                .into(),
        );
        self.intensity
            .push(p.intensity.unwrap_or(0.0).clamp(0.0, 1.0));
        self.station_of.push(self.station);
        Ok(())
    }

    fn finish(self) -> PointSet {
        let mut drop_reasons = Vec::new();
        if self.no_return > 0 {
            drop_reasons.push(("no return (invalid coordinate)".to_string(), self.no_return));
        }
        PointSet {
            positions: self.positions,
            origin: self.origin.unwrap_or(DVec3::ZERO),
            colors: self.all_color.then_some(self.colors),
            intensity: self.all_intensity.then_some(self.intensity),
            station_of: self.all_stations.then_some(self.station_of),
            stations: self.stations,
            dropped: self.no_return,
            drop_reasons,
            ..PointSet::default()
        }
    }
}
