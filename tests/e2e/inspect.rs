//! pc-inspect on stale or corrupt artifacts: exit code 2 and a message naming the file and the problem, never a crash.

use std::path::Path;

use pc_artifact::octree::sections;
use pc_artifact::Artifact;
use pcgi_tests::{args, pc_inspect, temp_dir};

/// pc-inspect --verify on `artifact` must fail naming it and each of `needles`.
#[track_caller]
fn inspect_fails(artifact: &Path, needles: &[&str]) -> String {
    let name = artifact.display().to_string();
    let mut all = vec![name.as_str()];
    all.extend_from_slice(needles);
    pc_inspect(args![artifact, "--verify"]).error(&all)
}

#[test]
fn a_fresh_artifact_verifies() {
    let dir = temp_dir();
    let (_, artifact) = crate::small_artifact(dir.path());
    let out = pc_inspect(args![artifact, "--verify"]).success();
    assert!(
        out.stdout
            .contains(&format!("{}: ok (", artifact.display())),
        "{out:?}"
    );
}

#[test]
fn truncated_artifacts() {
    let dir = temp_dir();
    let (_, artifact) = crate::small_artifact(dir.path());
    let full = std::fs::read(&artifact).unwrap();
    // Into the section table, into the header, and nothing at all.
    for keep in [full.len() - 10, 100, 0] {
        std::fs::write(&artifact, &full[..keep]).unwrap();
        let err = inspect_fails(&artifact, &["truncated"]);
        assert!(
            err.contains(&format!("the file has {keep}")),
            "kept {keep} bytes: {err}"
        );
    }
}

#[test]
fn a_flipped_byte_is_a_checksum_error() {
    let dir = temp_dir();
    let (_, artifact) = crate::small_artifact(dir.path());
    let splats = Artifact::open(&artifact)
        .unwrap()
        .section_info(sections::SPLATS)
        .expect("a splats section")
        .clone();
    let mut bytes = std::fs::read(&artifact).unwrap();
    let middle = (splats.offset + splats.len / 2) as usize;
    bytes[middle] ^= 0x10;
    std::fs::write(&artifact, &bytes).unwrap();
    inspect_fails(&artifact, &["section `splats` is corrupt", "checksum"]);
}

#[test]
fn a_flipped_byte_in_the_middle_of_the_file_is_reported() {
    let dir = temp_dir();
    let (_, artifact) = crate::small_artifact(dir.path());
    let mut bytes = std::fs::read(&artifact).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0xff;
    std::fs::write(&artifact, &bytes).unwrap();
    let err = inspect_fails(&artifact, &[]);
    // Whatever region the middle falls in (a section, padding, the metadata), every byte is
    // covered by a checksum or must be zero.
    assert!(err.contains("corrupt") || err.contains("padding"), "{err}");
}

#[test]
fn another_format_version_is_refused() {
    let dir = temp_dir();
    let (_, artifact) = crate::small_artifact(dir.path());
    let mut bytes = std::fs::read(&artifact).unwrap();
    bytes[8..12].copy_from_slice(&99u32.to_le_bytes());
    std::fs::write(&artifact, &bytes).unwrap();
    inspect_fails(
        &artifact,
        &["format version 99 is not supported", "rerun the stage"],
    );
}

#[test]
fn a_ply_is_not_an_artifact() {
    let dir = temp_dir();
    let (_, artifact) = crate::small_artifact(dir.path());
    std::fs::copy(dir.path().join("grid.ply"), &artifact).unwrap();
    inspect_fails(&artifact, &["not a pcgi artifact"]);
}

#[test]
fn a_missing_artifact_is_named() {
    let dir = temp_dir();
    let err = inspect_fails(&dir.path().join("nothing.pcgi"), &[]);
    #[cfg(unix)]
    assert!(err.contains("No such file or directory"), "{err}");
    let _ = err;
}

#[test]
fn exported_views_are_ply_files_and_splats_round_trip() {
    let dir = temp_dir();
    let (_, artifact) = crate::small_artifact(dir.path());
    for view in ["splats", "leaves", "areas"] {
        let ply = dir.path().join(format!("{view}.ply"));
        let out = pc_inspect(args![artifact, "--export-ply", ply, "--view", view]).success();
        let points = pcgi_tests::count_before(&out.stdout, "points")
            .unwrap_or_else(|| panic!("no point count: {out:?}"));
        assert!(points > 0, "{out:?}");
        let read = pc_import::ply::read_ply(&ply, &Default::default())
            .unwrap_or_else(|e| panic!("{view} view: {e}"));
        assert_eq!(read.positions.len() as u64, points, "{view} view");
    }
    // The splats view has positions, normals and radii: pc-octree takes it back as input.
    let cfg = pcgi_tests::write_pipeline(
        dir.path(),
        &["splats.ply"],
        "[octree]\nfile = \"again.pcgi\"\n",
    );
    let out = pcgi_tests::pc_octree(args!["--config", cfg, "--quiet"]).success();
    assert_eq!(
        pcgi_tests::count_before(&out.stdout, "splats"),
        Some(256),
        "{out:?}"
    );
    pc_inspect(args![dir.path().join("out").join("again.pcgi"), "--verify"]).success();
}
