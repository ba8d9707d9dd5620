//! examples/Makefile, run by make as a user's script would: the five stage binaries with
//! their dependencies, nothing to do the second time, and after a camera edit only the render
//! does work (the other stages, asked by make, find their artifacts up to date).

use std::path::Path;
use std::process::Command;

use pcgi_tests::{bin, bin_dir, sampled_cornell, temp_dir, workspace_root};

fn make(dir: &Path, extra: &[&str]) -> (bool, String, String) {
    let makefile = workspace_root().join("examples").join("Makefile");
    let scene: Vec<String> = std::fs::read_dir(dir.join("scene"))
        .unwrap()
        .map(|e| format!("scene/{}", e.unwrap().file_name().to_string_lossy()))
        .collect();
    let out = Command::new("make")
        .arg("-f")
        .arg(&makefile)
        .arg("CONFIG=pipeline.toml")
        .arg("OUT=out")
        .arg(format!("SCENE={}", scene.join(" ")))
        .arg(format!("BIN={}", bin_dir().display()))
        .args(extra)
        .current_dir(dir)
        .output()
        .expect("make is installed (.ci/run installs it)");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn config(fov: f32) -> String {
    format!(
        "include = [\"scene/scene.toml\"]\n[output]\ndir = \"out\"\n[vmap]\nleaf_splats = 16\n\
         [fmm]\nemitter_samples = 8\n[caustics]\nphotons = 50000\n[camera]\norigin = [0, 0, 3.9]\n\
         target = [0, 0, 0]\nfov = {fov}\nwidth = 24\nheight = 24\n[raytrace]\nspp = 1\n"
    )
}

#[test]
fn the_example_makefile_drives_the_stages_with_their_dependencies() {
    bin("pc-run"); // builds the stage binaries
    let dir = temp_dir();
    let d = dir.path();
    sampled_cornell(d, 4000, true, "");
    std::fs::write(d.join("pipeline.toml"), config(39.3)).unwrap();

    let (ok, out, err) = make(d, &[]);
    assert!(ok, "make failed:\n{out}\n{err}");
    for stage in [
        "pc-octree",
        "pc-vmap",
        "pc-caustics",
        "pc-fmm",
        "pc-raytrace",
    ] {
        assert!(
            out.contains(&format!("{stage}: wrote")),
            "{stage} did not run:\n{out}"
        );
    }
    assert!(d.join("out/image.exr").is_file() && d.join("out/image.png").is_file());

    let (ok, out, _) = make(d, &[]);
    assert!(ok && out.contains("Nothing to be done"), "{out}");

    // A camera edit: make reruns every recipe (the config is newer); only the render works.
    std::thread::sleep(std::time::Duration::from_millis(1100)); // mtime granularity
    std::fs::write(d.join("pipeline.toml"), config(30.0)).unwrap();
    let (ok, out, err) = make(d, &[]);
    assert!(ok, "{out}\n{err}");
    for stage in ["pc-octree", "pc-vmap", "pc-caustics", "pc-fmm"] {
        assert!(
            out.contains(&format!("{stage}: ")) && !out.contains(&format!("{stage}: wrote")),
            "{stage} should be up to date:\n{out}"
        );
        assert!(out.contains("is up to date"), "{out}");
    }
    assert!(out.contains("pc-raytrace: wrote"), "{out}");
    let (ok, out, _) = make(d, &["-q"]);
    assert!(ok, "make -q: everything is up to date again:\n{out}");

    let (ok, out, err) = make(d, &["inspect"]);
    assert!(ok, "{out}\n{err}");
    for kind in ["octree", "vmap", "photons", "radiosity"] {
        assert!(out.contains(kind), "pc-inspect {kind}:\n{out}");
    }
}
