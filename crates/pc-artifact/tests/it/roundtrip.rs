//! Writing an artifact and reading every part of it back.

use pc_artifact::{
    Artifact, ArtifactError, ArtifactKind, ArtifactWriter, KeyHasher, FORMAT_VERSION, SECTION_ALIGN,
};

use crate::common::*;

#[test]
fn sections_and_metadata_round_trip() {
    let (_dir, path) = sample();
    let art = Artifact::open(&path).unwrap();
    assert_eq!(art.path(), path);

    let h = art.header();
    assert_eq!(h.kind, ArtifactKind::Octree);
    assert_eq!(art.kind(), ArtifactKind::Octree);
    assert_eq!(h.format_version, FORMAT_VERSION);
    assert_eq!(h.stage, "pc-octree");
    assert_eq!(h.stage_version, "0.0.0");
    assert_eq!(h.key, key());
    assert_eq!(art.key(), key());
    assert_eq!(h.file_len, std::fs::metadata(&path).unwrap().len());
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs();
    assert!(h.created_unix <= now && h.created_unix + 600 > now);

    let names: Vec<&str> = art.sections().iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, SECTIONS);
    for s in art.sections() {
        assert_eq!(s.offset % SECTION_ALIGN, 0, "{s:?}");
        assert_eq!(s.align as u64, SECTION_ALIGN);
    }
    let counts: Vec<u64> = art.sections().iter().map(|s| s.count()).collect();
    assert_eq!(counts, [5, 7, 3, 0, 1]);
    let sizes: Vec<u32> = art.sections().iter().map(|s| s.elem_size).collect();
    assert_eq!(sizes, [24, 16, 2, 4, 1]);

    assert_eq!(art.section::<Node>("nodes").unwrap(), nodes());
    assert_eq!(art.section::<[f32; 4]>("points").unwrap(), points());
    assert_eq!(art.section::<u16>("ids").unwrap(), IDS);
    assert_eq!(art.section::<u8>("flags").unwrap(), FLAGS);
    assert_eq!(
        art.section_bytes("ids").unwrap(),
        bytemuck::cast_slice::<u16, u8>(&IDS)
    );
    for name in ["nodes", "points", "ids", "flags"] {
        let ptr = art.section_bytes(name).unwrap().as_ptr() as usize;
        assert_eq!(
            ptr % 64,
            0,
            "section {name} is not 64-byte aligned in memory"
        );
    }

    assert!(art.has_section("nodes"));
    assert!(!art.has_section("node"));
    assert_eq!(art.section_info("points").unwrap().len, 7 * 16);

    assert_eq!(art.metadata::<Meta>().unwrap(), meta());
    assert!(!art.metadata_bytes().is_empty());
    // The metadata is a MessagePack map with field names.
    let generic: std::collections::BTreeMap<String, serde::de::IgnoredAny> =
        art.metadata().unwrap();
    assert!(generic.contains_key("scene"));

    art.expect_key(&key()).unwrap();
    let opened = Artifact::open_kind(&path, ArtifactKind::Octree).unwrap();
    assert_eq!(opened.header(), art.header());
}

#[test]
fn zero_length_section_is_an_empty_slice() {
    let (_dir, path) = sample();
    let art = Artifact::open(&path).unwrap();
    assert_eq!(art.section::<u32>("empty").unwrap(), &[] as &[u32]);
    assert_eq!(art.section_bytes("empty").unwrap(), &[] as &[u8]);
    let info = art.section_info("empty").unwrap();
    assert_eq!((info.len, info.count()), (0, 0));
}

#[test]
fn artifact_without_sections_or_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bare.radiosity");
    let key = KeyHasher::new().finish();
    let w = ArtifactWriter::create(&path, ArtifactKind::Radiosity, "s", "", key).unwrap();
    w.finish().unwrap();
    let art = Artifact::open(&path).unwrap();
    assert!(art.sections().is_empty());
    assert_eq!(art.header().stage_version, "");
    assert_eq!(art.header().file_len, 256);
    assert!(art.metadata_bytes().is_empty());
    let err = art.metadata::<u32>().unwrap_err();
    assert!(matches!(err, ArtifactError::Metadata { .. }), "{err}");
}

#[test]
fn every_kind_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    for kind in ArtifactKind::ALL {
        let path = dir.path().join(format!("a.{kind}"));
        let mut w = ArtifactWriter::create(&path, kind, "stage", "1", key()).unwrap();
        w.section("v", &[kind as u32]).unwrap();
        w.finish().unwrap();
        let art = Artifact::open_kind(&path, kind).unwrap();
        assert_eq!(art.section::<u32>("v").unwrap(), [kind as u32]);
    }
}

/// Sections synced to the disk halfway (`sync_written`, as pc-octree does from its writer
/// thread) make the same file as one write; nothing is published before `finish`.
#[test]
fn syncing_halfway_writes_the_same_artifact() {
    let dir = tempfile::tempdir().unwrap();
    let plain = write_sample(&dir.path().join("plain.octree"));
    let path = dir.path().join("synced.octree");
    let mut w =
        ArtifactWriter::create(&path, ArtifactKind::Octree, "pc-octree", "0.0.0", key()).unwrap();
    w.section("nodes", &nodes()).unwrap();
    w.section("points", &points()).unwrap();
    w.sync_written().unwrap();
    assert!(!path.exists(), "published before finish");
    w.section("ids", &IDS).unwrap();
    w.section::<u32>("empty", &[]).unwrap();
    w.sync_written().unwrap();
    w.section("flags", &FLAGS).unwrap();
    w.metadata(&meta()).unwrap();
    w.finish().unwrap();
    let (a, b) = (
        std::fs::read(&plain).unwrap(),
        std::fs::read(&path).unwrap(),
    );
    // The same bytes but the creation time in the header.
    assert_eq!(a.len(), b.len());
    let (a, b) = (
        Artifact::open(&plain).unwrap(),
        Artifact::open(&path).unwrap(),
    );
    assert_eq!(a.sections(), b.sections());
    assert_eq!(a.metadata_bytes(), b.metadata_bytes());
}

#[test]
fn wrong_kind() {
    let (_dir, path) = sample();
    let err = Artifact::open_kind(&path, ArtifactKind::Photons).unwrap_err();
    match &err {
        ArtifactError::WrongKind { expected, got, .. } => {
            assert_eq!(*expected, ArtifactKind::Photons);
            assert_eq!(got, "octree");
        }
        other => panic!("expected WrongKind, got {other}"),
    }
    assert!(err.to_string().contains(path.to_str().unwrap()), "{err}");
    assert!(err
        .to_string()
        .contains("expected a photons artifact, found octree"));
}

#[test]
fn wrong_element_size() {
    let (_dir, path) = sample();
    let art = Artifact::open(&path).unwrap();
    let err = art.section::<u32>("nodes").unwrap_err();
    match &err {
        ArtifactError::ElementSize {
            section,
            expected,
            got,
            ..
        } => {
            assert_eq!(section, "nodes");
            assert_eq!((*expected, *got), (4, 24));
        }
        other => panic!("expected ElementSize, got {other}"),
    }
    assert!(err.to_string().contains(path.to_str().unwrap()), "{err}");
    // Same size, same alignment or less: allowed (the caller chose the type).
    assert_eq!(art.section::<[u8; 24]>("nodes").unwrap().len(), 5);
}

#[test]
fn over_aligned_type_is_a_cast_error() {
    #[repr(C, align(128))]
    #[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
    struct Wide {
        v: [u8; 128],
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("wide.vmap");
    let mut w = ArtifactWriter::create(&path, ArtifactKind::Vmap, "t", "1", key()).unwrap();
    w.section("pad", &[1u8]).unwrap();
    w.section("wide", &[Wide { v: [3; 128] }]).unwrap();
    w.finish().unwrap();
    let art = Artifact::open(&path).unwrap();
    // "wide" starts at 320, a multiple of 64 but not of 128.
    assert_eq!(art.section_info("wide").unwrap().offset, 320);
    let err = art.section::<Wide>("wide").unwrap_err();
    assert!(matches!(err, ArtifactError::Cast { .. }), "{err}");
}

#[test]
fn missing_section() {
    let (_dir, path) = sample();
    let art = Artifact::open(&path).unwrap();
    for err in [
        art.section::<u8>("nope").unwrap_err(),
        art.section_bytes("nope").unwrap_err(),
    ] {
        match &err {
            ArtifactError::MissingSection { section, .. } => assert_eq!(section, "nope"),
            other => panic!("expected MissingSection, got {other}"),
        }
        assert!(err.to_string().contains(path.to_str().unwrap()), "{err}");
    }
}

#[test]
fn stale_key_and_invalid() {
    let (_dir, path) = sample();
    let art = Artifact::open(&path).unwrap();
    let other = KeyHasher::new().update_str("other").finish();
    let err = art.expect_key(&other).unwrap_err();
    match &err {
        ArtifactError::StaleKey { expected, got, .. } => {
            assert_eq!((*expected, *got), (other, key()));
        }
        other => panic!("expected StaleKey, got {other}"),
    }
    let msg = err.to_string();
    assert!(msg.contains(path.to_str().unwrap()), "{msg}");
    assert!(msg.contains(&other.to_string()), "{msg}");

    let err = art.invalid("node 3 points past the end");
    assert_eq!(err.path(), path);
    assert_eq!(
        err.to_string(),
        format!("{}: node 3 points past the end", path.display())
    );
}

#[test]
fn metadata_of_the_wrong_type() {
    let (_dir, path) = sample();
    let art = Artifact::open(&path).unwrap();
    let err = art.metadata::<Vec<u64>>().unwrap_err();
    assert!(matches!(err, ArtifactError::Metadata { .. }), "{err}");
    assert!(err.to_string().contains(path.to_str().unwrap()), "{err}");
}

#[test]
fn large_section_streams_through() {
    // Larger than the writer's 1 MiB chunks and buffer.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.photons");
    let data: Vec<u32> = (0..(3 << 18) + 5).collect();
    let mut w = ArtifactWriter::create(&path, ArtifactKind::Photons, "t", "1", key()).unwrap();
    w.section("a", &[1u8, 2, 3]).unwrap();
    w.section("big", &data).unwrap();
    w.finish().unwrap();
    let art = Artifact::open(&path).unwrap();
    assert_eq!(art.section::<u32>("big").unwrap(), data);
    assert_eq!(art.section::<u8>("a").unwrap(), [1, 2, 3]);
}
