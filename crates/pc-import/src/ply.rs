//! PLY import: a fast, strict reader for oriented point clouds (ASCII and binary, any scalar type).
//!
//! The header is parsed by `ply-rs-bw`; the body is decoded here, without a per-vertex map:
//!
//! * binary, vertex element without list properties: fixed-size records, every used property at
//!   a precomputed offset, decoded in parallel (rayon) over chunks of records;
//! * binary with list properties in the vertex element: one sequential walk;
//! * ASCII: one vertex per line; a sequential scan finds the lines, then chunks of lines are
//!   parsed in parallel.
//!
//! Elements other than `vertex` (faces, edges, ...) are skipped, whether they come before or after
//! it, including their list properties. Every error names the file and, for a bad point, its
//! 0-based vertex index; when several points are bad the lowest index is reported, however the
//! work was split.
//!
//! Used properties: `x y z` (required), `nx ny nz` (optional, all three or none), `radius`
//! (optional), colors `red green blue`, or `r g b`, or `diffuse_red diffuse_green diffuse_blue`
//! (optional, the first complete set). Integer colors are normalized by 255 (`char`, `uchar`,
//! `int`, `uint`) or 65535 (`short`, `ushort`) and sRGB-decoded to linear RGB; `float`/`double`
//! colors are taken as linear already (negative values clamped to 0).

use std::path::Path;

use glam::Vec3;
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{DefaultElement, Encoding, PropertyType, ScalarType};
use rayon::prelude::*;

use crate::points::srgb_to_linear;
use crate::ImportError;

pub use crate::points::{PlyOptions, PointSet};

/// The header's `comment` and `obj_info` lines may hold any bytes (scanner software writes
/// Latin-1 names and degree signs there); the header parser reads UTF-8. Their bytes outside
/// ASCII become `?`, one for one, so the body stays where it was; `None` when there are none.
fn sanitize_comments(bytes: &[u8]) -> Option<Vec<u8>> {
    let end = bytes
        .windows(10)
        .take(1 << 20)
        .position(|w| w == b"end_header")?;
    let mut out: Option<Vec<u8>> = None;
    let mut start = 0;
    while start < end {
        let stop = bytes[start..end]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(end, |k| start + k);
        let line = &bytes[start..stop];
        let free = line.starts_with(b"comment") || line.starts_with(b"obj_info");
        if free && line.iter().any(|&b| b >= 0x80) {
            let v = out.get_or_insert_with(|| bytes.to_vec());
            for b in &mut v[start..stop] {
                if *b >= 0x80 {
                    *b = b'?';
                }
            }
        }
        start = stop + 1;
    }
    out
}

/// The 1-based number of the first header line that is not UTF-8, if any.
fn non_text_header_line(bytes: &[u8]) -> Option<usize> {
    let end = bytes
        .windows(10)
        .take(1 << 20)
        .position(|w| w == b"end_header")
        .unwrap_or(bytes.len().min(1 << 20));
    bytes[..end]
        .split(|&b| b == b'\n')
        .position(|line| std::str::from_utf8(line).is_err())
        .map(|i| i + 1)
}

/// Read a PLY point cloud from `path`, which must be a regular file: a FIFO or a device
/// (`/dev/zero`) would never end and is refused before it is opened.
pub fn read_ply(path: &Path, opts: &PlyOptions) -> Result<PointSet, ImportError> {
    crate::check_regular_file(path)?;
    let bytes = std::fs::read(path).map_err(|e| ImportError::io(path, e))?;
    parse_ply(&bytes, path, opts)
}

/// Parse a PLY file already in memory; `path` is only used in errors.
pub fn parse_ply(bytes: &[u8], path: &Path, opts: &PlyOptions) -> Result<PointSet, ImportError> {
    let sanitized = sanitize_comments(bytes);
    let bytes: &[u8] = sanitized.as_deref().unwrap_or(bytes);
    let mut reader = Reader::new(bytes);
    let header = Parser::<DefaultElement>::new()
        .read_header(&mut reader)
        .map_err(|e| {
            let why = match non_text_header_line(bytes) {
                Some(n) => format!(
                    "header line {n} is not UTF-8 text (bytes outside ASCII are allowed in \
                     comment and obj_info lines only)"
                ),
                None => flatten(&e.to_string()),
            };
            ImportError::ply(path, format!("header: {why}"))
        })?;
    let body_line = reader.line();
    let body: &[u8] = reader.into_inner();
    let header_len = bytes.len() - body.len();
    check_duplicates(&bytes[..header_len], header.elements.len(), path)?;

    let elements: Vec<ElemLayout> = header
        .elements
        .values()
        .map(|e| ElemLayout {
            name: e.name.clone(),
            count: e.count,
            props: e
                .properties
                .values()
                .map(|p| {
                    let kind = match &p.data_type {
                        PropertyType::Scalar(s) => PropKind::Scalar(Ty::from(s)),
                        PropertyType::List(c, s) => PropKind::List(Ty::from(c), Ty::from(s)),
                    };
                    (p.name.clone(), kind)
                })
                .collect(),
        })
        .collect();
    let vi = elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| ImportError::NoVertexElement {
            path: path.to_path_buf(),
        })?;
    let vertex = &elements[vi];
    let map = VertexMap::new(vertex, path)?;
    if vertex.count == 0 {
        return Err(ImportError::Empty {
            path: path.to_path_buf(),
        });
    }
    let ctx = Ctx {
        path,
        map: &map,
        drop_invalid: opts.drop_invalid,
        count: vertex.count,
    };
    match header.encoding {
        Encoding::Ascii => decode_ascii(body, body_line, &elements[..vi], vertex, &ctx),
        Encoding::BinaryLittleEndian => {
            decode_binary::<false>(body, header_len, &elements[..vi], vertex, &ctx)
        }
        Encoding::BinaryBigEndian => {
            decode_binary::<true>(body, header_len, &elements[..vi], vertex, &ctx)
        }
    }
}

/// ply-rs-bw's messages span several lines; keep errors on one.
fn flatten(msg: &str) -> String {
    let flat = msg
        .split(['\n', '\t'])
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect::<Vec<_>>()
        .join("; ");
    // ply-rs-bw appends its parser's internal state ("; Error: ParseError { .. }") after the
    // offending line; the line number and the quoted text are what a user needs.
    match flat.find("; Error: ") {
        Some(i) => flat[..i].trim_end_matches(';').trim_end().to_string(),
        None => flat,
    }
}

/// ply-rs-bw keeps elements and properties in maps, so a repeated name would silently merge
/// two declarations and shift every binary offset. Count the declarations in the raw header.
fn check_duplicates(header: &[u8], parsed_elements: usize, path: &Path) -> Result<(), ImportError> {
    let text = String::from_utf8_lossy(header);
    let mut elements = 0usize;
    let mut current: Vec<&str> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let mut words = line.split_ascii_whitespace();
        match words.next() {
            Some("element") => {
                elements += 1;
                current.clear();
            }
            Some("property") => {
                let name = words.last().unwrap_or("");
                if current.contains(&name) {
                    return Err(ImportError::ply(
                        path,
                        format!("header line {}: property `{name}` declared twice", n + 1),
                    ));
                }
                current.push(name);
            }
            _ => {}
        }
    }
    if elements != parsed_elements {
        return Err(ImportError::ply(
            path,
            "header: an element name is declared twice",
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Types and layout

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn from(s: &ScalarType) -> Ty {
        match s {
            ScalarType::Char => Ty::I8,
            ScalarType::UChar => Ty::U8,
            ScalarType::Short => Ty::I16,
            ScalarType::UShort => Ty::U16,
            ScalarType::Int => Ty::I32,
            ScalarType::UInt => Ty::U32,
            ScalarType::Float => Ty::F32,
            ScalarType::Double => Ty::F64,
        }
    }

    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum PropKind {
    Scalar(Ty),
    /// (count type, item type)
    List(Ty, Ty),
}

struct ElemLayout {
    name: String,
    count: usize,
    props: Vec<(String, PropKind)>,
}

impl ElemLayout {
    /// Record size when the element has no list properties.
    fn fixed_size(&self) -> Option<usize> {
        self.props.iter().try_fold(0usize, |acc, (_, k)| match k {
            PropKind::Scalar(t) => Some(acc + t.size()),
            PropKind::List(..) => None,
        })
    }
}

/// Value slots of one decoded vertex.
const SLOTS: usize = 10;
const POS: usize = 0;
const NRM: usize = 3;
const RAD: usize = 6;
const COL: usize = 7;

/// How a color channel is turned into linear RGB.
#[derive(Clone, Copy, Debug)]
enum ColorConv {
    /// `uchar`: sRGB table.
    U8,
    /// Other integers: normalize by the scale, clamp, sRGB-decode.
    Int(f64),
    /// Already linear.
    Float,
}

/// Which vertex properties we use, and where they go.
struct VertexMap {
    /// For each property of the vertex element, the slot it fills.
    slot_of: Vec<Option<usize>>,
    /// Property name of each used slot (for errors).
    names: [String; SLOTS],
    normals: bool,
    radius: bool,
    colors: bool,
    color_conv: [ColorConv; 3],
}

impl VertexMap {
    fn new(vertex: &ElemLayout, path: &Path) -> Result<VertexMap, ImportError> {
        let find = |name: &str| vertex.props.iter().position(|(n, _)| n == name);
        let mut slot_of = vec![None; vertex.props.len()];
        let mut names: [String; SLOTS] = Default::default();
        let mut bind = |prop: usize, slot: usize| -> Result<(), ImportError> {
            let (name, kind) = &vertex.props[prop];
            if let PropKind::List(..) = kind {
                return Err(ImportError::ListProperty {
                    path: path.to_path_buf(),
                    property: name.clone(),
                });
            }
            slot_of[prop] = Some(slot);
            names[slot] = name.clone();
            Ok(())
        };
        for (i, name) in ["x", "y", "z"].into_iter().enumerate() {
            let p = find(name).ok_or_else(|| ImportError::MissingProperty {
                path: path.to_path_buf(),
                property: name,
            })?;
            bind(p, POS + i)?;
        }
        let nrm = ["nx", "ny", "nz"].map(|n| (n, find(n)));
        let normals = nrm.iter().any(|(_, p)| p.is_some());
        if normals {
            for (i, (name, p)) in nrm.into_iter().enumerate() {
                let p = p.ok_or_else(|| ImportError::MissingProperty {
                    path: path.to_path_buf(),
                    property: name,
                })?;
                bind(p, NRM + i)?;
            }
        }
        let radius = match find("radius") {
            Some(p) => {
                bind(p, RAD)?;
                true
            }
            None => false,
        };
        let mut color_conv = [ColorConv::Float; 3];
        let mut colors = false;
        for set in [
            ["red", "green", "blue"],
            ["r", "g", "b"],
            ["diffuse_red", "diffuse_green", "diffuse_blue"],
        ] {
            let ps = set.map(find);
            if ps.iter().all(Option::is_some) {
                for (c, p) in ps.into_iter().enumerate() {
                    let p = p.unwrap();
                    bind(p, COL + c)?;
                    if let PropKind::Scalar(t) = vertex.props[p].1 {
                        color_conv[c] = match t {
                            Ty::U8 => ColorConv::U8,
                            Ty::I8 | Ty::I32 | Ty::U32 => ColorConv::Int(1.0 / 255.0),
                            Ty::I16 | Ty::U16 => ColorConv::Int(1.0 / 65535.0),
                            Ty::F32 | Ty::F64 => ColorConv::Float,
                        };
                    }
                }
                colors = true;
                break;
            }
        }
        Ok(VertexMap {
            slot_of,
            names,
            normals,
            radius,
            colors,
            color_conv,
        })
    }
}

/// What every decoder needs.
struct Ctx<'a> {
    path: &'a Path,
    map: &'a VertexMap,
    drop_invalid: bool,
    count: usize,
}

// ---------------------------------------------------------------------------------------------
// Validation and accumulation

/// Why a point is invalid.
#[derive(Clone, Copy, Debug)]
enum Invalid {
    NonFinite { slot: usize, value: f64 },
    ZeroNormal,
    BadRadius(f64),
}

const REASONS: [&str; 5] = [
    "non-finite position",
    "non-finite normal",
    "zero-length normal",
    "non-positive or non-finite radius",
    "non-finite color",
];

impl Invalid {
    fn reason(self) -> usize {
        match self {
            Invalid::NonFinite { slot, .. } if slot < NRM => 0,
            Invalid::NonFinite { slot, .. } if slot < RAD => 1,
            Invalid::NonFinite { .. } => 4,
            Invalid::ZeroNormal => 2,
            Invalid::BadRadius(_) => 3,
        }
    }

    fn into_error(self, ctx: &Ctx, index: usize) -> ImportError {
        let path = ctx.path.to_path_buf();
        match self {
            Invalid::NonFinite { slot, value } => ImportError::NonFinite {
                path,
                index,
                property: ctx.map.names[slot].clone(),
                value,
            },
            Invalid::ZeroNormal => ImportError::ZeroNormal { path, index },
            Invalid::BadRadius(value) => ImportError::BadRadius { path, index, value },
        }
    }
}

/// sRGB transfer function, decoded.
fn srgb_u8_table() -> &'static [f32; 256] {
    static TABLE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|i| srgb_to_linear(i as f64 / 255.0) as f32))
}

/// The output arrays, one slot per declared vertex (absent attributes are empty); chunks of
/// vertices are decoded into disjoint parts of them, and compacted afterwards if points were
/// dropped.
struct Outputs {
    pos: Vec<Vec3>,
    nrm: Vec<Vec3>,
    rad: Vec<f32>,
    col: Vec<Vec3>,
}

/// A zeroed `Vec<Vec3>` from `calloc` (no initialization pass; pages come in on first write).
fn zeroed_vec3(n: usize) -> Vec<Vec3> {
    bytemuck::allocation::cast_vec(vec![0f32; 3 * n])
}

impl Outputs {
    fn new(n: usize, map: &VertexMap) -> Outputs {
        let opt = |b: bool| if b { n } else { 0 };
        Outputs {
            pos: zeroed_vec3(n),
            nrm: zeroed_vec3(opt(map.normals)),
            rad: vec![0f32; opt(map.radius)],
            col: zeroed_vec3(opt(map.colors)),
        }
    }

    /// One sink per chunk of `sizes` consecutive vertices.
    fn sinks(&mut self, sizes: impl Iterator<Item = usize>) -> Vec<Sink<'_>> {
        fn take<'a, T>(rest: &mut &'a mut [T], n: usize) -> &'a mut [T] {
            let n = n.min(rest.len()); // 0 for an absent attribute
            let (head, tail) = std::mem::take(rest).split_at_mut(n);
            *rest = tail;
            head
        }
        let (mut pos, mut nrm, mut rad, mut col) = (
            &mut self.pos[..],
            &mut self.nrm[..],
            &mut self.rad[..],
            &mut self.col[..],
        );
        sizes
            .map(|n| Sink {
                pos: take(&mut pos, n),
                nrm: take(&mut nrm, n),
                rad: take(&mut rad, n),
                col: take(&mut col, n),
                done: Done::default(),
            })
            .collect()
    }
}

/// What decoding one chunk found.
#[derive(Clone, Copy, Debug, Default)]
struct Done {
    /// Valid points written (at the start of the chunk's part of the outputs).
    kept: usize,
    /// Vertices consumed.
    read: usize,
    drops: [usize; REASONS.len()],
    /// The first invalid point of the chunk (when not dropping); decoding stops there.
    first: Option<(usize, Invalid)>,
}

/// Decoded, validated points of one chunk of vertices go here.
struct Sink<'a> {
    pos: &'a mut [Vec3],
    nrm: &'a mut [Vec3],
    rad: &'a mut [f32],
    col: &'a mut [Vec3],
    done: Done,
}

impl Sink<'_> {
    /// Validate and store the chunk's vertex `local`; false when decoding must stop.
    #[inline]
    fn accept(&mut self, ctx: &Ctx, local: usize, v: &[f64; SLOTS]) -> bool {
        self.done.read += 1;
        match check(ctx.map, v) {
            Ok((p, n, r, c)) => {
                let w = self.done.kept;
                self.pos[w] = p;
                if ctx.map.normals {
                    self.nrm[w] = n;
                }
                if ctx.map.radius {
                    self.rad[w] = r;
                }
                if ctx.map.colors {
                    self.col[w] = c;
                }
                self.done.kept += 1;
                true
            }
            Err(inv) if ctx.drop_invalid => {
                self.done.drops[inv.reason()] += 1;
                true
            }
            Err(inv) => {
                self.done.first = Some((local, inv));
                false
            }
        }
    }
}

/// Validate one decoded vertex: (position, unit normal, radius, linear color).
#[inline]
fn check(map: &VertexMap, v: &[f64; SLOTS]) -> Result<(Vec3, Vec3, f32, Vec3), Invalid> {
    let p = Vec3::new(v[POS] as f32, v[POS + 1] as f32, v[POS + 2] as f32);
    if !p.is_finite() {
        let slot = (POS..POS + 3)
            .find(|&s| !(v[s] as f32).is_finite())
            .unwrap();
        return Err(Invalid::NonFinite {
            slot,
            value: v[slot],
        });
    }
    let mut n = Vec3::ZERO;
    if map.normals {
        let (x, y, z) = (v[NRM], v[NRM + 1], v[NRM + 2]);
        if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            let slot = (NRM..NRM + 3).find(|&s| !v[s].is_finite()).unwrap();
            return Err(Invalid::NonFinite {
                slot,
                value: v[slot],
            });
        }
        // Scale first so that huge or tiny doubles neither overflow nor underflow.
        let m = x.abs().max(y.abs()).max(z.abs());
        if m == 0.0 {
            return Err(Invalid::ZeroNormal);
        }
        let (sx, sy, sz) = (x / m, y / m, z / m);
        let l = (sx * sx + sy * sy + sz * sz).sqrt();
        if m * l < 1e-12 {
            return Err(Invalid::ZeroNormal);
        }
        n = Vec3::new((sx / l) as f32, (sy / l) as f32, (sz / l) as f32);
    }
    let mut r = 0.0f32;
    if map.radius {
        r = v[RAD] as f32;
        if !(r.is_finite() && r > 0.0) {
            return Err(Invalid::BadRadius(v[RAD]));
        }
    }
    let mut c = Vec3::ZERO;
    if map.colors {
        for k in 0..3 {
            let x = v[COL + k];
            if !x.is_finite() {
                return Err(Invalid::NonFinite {
                    slot: COL + k,
                    value: x,
                });
            }
            c[k] = match map.color_conv[k] {
                ColorConv::U8 => srgb_u8_table()[x.clamp(0.0, 255.0) as usize],
                ColorConv::Int(s) => srgb_to_linear((x * s).clamp(0.0, 1.0)) as f32,
                ColorConv::Float => (x as f32).max(0.0),
            };
            if !c[k].is_finite() {
                return Err(Invalid::NonFinite {
                    slot: COL + k,
                    value: x,
                });
            }
        }
    }
    Ok((p, n, r, c))
}

/// Report the lowest-index error, or compact the chunks' valid points into one `PointSet`.
/// `done` lists the chunks in vertex order, each with the size of its part of `out`.
fn finish(mut out: Outputs, done: &[(usize, Done)], ctx: &Ctx) -> Result<PointSet, ImportError> {
    let mut base = 0usize;
    for (_, d) in done {
        if let Some((local, inv)) = d.first {
            return Err(inv.into_error(ctx, base + local));
        }
        base += d.read;
    }
    // Move each chunk's kept points down to close the gaps left by dropped ones.
    let mut w = 0usize;
    let mut start = 0usize;
    let mut drops = [0usize; REASONS.len()];
    for (size, d) in done {
        if w != start && d.kept > 0 {
            let src = start..start + d.kept;
            out.pos.copy_within(src.clone(), w);
            if ctx.map.normals {
                out.nrm.copy_within(src.clone(), w);
            }
            if ctx.map.radius {
                out.rad.copy_within(src.clone(), w);
            }
            if ctx.map.colors {
                out.col.copy_within(src, w);
            }
        }
        w += d.kept;
        start += size;
        for (a, b) in drops.iter_mut().zip(d.drops) {
            *a += b;
        }
    }
    if w == 0 {
        return Err(ImportError::Empty {
            path: ctx.path.to_path_buf(),
        });
    }
    out.pos.truncate(w);
    let map = ctx.map;
    let keep = |mut v: Vec<Vec3>, b: bool| {
        v.truncate(w);
        b.then_some(v)
    };
    out.rad.truncate(w);
    Ok(PointSet {
        positions: out.pos,
        origin: glam::DVec3::ZERO,
        normals: keep(out.nrm, map.normals),
        radii: map.radius.then_some(out.rad),
        colors: keep(out.col, map.colors),
        dropped: drops.iter().sum(),
        drop_reasons: REASONS
            .iter()
            .zip(drops)
            .filter(|(_, n)| *n > 0)
            .map(|(r, n)| (r.to_string(), n))
            .collect(),
        ..PointSet::default()
    })
}

/// Vertices per parallel chunk.
const CHUNK: usize = 1 << 15;

// ---------------------------------------------------------------------------------------------
// Binary

#[inline(always)]
fn arr<const N: usize>(b: &[u8], off: usize) -> [u8; N] {
    b[off..off + N].try_into().unwrap()
}

/// Read one scalar at `off` of `b` (caller checked the bounds).
#[inline(always)]
fn read_scalar<const BE: bool>(b: &[u8], off: usize, ty: Ty) -> f64 {
    macro_rules! rd {
        ($t:ty, $n:expr) => {{
            let a = arr::<$n>(b, off);
            (if BE {
                <$t>::from_be_bytes(a)
            } else {
                <$t>::from_le_bytes(a)
            }) as f64
        }};
    }
    match ty {
        Ty::I8 => b[off] as i8 as f64,
        Ty::U8 => b[off] as f64,
        Ty::I16 => rd!(i16, 2),
        Ty::U16 => rd!(u16, 2),
        Ty::I32 => rd!(i32, 4),
        Ty::U32 => rd!(u32, 4),
        Ty::F32 => rd!(f32, 4),
        Ty::F64 => rd!(f64, 8),
    }
}

/// Outcome of walking one variable-size binary record.
enum Walk {
    /// The record ends at this offset.
    End(usize),
    /// The body ends inside the record.
    Truncated,
    /// A list length that is negative or not an integer, at this offset.
    BadCount(usize, f64),
}

/// Walk one record starting at `off`, storing used scalars in `v` when given.
#[inline]
fn walk_record<const BE: bool>(
    body: &[u8],
    mut off: usize,
    props: &[(String, PropKind)],
    slot_of: Option<&[Option<usize>]>,
    v: &mut [f64; SLOTS],
) -> Walk {
    for (i, (_, kind)) in props.iter().enumerate() {
        match *kind {
            PropKind::Scalar(t) => {
                if body.len() - off < t.size() {
                    return Walk::Truncated;
                }
                if let Some(Some(s)) = slot_of.map(|m| m[i]) {
                    v[s] = read_scalar::<BE>(body, off, t);
                }
                off += t.size();
            }
            PropKind::List(ct, it) => {
                if body.len() - off < ct.size() {
                    return Walk::Truncated;
                }
                let n = read_scalar::<BE>(body, off, ct);
                if !(n >= 0.0 && n.fract() == 0.0) {
                    return Walk::BadCount(off, n);
                }
                off += ct.size();
                let len = (n as usize).saturating_mul(it.size());
                if body.len() - off < len {
                    return Walk::Truncated;
                }
                off += len;
            }
        }
    }
    Walk::End(off)
}

fn decode_binary<const BE: bool>(
    body: &[u8],
    header_len: usize,
    before: &[ElemLayout],
    vertex: &ElemLayout,
    ctx: &Ctx,
) -> Result<PointSet, ImportError> {
    let truncated = |read: usize| ImportError::Truncated {
        path: ctx.path.to_path_buf(),
        expected_vertices: ctx.count,
        read,
    };
    let bad_count = |off: usize, n: f64, e: &ElemLayout, i: usize| {
        ImportError::ply(
            ctx.path,
            format!(
                "byte offset {}: element `{}` {i}: list length {n} is not a non-negative integer",
                header_len + off,
                e.name
            ),
        )
    };
    // Skip the elements before `vertex`.
    let mut off = 0usize;
    let mut scratch = [0f64; SLOTS];
    for e in before {
        match e.fixed_size() {
            Some(size) => {
                let len = size.checked_mul(e.count).ok_or_else(|| truncated(0))?;
                if body.len() - off < len {
                    return Err(truncated(0));
                }
                off += len;
            }
            None => {
                for i in 0..e.count {
                    match walk_record::<BE>(body, off, &e.props, None, &mut scratch) {
                        Walk::End(o) => off = o,
                        Walk::Truncated => return Err(truncated(0)),
                        Walk::BadCount(o, n) => return Err(bad_count(o, n, e, i)),
                    }
                }
            }
        }
    }
    let map = ctx.map;
    let n = ctx.count;
    match vertex.fixed_size() {
        Some(rec) => {
            let avail = body.len() - off;
            match rec.checked_mul(n) {
                Some(need) if need <= avail => {}
                _ => return Err(truncated(avail / rec.max(1))),
            }
            let vbody = &body[off..off + rec * n];
            // Offsets of the used properties within a record.
            let mut fields: Vec<(usize, Ty, usize)> = Vec::new();
            let mut o = 0;
            for (i, (_, kind)) in vertex.props.iter().enumerate() {
                if let PropKind::Scalar(t) = *kind {
                    if let Some(s) = map.slot_of[i] {
                        fields.push((o, t, s));
                    }
                    o += t.size();
                }
            }
            let sizes = (0..n.div_ceil(CHUNK)).map(|c| CHUNK.min(n - c * CHUNK));
            let mut out = Outputs::new(n, map);
            let mut sinks = out.sinks(sizes.clone());
            sinks.par_iter_mut().enumerate().for_each(|(c, sink)| {
                let start = c * CHUNK;
                let end = start + sink.pos.len();
                let mut v = [0f64; SLOTS];
                for (local, r) in vbody[start * rec..end * rec].chunks_exact(rec).enumerate() {
                    for &(o, t, s) in &fields {
                        v[s] = read_scalar::<BE>(r, o, t);
                    }
                    if !sink.accept(ctx, local, &v) {
                        break;
                    }
                }
            });
            let done: Vec<_> = sizes.zip(sinks.iter().map(|s| s.done)).collect();
            drop(sinks);
            finish(out, &done, ctx)
        }
        None => {
            // Variable-size records: check the length first (so that a huge count in a short
            // file allocates nothing), then decode sequentially.
            let mut v = [0f64; SLOTS];
            let vstart = off;
            for i in 0..n {
                match walk_record::<BE>(body, off, &vertex.props, None, &mut v) {
                    Walk::End(o) => off = o,
                    Walk::Truncated => return Err(truncated(i)),
                    Walk::BadCount(o, c) => return Err(bad_count(o, c, vertex, i)),
                }
            }
            let mut out = Outputs::new(n, map);
            let mut sinks = out.sinks(std::iter::once(n));
            let sink = &mut sinks[0];
            off = vstart;
            for i in 0..n {
                if let Walk::End(o) =
                    walk_record::<BE>(body, off, &vertex.props, Some(&map.slot_of), &mut v)
                {
                    off = o;
                }
                if !sink.accept(ctx, i, &v) {
                    break;
                }
            }
            let done = [(n, sink.done)];
            drop(sinks);
            finish(out, &done, ctx)
        }
    }
}

// ---------------------------------------------------------------------------------------------
// ASCII

fn is_blank(line: &[u8]) -> bool {
    line.iter().all(|c| matches!(c, b' ' | b'\t' | b'\r'))
}

/// The line starting at `pos`: (content without '\n', start of the next line).
#[inline]
fn line_at(body: &[u8], pos: usize) -> (&[u8], usize) {
    match body[pos..].iter().position(|&c| c == b'\n') {
        Some(k) => (&body[pos..pos + k], pos + k + 1),
        None => (&body[pos..], body.len()),
    }
}

/// Where a chunk of ASCII vertex lines starts.
struct AsciiChunk {
    offset: usize,
    line: usize,
    first_vertex: usize,
    vertices: usize,
}

fn decode_ascii(
    body: &[u8],
    body_line: usize,
    before: &[ElemLayout],
    vertex: &ElemLayout,
    ctx: &Ctx,
) -> Result<PointSet, ImportError> {
    let truncated = |read: usize| ImportError::Truncated {
        path: ctx.path.to_path_buf(),
        expected_vertices: ctx.count,
        read,
    };
    let mut pos = 0usize;
    let mut line = body_line;
    // Skip the records (one per non-blank line) of the elements before `vertex`.
    for e in before {
        let mut left = e.count;
        while left > 0 {
            if pos >= body.len() {
                return Err(truncated(0));
            }
            let (l, next) = line_at(body, pos);
            if !is_blank(l) {
                left -= 1;
            }
            pos = next;
            line += 1;
        }
    }
    // Find the vertex lines, cut them into chunks.
    let n = ctx.count;
    let mut chunks: Vec<AsciiChunk> = Vec::new();
    let mut found = 0usize;
    while found < n {
        if pos >= body.len() {
            // A last line without '\n' may be cut short: it does not count as read.
            let complete = if body.last() == Some(&b'\n') || found == 0 {
                found
            } else {
                found - 1
            };
            return Err(truncated(complete));
        }
        let (l, next) = line_at(body, pos);
        if !is_blank(l) {
            if chunks.last().is_none_or(|c| c.vertices == CHUNK) {
                chunks.push(AsciiChunk {
                    offset: pos,
                    line,
                    first_vertex: found,
                    vertices: 0,
                });
            }
            chunks.last_mut().unwrap().vertices += 1;
            found += 1;
        }
        pos = next;
        line += 1;
    }
    let mut out = Outputs::new(n, ctx.map);
    let mut sinks = out.sinks(chunks.iter().map(|c| c.vertices));
    let results: Vec<Result<(), ImportError>> = chunks
        .par_iter()
        .zip(sinks.par_iter_mut())
        .map(|(ch, sink)| parse_ascii_chunk(body, ch, vertex, ctx, sink))
        .collect();
    // The lowest-index problem wins: a syntax error in an earlier chunk before a later
    // invalid value, and within a chunk decoding stops at the first problem.
    for (r, sink) in results.into_iter().zip(&sinks) {
        r?;
        if sink.done.first.is_some() {
            break;
        }
    }
    let done: Vec<_> = chunks
        .iter()
        .map(|c| c.vertices)
        .zip(sinks.iter().map(|s| s.done))
        .collect();
    drop(sinks);
    finish(out, &done, ctx)
}

fn parse_ascii_chunk(
    body: &[u8],
    ch: &AsciiChunk,
    vertex: &ElemLayout,
    ctx: &Ctx,
    sink: &mut Sink,
) -> Result<(), ImportError> {
    let mut v = [0f64; SLOTS];
    let mut pos = ch.offset;
    let mut line = ch.line;
    let mut local = 0usize;
    while local < ch.vertices {
        let (l, next) = line_at(body, pos);
        if !is_blank(l) {
            let index = ch.first_vertex + local;
            let last_line_cut = next == body.len() && body.last() != Some(&b'\n');
            parse_ascii_vertex(l, line, index, last_line_cut, vertex, ctx, &mut v)?;
            if !sink.accept(ctx, local, &v) {
                break;
            }
            local += 1;
        }
        pos = next;
        line += 1;
    }
    Ok(())
}

fn parse_ascii_vertex(
    l: &[u8],
    line: usize,
    index: usize,
    last_line_cut: bool,
    vertex: &ElemLayout,
    ctx: &Ctx,
    v: &mut [f64; SLOTS],
) -> Result<(), ImportError> {
    let err =
        |msg: String| ImportError::ply(ctx.path, format!("line {line}: vertex {index}: {msg}"));
    let too_few = |msg: String| {
        if last_line_cut {
            ImportError::Truncated {
                path: ctx.path.to_path_buf(),
                expected_vertices: ctx.count,
                read: index,
            }
        } else {
            err(msg)
        }
    };
    let mut toks = l
        .split(|c| matches!(c, b' ' | b'\t' | b'\r'))
        .filter(|t| !t.is_empty());
    let parse = |t: &[u8], name: &str| -> Result<f64, ImportError> {
        std::str::from_utf8(t)
            .ok()
            .and_then(|s| s.parse::<f64>().ok())
            .ok_or_else(|| {
                err(format!(
                    "`{name}`: `{}` is not a number",
                    String::from_utf8_lossy(t)
                ))
            })
    };
    for (i, (name, kind)) in vertex.props.iter().enumerate() {
        match kind {
            PropKind::Scalar(_) => {
                let t = toks
                    .next()
                    .ok_or_else(|| too_few(format!("the line ends before `{name}`")))?;
                if let Some(s) = ctx.map.slot_of[i] {
                    v[s] = parse(t, name)?;
                }
            }
            PropKind::List(..) => {
                let t = toks
                    .next()
                    .ok_or_else(|| too_few(format!("the line ends before list `{name}`")))?;
                let c = std::str::from_utf8(t)
                    .ok()
                    .and_then(|s| s.parse::<usize>().ok())
                    .ok_or_else(|| {
                        err(format!(
                            "list `{name}`: length `{}` is not a non-negative integer",
                            String::from_utf8_lossy(t)
                        ))
                    })?;
                for _ in 0..c {
                    toks.next()
                        .ok_or_else(|| too_few(format!("list `{name}` is shorter than {c}")))?;
                }
            }
        }
    }
    if toks.next().is_some() {
        return Err(err(format!(
            "more values than the {} properties the header declares",
            vertex.props.len()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_table_endpoints() {
        let t = srgb_u8_table();
        assert_eq!(t[0], 0.0);
        assert!((t[255] - 1.0).abs() < 1e-6);
        // sRGB 128/255 is about 0.2158 linear.
        assert!((t[128] - 0.21586).abs() < 1e-4, "{}", t[128]);
    }

    #[test]
    fn flatten_keeps_one_line() {
        assert_eq!(
            flatten("Line 3: bad\n\tString: 'x'\n"),
            "Line 3: bad; String: 'x'"
        );
    }
}
