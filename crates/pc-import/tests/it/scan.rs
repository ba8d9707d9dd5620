//! The scan readers (LAS, LAZ, E57) on real files (tests/data/scans, README there), good and
//! broken: every point read with its f64 coordinate kept, colors, intensity, classes and
//! stations where the file has them, and a clear error naming the file for every bad one.

use std::path::{Path, PathBuf};

use glam::DVec3;
use pc_import::points::{read_points, Format, PlyOptions, PointSet};
use pc_import::ImportError;

fn scan(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/scans")
        .join(name)
}

fn read(name: &str) -> PointSet {
    read_points(&scan(name), &PlyOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn error(path: &Path) -> String {
    let e = read_points(path, &PlyOptions::default()).expect_err("the file must be refused");
    assert_eq!(e.path(), path, "the error names the file: {e}");
    e.to_string()
}

/// Every point of a LAS/LAZ file as the `las` crate reads it, in f64.
fn las_points(path: &Path) -> Vec<las::Point> {
    let mut r = las::Reader::from_path(path).unwrap();
    r.points().map(|p| p.unwrap()).collect()
}

/// The f64 coordinates of a point set, `origin + offset`.
fn world(pts: &PointSet, i: usize) -> DVec3 {
    pts.origin + pts.positions[i].as_dvec3()
}

#[test]
fn formats_follow_the_extension() {
    for (name, f) in [
        ("a.ply", Format::Ply),
        ("a.LAS", Format::Las),
        ("a.laz", Format::Las),
        ("a.E57", Format::E57),
    ] {
        assert_eq!(Format::of(Path::new(name)).unwrap(), f, "{name}");
    }
    let e = Format::of(Path::new("scans/room.xyz")).unwrap_err();
    assert_eq!(
        e.to_string(),
        "scans/room.xyz: unknown model format \"xyz\": pcgi reads .ply, .las, .laz and .e57 files"
    );
}

/// Georeferenced coordinates (hundreds of thousands to millions of metres) survive: each
/// point's `origin + offset` is the file's f64 coordinate to well within half the file's own
/// scale factor, though the offsets are f32, so quantizing it back with the file's scale and
/// offset gives the stored integer exactly (the LAS round trip).
#[test]
fn las_and_laz_keep_georeferenced_coordinates() {
    for name in ["autzen.las", "32-1-472-150-76.laz", "extrabytes.laz"] {
        let path = scan(name);
        let pts = read(name);
        let want = las_points(&path);
        assert_eq!(pts.len(), want.len(), "{name}");
        let header = las::Reader::from_path(&path).unwrap().header().clone();
        let t = header.transforms();
        let scale = t.x.scale.max(t.y.scale).max(t.z.scale);
        let mut worst = 0.0f64;
        for (i, p) in want.iter().enumerate() {
            let w = world(&pts, i);
            let d = (w - DVec3::new(p.x, p.y, p.z)).abs().max_element();
            worst = worst.max(d);
            let q = |v: f64, t: &las::Transform| ((v - t.offset) / t.scale).round();
            let raw = |v: f64, t: &las::Transform| ((v - t.offset) / t.scale).round();
            assert_eq!(
                [q(w.x, &t.x), q(w.y, &t.y), q(w.z, &t.z)],
                [raw(p.x, &t.x), raw(p.y, &t.y), raw(p.z, &t.z)],
                "{name} point {i}: the stored integers come back"
            );
        }
        assert!(
            worst < scale * 0.05,
            "{name}: worst coordinate error {worst} m, scale factor {scale}"
        );
        let classes = pts.classes.as_ref().expect("LAS has classes");
        for (i, p) in want.iter().enumerate() {
            assert_eq!(classes[i], u8::from(p.classification), "{name} point {i}");
        }
        if let Some(i) = &pts.intensity {
            assert!(i.iter().all(|v| (0.0..=1.0).contains(v)), "{name}");
            assert_eq!(
                i.iter().cloned().fold(0.0, f32::max),
                1.0,
                "{name}: per-file normalised"
            );
        }
    }
    // The tile's coordinates are far from zero: an f32 alone would lose centimetres.
    let tile = read("32-1-472-150-76.laz");
    assert!(tile.origin.abs().max_element() > 1e5, "{}", tile.origin);
    assert_eq!(
        tile.origin,
        tile.origin.round(),
        "the origin is rounded to whole metres"
    );
}

#[test]
fn las_colors_are_decoded_to_linear() {
    let path = scan("extrabytes.laz");
    let want = las_points(&path);
    let pts = read("extrabytes.laz");
    let colors = pts.colors.as_ref().expect("the file has RGB");
    let max = want
        .iter()
        .filter_map(|p| p.color)
        .map(|c| c.red.max(c.green).max(c.blue))
        .max()
        .unwrap();
    let full = if max <= 255 { 255.0 } else { 65535.0 };
    for (p, c) in want.iter().zip(colors) {
        let r = f64::from(p.color.unwrap().red) / full;
        let lin = if r <= 0.04045 {
            r / 12.92
        } else {
            ((r + 0.055) / 1.055).powf(2.4)
        };
        assert!((f64::from(c.x) - lin).abs() < 1e-5, "{} vs {lin}", c.x);
    }
}

#[test]
fn e57_reads_cartesian_spherical_and_color() {
    let bunny = read("bunnyFloat.e57");
    assert!(bunny.len() > 20_000, "{}", bunny.len());
    assert!(bunny.colors.is_none() && bunny.normals.is_none());

    let rgb = read("tinyCartesianFloatRgb.e57");
    let colors = rgb.colors.as_ref().expect("the file has RGB");
    assert!(colors
        .iter()
        .all(|c| c.min_element() >= 0.0 && c.max_element() <= 1.0));
    assert!(colors.iter().any(|c| c.max_element() > 0.0));

    // Spherical coordinates: converted, and the scan's frame origin is its scanner.
    let sph = read("tiny_spherical.e57");
    assert!(!sph.is_empty());
    let of = sph
        .station_of
        .as_ref()
        .expect("a spherical scan knows its station");
    assert_eq!(of.len(), sph.len());
    assert_eq!(sph.stations.len(), 1);
}

/// E57 points agree with what the `e57` crate itself gives, pose applied, in f64.
#[test]
fn e57_coordinates_match_the_crate() {
    for name in [
        "bunnyFloat.e57",
        "tinyCartesianFloatRgb.e57",
        "tiny_spherical.e57",
    ] {
        let pts = read(name);
        let mut r = e57::E57Reader::from_file(scan(name)).unwrap();
        let mut i = 0;
        for pc in r.pointclouds() {
            for p in r.pointcloud_simple(&pc).unwrap() {
                if let e57::CartesianCoordinate::Valid { x, y, z } = p.unwrap().cartesian {
                    let d = (world(&pts, i) - DVec3::new(x, y, z)).abs().max_element();
                    assert!(d < 1e-5, "{name} point {i}: off by {d}");
                    i += 1;
                }
            }
        }
        assert_eq!(i, pts.len(), "{name}");
    }
}

#[test]
fn a_page_with_a_wrong_checksum_is_refused() {
    let path = scan("corrupt_crc.e57");
    let msg = error(&path);
    assert!(msg.contains("E57 file:"), "{msg}");
    assert!(
        msg.to_lowercase().contains("crc") || msg.contains("checksum"),
        "{msg}"
    );
}

#[test]
fn an_empty_point_cloud_is_refused() {
    let path = scan("empty_pc.e57");
    let msg = error(&path);
    assert!(msg.ends_with("the model has no points"), "{msg}");
}

#[test]
fn a_truncated_laz_names_the_point_it_stopped_at() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(scan("32-1-472-150-76.laz")).unwrap();
    for keep in [bytes.len() / 2, bytes.len() - 100, 400] {
        let path = dir.path().join("cut.laz");
        std::fs::write(&path, &bytes[..keep]).unwrap();
        let msg = error(&path);
        assert!(
            msg.contains("LAZ file:") || msg.contains("LAS file:"),
            "{keep}: {msg}"
        );
    }
}

#[test]
fn las_header_counts_must_match_the_body() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(scan("autzen.las")).unwrap();
    let n = las_points(&scan("autzen.las")).len();
    let path = dir.path().join("cut.las");
    // One record short.
    let record = u16::from_le_bytes([bytes[105], bytes[106]]) as usize;
    std::fs::write(&path, &bytes[..bytes.len() - record]).unwrap();
    let msg = error(&path);
    assert!(
        msg.contains(&format!("the header announces {n} points"))
            && msg.contains(&format!("the body holds {}", n - 1))
            && msg.contains("truncated"),
        "{msg}"
    );
    // Two records more than the header says.
    let mut long = bytes.clone();
    long.extend_from_slice(&bytes[bytes.len() - 2 * record..]);
    std::fs::write(&path, &long).unwrap();
    let msg = error(&path);
    assert!(msg.contains(&format!("the body holds {}", n + 2)), "{msg}");
    // A header cut short.
    std::fs::write(&path, &bytes[..50]).unwrap();
    let msg = error(&path);
    assert!(msg.contains("LAS file: header"), "{msg}");
}

#[test]
fn garbage_with_a_scan_extension_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["noise.las", "noise.laz", "noise.e57"] {
        let path = dir.path().join(name);
        std::fs::write(&path, vec![0x5a_u8; 4096]).unwrap();
        let msg = error(&path);
        assert!(msg.contains(" file: "), "{name}: {msg}");
    }
    let e = read_points(&dir.path().join("missing.e57"), &PlyOptions::default()).unwrap_err();
    assert!(matches!(e, ImportError::Io { .. }), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Scans in a scene: materials per class, albedo from color or intensity, the origin, the
// stations, cleaning.

use pc_import::load::{load_scene, AlbedoSource, LoadedScene, Oriented};

fn scene(models: &str, import: &str) -> LoadedScene {
    try_scene(models, import).unwrap_or_else(|e| panic!("{e}"))
}

fn try_scene(models: &str, import: &str) -> Result<LoadedScene, String> {
    let text = format!(
        "{models}\n[materials.grey]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
         [materials.scan]\ntype = \"diffuse\"\nalbedo = \"vertex\"\n\
         [materials.ground]\ntype = \"diffuse\"\nalbedo = [0.3, 0.25, 0.2]\n\
         [import]\n{import}\n"
    );
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/scans");
    let cfg = pc_config::parse_config(&text, &dir).map_err(|e| e.to_string())?;
    load_scene(&cfg, &mut |_, _| {}).map_err(|e| e.to_string())
}

#[test]
fn las_classes_pick_materials_and_the_origin_is_the_bounds_centre() {
    let s = scene(
        "[[models]]\nfile = \"32-1-472-150-76.laz\"\nmaterial = \"grey\"\nclasses = { \"2\" = \"ground\" }\n",
        "",
    );
    let names: Vec<&str> = s.materials.iter().map(|(n, _)| n.as_str()).collect();
    let ground = names.iter().position(|n| *n == "ground").unwrap() as u32;
    let grey = names.iter().position(|n| *n == "grey").unwrap() as u32;
    let want = las_points(&scan("32-1-472-150-76.laz"));
    for (p, &m) in want.iter().zip(&s.splats.material) {
        let expect = if u8::from(p.classification) == 2 {
            ground
        } else {
            grey
        };
        assert_eq!(m, expect);
    }
    assert!(s.splats.material.contains(&ground) && s.splats.material.contains(&grey));
    // Origin: the bounds' centre, rounded; splats sit around it.
    let pts = read("32-1-472-150-76.laz");
    let (lo, hi) = pts.bounds().unwrap();
    assert_eq!(s.origin, ((lo + hi) * 0.5).round());
    for (i, p) in want.iter().enumerate() {
        let w = s.origin + s.splats.positions[i].as_dvec3();
        assert!(
            (w - DVec3::new(p.x, p.y, p.z)).abs().max_element() < 0.005,
            "point {i}"
        );
    }
    // import.origin overrides it.
    let s = scene(
        "[[models]]\nfile = \"autzen.las\"\nmaterial = \"grey\"\n",
        "origin = [637000.0, 851000.0, 450.0]",
    );
    assert_eq!(s.origin, DVec3::new(637000.0, 851000.0, 450.0));
}

#[test]
fn vertex_albedo_comes_from_color_or_intensity_and_is_clamped() {
    let s = scene(
        "[[models]]\nfile = \"extrabytes.laz\"\nmaterial = \"scan\"\nalbedo_scale = 4.0\n",
        "",
    );
    let m = &s.models[0];
    assert_eq!(m.albedo_from, Some(AlbedoSource::Color));
    let max = pc_config::MAX_ALBEDO;
    assert!(s.splats.albedo.iter().all(|a| a.max_element() <= max));
    let clamped = s
        .splats
        .albedo
        .iter()
        .filter(|a| a.max_element() == max)
        .count();
    assert_eq!(m.albedo_clamped, clamped);
    assert!(clamped > 0 && clamped < s.splats.len(), "{clamped}");
    assert!(
        m.describe().contains(&format!("{clamped} albedos clamped")),
        "{}",
        m.describe()
    );
    // Without color: the normalized intensity, as grey.
    let s = scene(
        "[[models]]\nfile = \"autzen.las\"\nmaterial = \"scan\"\n",
        "",
    );
    assert_eq!(s.models[0].albedo_from, Some(AlbedoSource::Intensity));
    let pts = read("autzen.las");
    for (a, i) in s.splats.albedo.iter().zip(pts.intensity.unwrap()) {
        assert_eq!(*a, glam::Vec3::splat(i.min(max)));
    }
    // Neither: refused.
    let e = try_scene(
        "[[models]]\nfile = \"bunnyFloat.e57\"\nmaterial = \"scan\"\n",
        "",
    )
    .unwrap_err();
    assert!(e.contains("bunnyFloat.e57") && e.contains("`red`"), "{e}");
}

#[test]
fn estimated_normals_face_the_scanner() {
    // The E57 spherical scan: every normal faces its station.
    let s = scene(
        "[[models]]\nfile = \"tiny_spherical.e57\"\nmaterial = \"grey\"\n",
        "",
    );
    assert_eq!(s.models[0].oriented, Oriented::Stations(1));
    let pts = read("tiny_spherical.e57");
    let station = (pts.stations[0] - s.origin).as_vec3();
    for (p, n) in s.splats.positions.iter().zip(&s.splats.normals) {
        assert!(n.dot(station - *p) >= 0.0);
    }
    // A LAS tile with a `scanner` high above it: every normal points up to it.
    let s = scene(
        "[[models]]\nfile = \"32-1-472-150-76.laz\"\nmaterial = \"grey\"\nscanners = [[326800.0, 6724186.0, 5000.0]]\n",
        "",
    );
    assert_eq!(s.models[0].oriented, Oriented::Scanner);
    let up = (DVec3::new(326800.0, 6724186.0, 5000.0) - s.origin).as_vec3();
    for (p, n) in s.splats.positions.iter().zip(&s.splats.normals) {
        assert!(n.dot(up - *p) >= 0.0);
    }
}

#[test]
fn duplicates_merge_and_outliers_go_with_counts() {
    let base = scene(
        "[[models]]\nfile = \"bunnyFloat.e57\"\nmaterial = \"grey\"\n",
        "",
    );
    let n = base.splats.len();
    let s = scene(
        "[[models]]\nfile = \"bunnyFloat.e57\"\nmaterial = \"grey\"\n",
        "merge_distance = 0.002\noutliers = { neighbors = 8, std_ratio = 2.0 }",
    );
    let m = &s.models[0];
    let merged = m
        .drop_reasons
        .iter()
        .find(|(r, _)| r == "duplicates merged")
        .unwrap()
        .1;
    let outliers = m
        .drop_reasons
        .iter()
        .find(|(r, _)| r == "statistical outliers")
        .unwrap()
        .1;
    assert!(merged > 0 && outliers > 0, "{:?}", m.drop_reasons);
    assert_eq!(s.splats.len() + merged + outliers, n);
    assert_eq!(m.points, s.splats.len());
    assert!(
        m.describe()
            .contains(&format!("{merged} duplicates merged")),
        "{}",
        m.describe()
    );
    // Kept points are at least the merge distance apart.
    let pts = &s.splats.positions;
    let probe = pts.len().min(300);
    for i in 0..probe {
        for j in 0..pts.len() {
            if i != j {
                assert!(pts[i].distance(pts[j]) >= 0.002 * 0.999, "{i} {j}");
            }
        }
    }
    // Bad values are refused by the config.
    let e = try_scene(
        "[[models]]\nfile = \"bunnyFloat.e57\"\nmaterial = \"grey\"\n",
        "outliers = { neighbors = 1 }",
    )
    .unwrap_err();
    assert!(e.contains("import.outliers.neighbors"), "{e}");
}

#[test]
fn neighbours_on_real_scans_match_brute_force() {
    // Real coordinates are quantised (LAS: integers times a scale), so distances tie often,
    // and scan lines make the density uneven: the search's 16 nearest must have brute
    // force's distances (a tied k-th place may name another point). Every 7th point is
    // checked, against every other point of the file.
    use pc_import::knn::Knn;
    for name in ["32-1-472-150-76.laz", "autzen.las", "bunnyFloat.e57"] {
        let p = read(name).positions;
        let k = 16;
        let got = Knn::new(&p).map(k, |_, near| {
            let mut d = [f32::NAN; 16];
            for (d, &(_, d2)) in d.iter_mut().zip(near) {
                *d = d2;
            }
            (near.len(), d)
        });
        for i in (0..p.len()).step_by(7) {
            let mut all: Vec<f32> = (0..p.len())
                .filter(|&j| j != i)
                .map(|j| {
                    let e = p[j] - p[i];
                    e.x * e.x + e.y * e.y + e.z * e.z
                })
                .collect();
            if all.len() > k {
                all.select_nth_unstable_by(k, f32::total_cmp);
                all.truncate(k);
            }
            all.sort_by(f32::total_cmp);
            let (len, d) = got[i];
            assert_eq!(&d[..len], &all[..], "{name}: point {i} of {}", p.len());
        }
    }
}
