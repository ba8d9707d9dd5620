//! End-to-end tests: pc-sample, pc-octree and pc-inspect run as a user runs them, on real files.
//!
//! Helpers (binary paths, temporary scenes, running commands) are in tests/src/lib.rs.

mod bad_input;
mod caustics_cli;
mod fmm_cli;
mod inspect;
mod kill;
mod makefile;
mod octree_cli;
mod raytrace_cli;
mod reference;
mod robustness;
mod run_cli;
mod scan_cli;
mod vmap_cli;

use std::path::{Path, PathBuf};

use pcgi_tests::{args, pc_octree, write_pipeline, Grid};

/// A one-model scene (a 16 × 16 grid of splats) in `dir`, its pipeline.toml, and the artifact
/// pc-octree built from it in `dir/out/octree.pcgi`.
pub fn small_artifact(dir: &Path) -> (PathBuf, PathBuf) {
    Grid::new(16).write(&dir.join("grid.ply"), Default::default());
    let cfg = write_pipeline(dir, &["grid.ply"], "");
    pc_octree(args!["--config", cfg, "--quiet"]).success();
    let artifact = dir.join("out").join("octree.pcgi");
    assert!(artifact.is_file(), "{}: not written", artifact.display());
    (cfg, artifact)
}
