//! PLY point writer: positions with optional normals, radii and linear colors, binary or ASCII, written atomically.
//!
//! The vertex element carries `float x y z`, then (when present) `float nx ny nz`, `float radius`
//! and `float red green blue` (linear RGB, not 8-bit). Files are first written to `<path>.tmp`
//! through a large buffer and then renamed over `path`, so a reader never sees a half-written file.

use glam::Vec3;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use pc_artifact::atomic::AtomicFile;

/// Encoding of the PLY body.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PlyFormat {
    #[default]
    BinaryLittleEndian,
    BinaryBigEndian,
    Ascii,
}

impl PlyFormat {
    /// The keyword used on the header's `format` line.
    pub fn keyword(self) -> &'static str {
        match self {
            PlyFormat::BinaryLittleEndian => "binary_little_endian",
            PlyFormat::BinaryBigEndian => "binary_big_endian",
            PlyFormat::Ascii => "ascii",
        }
    }
}

/// Borrowed per-vertex attributes to write. Every present slice must be as long as `positions`.
#[derive(Clone, Copy, Debug)]
pub struct PlyPoints<'a> {
    pub positions: &'a [Vec3],
    pub normals: Option<&'a [Vec3]>,
    pub radii: Option<&'a [f32]>,
    /// Linear RGB, written as `float red green blue`.
    pub colors: Option<&'a [Vec3]>,
}

impl<'a> PlyPoints<'a> {
    /// Positions only.
    pub fn new(positions: &'a [Vec3]) -> Self {
        PlyPoints {
            positions,
            normals: None,
            radii: None,
            colors: None,
        }
    }

    /// Number of floats per vertex.
    pub fn floats_per_vertex(&self) -> usize {
        3 + if self.normals.is_some() { 3 } else { 0 }
            + if self.radii.is_some() { 1 } else { 0 }
            + if self.colors.is_some() { 3 } else { 0 }
    }

    /// Byte size of one vertex in a binary file.
    pub fn stride(&self) -> usize {
        4 * self.floats_per_vertex()
    }

    /// The property names in file order.
    pub fn property_names(&self) -> Vec<&'static str> {
        let mut names = vec!["x", "y", "z"];
        if self.normals.is_some() {
            names.extend(["nx", "ny", "nz"]);
        }
        if self.radii.is_some() {
            names.push("radius");
        }
        if self.colors.is_some() {
            names.extend(["red", "green", "blue"]);
        }
        names
    }

    fn validate(&self) -> io::Result<()> {
        let n = self.positions.len();
        let check = |what: &str, len: Option<usize>| -> io::Result<()> {
            match len {
                Some(l) if l != n => Err(io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!("PLY write: {what} has {l} entries but there are {n} positions"),
                )),
                _ => Ok(()),
            }
        };
        check("normals", self.normals.map(<[Vec3]>::len))?;
        check("radii", self.radii.map(<[f32]>::len))?;
        check("colors", self.colors.map(<[Vec3]>::len))?;
        Ok(())
    }

    /// The floats of vertex `i` in file order, into `out` (length `floats_per_vertex()`).
    #[inline]
    fn vertex(&self, i: usize, out: &mut [f32; 10]) -> usize {
        let p = self.positions[i];
        out[0] = p.x;
        out[1] = p.y;
        out[2] = p.z;
        let mut k = 3;
        if let Some(n) = self.normals {
            let n = n[i];
            out[k] = n.x;
            out[k + 1] = n.y;
            out[k + 2] = n.z;
            k += 3;
        }
        if let Some(r) = self.radii {
            out[k] = r[i];
            k += 1;
        }
        if let Some(c) = self.colors {
            let c = c[i];
            out[k] = c.x;
            out[k + 1] = c.y;
            out[k + 2] = c.z;
            k += 3;
        }
        k
    }
}

/// The complete header text (ending with `end_header\n`). Newlines in comments become spaces.
pub fn ply_header(pts: &PlyPoints, format: PlyFormat, comments: &[String]) -> String {
    let mut h = String::with_capacity(256);
    h.push_str("ply\n");
    h.push_str("format ");
    h.push_str(format.keyword());
    h.push_str(" 1.0\n");
    for c in comments {
        let c: String = c
            .chars()
            .map(|ch| if ch == '\n' || ch == '\r' { ' ' } else { ch })
            .collect();
        h.push_str("comment ");
        h.push_str(c.trim_end());
        h.push('\n');
    }
    h.push_str(&format!("element vertex {}\n", pts.positions.len()));
    for name in pts.property_names() {
        h.push_str("property float ");
        h.push_str(name);
        h.push('\n');
    }
    h.push_str("end_header\n");
    h
}

/// Writes `pts` as a PLY file at `path`, atomically ([`pc_artifact::atomic::AtomicFile`]).
pub fn write_ply(
    path: &Path,
    pts: &PlyPoints,
    format: PlyFormat,
    comments: &[String],
) -> io::Result<()> {
    pts.validate()?;
    let mut out = AtomicFile::create(path)?;
    let mut w = BufWriter::with_capacity(1 << 20, out.file());
    write_ply_to(&mut w, pts, format, comments)?;
    w.into_inner().map_err(|e| e.into_error())?;
    out.commit()
}

/// Writes the PLY header and body to any writer (no atomicity; see [`write_ply`]).
pub fn write_ply_to<W: Write>(
    w: &mut W,
    pts: &PlyPoints,
    format: PlyFormat,
    comments: &[String],
) -> io::Result<()> {
    pts.validate()?;
    w.write_all(ply_header(pts, format, comments).as_bytes())?;
    let n = pts.positions.len();
    let nf = pts.floats_per_vertex();
    let mut v = [0f32; 10];
    match format {
        PlyFormat::BinaryLittleEndian | PlyFormat::BinaryBigEndian => {
            let le = format == PlyFormat::BinaryLittleEndian;
            const CHUNK: usize = 16 * 1024;
            let mut buf: Vec<u8> = Vec::with_capacity(CHUNK * nf * 4);
            let mut start = 0;
            while start < n {
                let end = (start + CHUNK).min(n);
                buf.clear();
                for i in start..end {
                    let k = pts.vertex(i, &mut v);
                    if le {
                        for f in &v[..k] {
                            buf.extend_from_slice(&f.to_le_bytes());
                        }
                    } else {
                        for f in &v[..k] {
                            buf.extend_from_slice(&f.to_be_bytes());
                        }
                    }
                }
                w.write_all(&buf)?;
                start = end;
            }
        }
        PlyFormat::Ascii => {
            use std::fmt::Write as _;
            let mut line = String::with_capacity(160);
            for i in 0..n {
                let k = pts.vertex(i, &mut v);
                line.clear();
                for (j, f) in v[..k].iter().enumerate() {
                    if j > 0 {
                        line.push(' ');
                    }
                    // `{}` prints the shortest text that reads back to the same f32.
                    let _ = write!(line, "{f}");
                }
                line.push('\n');
                w.write_all(line.as_bytes())?;
            }
        }
    }
    w.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Minimal header parser: header lines and the byte length of the header.
    fn parse_header(bytes: &[u8]) -> (Vec<String>, usize) {
        let marker = b"end_header\n";
        let end = bytes
            .windows(marker.len())
            .position(|w| w == marker)
            .expect("end_header")
            + marker.len();
        let text = std::str::from_utf8(&bytes[..end]).unwrap();
        (text.lines().map(str::to_owned).collect(), end)
    }

    fn sample_points(n: usize) -> (Vec<Vec3>, Vec<Vec3>, Vec<f32>, Vec<Vec3>) {
        let p: Vec<Vec3> = (0..n)
            .map(|i| Vec3::new(i as f32 * 0.5, -(i as f32), 1.0 / (i as f32 + 1.0)))
            .collect();
        let nn: Vec<Vec3> = (0..n)
            .map(|i| Vec3::new((i as f32).cos(), (i as f32).sin(), 0.0))
            .collect();
        let r: Vec<f32> = (0..n).map(|i| 0.01 + i as f32 * 1e-3).collect();
        let c: Vec<Vec3> = (0..n).map(|i| Vec3::splat(i as f32 / n as f32)).collect();
        (p, nn, r, c)
    }

    #[test]
    fn binary_le_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.ply");
        let n = 1000;
        let (p, nn, r, _) = sample_points(n);
        let pts = PlyPoints {
            positions: &p,
            normals: Some(&nn),
            radii: Some(&r),
            colors: None,
        };
        let comments = vec!["scene test".to_string(), "two\nlines".to_string()];
        write_ply(&path, &pts, PlyFormat::BinaryLittleEndian, &comments).unwrap();
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no temporary file left"
        );
        let bytes = std::fs::read(&path).unwrap();
        let (lines, hlen) = parse_header(&bytes);
        assert_eq!(
            lines,
            vec![
                "ply",
                "format binary_little_endian 1.0",
                "comment scene test",
                "comment two lines",
                "element vertex 1000",
                "property float x",
                "property float y",
                "property float z",
                "property float nx",
                "property float ny",
                "property float nz",
                "property float radius",
                "end_header",
            ]
        );
        assert_eq!(pts.stride(), 28);
        assert_eq!(bytes.len(), hlen + n * 28);
        let body: Vec<f32> = bytes[hlen..]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        for i in 0..n {
            let v = &body[i * 7..i * 7 + 7];
            assert_eq!(Vec3::new(v[0], v[1], v[2]), p[i]);
            assert_eq!(Vec3::new(v[3], v[4], v[5]), nn[i]);
            assert_eq!(v[6], r[i]);
        }
    }

    #[test]
    fn binary_be_with_colors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.ply");
        let n = 37;
        let (p, _, _, c) = sample_points(n);
        let pts = PlyPoints {
            positions: &p,
            normals: None,
            radii: None,
            colors: Some(&c),
        };
        write_ply(&path, &pts, PlyFormat::BinaryBigEndian, &[]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let (lines, hlen) = parse_header(&bytes);
        assert_eq!(lines[1], "format binary_big_endian 1.0");
        assert_eq!(lines[2], "element vertex 37");
        assert_eq!(&lines[3..9].join(","), "property float x,property float y,property float z,property float red,property float green,property float blue");
        assert_eq!(bytes.len(), hlen + n * 24);
        let f = |k: usize| {
            f32::from_be_bytes(bytes[hlen + 4 * k..hlen + 4 * k + 4].try_into().unwrap())
        };
        assert_eq!(f(6 * 5 + 3), c[5].x);
        assert_eq!(f(6 * 36 + 1), p[36].y);
    }

    #[test]
    fn ascii_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.ply");
        let n = 50;
        let (p, nn, r, c) = sample_points(n);
        let pts = PlyPoints {
            positions: &p,
            normals: Some(&nn),
            radii: Some(&r),
            colors: Some(&c),
        };
        write_ply(&path, &pts, PlyFormat::Ascii, &["x".into()]).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let (lines, hlen) = parse_header(text.as_bytes());
        assert_eq!(lines.len(), 2 + 1 + 1 + 10 + 1);
        let body: Vec<&str> = text[hlen..].lines().collect();
        assert_eq!(body.len(), n);
        for (i, line) in body.iter().enumerate() {
            let v: Vec<f32> = line.split(' ').map(|s| s.parse().unwrap()).collect();
            assert_eq!(v.len(), 10);
            assert_eq!(Vec3::new(v[0], v[1], v[2]), p[i]);
            assert_eq!(Vec3::new(v[3], v[4], v[5]), nn[i]);
            assert_eq!(v[6], r[i]);
            assert_eq!(Vec3::new(v[7], v[8], v[9]), c[i]);
        }
    }

    #[test]
    fn length_mismatch_is_an_error_and_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.ply");
        let p = vec![Vec3::ZERO; 3];
        let r = vec![1.0; 2];
        let pts = PlyPoints {
            positions: &p,
            normals: None,
            radii: Some(&r),
            colors: None,
        };
        let e = write_ply(&path, &pts, PlyFormat::BinaryLittleEndian, &[]).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
        assert!(!path.exists());
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "no temporary file left"
        );
    }

    #[test]
    fn empty_point_set() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("e.ply");
        let pts = PlyPoints::new(&[]);
        write_ply(&path, &pts, PlyFormat::BinaryLittleEndian, &[]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let (lines, hlen) = parse_header(&bytes);
        assert_eq!(lines[2], "element vertex 0");
        assert_eq!(bytes.len(), hlen);
    }
}
