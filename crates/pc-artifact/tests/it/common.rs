//! A small sample artifact and byte-patching helpers shared by the tests.

use std::path::{Path, PathBuf};

use bytemuck::{Pod, Zeroable};
use pc_artifact::{ArtifactKind, ArtifactWriter, Key, KeyHasher};
use serde::{Deserialize, Serialize};
use xxhash_rust::xxh3::xxh3_64;

/// A 24-byte element, like an octree node.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Node {
    pub center: [f32; 3],
    pub size: f32,
    pub first_child: u32,
    pub count: u32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Meta {
    pub scene: String,
    pub levels: u32,
    pub bounds: [f32; 6],
    pub key_of_input: Key,
}

pub fn nodes() -> Vec<Node> {
    (0..5)
        .map(|i| Node {
            center: [i as f32, -(i as f32), 0.5],
            size: 1.0 / (i + 1) as f32,
            first_child: i * 8,
            count: i + 100,
        })
        .collect()
}

pub fn points() -> Vec<[f32; 4]> {
    (0..7).map(|i| [i as f32, 2.0, 3.0, 1.0]).collect()
}

pub const IDS: [u16; 3] = [7, 8, 9];
pub const FLAGS: [u8; 1] = [0xa5];

pub fn meta() -> Meta {
    Meta {
        scene: "cornell".to_owned(),
        levels: 6,
        bounds: [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0],
        key_of_input: KeyHasher::new().update_str("input").finish(),
    }
}

pub fn key() -> Key {
    KeyHasher::new().update_str("sample").finish()
}

/// Section names of the sample artifact, in file order.
pub const SECTIONS: [&str; 5] = ["nodes", "points", "ids", "empty", "flags"];

/// Writes the sample artifact at `path`.
pub fn write_sample(path: &Path) -> PathBuf {
    let mut w =
        ArtifactWriter::create(path, ArtifactKind::Octree, "pc-octree", "0.0.0", key()).unwrap();
    w.section("nodes", &nodes()).unwrap();
    w.section("points", &points()).unwrap();
    w.section("ids", &IDS).unwrap();
    w.section::<u32>("empty", &[]).unwrap();
    w.section("flags", &FLAGS).unwrap();
    w.metadata(&meta()).unwrap();
    w.finish().unwrap()
}

/// A temporary folder holding the sample artifact at `sample.octree`.
pub fn sample() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = write_sample(&dir.path().join("sample.octree"));
    (dir, path)
}

pub fn u64_at(bytes: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap())
}

pub fn put_u32(bytes: &mut [u8], at: usize, v: u32) {
    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

pub fn put_u64(bytes: &mut [u8], at: usize, v: u64) {
    bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

// Header field offsets, from the layout documented in container.rs.
pub const H_VERSION: usize = 8;
pub const H_KIND: usize = 12;
pub const H_STAGE: usize = 24;
pub const H_TABLE_OFFSET: usize = 104;
pub const H_TABLE_LEN: usize = 112;
pub const H_TABLE_CHECKSUM: usize = 120;
pub const H_METADATA_OFFSET: usize = 128;
pub const H_METADATA_LEN: usize = 136;
pub const H_CHECKSUM: usize = 248;

// Section table entry field offsets.
pub const E_OFFSET: usize = 24;
pub const E_ELEM_SIZE: usize = 40;

/// Recomputes the header checksum, so that only the fields a test changed are wrong.
pub fn fix_header_checksum(bytes: &mut [u8]) {
    let mut header = bytes[..256].to_vec();
    header[H_CHECKSUM..H_CHECKSUM + 8].fill(0);
    put_u64(bytes, H_CHECKSUM, xxh3_64(&header));
}

/// Recomputes the table checksum and then the header checksum.
pub fn fix_table_checksum(bytes: &mut [u8]) {
    let offset = u64_at(bytes, H_TABLE_OFFSET) as usize;
    let len = u64_at(bytes, H_TABLE_LEN) as usize;
    let sum = xxh3_64(&bytes[offset..offset + len]);
    put_u64(bytes, H_TABLE_CHECKSUM, sum);
    fix_header_checksum(bytes);
}

/// The byte offset of table entry `index`.
pub fn entry_at(bytes: &[u8], index: usize) -> usize {
    u64_at(bytes, H_TABLE_OFFSET) as usize + 64 * index
}
