//! The running program's identity, which every stage key includes so that a rebuilt stage (a
//! changed algorithm) never reuses an artifact another build made.
//!
//! The identity is the linker's build id where the executable carries one (the ELF note
//! `NT_GNU_BUILD_ID`: GNU ld, gold, lld and mold compute it from the linked output's bytes, so
//! it changes with any change of code, and Rust's default Linux linking writes it), read from
//! the first pages of the file; else the xxh3-128 of the whole executable. Hashing the file was
//! the only way before, and it cost every stage process about 0.1 s (a 55 MB release binary
//! with its line tables) before its first useful step: half of the renderer's time to a new
//! view beyond its rendering (docs/chain.md, "Time to a new view").

use std::fs::File;
use std::io::{self, Read, Seek, SeekFrom};
use std::path::Path;

use crate::key::{Key, KeyHasher};

/// Identity of the running program (see the module), computed once per process. Falls back to
/// the package version when the executable cannot be read.
pub fn build_id() -> Key {
    static ID: std::sync::OnceLock<Key> = std::sync::OnceLock::new();
    *ID.get_or_init(|| {
        let exe = std::env::current_exe();
        let mut h = KeyHasher::new();
        match exe.as_deref().map(gnu_build_id) {
            Ok(Ok(Some(id))) => {
                h.update_str("gnu-build-id").update(&id);
            }
            _ => match exe.map(|p| h.update_file(&p).map(|_| ())) {
                Ok(Ok(())) => {}
                _ => {
                    h.update_str(env!("CARGO_PKG_VERSION"));
                }
            },
        }
        h.finish()
    })
}

/// The bytes of the `NT_GNU_BUILD_ID` note of the 64-bit little-endian ELF file at `path`, or
/// None where the file is no such ELF file or has no such note (then the caller hashes it).
pub fn gnu_build_id(path: &Path) -> io::Result<Option<Vec<u8>>> {
    let mut f = File::open(path)?;
    let mut header = [0u8; 64];
    if f.read_exact(&mut header).is_err() {
        return Ok(None);
    }
    // ELF magic, 64-bit class (2), little-endian data (1).
    if header[..4] != *b"\x7fELF" || header[4] != 2 || header[5] != 1 {
        return Ok(None);
    }
    let u16_at = |b: &[u8], at: usize| u16::from_le_bytes([b[at], b[at + 1]]);
    let u32_at = |b: &[u8], at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    let u64_at = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    let (phoff, phentsize, phnum) = (
        u64_at(&header, 32),
        u16_at(&header, 54) as usize,
        u16_at(&header, 56) as usize,
    );
    if phentsize < 56 || phnum == 0 || phnum > 256 {
        return Ok(None);
    }
    let mut table = vec![0u8; phentsize * phnum];
    f.seek(SeekFrom::Start(phoff))?;
    if f.read_exact(&mut table).is_err() {
        return Ok(None);
    }
    const PT_NOTE: u32 = 4;
    const NT_GNU_BUILD_ID: u32 = 3;
    for entry in table.chunks_exact(phentsize) {
        let (offset, size) = (u64_at(entry, 8), u64_at(entry, 32));
        if u32_at(entry, 0) != PT_NOTE || size > 1 << 16 {
            continue;
        }
        let mut notes = vec![0u8; size as usize];
        f.seek(SeekFrom::Start(offset))?;
        if f.read_exact(&mut notes).is_err() {
            return Ok(None);
        }
        // Notes: name size, descriptor size, type, then the name and the descriptor, each
        // padded to 4 bytes.
        let pad = |n: usize| n.div_ceil(4) * 4;
        let mut at = 0;
        while at + 12 <= notes.len() {
            let (namesz, descsz, kind) = (
                u32_at(&notes, at) as usize,
                u32_at(&notes, at + 4) as usize,
                u32_at(&notes, at + 8),
            );
            let name = at + 12;
            let desc = name + pad(namesz);
            let end = desc + pad(descsz);
            if end > notes.len() {
                break;
            }
            if kind == NT_GNU_BUILD_ID && notes[name..name + namesz] == *b"GNU\0" && descsz > 0 {
                return Ok(Some(notes[desc..desc + descsz].to_vec()));
            }
            at = end;
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn the_test_binary_has_a_gnu_build_id() {
        let exe = std::env::current_exe().unwrap();
        let id = gnu_build_id(&exe).unwrap().expect("a build id note");
        assert!(id.len() >= 8, "{id:?}");
        assert!(id.iter().any(|&b| b != 0), "{id:?}");
    }

    #[test]
    fn a_file_that_is_no_elf_has_none() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x");
        std::fs::write(&p, b"#!/bin/sh\necho hi\n").unwrap();
        assert_eq!(gnu_build_id(&p).unwrap(), None);
        std::fs::write(&p, b"\x7fELF\x02\x01").unwrap();
        assert_eq!(gnu_build_id(&p).unwrap(), None, "truncated");
    }

    /// A hand-made ELF header with one note segment holding a foreign note, then the build id.
    #[test]
    fn the_build_id_note_is_found_among_others() {
        let mut f = vec![0u8; 64];
        f[..6].copy_from_slice(b"\x7fELF\x02\x01");
        f[32..40].copy_from_slice(&64u64.to_le_bytes()); // program headers at 64
        f[54..56].copy_from_slice(&56u16.to_le_bytes());
        f[56..58].copy_from_slice(&1u16.to_le_bytes());
        let mut notes = Vec::new();
        let mut note = |name: &[u8], kind: u32, desc: &[u8]| {
            notes.extend((name.len() as u32).to_le_bytes());
            notes.extend((desc.len() as u32).to_le_bytes());
            notes.extend(kind.to_le_bytes());
            notes.extend(name);
            notes.resize(notes.len().div_ceil(4) * 4, 0);
            notes.extend(desc);
            notes.resize(notes.len().div_ceil(4) * 4, 0);
        };
        note(b"GNU\0", 1, &[9; 16]); // an ABI tag, not the id
        note(b"GNU\0", 3, &[1, 2, 3, 4, 5, 6, 7, 8, 9]);
        let mut ph = vec![0u8; 56];
        ph[..4].copy_from_slice(&4u32.to_le_bytes());
        ph[8..16].copy_from_slice(&120u64.to_le_bytes());
        ph[32..40].copy_from_slice(&(notes.len() as u64).to_le_bytes());
        f.extend(ph);
        f.extend(&notes);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("elf");
        std::fs::write(&p, &f).unwrap();
        assert_eq!(
            gnu_build_id(&p).unwrap(),
            Some(vec![1, 2, 3, 4, 5, 6, 7, 8, 9])
        );
    }
}
