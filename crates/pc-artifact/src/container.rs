//! The artifact container: its byte layout and the validating memory-mapped reader (the atomic
//! writer, [`crate::ArtifactWriter`], is in `writer.rs`).
//!
//! # File layout, format version 1
//!
//! All integers are little-endian. Every region starts on a multiple of [`SECTION_ALIGN`]
//! (64) bytes and the gaps between regions are zero bytes, so every byte of a valid file is
//! either covered by a checksum or must be zero: one flipped byte anywhere is an error.
//!
//! ```text
//! offset  size  region
//! 0       256   header
//! 256     ..    section 0 data, then zero padding up to the next multiple of 64
//! ..      ..    section 1 data, ... (sections in table order)
//! ..      ..    metadata: one MessagePack value (struct fields by name), may be empty
//! ..      64*n  section table: n entries of 64 bytes; its end is the end of the file
//! ```
//!
//! Header (256 bytes):
//!
//! ```text
//! offset  size  field
//! 0       8     magic: "PCGIART\x01"
//! 8       4     format version (u32) = 1; a reader accepts exactly its own version
//! 12      4     artifact kind (u32): 1 octree, 2 vmap, 3 photons, 4 radiosity
//! 16      4     section count n (u32)
//! 20      4     flags (u32), 0
//! 24      32    stage name: UTF-8, 1..=32 bytes, zero padded
//! 56      16    stage version: UTF-8, 0..=16 bytes, zero padded
//! 72      16    key: xxh3-128 of the inputs and parameters (see `KeyHasher`)
//! 88      8     created, unix seconds (u64)
//! 96      8     file length in bytes (u64)
//! 104     8     section table offset (u64)
//! 112     8     section table length in bytes (u64) = 64 * n
//! 120     8     section table checksum: xxh3-64 of the table bytes (u64)
//! 128     8     metadata offset (u64)
//! 136     8     metadata length in bytes (u64)
//! 144     8     metadata checksum: xxh3-64 of the metadata bytes (u64)
//! 152     96    reserved, zero
//! 248     8     header checksum: xxh3-64 of these 256 bytes with this field zeroed (u64)
//! ```
//!
//! Section table entry (64 bytes):
//!
//! ```text
//! offset  size  field
//! 0       24    name: 1..=24 bytes of [a-z0-9_], zero padded
//! 24      8     offset of the data in the file (u64), a multiple of 64
//! 32      8     length of the data in bytes (u64), a multiple of the element size
//! 40      4     element size in bytes (u32), not 0
//! 44      4     alignment (u32) = 64
//! 48      8     checksum: xxh3-64 of the data (u64)
//! 56      8     reserved, zero
//! ```
//!
//! Section data is a plain array of `bytemuck::Pod` elements exactly as they lie in memory on
//! a little-endian machine, so a mapped section can be viewed as `&[T]` or uploaded to a GPU
//! buffer without conversion.

use std::fmt;
use std::fs::File;
use std::io;
use std::ops::Range;
use std::path::{Path, PathBuf};

use bytemuck::{Pod, Zeroable};
use memmap2::Mmap;
use serde::Deserialize;
use xxhash_rust::xxh3::xxh3_64;

use crate::error::{ArtifactError, METADATA_REGION, TABLE_REGION};
use crate::key::Key;
use crate::kind::ArtifactKind;

#[cfg(target_endian = "big")]
compile_error!("pcgi artifacts are little-endian arrays mapped as they are: big-endian targets are not supported");

/// The first eight bytes of every artifact.
pub const MAGIC: [u8; 8] = *b"PCGIART\x01";
/// The container format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// Every section (and the metadata and the table) starts on a multiple of this many bytes.
pub const SECTION_ALIGN: u64 = 64;
/// Size of the header at the start of the file.
pub const HEADER_SIZE: u64 = 256;
/// Size of one section table entry.
pub const TABLE_ENTRY_SIZE: u64 = 64;
/// Longest section name, in bytes.
pub const MAX_SECTION_NAME: usize = 24;
/// Longest stage name, in bytes of UTF-8.
pub const MAX_STAGE_NAME: usize = 32;
/// Longest stage version, in bytes of UTF-8.
pub const MAX_STAGE_VERSION: usize = 16;

/// The header as it lies on disk. Only ever read with `pod_read_unaligned` from a slice whose
/// length has been checked.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct RawHeader {
    pub(crate) magic: [u8; 8],
    pub(crate) format_version: u32,
    pub(crate) kind: u32,
    pub(crate) section_count: u32,
    pub(crate) flags: u32,
    pub(crate) stage: [u8; 32],
    pub(crate) stage_version: [u8; 16],
    pub(crate) key: [u8; 16],
    pub(crate) created_unix: u64,
    pub(crate) file_len: u64,
    pub(crate) table_offset: u64,
    pub(crate) table_len: u64,
    pub(crate) table_checksum: u64,
    pub(crate) metadata_offset: u64,
    pub(crate) metadata_len: u64,
    pub(crate) metadata_checksum: u64,
    pub(crate) reserved: [u64; 12],
    pub(crate) header_checksum: u64,
}

/// One section table entry as it lies on disk.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct RawEntry {
    pub(crate) name: [u8; 24],
    pub(crate) offset: u64,
    pub(crate) len: u64,
    pub(crate) elem_size: u32,
    pub(crate) align: u32,
    pub(crate) checksum: u64,
    pub(crate) reserved: u64,
}

const _: () = assert!(std::mem::size_of::<RawHeader>() == HEADER_SIZE as usize);
const _: () = assert!(std::mem::size_of::<RawEntry>() == TABLE_ENTRY_SIZE as usize);
const _: () = assert!(std::mem::offset_of!(RawHeader, format_version) == 8);
const _: () = assert!(std::mem::offset_of!(RawHeader, key) == 72);
const _: () = assert!(std::mem::offset_of!(RawHeader, file_len) == 96);
const _: () = assert!(std::mem::offset_of!(RawHeader, metadata_checksum) == 144);
const _: () = assert!(std::mem::offset_of!(RawHeader, header_checksum) == 248);
const _: () = assert!(std::mem::offset_of!(RawEntry, checksum) == 48);

impl RawHeader {
    /// xxh3-64 of the header with the checksum field zeroed.
    pub(crate) fn checksum(&self) -> u64 {
        let mut copy = *self;
        copy.header_checksum = 0;
        xxh3_64(bytemuck::bytes_of(&copy))
    }
}

pub(crate) fn align_up(pos: u64) -> u64 {
    pos.div_ceil(SECTION_ALIGN) * SECTION_ALIGN
}

/// Whether `name` is a valid section name: 1 to 24 bytes of `[a-z0-9_]`.
pub fn is_valid_section_name(name: &str) -> bool {
    valid_name_bytes(name.as_bytes())
}

pub(crate) fn valid_name_bytes(name: &[u8]) -> bool {
    (1..=MAX_SECTION_NAME).contains(&name.len())
        && name
            .iter()
            .all(|&b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
}

/// Decodes a zero-padded header field; the padding must be all zero.
fn decode_label(
    path: &Path,
    field: &'static str,
    raw: &[u8],
    min: usize,
) -> Result<String, ArtifactError> {
    let end = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
    let (text, padding) = raw.split_at(end);
    match std::str::from_utf8(text) {
        Ok(s) if s.len() >= min && padding.iter().all(|&b| b == 0) => Ok(s.to_owned()),
        _ => Err(ArtifactError::BadLabel {
            path: path.to_owned(),
            field,
            value: String::from_utf8_lossy(raw).into_owned(),
            min,
            max: raw.len(),
        }),
    }
}

// ---------------------------------------------------------------------------------------------
// Reader (the writer is in writer.rs)
// ---------------------------------------------------------------------------------------------

/// What the header of an artifact says.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HeaderInfo {
    pub kind: ArtifactKind,
    pub format_version: u32,
    /// The stage that wrote the artifact.
    pub stage: String,
    /// That stage's version.
    pub stage_version: String,
    /// The hash of the inputs and parameters the artifact was made from.
    pub key: Key,
    pub created_unix: u64,
    pub file_len: u64,
}

/// One entry of the section table, validated.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SectionInfo {
    pub name: String,
    /// Offset of the data in the file, a multiple of [`SECTION_ALIGN`].
    pub offset: u64,
    /// Length of the data in bytes.
    pub len: u64,
    /// Size of one element in bytes (not 0; divides `len`).
    pub elem_size: u32,
    pub align: u32,
    /// xxh3-64 of the data.
    pub checksum: u64,
}

impl SectionInfo {
    /// The number of elements in the section.
    pub fn count(&self) -> u64 {
        self.len / self.elem_size as u64
    }
}

/// A validated, memory-mapped artifact.
///
/// [`open`](Artifact::open) checks the whole file (lengths, magic, version, every bound,
/// alignment, and the checksums of the header, every section, the metadata and the table)
/// before it hands out anything, so a truncated or corrupt file is an error, never undefined
/// behaviour. Sections are borrowed straight from the mapping.
///
/// The mapping relies on pcgi's writers never modifying an artifact in place (they rename a
/// finished temporary file over it). If another program truncates a mapped artifact, reading
/// it raises SIGBUS; pcgi accepts that rather than copying every artifact into memory.
pub struct Artifact {
    path: PathBuf,
    map: Mmap,
    header: HeaderInfo,
    sections: Vec<SectionInfo>,
    metadata: Range<usize>,
}

impl fmt::Debug for Artifact {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Artifact")
            .field("path", &self.path)
            .field("header", &self.header)
            .field("sections", &self.sections)
            .finish_non_exhaustive()
    }
}

/// What validation found, for [`Artifact`] to keep.
struct Validated {
    header: HeaderInfo,
    sections: Vec<SectionInfo>,
    metadata: Range<usize>,
}

impl Artifact {
    /// Maps and validates the artifact at `path`, of any kind this build knows.
    pub fn open(path: impl AsRef<Path>) -> Result<Artifact, ArtifactError> {
        Artifact::open_inner(path.as_ref(), None)
    }

    /// Like [`open`](Artifact::open), and the artifact must be of `kind` (else
    /// [`ArtifactError::WrongKind`], reported before the sections are checked).
    pub fn open_kind(
        path: impl AsRef<Path>,
        kind: ArtifactKind,
    ) -> Result<Artifact, ArtifactError> {
        Artifact::open_inner(path.as_ref(), Some(kind))
    }

    /// [`ArtifactError::WrongKind`] unless the artifact is of `kind`.
    pub fn ensure_kind(&self, kind: ArtifactKind) -> Result<(), ArtifactError> {
        if self.kind() == kind {
            return Ok(());
        }
        Err(ArtifactError::WrongKind {
            path: self.path.clone(),
            expected: kind,
            got: self.kind().name().to_owned(),
        })
    }

    /// Like [`open_kind`](Artifact::open_kind) for a stage's input: a missing file is
    /// [`ArtifactError::MissingInput`], which names the stage that makes the kind.
    pub fn open_input(
        path: impl AsRef<Path>,
        kind: ArtifactKind,
    ) -> Result<Artifact, ArtifactError> {
        Artifact::open_inner(path.as_ref(), Some(kind)).map_err(|e| missing_input(e, kind))
    }

    /// The key of the artifact of `kind` at `path`, for deciding whether a stage that reads it
    /// is up to date: the header, the section table, the layout and the metadata are validated
    /// as [`open_input`](Artifact::open_input) does (with its errors), the sections' data is
    /// not read. Nothing of the file is handed out but the key, so no unchecked byte is ever
    /// cast; a stage that then runs opens the artifact whole. On the 1M Cornell this spares
    /// the up-to-date checks of a pc-run about 0.8 GB of checksums (docs/chain.md).
    pub fn input_key(path: impl AsRef<Path>, kind: ArtifactKind) -> Result<Key, ArtifactError> {
        let path = path.as_ref();
        Artifact::map_checked(path, Some(kind), Sections::Unread)
            .map(|(_, validated)| validated.header.key)
            .map_err(|e| missing_input(e, kind))
    }

    /// Like [`open_input`](Artifact::open_input) for a reader of some of the artifact's
    /// sections: the data of the sections `names` is checked (every section's bounds,
    /// alignment and layout still are), and only they are handed out (another is
    /// [`ArtifactError::MissingSection`]), so no unchecked byte is ever cast. The renderer
    /// reads the photon map's photons, not its specular links: 26 of its 172 MB at 1M splats.
    pub fn open_input_sections(
        path: impl AsRef<Path>,
        kind: ArtifactKind,
        names: &[&str],
    ) -> Result<Artifact, ArtifactError> {
        let path = path.as_ref();
        let (map, mut validated) = Artifact::map_checked(path, Some(kind), Sections::Only(names))
            .map_err(|e| missing_input(e, kind))?;
        validated
            .sections
            .retain(|s| names.contains(&s.name.as_str()));
        Ok(Artifact::from_validated(path, map, validated))
    }

    fn open_inner(path: &Path, expected: Option<ArtifactKind>) -> Result<Artifact, ArtifactError> {
        let (map, validated) = Artifact::map_checked(path, expected, Sections::Checked)?;
        Ok(Artifact::from_validated(path, map, validated))
    }

    fn from_validated(path: &Path, map: Mmap, validated: Validated) -> Artifact {
        Artifact {
            path: path.to_owned(),
            map,
            header: validated.header,
            sections: validated.sections,
            metadata: validated.metadata,
        }
    }

    /// Maps the file at `path` and validates it (the sections' checksums as `sections` says).
    fn map_checked(
        path: &Path,
        expected: Option<ArtifactKind>,
        sections: Sections<'_>,
    ) -> Result<(Mmap, Validated), ArtifactError> {
        let io_err = |e| ArtifactError::io(path, e);
        let file = File::open(path).map_err(io_err)?;
        let meta = file.metadata().map_err(io_err)?;
        if meta.is_dir() {
            return Err(io_err(io::Error::new(
                io::ErrorKind::IsADirectory,
                "this is a folder, not an artifact file",
            )));
        }
        if !meta.is_file() {
            return Err(io_err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "not a regular file",
            )));
        }
        if meta.len() < HEADER_SIZE {
            return Err(ArtifactError::Truncated {
                path: path.to_owned(),
                what: "header",
                need: HEADER_SIZE,
                have: meta.len(),
            });
        }
        // SAFETY: mapping a file is sound only while nobody modifies or truncates it. pcgi's
        // writers never modify an artifact in place: `ArtifactWriter` writes a temporary file
        // (`NAME.<pid>.<unique>.tmp`) and renames the finished file over `NAME`, which replaces
        // the directory entry and leaves the inode mapped here unchanged. Every byte is validated below before any cast, and
        // the mapping is read-only. Another program truncating the file while it is mapped
        // would make reads raise SIGBUS; we accept and document that (see `Artifact`).
        let map = unsafe { Mmap::map(&file) }.map_err(io_err)?;
        let validated = validate(path, &map, expected, sections)?;
        Ok((map, validated))
    }

    /// The file this artifact was opened from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What the header says.
    pub fn header(&self) -> &HeaderInfo {
        &self.header
    }

    /// The artifact's kind.
    pub fn kind(&self) -> ArtifactKind {
        self.header.kind
    }

    /// The key of the inputs and parameters the artifact was made from.
    pub fn key(&self) -> Key {
        self.header.key
    }

    /// The sections, in file order.
    pub fn sections(&self) -> &[SectionInfo] {
        &self.sections
    }

    /// The section named `name`, if there is one.
    pub fn section_info(&self, name: &str) -> Option<&SectionInfo> {
        self.sections.iter().find(|s| s.name == name)
    }

    /// Whether the artifact has a section named `name`.
    pub fn has_section(&self, name: &str) -> bool {
        self.section_info(name).is_some()
    }

    fn find(&self, name: &str) -> Result<&SectionInfo, ArtifactError> {
        self.section_info(name)
            .ok_or_else(|| ArtifactError::MissingSection {
                path: self.path.clone(),
                section: name.to_owned(),
            })
    }

    fn data(&self, info: &SectionInfo) -> &[u8] {
        // In bounds: checked by `validate` against this very mapping.
        let bytes = &self.map[info.offset as usize..(info.offset + info.len) as usize];
        debug_assert_eq!(bytes.as_ptr() as usize % SECTION_ALIGN as usize, 0);
        bytes
    }

    /// The section named `name` as a slice of `T`, borrowed from the mapping (64-byte aligned).
    ///
    /// Errors if there is no such section ([`ArtifactError::MissingSection`]) or its element
    /// size is not `size_of::<T>()` ([`ArtifactError::ElementSize`]).
    pub fn section<T: Pod>(&self, name: &str) -> Result<&[T], ArtifactError> {
        let info = self.find(name)?;
        if info.elem_size as usize != std::mem::size_of::<T>() {
            return Err(ArtifactError::ElementSize {
                path: self.path.clone(),
                section: name.to_owned(),
                expected: std::mem::size_of::<T>(),
                got: info.elem_size,
            });
        }
        let bytes = self.data(info);
        if bytes.is_empty() {
            return Ok(&[]);
        }
        bytemuck::try_cast_slice(bytes).map_err(|e| ArtifactError::Cast {
            path: self.path.clone(),
            section: name.to_owned(),
            msg: e.to_string(),
        })
    }

    /// The raw bytes of the section named `name`, whatever its element size.
    pub fn section_bytes(&self, name: &str) -> Result<&[u8], ArtifactError> {
        let info = self.find(name)?;
        Ok(self.data(info))
    }

    /// Decodes the MessagePack metadata.
    pub fn metadata<'a, M: Deserialize<'a>>(&'a self) -> Result<M, ArtifactError> {
        let bytes = self.metadata_bytes();
        if bytes.is_empty() {
            return Err(ArtifactError::Metadata {
                path: self.path.clone(),
                msg: "the artifact has no metadata".to_owned(),
            });
        }
        // An intact file whose metadata this build cannot read was written by another build
        // of its stage (a field added or retired): say which, and what makes it anew.
        rmp_serde::from_slice(bytes).map_err(|e| ArtifactError::Metadata {
            path: self.path.clone(),
            msg: format!(
                "{e} (written by {} {}, whose metadata this build does not read: rerun {})",
                self.header.stage, self.header.stage_version, self.header.stage
            ),
        })
    }

    /// The raw MessagePack metadata (empty if the writer set none).
    pub fn metadata_bytes(&self) -> &[u8] {
        &self.map[self.metadata.clone()]
    }

    /// Errors with [`ArtifactError::StaleKey`] unless the artifact was made with key `expected`.
    pub fn expect_key(&self, expected: &Key) -> Result<(), ArtifactError> {
        if self.header.key == *expected {
            Ok(())
        } else {
            Err(ArtifactError::StaleKey {
                path: self.path.clone(),
                expected: *expected,
                got: self.header.key,
            })
        }
    }

    /// An [`ArtifactError::Invalid`] naming this file, for the structural checks of the crate
    /// that owns this kind of artifact.
    pub fn invalid(&self, msg: impl Into<String>) -> ArtifactError {
        ArtifactError::invalid(&self.path, msg)
    }
}

/// A missing file of `kind` as [`ArtifactError::MissingInput`], which names the stage that makes
/// it; any other error as it is.
fn missing_input(e: ArtifactError, kind: ArtifactKind) -> ArtifactError {
    match e {
        ArtifactError::Io { path, source } if source.kind() == io::ErrorKind::NotFound => {
            ArtifactError::MissingInput {
                path,
                stage: kind.stage(),
                source,
            }
        }
        e => e,
    }
}

/// Whether [`validate`] checks the sections' checksums.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Sections<'n> {
    /// Every section's data against its checksum: an artifact whose sections are handed out.
    Checked,
    /// Not the data (its bounds, alignment and layout still): only the key is handed out
    /// ([`Artifact::input_key`]).
    Unread,
    /// The data of the sections named (the others' as [`Sections::Unread`]).
    Only(&'n [&'n str]),
}

impl Sections<'_> {
    /// Whether the data of the section `name` is checked.
    fn checks(&self, name: &str) -> bool {
        match self {
            Sections::Checked => true,
            Sections::Unread => false,
            Sections::Only(names) => names.contains(&name),
        }
    }
}

/// Checks every byte of `bytes` (the whole file; the sections' data as `sections` says) before
/// anything is cast.
fn validate(
    path: &Path,
    bytes: &[u8],
    expected_kind: Option<ArtifactKind>,
    sections: Sections<'_>,
) -> Result<Validated, ArtifactError> {
    let v = Checker {
        path,
        bytes,
        sections,
    };
    let (raw, kind) = v.header(expected_kind)?;
    let stage = decode_label(path, "stage name", &raw.stage, 1)?;
    let stage_version = decode_label(path, "stage version", &raw.stage_version, 0)?;
    let table = v.table(&raw)?;
    let metadata = v.region(METADATA_REGION, raw.metadata_offset, raw.metadata_len)?;
    v.checksum(
        METADATA_REGION,
        &bytes[metadata.clone()],
        raw.metadata_checksum,
    )?;
    let mut sections: Vec<SectionInfo> = Vec::with_capacity(raw.section_count as usize);
    for entry in table.chunks_exact(TABLE_ENTRY_SIZE as usize) {
        let info = v.section(bytemuck::pod_read_unaligned(entry), &sections)?;
        sections.push(info);
    }
    v.checksums(&sections)?;
    v.layout(&sections, &raw)?;
    Ok(Validated {
        header: HeaderInfo {
            kind,
            format_version: raw.format_version,
            stage,
            stage_version,
            key: Key(raw.key),
            created_unix: raw.created_unix,
            file_len: bytes.len() as u64,
        },
        sections,
        metadata,
    })
}

/// The checks of [`validate`], one per part of the file, each naming the file in its error.
struct Checker<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    sections: Sections<'a>,
}

impl Checker<'_> {
    fn file_len(&self) -> u64 {
        self.bytes.len() as u64
    }

    fn err_path(&self) -> PathBuf {
        self.path.to_owned()
    }

    /// The header: length, magic, version, checksum, kind (`expected` when given), file length.
    fn header(
        &self,
        expected: Option<ArtifactKind>,
    ) -> Result<(RawHeader, ArtifactKind), ArtifactError> {
        let file_len = self.file_len();
        if file_len < HEADER_SIZE {
            return Err(ArtifactError::Truncated {
                path: self.err_path(),
                what: "header",
                need: HEADER_SIZE,
                have: file_len,
            });
        }
        let raw: RawHeader = bytemuck::pod_read_unaligned(&self.bytes[..HEADER_SIZE as usize]);
        if raw.magic != MAGIC {
            return Err(ArtifactError::BadMagic {
                path: self.err_path(),
                found: raw.magic,
            });
        }
        // Before the checksum: another version may lay its header out differently, and "rerun
        // the stage" is the useful message then.
        if raw.format_version != FORMAT_VERSION {
            return Err(ArtifactError::Version {
                path: self.err_path(),
                expected: FORMAT_VERSION,
                got: raw.format_version,
            });
        }
        let header_checksum = raw.checksum();
        if header_checksum != raw.header_checksum {
            return Err(ArtifactError::HeaderChecksum {
                path: self.err_path(),
                expected: raw.header_checksum,
                got: header_checksum,
            });
        }
        let kind = self.kind(&raw, expected)?;
        if file_len < raw.file_len {
            return Err(ArtifactError::Truncated {
                path: self.err_path(),
                what: "artifact",
                need: raw.file_len,
                have: file_len,
            });
        }
        if file_len > raw.file_len {
            return Err(ArtifactError::FileLength {
                path: self.err_path(),
                expected: raw.file_len,
                have: file_len,
            });
        }
        Ok((raw, kind))
    }

    /// The header's kind: known, and `expected` when given.
    fn kind(
        &self,
        raw: &RawHeader,
        expected: Option<ArtifactKind>,
    ) -> Result<ArtifactKind, ArtifactError> {
        match (expected, ArtifactKind::from_u32(raw.kind)) {
            (Some(want), Some(got)) if want == got => Ok(got),
            (Some(want), got) => Err(ArtifactError::WrongKind {
                path: self.err_path(),
                expected: want,
                got: match got {
                    Some(k) => k.name().to_owned(),
                    None => format!("unknown kind {}", raw.kind),
                },
            }),
            (None, Some(got)) => Ok(got),
            (None, None) => Err(ArtifactError::UnknownKind {
                path: self.err_path(),
                kind: raw.kind,
            }),
        }
    }

    /// Byte range of a region, once it is known to lie inside the file after the header.
    fn region(&self, name: &str, offset: u64, len: u64) -> Result<Range<usize>, ArtifactError> {
        let file_len = self.file_len();
        match offset.checked_add(len) {
            Some(end) if offset >= HEADER_SIZE && end <= file_len => {
                Ok(offset as usize..end as usize)
            }
            _ => Err(ArtifactError::SectionBounds {
                path: self.err_path(),
                section: name.to_owned(),
                offset,
                len,
                file_len,
            }),
        }
    }

    fn checksum(&self, name: &str, data: &[u8], expected: u64) -> Result<(), ArtifactError> {
        let got = xxh3_64(data);
        if got == expected {
            return Ok(());
        }
        Err(ArtifactError::Checksum {
            path: self.err_path(),
            section: name.to_owned(),
            expected,
            got,
        })
    }

    /// The section table: its size for the section count, its bounds, its checksum.
    fn table(&self, raw: &RawHeader) -> Result<&[u8], ArtifactError> {
        if raw.table_len != raw.section_count as u64 * TABLE_ENTRY_SIZE {
            return Err(ArtifactError::Layout {
                path: self.err_path(),
                msg: format!(
                    "the section table is {} bytes, {} sections need {}",
                    raw.table_len,
                    raw.section_count,
                    raw.section_count as u64 * TABLE_ENTRY_SIZE
                ),
            });
        }
        let table = &self.bytes[self.region(TABLE_REGION, raw.table_offset, raw.table_len)?];
        self.checksum(TABLE_REGION, table, raw.table_checksum)?;
        Ok(table)
    }

    /// The checksums of the sections whose data is checked ([`Sections`]), hashed in parallel
    /// (at 20M points an octree's 4 GB took each later stage seconds on one core); the first
    /// mismatch in table order is the error.
    fn checksums(&self, sections: &[SectionInfo]) -> Result<(), ArtifactError> {
        use rayon::prelude::*;
        let checked: Vec<&SectionInfo> = sections
            .iter()
            .filter(|s| self.sections.checks(&s.name))
            .collect();
        // The largest first, so the others fill in beside it; then back in table order.
        let mut order: Vec<usize> = (0..checked.len()).collect();
        order.sort_by_key(|&k| std::cmp::Reverse(checked[k].len));
        let mut hashed: Vec<(usize, u64)> = order
            .par_iter()
            .with_max_len(1)
            .map(|&k| {
                let s = checked[k];
                let data = &self.bytes[s.offset as usize..(s.offset + s.len) as usize];
                (k, xxh3_64(data))
            })
            .collect();
        hashed.sort_unstable();
        let got = hashed.into_iter().map(|(_, h)| h);
        match checked.iter().zip(got).find(|(s, h)| *h != s.checksum) {
            Some((s, h)) => Err(ArtifactError::Checksum {
                path: self.err_path(),
                section: s.name.clone(),
                expected: s.checksum,
                got: h,
            }),
            None => Ok(()),
        }
    }

    /// One table entry: a valid name not seen `before`, in bounds, aligned, whole elements,
    /// reserved field zero (its checksum: [`Checker::checksums`]).
    fn section(
        &self,
        entry: RawEntry,
        before: &[SectionInfo],
    ) -> Result<SectionInfo, ArtifactError> {
        let end = entry
            .name
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(entry.name.len());
        let (name, padding) = entry.name.split_at(end);
        if !valid_name_bytes(name) || padding.iter().any(|&b| b != 0) {
            return Err(ArtifactError::BadName {
                path: self.err_path(),
                name: String::from_utf8_lossy(&entry.name).into_owned(),
            });
        }
        let name = std::str::from_utf8(name).expect("checked ASCII").to_owned();
        if before.iter().any(|s| s.name == name) {
            return Err(ArtifactError::DuplicateSection {
                path: self.err_path(),
                section: name,
            });
        }
        self.region(&name, entry.offset, entry.len)?;
        if !entry.offset.is_multiple_of(SECTION_ALIGN) || entry.align as u64 != SECTION_ALIGN {
            return Err(ArtifactError::Misaligned {
                path: self.err_path(),
                section: name,
                offset: entry.offset,
                align: entry.align,
            });
        }
        if entry.elem_size == 0 || !entry.len.is_multiple_of(entry.elem_size as u64) {
            return Err(ArtifactError::Ragged {
                path: self.err_path(),
                section: name,
                len: entry.len,
                elem_size: entry.elem_size,
            });
        }
        if entry.reserved != 0 {
            return Err(ArtifactError::Layout {
                path: self.err_path(),
                msg: format!("section `{name}` has a nonzero reserved field"),
            });
        }
        Ok(SectionInfo {
            name,
            offset: entry.offset,
            len: entry.len,
            elem_size: entry.elem_size,
            align: entry.align,
            checksum: entry.checksum,
        })
    }

    /// The regions follow the header in order, each on the next 64-byte boundary, with zero
    /// padding between them and nothing after the table. Together with the checksums this
    /// leaves no byte of the file unchecked.
    fn layout(&self, sections: &[SectionInfo], raw: &RawHeader) -> Result<(), ArtifactError> {
        let mut pos = HEADER_SIZE;
        let regions = sections
            .iter()
            .map(|s| (format!("section `{}`", s.name), s.offset, s.len))
            .chain([
                (
                    "the metadata".to_owned(),
                    raw.metadata_offset,
                    raw.metadata_len,
                ),
                (
                    "the section table".to_owned(),
                    raw.table_offset,
                    raw.table_len,
                ),
            ]);
        for (what, offset, len) in regions {
            let start = align_up(pos);
            if offset != start {
                return Err(ArtifactError::Layout {
                    path: self.err_path(),
                    msg: format!(
                        "{what} starts at offset {offset}, expected {start} \
                         (each region starts on the 64-byte boundary after the previous one)"
                    ),
                });
            }
            if let Some(i) = self.bytes[pos as usize..start as usize]
                .iter()
                .position(|&b| b != 0)
            {
                return Err(ArtifactError::Layout {
                    path: self.err_path(),
                    msg: format!(
                        "nonzero padding byte at offset {} before {what}",
                        pos + i as u64
                    ),
                });
            }
            pos = offset + len;
        }
        if pos != self.file_len() {
            return Err(ArtifactError::Layout {
                path: self.err_path(),
                msg: format!(
                    "{} bytes after the section table",
                    self.file_len().saturating_sub(pos)
                ),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::writer::encode_label;
    use crate::ArtifactWriter;

    #[test]
    fn section_names() {
        assert!(is_valid_section_name("nodes"));
        assert!(is_valid_section_name("a"));
        assert!(is_valid_section_name("abcdefghijklmnopqrstuvwx"));
        assert!(is_valid_section_name("level_0_points"));
        assert!(!is_valid_section_name(""));
        assert!(!is_valid_section_name("abcdefghijklmnopqrstuvwxy"));
        assert!(!is_valid_section_name("Nodes"));
        assert!(!is_valid_section_name("a-b"));
        assert!(!is_valid_section_name("a b"));
        assert!(!is_valid_section_name("é"));
    }

    #[test]
    fn labels() {
        let p = Path::new("x");
        let field = encode_label::<16>(p, "stage version", "0.1.0", 0).unwrap();
        assert_eq!(
            decode_label(p, "stage version", &field, 0).unwrap(),
            "0.1.0"
        );
        let empty = encode_label::<16>(p, "stage version", "", 0).unwrap();
        assert_eq!(decode_label(p, "stage version", &empty, 0).unwrap(), "");
        assert!(encode_label::<32>(p, "stage name", "", 1).is_err());
        assert!(encode_label::<4>(p, "stage name", "toolong", 1).is_err());
        assert!(encode_label::<8>(p, "stage name", "a\0b", 1).is_err());
        let full = encode_label::<4>(p, "stage name", "abcd", 1).unwrap();
        assert_eq!(decode_label(p, "stage name", &full, 1).unwrap(), "abcd");
        assert!(decode_label(p, "stage name", b"ab\0c", 1).is_err());
        assert!(decode_label(p, "stage name", b"\xff\0\0\0", 1).is_err());
    }

    #[test]
    fn types_cross_threads() {
        fn send_sync<T: Send + Sync + 'static>() {}
        send_sync::<Artifact>();
        send_sync::<ArtifactWriter>();
        send_sync::<ArtifactError>();
    }

    #[test]
    fn align() {
        assert_eq!(align_up(0), 0);
        assert_eq!(align_up(1), 64);
        assert_eq!(align_up(64), 64);
        assert_eq!(align_up(256), 256);
        assert_eq!(align_up(257), 320);
    }
}
