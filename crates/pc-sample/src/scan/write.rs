//! Writing a virtual scan as scanners do: LAS 1.2 or LAZ (point format 2: RGB, intensity,
//! class, the station as `point_source_id`, millimetre integers around the georeference), or
//! E57 (one scan per station, spherical coordinates in the scanner's own frame, its pose,
//! 8-bit color, 16-bit intensity). Each file is written to a temporary name and renamed when
//! complete. Beside it, a `scene.toml` in pipeline.toml's schema lights and frames the hall.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter};
use std::path::{Path, PathBuf};

use glam::DVec3;
use pc_artifact::atomic::publish_with;
use pc_artifact::PointLight;
use pc_config::{Albedo, CameraConfig, ImportConfig, MaterialConfig, ModelConfig};
use serde::Serialize;

use super::room::Room;
use super::{scan_station, ScanParams, ScanPoint};

/// The file format of a virtual scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanFormat {
    Las,
    Laz,
    E57,
}

impl ScanFormat {
    pub fn extension(self) -> &'static str {
        match self {
            ScanFormat::Las => "las",
            ScanFormat::Laz => "laz",
            ScanFormat::E57 => "e57",
        }
    }
}

/// LAS coordinates are integers of this many metres.
const LAS_SCALE: f64 = 0.001;

fn other(path: &Path, e: impl std::fmt::Display) -> io::Error {
    io::Error::other(format!("{}: {e}", path.display()))
}

/// Scans the hall with `p` into `path` (its format from `format`), atomically. Returns the
/// number of points written.
pub fn write_scan(room: &Room, p: &ScanParams, format: ScanFormat, path: &Path) -> io::Result<u64> {
    publish_with(path, |tmp| match format {
        ScanFormat::Las | ScanFormat::Laz => write_las(room, p, format == ScanFormat::Laz, tmp),
        ScanFormat::E57 => write_e57(room, p, tmp),
    })
    .map_err(|e| other(path, e))
}

fn write_las(room: &Room, p: &ScanParams, laz: bool, tmp: &Path) -> io::Result<u64> {
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(2).map_err(|e| other(tmp, e))?;
    b.point_format.is_compressed = laz;
    b.generating_software = "pcgi pc-sample scan".into();
    let t = |offset: f64| las::Transform {
        scale: LAS_SCALE,
        offset,
    };
    b.transforms = las::Vector {
        x: t(p.georef.x),
        y: t(p.georef.y),
        z: t(p.georef.z),
    };
    let header = b.into_header().map_err(|e| other(tmp, e))?;
    let file = BufWriter::new(File::create(tmp)?);
    let mut w = las::Writer::new(file, header).map_err(|e| other(tmp, e))?;
    let mut total = 0;
    let mut result = Ok(());
    for s in 0..p.stations.len() {
        result = scan_station(room, p, s, &mut |pts| {
            for q in pts {
                w.write_point(las_point(p, q)).map_err(|e| other(tmp, e))?;
            }
            Ok(())
        })
        .map(|n| total += n);
        if result.is_err() {
            break;
        }
    }
    match result.and_then(|()| w.close().map_err(|e| other(tmp, e))) {
        Ok(()) => Ok(total),
        Err(e) => {
            // The writer's Drop would close again and panic on a second failure.
            std::mem::forget(w);
            Err(e)
        }
    }
}

fn las_point(p: &ScanParams, q: &ScanPoint) -> las::Point {
    let w = p.georef + q.position.as_dvec3();
    let c = q.color.map(|v| u16::from(v) * 257);
    las::Point {
        x: w.x,
        y: w.y,
        z: w.z,
        intensity: q.intensity,
        classification: las::point::Classification::new(q.class)
            .unwrap_or(las::point::Classification::Unclassified),
        point_source_id: q.station,
        color: Some(las::Color::new(c[0], c[1], c[2])),
        ..Default::default()
    }
}

fn write_e57(room: &Room, p: &ScanParams, tmp: &Path) -> io::Result<u64> {
    use e57::{Quaternion, Record, RecordValue, Transform, Translation};
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create_new(true)
        .open(tmp)?;
    let mut e = e57::E57Writer::new(file, "pcgi-virtual-scan").map_err(|x| other(tmp, x))?;
    let mut total = 0;
    for (s, st) in p.stations.iter().enumerate() {
        let proto = vec![
            Record::SPHERICAL_RANGE_F64,
            Record::SPHERICAL_AZIMUTH_F64,
            Record::SPHERICAL_ELEVATION_F64,
            Record::COLOR_RED_U8,
            Record::COLOR_GREEN_U8,
            Record::COLOR_BLUE_U8,
            Record::INTENSITY_U16,
        ];
        let mut pc = e
            .add_pointcloud(&format!("pcgi-virtual-scan-{s}"), proto)
            .map_err(|x| other(tmp, x))?;
        pc.set_name(Some(format!("station {s}")));
        let q = st.rotation();
        let at = p.georef + st.position.as_dvec3();
        pc.set_transform(Some(Transform {
            rotation: Quaternion {
                w: q.w,
                x: q.x,
                y: q.y,
                z: q.z,
            },
            translation: Translation {
                x: at.x,
                y: at.y,
                z: at.z,
            },
        }));
        total += scan_station(room, p, s, &mut |pts| {
            for q in pts {
                let mut v = vec![
                    RecordValue::Double(q.range),
                    RecordValue::Double(wrap_azimuth(q.azimuth)),
                    RecordValue::Double(q.elevation),
                ];
                v.extend(q.color.map(|c| RecordValue::Integer(i64::from(c))));
                v.push(RecordValue::Integer(i64::from(q.intensity)));
                pc.add_point(v).map_err(|x| other(tmp, x))?;
            }
            Ok(())
        })?;
        pc.finalize().map_err(|x| other(tmp, x))?;
    }
    e.finalize().map_err(|x| other(tmp, x))?;
    Ok(total)
}

/// E57 azimuths lie in (-π, π].
fn wrap_azimuth(a: f64) -> f64 {
    if a > std::f64::consts::PI {
        a - 2.0 * std::f64::consts::PI
    } else {
        a
    }
}

/// What the scan's `scene.toml` holds.
#[derive(Serialize)]
struct ScanScene {
    import: ImportConfig,
    materials: BTreeMap<String, MaterialConfig>,
    models: Vec<ModelConfig>,
    lights: Vec<PointLight>,
    camera: CameraConfig,
}

/// Writes `scene.toml` beside the scan `file` (a name in `dir`): the scan as one model whose
/// albedo is its colors, the scanners where they stood, the scene's origin at the georeference
/// (so the camera and the lights are in the hall's own metres), the sun above the skylight and
/// a camera looking at the niche.
pub fn write_scan_scene(
    dir: &Path,
    file: &str,
    p: &ScanParams,
    format: ScanFormat,
) -> io::Result<PathBuf> {
    let scanners = (format != ScanFormat::E57).then(|| {
        p.stations
            .iter()
            .map(|s| {
                // f32 positions printed as the decimals they were written as
                let at = (s.position.as_dvec3() * 1e6).round() / 1e6;
                (p.georef + at).to_array()
            })
            .collect()
    });
    let scene = ScanScene {
        import: ImportConfig {
            origin: Some(p.georef.to_array()),
            // What docs/import.md's checklist asks of a terrestrial scan: returns closer than
            // the range noise are one surface point. Where a station's rings converge
            // (straight above it) they are closer than that, and the normals fitted through
            // them tilt.
            merge_distance: (p.noise > 0.0).then_some(p.noise as f32),
            ..ImportConfig::default()
        },
        materials: BTreeMap::from([(
            "scan".to_string(),
            MaterialConfig::Diffuse {
                albedo: Albedo::Source("vertex".into()),
            },
        )]),
        models: vec![ModelConfig {
            file: file.into(),
            material: "scan".into(),
            scanners,
            ..ModelConfig::default()
        }],
        lights: vec![
            // The sun, high above the skylight, and a small lamp before the niche.
            PointLight::new([1.8, -0.6, 40.0], [16_000.0, 15_000.0, 13_000.0]),
            PointLight::new([0.0, 2.6, 3.2], [1.2, 1.0, 0.7]),
        ],
        camera: CameraConfig {
            origin: [-0.4, -3.6, 1.7],
            target: [0.0, 4.4, 1.5],
            up: [0.0, 0.0, 1.0],
            fov: 75.0,
            width: 640,
            height: 480,
            ..CameraConfig::default()
        },
    };
    let text = toml::to_string(&scene).map_err(io::Error::other)?;
    let g: DVec3 = p.georef;
    let head = format!(
        "# generated by pc-sample scan: {} points from {} stations, seed {}, georeference ({}, {}, {})\n\n",
        p.points,
        p.stations.len(),
        p.seed,
        g.x,
        g.y,
        g.z
    );
    let path = dir.join("scene.toml");
    pc_artifact::write_file_atomically(&path, format!("{head}{text}").as_bytes())?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pc_import::points::{read_points, PlyOptions};

    /// What the scanner generated, for comparison with what the readers give back.
    fn generated(p: &ScanParams) -> Vec<ScanPoint> {
        let room = Room::hall();
        let mut all = Vec::new();
        for s in 0..p.stations.len() {
            scan_station(&room, p, s, &mut |pts| {
                all.extend_from_slice(pts);
                Ok(())
            })
            .unwrap();
        }
        all
    }

    #[test]
    fn every_format_reads_back_as_it_was_scanned() {
        let dir = tempfile::tempdir().unwrap();
        let p = ScanParams::hall(5_000, 4);
        let want = generated(&p);
        for format in [ScanFormat::Las, ScanFormat::Laz, ScanFormat::E57] {
            let path = dir.path().join(format!("hall.{}", format.extension()));
            assert_eq!(write_scan(&Room::hall(), &p, format, &path).unwrap(), 5_000);
            let got = read_points(&path, &PlyOptions::default()).unwrap();
            assert_eq!(got.len(), want.len(), "{format:?}");
            // LAS keeps millimetre integers; E57 doubles.
            let tol = if format == ScanFormat::E57 {
                1e-4
            } else {
                0.5e-3 + 1e-5
            };
            for (i, q) in want.iter().enumerate() {
                let file = got.origin + got.positions[i].as_dvec3();
                let expect = p.georef + q.position.as_dvec3();
                let d = (file - expect).abs().max_element();
                assert!(d <= tol, "{format:?} point {i}: off by {d}");
            }
            let colors = got.colors.as_ref().expect("the scan has color");
            let srgb = |c: u8| pc_import::points::srgb_to_linear(f64::from(c) / 255.0) as f32;
            for (q, c) in want.iter().zip(colors) {
                assert!((c.x - srgb(q.color[0])).abs() < 1e-3, "{format:?}");
            }
            match format {
                ScanFormat::E57 => {
                    // Each scan's pose gives its station.
                    assert_eq!(got.stations.len(), 3);
                    for (s, st) in p.stations.iter().enumerate() {
                        let at = p.georef + st.position.as_dvec3();
                        assert!((got.stations[s] - at).length() < 1e-6);
                    }
                    let of = got.station_of.as_ref().unwrap();
                    assert!(want.iter().zip(of).all(|(q, &s)| u32::from(q.station) == s));
                }
                _ => {
                    let ids = got.source_ids.as_ref().unwrap();
                    assert!(want.iter().zip(ids).all(|(q, &s)| q.station == s));
                    let classes = got.classes.as_ref().unwrap();
                    assert!(want.iter().zip(classes).all(|(q, &c)| q.class == c));
                }
            }
        }
        // The scene file loads with its scan and faces every normal to the right scanner.
        let toml = write_scan_scene(dir.path(), "hall.laz", &p, ScanFormat::Laz).unwrap();
        let cfg = pc_config::load_config(&toml, &[]).unwrap();
        // Returns closer than the range noise are merged (none are, this sparse).
        assert_eq!(cfg.config.import.merge_distance, Some(p.noise as f32));
        let scene = pc_import::load::load_scene(&cfg, &mut |_, _| {}).unwrap();
        assert_eq!(scene.splats.len(), 5_000);
        assert_eq!(scene.origin, p.georef);
        for (i, q) in want.iter().enumerate() {
            let st = p.stations[q.station as usize].position;
            let n = scene.splats.normals[i];
            assert!(n.dot(st - scene.splats.positions[i]) >= 0.0, "point {i}");
        }
    }
}
