//! The atomic artifact writer: sections, metadata, table and header in the layout of
//! `container.rs`, published by [`crate::atomic::AtomicFile`].

use std::fmt;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use bytemuck::{Pod, Zeroable};
use serde::Serialize;
use xxhash_rust::xxh3::{xxh3_64, Xxh3};

use crate::atomic::AtomicFile;
use crate::container::{
    align_up, is_valid_section_name, RawEntry, RawHeader, FORMAT_VERSION, HEADER_SIZE, MAGIC,
    MAX_STAGE_NAME, MAX_STAGE_VERSION, SECTION_ALIGN,
};
use crate::{ArtifactError, ArtifactKind, Key};

/// Encodes a stage name or version into its zero-padded header field.
pub(crate) fn encode_label<const N: usize>(
    path: &Path,
    field: &'static str,
    value: &str,
    min: usize,
) -> Result<[u8; N], ArtifactError> {
    if value.len() < min || value.len() > N || value.contains('\0') {
        return Err(ArtifactError::BadLabel {
            path: path.to_owned(),
            field,
            value: value.to_owned(),
            min,
            max: N,
        });
    }
    let mut out = [0u8; N];
    out[..value.len()].copy_from_slice(value.as_bytes());
    Ok(out)
}

fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// Writes one artifact atomically ([`crate::atomic::AtomicFile`]): everything goes to a
/// temporary file `NAME.<pid>.<unique>.tmp` in the same folder, and
/// [`finish`](ArtifactWriter::finish) fsyncs it and renames it over `NAME`.
///
/// A reader never sees a half-written artifact, and a crash (or an error, or dropping the
/// writer without calling `finish`) leaves any older artifact at `NAME` as it was; dropping an
/// unfinished writer deletes its temporary file. Two writers of the same path each write their
/// own temporary file; the last to finish wins, and either result is complete.
///
/// ```no_run
/// # use pc_artifact::{ArtifactWriter, ArtifactKind, KeyHasher};
/// # fn main() -> Result<(), pc_artifact::ArtifactError> {
/// let key = KeyHasher::new().update_str("params").finish();
/// let mut w = ArtifactWriter::create("out/scene.photons", ArtifactKind::Photons, "pc-photons", "0.1.0", key)?;
/// w.section("positions", &[[0.0f32; 4]; 8])?;
/// w.metadata(&("any serde value", 42))?;
/// let path = w.finish()?;
/// # Ok(()) }
/// ```
pub struct ArtifactWriter {
    path: PathBuf,
    tmp_path: PathBuf,
    /// A second handle to `out`'s temporary file, buffered (the header is written last, through
    /// `out`'s own handle).
    file: Option<BufWriter<File>>,
    out: Option<AtomicFile>,
    header: RawHeader,
    pos: u64,
    entries: Vec<RawEntry>,
    names: Vec<String>,
    metadata: Vec<u8>,
    finished: bool,
}

impl fmt::Debug for ArtifactWriter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ArtifactWriter")
            .field("path", &self.path)
            .field("sections", &self.names)
            .field("pos", &self.pos)
            .finish_non_exhaustive()
    }
}

impl ArtifactWriter {
    /// Starts writing an artifact that [`finish`](ArtifactWriter::finish) will place at `path`.
    ///
    /// Creates the parent folders and a fresh temporary file beside `path`. `stage` is the
    /// producing stage's name (1 to 32 bytes), `stage_version` its version (0 to 16 bytes),
    /// `key` the hash of the inputs and parameters the artifact is made from.
    pub fn create(
        path: impl AsRef<Path>,
        kind: ArtifactKind,
        stage: &str,
        stage_version: &str,
        key: Key,
    ) -> Result<ArtifactWriter, ArtifactError> {
        let path = path.as_ref().to_path_buf();
        let stage = encode_label::<MAX_STAGE_NAME>(&path, "stage name", stage, 1)?;
        let stage_version =
            encode_label::<MAX_STAGE_VERSION>(&path, "stage version", stage_version, 0)?;
        let mut out = AtomicFile::create(&path).map_err(|e| ArtifactError::io(&path, e))?;
        let tmp_path = out.tmp_path().to_path_buf();
        let file = out
            .file()
            .try_clone()
            .map_err(|e| ArtifactError::io(&tmp_path, e))?;
        let header = RawHeader {
            magic: MAGIC,
            format_version: FORMAT_VERSION,
            kind: kind.as_u32(),
            stage,
            stage_version,
            key: key.0,
            ..RawHeader::zeroed()
        };
        let mut writer = ArtifactWriter {
            path,
            tmp_path,
            file: Some(BufWriter::with_capacity(1 << 20, file)),
            out: Some(out),
            header,
            pos: 0,
            entries: Vec::new(),
            names: Vec::new(),
            metadata: Vec::new(),
            finished: false,
        };
        // Placeholder; `finish` writes the real header once it knows the table and metadata.
        writer.write_raw(&[0u8; HEADER_SIZE as usize])?;
        Ok(writer)
    }

    /// The path the artifact will have once finished.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends a section holding `data`, an array of plain-old-data elements.
    ///
    /// `name` is 1 to 24 characters of `a-z`, `0-9` and `_`, unique within the artifact.
    /// `T` must not be zero-sized.
    pub fn section<T: Pod>(&mut self, name: &str, data: &[T]) -> Result<(), ArtifactError> {
        let elem_size = u32::try_from(std::mem::size_of::<T>()).unwrap_or(0);
        self.section_bytes(name, elem_size, bytemuck::cast_slice(data))
    }

    /// Appends a section of raw bytes holding `bytes.len() / elem_size` elements of
    /// `elem_size` bytes each (`elem_size` is not 0 and divides `bytes.len()`).
    pub fn section_bytes(
        &mut self,
        name: &str,
        elem_size: u32,
        bytes: &[u8],
    ) -> Result<(), ArtifactError> {
        if !is_valid_section_name(name) {
            return Err(ArtifactError::BadName {
                path: self.path.clone(),
                name: name.to_owned(),
            });
        }
        if self.names.iter().any(|n| n == name) {
            return Err(ArtifactError::DuplicateSection {
                path: self.path.clone(),
                section: name.to_owned(),
            });
        }
        if elem_size == 0 || !bytes.len().is_multiple_of(elem_size as usize) {
            return Err(ArtifactError::Ragged {
                path: self.path.clone(),
                section: name.to_owned(),
                len: bytes.len() as u64,
                elem_size,
            });
        }
        self.pad()?;
        let offset = self.pos;
        let mut hasher = Xxh3::new();
        for chunk in bytes.chunks(1 << 20) {
            hasher.update(chunk);
            self.write_raw(chunk)?;
        }
        let mut entry = RawEntry {
            offset,
            len: bytes.len() as u64,
            elem_size,
            align: SECTION_ALIGN as u32,
            checksum: hasher.digest(),
            ..RawEntry::zeroed()
        };
        entry.name[..name.len()].copy_from_slice(name.as_bytes());
        self.entries.push(entry);
        self.names.push(name.to_owned());
        Ok(())
    }

    /// Puts the sections written so far on the disk (flush and `fdatasync`), so that
    /// [`finish`](ArtifactWriter::finish)'s own sync waits only for what follows. A writer
    /// that has work to overlap calls it from its own thread: pc-octree writes its tree this
    /// way while the splats' areas are computed, instead of waiting for the disk at the end.
    pub fn sync_written(&mut self) -> Result<(), ArtifactError> {
        let file = self.file.as_mut().expect("file is present until finish");
        let io_err = |e| ArtifactError::io(&self.tmp_path, e);
        file.flush().map_err(io_err)?;
        file.get_ref().sync_data().map_err(io_err)
    }

    /// Sets the metadata to bytes already encoded (tools that copy or rewrite an artifact).
    pub fn metadata_raw(&mut self, bytes: Vec<u8>) {
        self.metadata = bytes;
    }

    /// Sets the artifact's metadata, stored as MessagePack (struct fields by name) when the
    /// artifact is finished. A second call replaces the first.
    pub fn metadata<M: Serialize + ?Sized>(&mut self, metadata: &M) -> Result<(), ArtifactError> {
        self.metadata = rmp_serde::to_vec_named(metadata).map_err(|e| ArtifactError::Metadata {
            path: self.path.clone(),
            msg: e.to_string(),
        })?;
        Ok(())
    }

    /// Writes the metadata, the section table and the header, fsyncs the file, renames it
    /// over the final path and fsyncs the folder (best effort). Returns the final path.
    pub fn finish(mut self) -> Result<PathBuf, ArtifactError> {
        self.pad()?;
        let metadata = std::mem::take(&mut self.metadata);
        self.header.metadata_offset = self.pos;
        self.header.metadata_len = metadata.len() as u64;
        self.header.metadata_checksum = xxh3_64(&metadata);
        self.write_raw(&metadata)?;

        self.pad()?;
        let entries = std::mem::take(&mut self.entries);
        let table: &[u8] = bytemuck::cast_slice(&entries);
        self.header.section_count = entries.len() as u32;
        self.header.table_offset = self.pos;
        self.header.table_len = table.len() as u64;
        self.header.table_checksum = xxh3_64(table);
        self.write_raw(table)?;

        self.header.file_len = self.pos;
        self.header.created_unix = now_unix();
        self.header.header_checksum = self.header.checksum();

        let tmp = self.tmp_path.clone();
        let io_err = |e| ArtifactError::io(&tmp, e);
        let buffered = self.file.take().expect("file is present until finish");
        let mut file = buffered.into_inner().map_err(|e| io_err(e.into_error()))?;
        file.seek(SeekFrom::Start(0)).map_err(io_err)?;
        file.write_all(bytemuck::bytes_of(&self.header))
            .map_err(io_err)?;
        drop(file);
        // fsync, rename over the final path, fsync the folder.
        let out = self.out.take().expect("present until finish");
        out.commit().map_err(|e| ArtifactError::io(&self.path, e))?;
        self.finished = true;
        Ok(self.path.clone())
    }

    fn write_raw(&mut self, bytes: &[u8]) -> Result<(), ArtifactError> {
        let file = self.file.as_mut().expect("file is present until finish");
        file.write_all(bytes)
            .map_err(|e| ArtifactError::io(&self.tmp_path, e))?;
        self.pos += bytes.len() as u64;
        Ok(())
    }

    /// Zero bytes up to the next multiple of [`SECTION_ALIGN`].
    fn pad(&mut self) -> Result<(), ArtifactError> {
        let padding = (align_up(self.pos) - self.pos) as usize;
        self.write_raw(&[0u8; SECTION_ALIGN as usize][..padding])
    }
}

impl Drop for ArtifactWriter {
    fn drop(&mut self) {
        if !self.finished {
            if let Some(buffered) = self.file.take() {
                // Discard the buffer instead of flushing it into a file about to be deleted.
                let (file, _unflushed) = buffered.into_parts();
                drop(file);
            }
            // Dropping the uncommitted `AtomicFile` deletes the temporary file.
            self.out = None;
        }
    }
}
