//! Checks of the sizes a LAS/LAZ file declares, made before the `las` and `laz` crates read
//! it: they allocate what the file says (an extended VLR's length, a LAZ chunk table's count
//! and sizes), so a damaged file would abort the process instead of giving an error. Found by
//! fuzzing (docs/artifacts.md, "Fuzzing").

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use crate::ImportError;

/// The largest LAZ chunk (points) accepted; writers use 50,000.
const MAX_CHUNK_POINTS: u64 = 1 << 26;
/// The most points a LAZ file may announce per byte of its size: LAZ takes 1.5 to 5 bytes a
/// point on real data; a count far beyond its size is a damaged header, and would otherwise
/// be allocated.
const MAX_LAZ_POINTS_PER_BYTE: u64 = 256;

fn read_at(file: &mut File, at: u64, buf: &mut [u8]) -> std::io::Result<()> {
    file.seek(SeekFrom::Start(at))?;
    file.read_exact(buf)
}

fn damaged(path: &Path, format: &'static str, what: String) -> ImportError {
    ImportError::scan(
        path,
        format,
        format!("{what}: the file is damaged or cut short"),
    )
}

/// Every extended VLR (LAS 1.4) lies within the file.
pub fn check_evlrs(
    path: &Path,
    file: &mut File,
    raw: &las::raw::Header,
    len: u64,
) -> Result<(), ImportError> {
    let Some(e) = &raw.evlr else {
        return Ok(());
    };
    let mut at = e.start_of_first_evlr;
    for i in 0..e.number_of_evlrs {
        let mut head = [0u8; 60];
        read_at(file, at, &mut head).map_err(|_| {
            damaged(
                path,
                "LAS",
                format!("extended VLR {i} at byte {at} lies beyond the end"),
            )
        })?;
        let size = u64::from_le_bytes(head[20..28].try_into().expect("eight bytes"));
        let end = at.checked_add(60).and_then(|a| a.checked_add(size));
        match end {
            Some(end) if end <= len => at = end,
            _ => {
                return Err(damaged(
                    path,
                    "LAS",
                    format!("extended VLR {i} declares {size} bytes, beyond the file's {len}"),
                ))
            }
        }
    }
    Ok(())
}

/// The LAZ chunk table: its count no larger than the points (each chunk holds one at least)
/// and the file, its chunks' sizes within the file, their point counts within the header's.
pub fn check_laz_tables(
    path: &Path,
    file: &mut File,
    raw: &las::raw::Header,
    announced: u64,
    len: u64,
) -> Result<(), ImportError> {
    if announced > len.saturating_mul(MAX_LAZ_POINTS_PER_BYTE) {
        return Err(damaged(
            path,
            "LAZ",
            format!(
                "the header announces {announced} points, more than a file of {len} bytes holds"
            ),
        ));
    }
    let Some(vlr) = laszip_vlr(file, raw)? else {
        return Err(ImportError::scan(
            path,
            "LAZ",
            "no laszip VLR: the file is not LAZ",
        ));
    };
    let vlr = laz::LazVlr::read_from(&vlr[..])
        .map_err(|e| damaged(path, "LAZ", format!("laszip VLR: {e}")))?;
    let record = u64::from(raw.point_data_record_length);
    if vlr.items_size() != record {
        let items = vlr.items_size();
        return Err(damaged(
            path,
            "LAZ",
            format!("the laszip VLR's records of {items} bytes differ from the header's {record}"),
        ));
    }
    if !vlr.uses_variable_size_chunks() && u64::from(vlr.chunk_size()) > MAX_CHUNK_POINTS {
        let n = vlr.chunk_size();
        return Err(damaged(path, "LAZ", format!("chunks of {n} points")));
    }
    let data = u64::from(raw.offset_to_point_data);
    let Some(table) = chunk_table_offset(file, data, len) else {
        return Ok(()); // no table: the reader says so itself
    };
    let mut head = [0u8; 8];
    read_at(file, table, &mut head)
        .map_err(|_| damaged(path, "LAZ", format!("the chunk table at byte {table}")))?;
    let chunks = u64::from(u32::from_le_bytes(
        head[4..8].try_into().expect("four bytes"),
    ));
    if chunks > announced.max(1) || chunks > len {
        return Err(damaged(
            path,
            "LAZ",
            format!("the chunk table lists {chunks} chunks for {announced} points"),
        ));
    }
    file.seek(SeekFrom::Start(data))
        .map_err(|e| ImportError::io(path, e))?;
    let entries = laz::laszip::ChunkTable::read_from(&mut *file, &vlr)
        .map_err(|e| damaged(path, "LAZ", format!("the chunk table: {e}")))?;
    let (mut bytes, mut points) = (0u64, 0u64);
    let entries = entries.as_ref();
    for (i, c) in entries.iter().enumerate() {
        bytes = bytes.saturating_add(c.byte_count);
        points = points.saturating_add(c.point_count);
        if c.point_count > MAX_CHUNK_POINTS || bytes > len {
            let (p, b) = (c.point_count, c.byte_count);
            return Err(damaged(
                path,
                "LAZ",
                format!("chunk {i} declares {p} points in {b} bytes"),
            ));
        }
    }
    if !entries.is_empty() && points < announced {
        return Err(damaged(
            path,
            "LAZ",
            format!("the chunk table holds {points} points, the header announces {announced}"),
        ));
    }
    Ok(())
}

/// Where the chunk table is, as the `laz` crate finds it: the offset at the start of the point
/// data, or (when a writer could not go back to fill it in) in the file's last eight bytes.
fn chunk_table_offset(file: &mut File, data: u64, len: u64) -> Option<u64> {
    let mut b = [0u8; 8];
    read_at(file, data, &mut b).ok()?;
    let mut at = i64::from_le_bytes(b);
    if at <= data as i64 {
        read_at(file, len.checked_sub(8)?, &mut b).ok()?;
        at = i64::from_le_bytes(b);
    }
    (at > data as i64).then_some(at as u64)
}

/// The record data of the laszip VLR, if the header's VLRs hold one.
fn laszip_vlr(file: &mut File, raw: &las::raw::Header) -> Result<Option<Vec<u8>>, ImportError> {
    let mut at = u64::from(raw.header_size);
    for _ in 0..raw.number_of_variable_length_records {
        let mut head = [0u8; 54];
        if read_at(file, at, &mut head).is_err() {
            return Ok(None);
        }
        let user = &head[2..18];
        let record = u16::from_le_bytes([head[18], head[19]]);
        let size = u16::from_le_bytes([head[20], head[21]]) as usize;
        if user.starts_with(laz::LazVlr::USER_ID.as_bytes()) && record == laz::LazVlr::RECORD_ID {
            let mut data = vec![0u8; size];
            if read_at(file, at + 54, &mut data).is_err() {
                return Ok(None);
            }
            return Ok(Some(data));
        }
        at += 54 + size as u64;
    }
    Ok(None)
}
