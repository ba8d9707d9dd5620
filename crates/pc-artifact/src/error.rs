//! The one error type of the artifact container: every problem names the file it is about.

use std::path::{Path, PathBuf};

use crate::key::Key;
use crate::kind::ArtifactKind;

/// The name under which errors about the metadata blob report it (`section` fields).
///
/// Real section names are `[a-z0-9_]`, so this can never be mistaken for one.
pub const METADATA_REGION: &str = "<metadata>";

/// The name under which errors about the section table report it (`section` fields).
pub const TABLE_REGION: &str = "<section table>";

/// "section `nodes`", "the metadata" or "the section table", for messages.
fn region(section: &str) -> String {
    match section {
        METADATA_REGION => "the metadata".to_owned(),
        TABLE_REGION => "the section table".to_owned(),
        name => format!("section `{name}`"),
    }
}

/// One past the last byte of `offset..offset + len`, without overflow.
fn end(offset: &u64, len: &u64) -> u128 {
    *offset as u128 + *len as u128
}

/// Everything that can go wrong writing, opening or reading an artifact.
///
/// Every variant carries the path of the file, and its message starts with `{path}: `.
/// `Io` keeps the operating system's error as its [`source`](std::error::Error::source), so
/// print errors with their chain (`{:#}` with anyhow).
#[derive(Debug, thiserror::Error)]
pub enum ArtifactError {
    /// Reading, writing, creating, renaming or mapping the file failed.
    #[error("{}: I/O error", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },

    /// The file is shorter than the header says (or than a header).
    #[error("{}: file is truncated: the {what} needs {need} bytes, the file has {have}", .path.display())]
    Truncated {
        path: PathBuf,
        what: &'static str,
        need: u64,
        have: u64,
    },

    /// The file is longer than the header says.
    #[error("{}: the file has {have} bytes but its header says {expected}: trailing data", .path.display())]
    FileLength {
        path: PathBuf,
        expected: u64,
        have: u64,
    },

    /// The first eight bytes are not the pcgi artifact magic.
    #[error("{}: not a pcgi artifact (magic {found:02x?}, expected {:02x?})", .path.display(), crate::MAGIC)]
    BadMagic { path: PathBuf, found: [u8; 8] },

    /// The artifact was written by a build with another container format version.
    #[error(
        "{}: artifact format version {got} is not supported (this build reads version {expected}): rerun the stage that made it",
        .path.display()
    )]
    Version {
        path: PathBuf,
        expected: u32,
        got: u32,
    },

    /// The header names a kind of artifact this build does not know.
    #[error("{}: unknown artifact kind {kind}", .path.display())]
    UnknownKind { path: PathBuf, kind: u32 },

    /// The artifact is of another kind than the one asked for.
    #[error("{}: expected a {expected} artifact, found {got}", .path.display())]
    WrongKind {
        path: PathBuf,
        expected: ArtifactKind,
        /// The kind found: its name, or "unknown kind N".
        got: String,
    },

    /// The header checksum does not match: the header is corrupt.
    #[error("{}: the header is corrupt: checksum {got:#018x}, expected {expected:#018x}", .path.display())]
    HeaderChecksum {
        path: PathBuf,
        expected: u64,
        got: u64,
    },

    /// A section (or the metadata, or the section table) lies partly outside the file.
    #[error(
        "{}: {} lies outside the file: bytes {offset}..{} but the file has {file_len}",
        .path.display(), region(.section), end(.offset, .len)
    )]
    SectionBounds {
        path: PathBuf,
        /// A section name, [`METADATA_REGION`] or [`TABLE_REGION`].
        section: String,
        offset: u64,
        len: u64,
        file_len: u64,
    },

    /// A section does not start on a 64-byte boundary (or declares another alignment).
    #[error(
        "{}: section `{section}` is misaligned: it starts at offset {offset} and declares alignment {align}, sections start on 64-byte boundaries",
        .path.display()
    )]
    Misaligned {
        path: PathBuf,
        section: String,
        offset: u64,
        align: u32,
    },

    /// The regions of the file are not where the format puts them, or padding is not zero.
    #[error("{}: bad layout: {msg}", .path.display())]
    Layout { path: PathBuf, msg: String },

    /// The bytes of a section (or of the metadata, or of the section table) do not match
    /// their checksum: the file is corrupt.
    #[error("{}: {} is corrupt: checksum {got:#018x}, expected {expected:#018x}", .path.display(), region(.section))]
    Checksum {
        path: PathBuf,
        /// A section name, [`METADATA_REGION`] or [`TABLE_REGION`].
        section: String,
        expected: u64,
        got: u64,
    },

    /// A section the reader needs is not in the file.
    #[error("{}: the artifact has no section `{section}`", .path.display())]
    MissingSection { path: PathBuf, section: String },

    /// The writer was given the same section name twice, or the table lists it twice.
    #[error("{}: section `{section}` appears twice", .path.display())]
    DuplicateSection { path: PathBuf, section: String },

    /// The section's element size is not the size of the type the reader asked for.
    #[error(
        "{}: section `{section}` holds {got}-byte elements, the reader expects {expected}-byte elements (written by another version of pcgi? rerun the stage that made it)",
        .path.display()
    )]
    ElementSize {
        path: PathBuf,
        section: String,
        expected: usize,
        got: u32,
    },

    /// The section's length is not a whole number of elements (or its element size is zero).
    #[error(
        "{}: section `{section}` is {len} bytes, not a whole number of {elem_size}-byte elements",
        .path.display()
    )]
    Ragged {
        path: PathBuf,
        section: String,
        len: u64,
        elem_size: u32,
    },

    /// bytemuck refused the cast (the type's alignment is over 64 bytes).
    #[error("{}: cannot view section `{section}` as the requested type: {msg}", .path.display())]
    Cast {
        path: PathBuf,
        section: String,
        msg: String,
    },

    /// The metadata could not be encoded or decoded.
    #[error("{}: bad metadata: {msg}", .path.display())]
    Metadata { path: PathBuf, msg: String },

    /// The artifact was made from other inputs than the current ones.
    #[error(
        "{}: artifact is stale: it was made with key {got}, the current inputs give key {expected}: rerun the stage that makes it",
        .path.display()
    )]
    StaleKey {
        path: PathBuf,
        expected: Key,
        got: Key,
    },

    /// An input artifact does not exist: the stage that makes it has not run (or wrote
    /// elsewhere).
    #[error("{}: not found: run {stage} first to make it", .path.display())]
    MissingInput {
        path: PathBuf,
        /// The stage that makes this kind of artifact.
        stage: &'static str,
        source: std::io::Error,
    },

    /// An input artifact was made from other inputs than the ones it is used with: another
    /// octree, other lights, another size.
    #[error("{}: stale {what}: {why}: rerun {rerun}", .path.display())]
    Stale {
        path: PathBuf,
        /// What the artifact is, in words ("V-map", "photon map").
        what: &'static str,
        /// What disagrees.
        why: String,
        /// What to rerun.
        rerun: String,
    },

    /// A kind-specific structural check failed (reported by the crate that owns the kind).
    #[error("{}: {msg}", .path.display())]
    Invalid { path: PathBuf, msg: String },

    /// A section name is not 1 to 24 characters of `a-z`, `0-9` and `_`.
    #[error(
        "{}: invalid section name {name:?}: names are 1 to 24 characters of a-z, 0-9 and _",
        .path.display()
    )]
    BadName { path: PathBuf, name: String },

    /// The stage name or stage version does not fit its header field.
    #[error(
        "{}: invalid {field} {value:?}: it must be {min} to {max} bytes of UTF-8 without NUL",
        .path.display()
    )]
    BadLabel {
        path: PathBuf,
        field: &'static str,
        value: String,
        min: usize,
        max: usize,
    },
}

impl ArtifactError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            ArtifactError::Io { path, .. }
            | ArtifactError::Truncated { path, .. }
            | ArtifactError::FileLength { path, .. }
            | ArtifactError::BadMagic { path, .. }
            | ArtifactError::Version { path, .. }
            | ArtifactError::UnknownKind { path, .. }
            | ArtifactError::WrongKind { path, .. }
            | ArtifactError::HeaderChecksum { path, .. }
            | ArtifactError::SectionBounds { path, .. }
            | ArtifactError::Misaligned { path, .. }
            | ArtifactError::Layout { path, .. }
            | ArtifactError::Checksum { path, .. }
            | ArtifactError::MissingSection { path, .. }
            | ArtifactError::DuplicateSection { path, .. }
            | ArtifactError::ElementSize { path, .. }
            | ArtifactError::Ragged { path, .. }
            | ArtifactError::Cast { path, .. }
            | ArtifactError::Metadata { path, .. }
            | ArtifactError::StaleKey { path, .. }
            | ArtifactError::MissingInput { path, .. }
            | ArtifactError::Stale { path, .. }
            | ArtifactError::Invalid { path, .. }
            | ArtifactError::BadName { path, .. }
            | ArtifactError::BadLabel { path, .. } => path,
        }
    }

    /// An [`ArtifactError::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> ArtifactError {
        ArtifactError::Io {
            path: path.into(),
            source,
        }
    }

    /// An [`ArtifactError::Invalid`] for `path`, for kind-specific structural checks.
    pub fn invalid(path: impl Into<PathBuf>, msg: impl Into<String>) -> ArtifactError {
        ArtifactError::Invalid {
            path: path.into(),
            msg: msg.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_start_with_the_path() {
        let path = PathBuf::from("out/a.octree");
        let errors = [
            ArtifactError::io(&path, std::io::Error::other("boom")),
            ArtifactError::Truncated {
                path: path.clone(),
                what: "header",
                need: 256,
                have: 17,
            },
            ArtifactError::Checksum {
                path: path.clone(),
                section: "nodes".into(),
                expected: 1,
                got: 2,
            },
            ArtifactError::Checksum {
                path: path.clone(),
                section: METADATA_REGION.into(),
                expected: 1,
                got: 2,
            },
            ArtifactError::Version {
                path: path.clone(),
                expected: 1,
                got: 7,
            },
            ArtifactError::SectionBounds {
                path: path.clone(),
                section: TABLE_REGION.into(),
                offset: u64::MAX,
                len: 64,
                file_len: 300,
            },
            ArtifactError::invalid(&path, "node 3 has child 99 of 10"),
        ];
        for e in &errors {
            assert!(e.to_string().starts_with("out/a.octree: "), "{e}");
            assert_eq!(e.path(), path);
        }
        assert_eq!(
            errors[1].to_string(),
            "out/a.octree: file is truncated: the header needs 256 bytes, the file has 17"
        );
        assert_eq!(
            errors[2].to_string(),
            "out/a.octree: section `nodes` is corrupt: checksum 0x0000000000000002, expected 0x0000000000000001"
        );
        assert!(errors[3].to_string().contains(": the metadata is corrupt"));
        assert_eq!(
            errors[4].to_string(),
            "out/a.octree: artifact format version 7 is not supported (this build reads version 1): rerun the stage that made it"
        );
        assert!(errors[5]
            .to_string()
            .contains("the section table lies outside"));
        let io = &errors[0];
        assert_eq!(std::error::Error::source(io).unwrap().to_string(), "boom");
    }
}
