//! The atomic writer: temporary files, replacement of older artifacts, and refused input.

use std::path::Path;

use pc_artifact::{Artifact, ArtifactError, ArtifactKind, ArtifactWriter, KeyHasher};

use crate::common::*;

/// The temporary files of writes of `path` in its folder (`NAME.<pid>.<unique>.tmp`).
fn tmps_of(path: &Path) -> Vec<std::path::PathBuf> {
    let name = path.file_name().unwrap();
    std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap())
        .filter(|e| pc_artifact::atomic::tmp_owner(&e.file_name(), name).is_some())
        .map(|e| e.path())
        .collect()
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    names
}

#[test]
fn finish_leaves_no_tmp_and_creates_folders() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("deep/er/sample.octree");
    let mut w =
        ArtifactWriter::create(&path, ArtifactKind::Octree, "pc-octree", "0.0.0", key()).unwrap();
    assert_eq!(w.path(), path);
    assert_eq!(
        tmps_of(&path).len(),
        1,
        "the writer works in a temporary file"
    );
    assert!(!path.exists(), "nothing at NAME before finish");
    w.section("nodes", &nodes()).unwrap();
    assert_eq!(w.finish().unwrap(), path);
    assert_eq!(files_in(path.parent().unwrap()), ["sample.octree"]);
    Artifact::open(&path).unwrap();
}

#[test]
fn dropped_writer_removes_tmp_and_keeps_older_artifact() {
    let (dir, path) = sample();
    let before = std::fs::read(&path).unwrap();
    {
        let mut w =
            ArtifactWriter::create(&path, ArtifactKind::Octree, "pc-octree", "0.0.0", key())
                .unwrap();
        w.section("nodes", &[1u64; 1000]).unwrap();
        assert_eq!(tmps_of(&path).len(), 1);
        // Dropped without finish, as on an error or a panic in the stage.
    }
    assert_eq!(files_in(dir.path()), ["sample.octree"]);
    assert_eq!(std::fs::read(&path).unwrap(), before);
    Artifact::open(&path).unwrap();
}

#[test]
fn writer_error_then_drop_removes_tmp() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.vmap");
    let mut w = ArtifactWriter::create(&path, ArtifactKind::Vmap, "pc-vmap", "1", key()).unwrap();
    w.section("a", &[1u32]).unwrap();
    let err = w.section("a", &[2u32]).unwrap_err();
    assert!(
        matches!(err, ArtifactError::DuplicateSection { .. }),
        "{err}"
    );
    drop(w);
    assert!(files_in(dir.path()).is_empty());
}

#[test]
fn a_stale_tmp_neither_disturbs_a_write_nor_survives_the_cleanup() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.vmap");
    // What a run killed before its rename leaves (the old fixed name and a dead process's).
    std::fs::write(dir.path().join("x.vmap.tmp"), vec![0xffu8; 10_000]).unwrap();
    std::fs::write(dir.path().join("x.vmap.0.0123456789abcdef.tmp"), [0u8; 64]).unwrap();
    let mut w = ArtifactWriter::create(&path, ArtifactKind::Vmap, "pc-vmap", "1", key()).unwrap();
    w.section("a", &[1u32]).unwrap();
    w.finish().unwrap();
    assert_eq!(pc_artifact::atomic::remove_stale_temps(&path).unwrap(), 2);
    assert_eq!(files_in(dir.path()), ["x.vmap"]);
    assert_eq!(
        Artifact::open(&path).unwrap().section::<u32>("a").unwrap(),
        [1]
    );
}

#[test]
fn replacing_a_mapped_artifact_leaves_the_old_mapping_intact() {
    let (_dir, path) = sample();
    let old = Artifact::open(&path).unwrap();
    let mut w =
        ArtifactWriter::create(&path, ArtifactKind::Octree, "pc-octree", "0.0.1", key()).unwrap();
    w.section(
        "nodes",
        &[Node {
            center: [9.0; 3],
            size: 9.0,
            first_child: 9,
            count: 9,
        }],
    )
    .unwrap();
    w.finish().unwrap();
    // The old mapping still reads the old, valid file...
    assert_eq!(old.section::<Node>("nodes").unwrap(), nodes());
    assert_eq!(old.header().stage_version, "0.0.0");
    // ...and a new open sees the new one.
    let new = Artifact::open(&path).unwrap();
    assert_eq!(new.header().stage_version, "0.0.1");
    assert_eq!(new.section::<Node>("nodes").unwrap()[0].count, 9);
    assert!(!new.has_section("points"));
}

#[test]
fn bad_section_names_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.photons");
    let mut w = ArtifactWriter::create(&path, ArtifactKind::Photons, "s", "1", key()).unwrap();
    for name in ["", "Nodes", "a-b", "a b", "abcdefghijklmnopqrstuvwxy", "é"] {
        let err = w.section(name, &[1u8]).unwrap_err();
        match &err {
            ArtifactError::BadName { name: n, .. } => assert_eq!(n, name),
            other => panic!("expected BadName for {name:?}, got {other}"),
        }
        assert!(err.to_string().contains(path.to_str().unwrap()), "{err}");
    }
    w.section("abcdefghijklmnopqrstuvwx", &[1u8]).unwrap();
    w.section("a_0", &[1u8]).unwrap();
    w.finish().unwrap();
}

#[test]
fn ragged_and_zero_sized_elements_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.photons");
    let mut w = ArtifactWriter::create(&path, ArtifactKind::Photons, "s", "1", key()).unwrap();
    let err = w.section_bytes("a", 4, &[0u8; 6]).unwrap_err();
    assert!(
        matches!(
            err,
            ArtifactError::Ragged {
                len: 6,
                elem_size: 4,
                ..
            }
        ),
        "{err}"
    );
    let err = w.section_bytes("a", 0, &[]).unwrap_err();
    assert!(
        matches!(err, ArtifactError::Ragged { elem_size: 0, .. }),
        "{err}"
    );
    let err = w.section::<()>("a", &[(), ()]).unwrap_err();
    assert!(matches!(err, ArtifactError::Ragged { .. }), "{err}");
    // A refused section does not take its name.
    w.section_bytes("a", 12, &[7u8; 24]).unwrap();
    w.finish().unwrap();
    let art = Artifact::open(&path).unwrap();
    assert_eq!(art.section_info("a").unwrap().count(), 2);
    assert_eq!(art.section::<[u32; 3]>("a").unwrap().len(), 2);
}

#[test]
fn bad_stage_labels_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.photons");
    let k = KeyHasher::new().finish();
    for (stage, version) in [
        ("", "1"),
        (&"s".repeat(33)[..], "1"),
        ("s", "12345678901234567"),
        ("a\0b", "1"),
    ] {
        let err =
            ArtifactWriter::create(&path, ArtifactKind::Photons, stage, version, k).unwrap_err();
        assert!(matches!(err, ArtifactError::BadLabel { .. }), "{err}");
    }
    assert!(files_in(dir.path()).is_empty());
    let w = ArtifactWriter::create(
        &path,
        ArtifactKind::Photons,
        &"s".repeat(32),
        "1234567890123456",
        k,
    )
    .unwrap();
    w.finish().unwrap();
    let art = Artifact::open(&path).unwrap();
    assert_eq!(art.header().stage.len(), 32);
    assert_eq!(art.header().stage_version, "1234567890123456");
}

#[test]
fn metadata_can_be_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.photons");
    let mut w = ArtifactWriter::create(&path, ArtifactKind::Photons, "s", "1", key()).unwrap();
    w.metadata(&1u32).unwrap();
    w.metadata(&meta()).unwrap();
    w.finish().unwrap();
    assert_eq!(
        Artifact::open(&path).unwrap().metadata::<Meta>().unwrap(),
        meta()
    );
}

#[test]
fn same_input_gives_the_same_bytes_except_the_time() {
    let dir = tempfile::tempdir().unwrap();
    let a = std::fs::read(write_sample(&dir.path().join("a"))).unwrap();
    let b = std::fs::read(write_sample(&dir.path().join("b"))).unwrap();
    assert_eq!(a.len(), b.len());
    // Bytes 88..96 hold the creation time and 248..256 the header checksum that covers it.
    let differ: Vec<usize> = (0..a.len()).filter(|&i| a[i] != b[i]).collect();
    assert!(
        differ
            .iter()
            .all(|&i| (88..96).contains(&i) || (248..256).contains(&i)),
        "{differ:?}"
    );
}
