//! pc-octree on bad input (broken PLYs, bad configs): exit code 2, a message naming the file and the problem, nothing written.

use std::path::Path;

use pc_import::ply_write::PlyFormat;
use pcgi_tests::{
    args, assert_nothing_written, pc_inspect, pc_octree, temp_dir, write_pipeline, Grid, Vec3,
};

/// Write `bad.ply` with `write`, run pc-octree on a config naming it, and check the failure:
/// exit 2, stderr names the PLY (its full path) and each of `needles`, nothing written.
/// Returns stderr.
#[track_caller]
fn fails_on_ply(write: impl FnOnce(&Path), needles: &[&str]) -> String {
    let dir = temp_dir();
    let ply = dir.path().join("bad.ply");
    write(&ply);
    let cfg = write_pipeline(dir.path(), &["bad.ply"], "");
    let ply_name = ply.display().to_string();
    let mut all = vec![ply_name.as_str()];
    all.extend_from_slice(needles);
    let err = pc_octree(args!["--config", cfg, "--quiet"]).error(&all);
    assert_nothing_written(dir.path());
    err
}

/// A 4 × 4 grid with `edit` applied, written as binary little-endian PLY.
fn grid_with(edit: impl FnOnce(&mut Grid)) -> impl FnOnce(&Path) {
    move |path| {
        let mut g = Grid::new(4);
        edit(&mut g);
        g.write(path, PlyFormat::BinaryLittleEndian);
    }
}

fn text(s: &'static str) -> impl FnOnce(&Path) {
    move |path| std::fs::write(path, s).unwrap()
}

#[test]
fn malformed_header() {
    let err = fails_on_ply(
        text("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty flaot x\nend_header\n"),
        &["header", "flaot"],
    );
    assert!(
        err.to_lowercase().contains("line 4"),
        "names the line: {err}"
    );
}

#[test]
fn not_a_ply_file() {
    fails_on_ply(text("solid cube\nfacet normal 0 0 1\n"), &["header"]);
}

#[test]
fn missing_y_property() {
    fails_on_ply(
        text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float z\nend_header\n0 0\n1 0\n0 1\n"),
        &["no `y` property"],
    );
}

#[test]
fn nan_coordinate_at_vertex_3() {
    fails_on_ply(
        grid_with(|g| g.positions[3].x = f32::NAN),
        &["vertex 3", "`x`", "NaN"],
    );
}

#[test]
fn nan_coordinate_in_ascii() {
    fails_on_ply(
        |path| {
            let mut g = Grid::new(3);
            g.positions[2].z = f32::NAN;
            g.write(path, PlyFormat::Ascii);
        },
        &["vertex 2", "`z`", "NaN"],
    );
}

#[test]
fn zero_length_normal() {
    fails_on_ply(
        grid_with(|g| g.normals[5] = Vec3::ZERO),
        &["vertex 5", "normal has zero length"],
    );
}

#[test]
fn negative_radius() {
    fails_on_ply(
        grid_with(|g| g.radii[7] = -0.5),
        &["vertex 7", "radius -0.5", "not a positive"],
    );
}

#[test]
fn empty_model() {
    fails_on_ply(
        |path| Grid::new(0).write(path, PlyFormat::BinaryLittleEndian),
        &["no points"],
    );
}

#[test]
fn truncated_binary_body() {
    fails_on_ply(
        |path| {
            Grid::new(4).write(path, PlyFormat::BinaryLittleEndian);
            let len = std::fs::metadata(path).unwrap().len();
            let f = std::fs::OpenOptions::new().write(true).open(path).unwrap();
            // 16 vertices of 7 floats (28 bytes): cut into the last one.
            f.set_len(len - 10).unwrap();
        },
        &["body ends after 15 of 16 vertices"],
    );
}

#[test]
fn list_property_where_x_is_expected() {
    fails_on_ply(
        text("ply\nformat ascii 1.0\nelement vertex 2\nproperty list uchar float x\nproperty float y\nproperty float z\nend_header\n1 0.5 0 0\n1 0.5 1 0\n"),
        &["`x` is a list"],
    );
}

#[test]
fn nonexistent_ply() {
    let dir = temp_dir();
    let cfg = write_pipeline(dir.path(), &["missing.ply"], "");
    let missing = dir.path().join("missing.ply").display().to_string();
    let err = pc_octree(args!["--config", cfg, "--quiet"]).error(&[&missing]);
    #[cfg(unix)]
    assert!(err.contains("No such file or directory"), "{err}");
    let _ = err;
    assert_nothing_written(dir.path());
}

/// A valid model, a config with `extra` appended and `--set` overrides; the run must fail
/// naming the config file and each of `needles`.
#[track_caller]
fn fails_on_config(models: &[&str], extra: &str, sets: &[&str], needles: &[&str]) -> String {
    let dir = temp_dir();
    Grid::new(4).write(&dir.path().join("grid.ply"), PlyFormat::BinaryLittleEndian);
    let cfg = write_pipeline(dir.path(), models, extra);
    let mut argv = args!["--config", cfg, "--quiet"];
    for s in sets {
        argv.extend(args!["--set", s]);
    }
    let cfg_name = cfg.display().to_string();
    let mut all = vec![cfg_name.as_str()];
    all.extend_from_slice(needles);
    let err = pc_octree(argv).error(&all);
    assert_nothing_written(dir.path());
    err
}

#[test]
fn unknown_material() {
    let err = fails_on_config(
        &[],
        "[[models]]\nfile = \"grid.ply\"\nmaterial = \"chalk\"\n",
        &[],
        &["`chalk`", "not defined", "white"],
    );
    assert!(err.contains("grid.ply"), "the model is named too: {err}");
}

#[test]
fn unknown_config_key() {
    fails_on_config(
        &["grid.ply"],
        "[octree]\nmax_leaf_point = 3\n",
        &[],
        &["max_leaf_point"],
    );
}

#[test]
fn set_with_a_bad_path() {
    fails_on_config(
        &["grid.ply"],
        "",
        &["models.9.material=x"],
        &["models.9.material=x", "index 9 is out of range"],
    );
}

#[test]
fn set_with_a_bad_value() {
    fails_on_config(
        &["grid.ply"],
        "",
        &["octree.max_leaf_points=0"],
        &["max_leaf_points must be at least 1"],
    );
}

#[test]
fn config_without_models() {
    fails_on_config(&[], "", &[], &["no models"]);
}

#[test]
fn missing_config_file() {
    let dir = temp_dir();
    let cfg = dir.path().join("nope.toml");
    let name = cfg.display().to_string();
    let err = pc_octree(args!["--config", cfg, "--quiet"]).error(&[&name]);
    // The OS reason, once (SceneError::Io used to print it in its message and as its source).
    #[cfg(unix)]
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
    let _ = err;
    assert_nothing_written(dir.path());
    assert!(!dir.path().join("out").exists());
}

#[test]
fn drop_invalid_skips_the_nan_point_and_says_so() {
    let dir = temp_dir();
    let mut g = Grid::new(4);
    g.positions[3].x = f32::NAN;
    g.write(&dir.path().join("bad.ply"), PlyFormat::BinaryLittleEndian);
    let cfg = write_pipeline(dir.path(), &["bad.ply"], "");
    let out = pc_octree(args![
        "--config",
        cfg,
        "--quiet",
        "--set",
        "import.drop_invalid=true"
    ])
    .success();
    assert!(out.stdout.contains("(15 splats,"), "{out:?}");
    assert!(out.stdout.contains("left out 1 point)"), "{out:?}");
    assert!(out.stdout.contains("1 left out (1 "), "{out:?}");
    let artifact = dir.path().join("out").join("octree.pcgi");
    let out = pc_inspect(args![artifact, "--verify", "--metadata"]).success();
    assert!(out.stdout.contains("\"dropped_points\": 1"), "{out:?}");
    assert!(out.stdout.contains("15 splats located"), "{out:?}");
}
