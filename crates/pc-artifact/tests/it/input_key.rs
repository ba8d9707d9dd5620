//! `Artifact::input_key`: the key of a stage's input from its validated header, table, layout
//! and metadata, without the sections' data.

use pc_artifact::{Artifact, ArtifactError, ArtifactKind};

use crate::common::*;

#[test]
fn the_key_is_the_opened_artifacts() {
    let (_dir, path) = sample();
    let key = Artifact::input_key(&path, ArtifactKind::Octree).unwrap();
    assert_eq!(key, Artifact::open(&path).unwrap().key());
    assert_eq!(key, crate::common::key());
}

/// The sample artifact with the first byte of `section` flipped, at `bad.octree` in the
/// returned folder, and its bytes.
fn with_a_flipped_byte_in(section: &str) -> (tempfile::TempDir, std::path::PathBuf, Vec<u8>) {
    let (dir, path) = sample();
    let art = Artifact::open(&path).unwrap();
    let at = art.section_info(section).unwrap().offset as usize;
    drop(art);
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[at] ^= 0x40;
    let bad = dir.path().join("bad.octree");
    std::fs::write(&bad, &bytes).unwrap();
    (dir, bad, bytes)
}

#[test]
fn a_flipped_byte_in_a_section_is_left_to_the_open_that_reads_it() {
    let (_dir, bad, _) = with_a_flipped_byte_in("points");
    assert_eq!(
        Artifact::input_key(&bad, ArtifactKind::Octree).unwrap(),
        crate::common::key()
    );
    match Artifact::open_input(&bad, ArtifactKind::Octree).unwrap_err() {
        ArtifactError::Checksum { section, path, .. } => {
            assert_eq!(section, "points");
            assert_eq!(path, bad);
        }
        other => panic!("expected a checksum error, got {other}"),
    }
}

#[test]
fn the_header_table_and_metadata_are_still_checked() {
    let (dir, path) = sample();
    let bytes = std::fs::read(&path).unwrap();
    let bad = dir.path().join("bad.octree");
    let key_of = |b: &[u8]| {
        std::fs::write(&bad, b).unwrap();
        Artifact::input_key(&bad, ArtifactKind::Octree)
    };
    let err = key_of(&bytes[..bytes.len() - 1]).unwrap_err();
    assert!(matches!(err, ArtifactError::Truncated { .. }), "{err}");
    let mut header = bytes.clone();
    header[80] ^= 1; // inside the key
    let err = key_of(&header).unwrap_err();
    assert!(matches!(err, ArtifactError::HeaderChecksum { .. }), "{err}");
    let mut meta = bytes.clone();
    let offset = u64_at(&bytes, H_METADATA_OFFSET) as usize;
    let len = u64_at(&bytes, H_METADATA_LEN) as usize;
    meta[offset + len / 2] ^= 0x40;
    let err = key_of(&meta).unwrap_err();
    assert!(err.to_string().contains("the metadata is corrupt"), "{err}");
    assert!(err.to_string().starts_with(&format!("{}: ", bad.display())));
}

#[test]
fn a_missing_input_names_the_stage_and_a_wrong_kind_is_refused() {
    let (dir, path) = sample();
    let missing = dir.path().join("nothing.pcgi");
    match Artifact::input_key(&missing, ArtifactKind::Vmap).unwrap_err() {
        ArtifactError::MissingInput { stage, path, .. } => {
            assert_eq!(stage, ArtifactKind::Vmap.stage());
            assert_eq!(path, missing);
        }
        other => panic!("expected a missing input, got {other}"),
    }
    let err = Artifact::input_key(&path, ArtifactKind::Vmap).unwrap_err();
    assert!(matches!(err, ArtifactError::WrongKind { .. }), "{err}");
}

/// `Artifact::open_input_sections`: the named sections' data is checked and handed out, the
/// others are neither (a reader of a photon map's photons skips its specular links).
#[test]
fn an_open_of_some_sections_checks_and_hands_out_only_them() {
    let (dir, bad, bytes) = with_a_flipped_byte_in("ids");
    // A flipped byte in a section not read is not this reader's error...
    let some = Artifact::open_input_sections(&bad, ArtifactKind::Octree, &["points"]).unwrap();
    assert_eq!(some.section::<[f32; 4]>("points").unwrap(), points());
    assert_eq!(some.key(), crate::common::key());
    // ...and that section is not handed out.
    match some.section::<u16>("ids").unwrap_err() {
        ArtifactError::MissingSection { section, .. } => assert_eq!(section, "ids"),
        other => panic!("expected a missing section, got {other}"),
    }
    // In a section read, it is.
    match Artifact::open_input_sections(&bad, ArtifactKind::Octree, &["points", "ids"]).unwrap_err()
    {
        ArtifactError::Checksum { section, path, .. } => {
            assert_eq!(section, "ids");
            assert_eq!(path, bad);
        }
        other => panic!("expected a checksum error, got {other}"),
    }
    // The layout is checked whole: a truncated file is refused whatever is read.
    std::fs::write(&bad, &bytes[..bytes.len() - 1]).unwrap();
    let err = Artifact::open_input_sections(&bad, ArtifactKind::Octree, &["points"]).unwrap_err();
    assert!(matches!(err, ArtifactError::Truncated { .. }), "{err}");
    // A missing file names the stage that makes it.
    let missing = dir.path().join("nothing.pcgi");
    let err = Artifact::open_input_sections(&missing, ArtifactKind::Photons, &[]).unwrap_err();
    assert!(matches!(err, ArtifactError::MissingInput { .. }), "{err}");
}
