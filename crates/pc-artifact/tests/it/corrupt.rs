//! Truncated, corrupted and foreign files: every one is a clear error naming the file, never a panic.

use std::path::Path;

use pc_artifact::{
    Artifact, ArtifactError, ArtifactKind, FORMAT_VERSION, METADATA_REGION, TABLE_REGION,
};

use crate::common::*;

/// Writes `bytes` to a new file beside `path` and opens it.
fn open_bytes(path: &Path, bytes: &[u8]) -> Result<Artifact, ArtifactError> {
    let bad = path.with_file_name("bad.octree");
    std::fs::write(&bad, bytes).unwrap();
    let result = Artifact::open(&bad);
    if let Err(e) = &result {
        assert_eq!(e.path(), bad);
        assert!(
            e.to_string().starts_with(&format!("{}: ", bad.display())),
            "message does not start with the path: {e}"
        );
    }
    result
}

#[test]
fn missing_empty_and_folder() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.octree");
    let err = Artifact::open(&missing).unwrap_err();
    match &err {
        ArtifactError::Io { source, .. } => {
            assert_eq!(source.kind(), std::io::ErrorKind::NotFound)
        }
        other => panic!("expected Io, got {other}"),
    }
    assert!(err.to_string().contains(missing.to_str().unwrap()), "{err}");

    let empty = dir.path().join("empty.octree");
    std::fs::write(&empty, b"").unwrap();
    let err = Artifact::open(&empty).unwrap_err();
    assert!(
        matches!(
            err,
            ArtifactError::Truncated {
                need: 256,
                have: 0,
                ..
            }
        ),
        "{err}"
    );
    assert_eq!(
        err.to_string(),
        format!(
            "{}: file is truncated: the header needs 256 bytes, the file has 0",
            empty.display()
        )
    );

    let folder = dir.path().join("folder.octree");
    std::fs::create_dir(&folder).unwrap();
    let err = Artifact::open(&folder).unwrap_err();
    assert!(matches!(err, ArtifactError::Io { .. }), "{err}");
    assert!(err.to_string().contains(folder.to_str().unwrap()), "{err}");
}

#[test]
fn truncated_at_any_length() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    let art = Artifact::open(&path).unwrap();
    let mut lengths = vec![0, 10, 255, 256, good.len() - 1];
    for s in art.sections() {
        lengths.push((s.offset + s.len / 2) as usize);
    }
    for &len in &lengths {
        let err = open_bytes(&path, &good[..len]).unwrap_err();
        match err {
            ArtifactError::Truncated { need, have, .. } => {
                assert_eq!(have, len as u64);
                let need_expected = if len < 256 { 256 } else { good.len() as u64 };
                assert_eq!(need, need_expected);
            }
            other => panic!("truncated to {len}: expected Truncated, got {other}"),
        }
    }
    // Every other length too: an error, never a panic.
    for len in 0..good.len() {
        let err = open_bytes(&path, &good[..len]).unwrap_err();
        assert!(
            matches!(
                err,
                ArtifactError::Truncated { .. } | ArtifactError::SectionBounds { .. }
            ),
            "truncated to {len}: {err}"
        );
    }
}

#[test]
fn trailing_data() {
    let (_dir, path) = sample();
    let mut bytes = std::fs::read(&path).unwrap();
    bytes.push(0);
    let err = open_bytes(&path, &bytes).unwrap_err();
    assert!(matches!(err, ArtifactError::FileLength { .. }), "{err}");
}

#[test]
fn flipped_byte_in_each_section() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    let art = Artifact::open(&path).unwrap();
    for s in art.sections().iter().filter(|s| s.len > 0) {
        for at in [s.offset, s.offset + s.len / 2, s.offset + s.len - 1] {
            let mut bytes = good.clone();
            bytes[at as usize] ^= 0x01;
            let err = open_bytes(&path, &bytes).unwrap_err();
            match &err {
                ArtifactError::Checksum { section, .. } => assert_eq!(section, &s.name),
                other => panic!(
                    "byte {at} of section {}: expected Checksum, got {other}",
                    s.name
                ),
            }
            assert!(
                err.to_string()
                    .contains(&format!("section `{}` is corrupt", s.name)),
                "{err}"
            );
        }
    }
}

#[test]
fn flipped_byte_in_metadata() {
    let (_dir, path) = sample();
    let mut bytes = std::fs::read(&path).unwrap();
    let offset = u64_at(&bytes, H_METADATA_OFFSET) as usize;
    let len = u64_at(&bytes, H_METADATA_LEN) as usize;
    assert!(len > 0);
    bytes[offset + len / 2] ^= 0x40;
    let err = open_bytes(&path, &bytes).unwrap_err();
    match &err {
        ArtifactError::Checksum { section, .. } => assert_eq!(section, METADATA_REGION),
        other => panic!("expected Checksum, got {other}"),
    }
    assert!(err.to_string().contains("the metadata is corrupt"), "{err}");
}

#[test]
fn flipped_byte_in_table() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    let table = u64_at(&good, H_TABLE_OFFSET) as usize;
    // In a name, an offset, a checksum and a reserved field.
    for at in [
        table,
        table + 64 + E_OFFSET,
        table + 2 * 64 + 50,
        table + 4 * 64 + 63,
    ] {
        let mut bytes = good.clone();
        bytes[at] ^= 0x02;
        let err = open_bytes(&path, &bytes).unwrap_err();
        match &err {
            ArtifactError::Checksum { section, .. } => assert_eq!(section, TABLE_REGION),
            other => panic!("table byte {at}: expected Checksum, got {other}"),
        }
        assert!(
            err.to_string().contains("the section table is corrupt"),
            "{err}"
        );
    }
}

#[test]
fn flipped_byte_in_header() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    // Stage name, key, created time, table offset, metadata checksum, reserved, checksum.
    for at in [H_STAGE, 72, 90, H_TABLE_OFFSET, 150, 200, H_CHECKSUM + 3] {
        let mut bytes = good.clone();
        bytes[at] ^= 0x10;
        let err = open_bytes(&path, &bytes).unwrap_err();
        assert!(
            matches!(err, ArtifactError::HeaderChecksum { .. }),
            "header byte {at}: {err}"
        );
        assert!(err.to_string().contains("the header is corrupt"), "{err}");
    }
}

#[test]
fn flipped_byte_anywhere() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    for at in 0..good.len() {
        let mut bytes = good.clone();
        bytes[at] ^= 0x80;
        assert!(
            open_bytes(&path, &bytes).is_err(),
            "flipping byte {at} went unnoticed"
        );
    }
}

#[test]
fn bad_magic() {
    let (_dir, path) = sample();
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[0] = b'X';
    let err = open_bytes(&path, &bytes).unwrap_err();
    assert!(
        matches!(err, ArtifactError::BadMagic { found, .. } if found[0] == b'X'),
        "{err}"
    );
    assert!(err.to_string().contains("not a pcgi artifact"), "{err}");

    let err = open_bytes(&path, &[b'{'; 300]).unwrap_err();
    assert!(matches!(err, ArtifactError::BadMagic { .. }), "{err}");
}

#[test]
fn other_format_version() {
    let (_dir, path) = sample();
    for version in [0, FORMAT_VERSION + 1, 7, u32::MAX] {
        let mut bytes = std::fs::read(&path).unwrap();
        put_u32(&mut bytes, H_VERSION, version);
        fix_header_checksum(&mut bytes);
        let err = open_bytes(&path, &bytes).unwrap_err();
        match &err {
            ArtifactError::Version { expected, got, .. } => {
                assert_eq!((*expected, *got), (FORMAT_VERSION, version));
            }
            other => panic!("expected Version, got {other}"),
        }
        assert!(
            err.to_string().contains(&format!(
                "artifact format version {version} is not supported (this build reads version {FORMAT_VERSION}): rerun the stage that made it"
            )),
            "{err}"
        );
    }
}

#[test]
fn unknown_kind() {
    let (_dir, path) = sample();
    let mut bytes = std::fs::read(&path).unwrap();
    put_u32(&mut bytes, H_KIND, 99);
    fix_header_checksum(&mut bytes);
    let err = open_bytes(&path, &bytes).unwrap_err();
    assert!(
        matches!(err, ArtifactError::UnknownKind { kind: 99, .. }),
        "{err}"
    );
    let bad = path.with_file_name("bad.octree");
    let err = Artifact::open_kind(&bad, ArtifactKind::Octree).unwrap_err();
    match &err {
        ArtifactError::WrongKind { got, .. } => assert_eq!(got, "unknown kind 99"),
        other => panic!("expected WrongKind, got {other}"),
    }
}

/// Rewrites one table entry field and fixes the checksums, so that only that field is wrong.
fn patch_entry(good: &[u8], index: usize, field: usize, value: u64, width: usize) -> Vec<u8> {
    let mut bytes = good.to_vec();
    let at = entry_at(&bytes, index) + field;
    bytes[at..at + width].copy_from_slice(&value.to_le_bytes()[..width]);
    fix_table_checksum(&mut bytes);
    bytes
}

#[test]
fn section_out_of_bounds() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    for offset in [good.len() as u64, u64::MAX - 63, 0] {
        let bytes = patch_entry(&good, 1, E_OFFSET, offset, 8);
        let err = open_bytes(&path, &bytes).unwrap_err();
        match &err {
            ArtifactError::SectionBounds { section, .. } => assert_eq!(section, "points"),
            other => panic!("offset {offset}: expected SectionBounds, got {other}"),
        }
    }
    // A length running past the end.
    let bytes = patch_entry(&good, 0, 32, 1 << 40, 8);
    let err = open_bytes(&path, &bytes).unwrap_err();
    assert!(matches!(err, ArtifactError::SectionBounds { .. }), "{err}");
}

#[test]
fn table_or_metadata_out_of_bounds() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    let mut bytes = good.clone();
    put_u64(&mut bytes, H_METADATA_OFFSET, good.len() as u64 - 4);
    fix_header_checksum(&mut bytes);
    let err = open_bytes(&path, &bytes).unwrap_err();
    match &err {
        ArtifactError::SectionBounds { section, .. } => assert_eq!(section, METADATA_REGION),
        other => panic!("expected SectionBounds, got {other}"),
    }
    let mut bytes = good.clone();
    put_u64(&mut bytes, H_TABLE_OFFSET, good.len() as u64 - 64);
    fix_header_checksum(&mut bytes);
    let err = open_bytes(&path, &bytes).unwrap_err();
    match &err {
        ArtifactError::SectionBounds { section, .. } => assert_eq!(section, TABLE_REGION),
        other => panic!("expected SectionBounds, got {other}"),
    }
    assert!(
        err.to_string()
            .contains("the section table lies outside the file"),
        "{err}"
    );
}

#[test]
fn misaligned_section() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    let art = Artifact::open(&path).unwrap();
    let points = art.section_info("points").unwrap();
    let bytes = patch_entry(&good, 1, E_OFFSET, points.offset + 4, 8);
    let err = open_bytes(&path, &bytes).unwrap_err();
    match &err {
        ArtifactError::Misaligned {
            section, offset, ..
        } => {
            assert_eq!((section.as_str(), *offset), ("points", points.offset + 4));
        }
        other => panic!("expected Misaligned, got {other}"),
    }
    // Declared alignment other than 64.
    let bytes = patch_entry(&good, 1, 44, 16, 4);
    let err = open_bytes(&path, &bytes).unwrap_err();
    assert!(
        matches!(err, ArtifactError::Misaligned { align: 16, .. }),
        "{err}"
    );
}

#[test]
fn element_size_must_divide_length() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    for elem_size in [0u64, 7, 25] {
        let bytes = patch_entry(&good, 0, E_ELEM_SIZE, elem_size, 4);
        let err = open_bytes(&path, &bytes).unwrap_err();
        match &err {
            ArtifactError::Ragged { section, .. } => assert_eq!(section, "nodes"),
            other => panic!("elem size {elem_size}: expected Ragged, got {other}"),
        }
    }
    // A size that divides the length is structurally fine (48 = two 24-byte nodes)...
    let bytes = patch_entry(&good, 0, E_ELEM_SIZE, 40, 4);
    let art = open_bytes(&path, &bytes).unwrap();
    // ...and then a reader of 24-byte nodes is told the sizes differ.
    let err = art.section::<Node>("nodes").unwrap_err();
    assert!(
        matches!(
            err,
            ArtifactError::ElementSize {
                expected: 24,
                got: 40,
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn bad_and_duplicate_names_in_the_table() {
    let (_dir, path) = sample();
    let good = std::fs::read(&path).unwrap();
    // "nodes" -> "Nodes"
    let bytes = patch_entry(&good, 0, 0, b'N' as u64, 1);
    let err = open_bytes(&path, &bytes).unwrap_err();
    assert!(matches!(err, ArtifactError::BadName { .. }), "{err}");
    // "points" -> "nodes\0"
    let mut name = [0u8; 8];
    name[..5].copy_from_slice(b"nodes");
    let bytes = patch_entry(&good, 1, 0, u64::from_le_bytes(name), 8);
    let err = open_bytes(&path, &bytes).unwrap_err();
    assert!(
        matches!(&err, ArtifactError::DuplicateSection { section, .. } if section == "nodes"),
        "{err}"
    );
}

#[test]
fn nonzero_padding() {
    let (_dir, path) = sample();
    let mut bytes = std::fs::read(&path).unwrap();
    let art = Artifact::open(&path).unwrap();
    let ids = art.section_info("ids").unwrap();
    // Right after the 6 bytes of "ids", before the next 64-byte boundary.
    bytes[(ids.offset + ids.len) as usize] = 1;
    let err = open_bytes(&path, &bytes).unwrap_err();
    assert!(matches!(err, ArtifactError::Layout { .. }), "{err}");
    assert!(err.to_string().contains("nonzero padding"), "{err}");
}

/// Metadata of another build of its stage (a field this build no longer has): the file is intact,
/// so the error says who wrote it and what makes it anew.
#[test]
fn metadata_of_another_build_names_the_stage_to_rerun() {
    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Fewer {
        scene: String,
        levels: u32,
        bounds: [f32; 6],
    }
    let (_dir, path) = sample();
    let artifact = Artifact::open(&path).unwrap();
    let err = artifact.metadata::<Fewer>().unwrap_err();
    assert!(matches!(err, ArtifactError::Metadata { .. }), "{err}");
    let text = err.to_string();
    assert!(text.contains("sample.octree: bad metadata"), "{text}");
    assert!(text.contains("key_of_input"), "{text}");
    assert!(
        text.contains("written by pc-octree 0.0.0") && text.contains("rerun pc-octree"),
        "{text}"
    );
}
