//! PLY reader tests: every encoding and scalar type, skipped elements, every error case.

use std::path::{Path, PathBuf};

use glam::Vec3;
use pc_import::ply::{parse_ply, read_ply, PlyOptions, PointSet};
use pc_import::ImportError;

// ---------------------------------------------------------------------------------------------
// A tiny PLY writer, independent of the crate's own.

#[derive(Clone, Copy, Debug, PartialEq)]
enum Fmt {
    Ascii,
    Le,
    Be,
}
const ALL: [Fmt; 3] = [Fmt::Ascii, Fmt::Le, Fmt::Be];

#[derive(Clone, Copy)]
enum T {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl T {
    fn name(self) -> &'static str {
        match self {
            T::I8 => "char",
            T::U8 => "uchar",
            T::I16 => "short",
            T::U16 => "ushort",
            T::I32 => "int",
            T::U32 => "uint",
            T::F32 => "float",
            T::F64 => "double",
        }
    }

    fn put(self, fmt: Fmt, v: f64, out: &mut Vec<u8>) {
        macro_rules! b {
            ($x:expr) => {
                if fmt == Fmt::Be {
                    out.extend_from_slice(&$x.to_be_bytes())
                } else {
                    out.extend_from_slice(&$x.to_le_bytes())
                }
            };
        }
        match self {
            T::I8 => b!(v as i8),
            T::U8 => b!(v as u8),
            T::I16 => b!(v as i16),
            T::U16 => b!(v as u16),
            T::I32 => b!(v as i32),
            T::U32 => b!(v as u32),
            T::F32 => b!(v as f32),
            T::F64 => b!(v),
        }
    }

    fn ascii(self, v: f64) -> String {
        match self {
            T::F32 => format!("{}", v as f32),
            T::F64 => format!("{v:?}"),
            _ => format!("{}", v as i64),
        }
    }
}

/// A property: scalar, or list (count type, item type).
enum P {
    S(&'static str, T),
    L(&'static str, T, T),
}

/// An element; rows hold the values in property order, a list as its count then its items.
struct E {
    name: &'static str,
    props: Vec<P>,
    rows: Vec<Vec<f64>>,
    /// Declared count, when it should differ from `rows.len()`.
    count: Option<usize>,
}

fn elem(name: &'static str, props: Vec<P>, rows: Vec<Vec<f64>>) -> E {
    E {
        name,
        props,
        rows,
        count: None,
    }
}

fn ply(fmt: Fmt, elems: &[E]) -> Vec<u8> {
    let mut out = Vec::new();
    let f = match fmt {
        Fmt::Ascii => "ascii",
        Fmt::Le => "binary_little_endian",
        Fmt::Be => "binary_big_endian",
    };
    out.extend_from_slice(format!("ply\nformat {f} 1.0\ncomment test file\n").as_bytes());
    for e in elems {
        let count = e.count.unwrap_or(e.rows.len());
        out.extend_from_slice(format!("element {} {count}\n", e.name).as_bytes());
        for p in &e.props {
            let line = match p {
                P::S(n, t) => format!("property {} {n}\n", t.name()),
                P::L(n, c, t) => format!("property list {} {} {n}\n", c.name(), t.name()),
            };
            out.extend_from_slice(line.as_bytes());
        }
    }
    out.extend_from_slice(b"end_header\n");
    for e in elems {
        for row in &e.rows {
            let mut vals = row.iter().copied();
            let mut words = Vec::new();
            for p in &e.props {
                match *p {
                    P::S(_, t) => {
                        let v = vals.next().unwrap();
                        if fmt == Fmt::Ascii {
                            words.push(t.ascii(v));
                        } else {
                            t.put(fmt, v, &mut out);
                        }
                    }
                    P::L(_, c, t) => {
                        let n = vals.next().unwrap();
                        if fmt == Fmt::Ascii {
                            words.push(c.ascii(n));
                        } else {
                            c.put(fmt, n, &mut out);
                        }
                        for _ in 0..n as usize {
                            let v = vals.next().unwrap();
                            if fmt == Fmt::Ascii {
                                words.push(t.ascii(v));
                            } else {
                                t.put(fmt, v, &mut out);
                            }
                        }
                    }
                }
            }
            if fmt == Fmt::Ascii {
                out.extend_from_slice(words.join(" ").as_bytes());
                out.push(b'\n');
            }
        }
    }
    out
}

fn xyz(t: T) -> Vec<P> {
    vec![P::S("x", t), P::S("y", t), P::S("z", t)]
}

fn oriented() -> Vec<P> {
    let mut p = xyz(T::F32);
    p.extend([
        P::S("nx", T::F32),
        P::S("ny", T::F32),
        P::S("nz", T::F32),
        P::S("radius", T::F32),
    ]);
    p
}

/// `n` valid oriented points: x = i, normal (0, 0, 2) (not unit), radius 0.5.
fn oriented_rows(n: usize) -> Vec<Vec<f64>> {
    (0..n)
        .map(|i| vec![i as f64, 1.0, -2.0, 0.0, 0.0, 2.0, 0.5])
        .collect()
}

struct Tmp {
    _dir: tempfile::TempDir,
    path: PathBuf,
}

fn write(bytes: &[u8]) -> Tmp {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cloud.ply");
    std::fs::write(&path, bytes).unwrap();
    Tmp { _dir: dir, path }
}

fn read(bytes: &[u8]) -> Result<PointSet, ImportError> {
    let t = write(bytes);
    let r = read_ply(&t.path, &PlyOptions::default());
    if let Err(e) = &r {
        assert_names_file(e, &t.path);
    }
    r
}

fn read_dropping(bytes: &[u8]) -> Result<PointSet, ImportError> {
    parse_ply(
        bytes,
        Path::new("mem.ply"),
        &PlyOptions { drop_invalid: true },
    )
}

fn assert_names_file(e: &ImportError, path: &Path) {
    let s = e.to_string();
    assert!(
        s.starts_with(&format!("{}: ", path.display())),
        "error does not start with the path: {s}"
    );
    assert_eq!(e.path(), path);
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).length() < 1e-5
}

// ---------------------------------------------------------------------------------------------
// Valid files

#[test]
fn oriented_points_in_every_encoding() {
    for fmt in ALL {
        let pts = read(&ply(fmt, &[elem("vertex", oriented(), oriented_rows(5))])).unwrap();
        assert_eq!(pts.len(), 5, "{fmt:?}");
        assert_eq!(pts.positions[3], Vec3::new(3.0, 1.0, -2.0));
        assert!(
            pts.normals.as_ref().unwrap().iter().all(|&n| n == Vec3::Z),
            "normalized"
        );
        assert_eq!(pts.radii.as_ref().unwrap(), &vec![0.5; 5]);
        assert!(pts.colors.is_none());
        assert_eq!(pts.dropped, 0);
        assert!(pts.drop_reasons.is_empty());
    }
}

#[test]
fn positions_only() {
    for fmt in ALL {
        let rows = vec![vec![0.25, -1.5, 3.0], vec![1e-3, 2e3, -7.0]];
        let pts = read(&ply(fmt, &[elem("vertex", xyz(T::F32), rows)])).unwrap();
        assert_eq!(
            pts.positions,
            vec![Vec3::new(0.25, -1.5, 3.0), Vec3::new(1e-3, 2e3, -7.0)]
        );
        assert!(pts.normals.is_none() && pts.radii.is_none() && pts.colors.is_none());
    }
}

#[test]
fn double_and_integer_coordinates() {
    for fmt in ALL {
        let rows = vec![vec![0.1, 1e6 + 0.5, -3.25]];
        let pts = read(&ply(fmt, &[elem("vertex", xyz(T::F64), rows)])).unwrap();
        assert_eq!(pts.positions[0], Vec3::new(0.1, 1e6 + 0.5, -3.25));
        for t in [T::I8, T::U8, T::I16, T::U16, T::I32, T::U32] {
            let rows = vec![vec![1.0, 2.0, 100.0]];
            let mut props = xyz(t);
            props.push(P::S("radius", t));
            let rows = rows.into_iter().map(|mut r| {
                r.push(3.0);
                r
            });
            let pts = read(&ply(fmt, &[elem("vertex", props, rows.collect())])).unwrap();
            assert_eq!(pts.positions[0], Vec3::new(1.0, 2.0, 100.0));
            assert_eq!(pts.radii.unwrap()[0], 3.0);
        }
        // Negative values of signed types.
        let pts = read(&ply(
            fmt,
            &[elem("vertex", xyz(T::I16), vec![vec![-5.0, -300.0, 7.0]])],
        ))
        .unwrap();
        assert_eq!(pts.positions[0], Vec3::new(-5.0, -300.0, 7.0));
        // Double normals and radius.
        let mut props = xyz(T::F64);
        props.extend([
            P::S("nx", T::F64),
            P::S("ny", T::F64),
            P::S("nz", T::F64),
            P::S("radius", T::F64),
        ]);
        let pts = read(&ply(
            fmt,
            &[elem(
                "vertex",
                props,
                vec![vec![0.0, 0.0, 0.0, 3.0, 4.0, 0.0, 0.01]],
            )],
        ))
        .unwrap();
        assert!(close(pts.normals.unwrap()[0], Vec3::new(0.6, 0.8, 0.0)));
        assert_eq!(pts.radii.unwrap()[0], 0.01);
    }
}

fn srgb(c: f64) -> f32 {
    (if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }) as f32
}

#[test]
fn uchar_colors_are_srgb_decoded() {
    for fmt in ALL {
        let mut props = xyz(T::F32);
        props.extend([
            P::S("red", T::U8),
            P::S("green", T::U8),
            P::S("blue", T::U8),
            P::S("alpha", T::U8),
        ]);
        let rows = vec![
            vec![0.0, 0.0, 0.0, 255.0, 128.0, 0.0, 7.0],
            vec![1.0, 0.0, 0.0, 10.0, 200.0, 64.0, 255.0],
        ];
        let pts = read(&ply(fmt, &[elem("vertex", props, rows)])).unwrap();
        let c = pts.colors.unwrap();
        assert!(
            close(c[0], Vec3::new(1.0, 0.21586, 0.0)),
            "{fmt:?} {:?}",
            c[0]
        );
        let want = Vec3::new(srgb(10.0 / 255.0), srgb(200.0 / 255.0), srgb(64.0 / 255.0));
        assert!(close(c[1], want), "{:?} {want:?}", c[1]);
    }
}

#[test]
fn other_color_conventions() {
    for fmt in ALL {
        // ushort, named r g b.
        let mut props = xyz(T::F32);
        props.extend([P::S("r", T::U16), P::S("g", T::U16), P::S("b", T::U16)]);
        let pts = read(&ply(
            fmt,
            &[elem(
                "vertex",
                props,
                vec![vec![0.0, 0.0, 0.0, 65535.0, 0.0, 32768.0]],
            )],
        ))
        .unwrap();
        let c = pts.colors.unwrap()[0];
        assert!(
            close(c, Vec3::new(1.0, 0.0, srgb(32768.0 / 65535.0))),
            "{c:?}"
        );
        // float diffuse_*: linear already.
        let mut props = xyz(T::F32);
        props.extend([
            P::S("diffuse_red", T::F32),
            P::S("diffuse_green", T::F32),
            P::S("diffuse_blue", T::F64),
        ]);
        let pts = read(&ply(
            fmt,
            &[elem(
                "vertex",
                props,
                vec![vec![0.0, 0.0, 0.0, 0.5, 0.25, 0.125]],
            )],
        ))
        .unwrap();
        assert!(close(pts.colors.unwrap()[0], Vec3::new(0.5, 0.25, 0.125)));
    }
}

#[test]
fn other_elements_are_skipped() {
    let faces = |name: &'static str| {
        elem(
            name,
            vec![
                P::L("vertex_indices", T::U8, T::I32),
                P::S("flags", T::I16),
                P::L("uv", T::I32, T::F64),
            ],
            vec![
                vec![3.0, 0.0, 1.0, 2.0, 9.0, 2.0, 0.5, 0.25],
                vec![4.0, 0.0, 1.0, 2.0, 3.0, -1.0, 0.0],
            ],
        )
    };
    let edges = || {
        elem(
            "edge",
            vec![P::S("a", T::I32), P::S("b", T::I32)],
            vec![vec![0.0, 1.0]; 7],
        )
    };
    let vertex = || {
        let mut props = vec![P::S("confidence", T::F64), P::S("intensity", T::U8)];
        props.extend(oriented());
        props.push(P::S("scalar_tail", T::F32));
        let rows = oriented_rows(4)
            .into_iter()
            .map(|r| [vec![0.9, 17.0], r, vec![123.0]].concat())
            .collect();
        elem("vertex", props, rows)
    };
    for fmt in ALL {
        for file in [
            vec![faces("face"), vertex()],
            vec![edges(), faces("face"), vertex(), faces("material")],
            vec![vertex(), faces("face"), edges()],
        ] {
            let pts = read(&ply(fmt, &file)).unwrap();
            assert_eq!(pts.len(), 4, "{fmt:?}");
            assert_eq!(pts.positions[2], Vec3::new(2.0, 1.0, -2.0));
            assert_eq!(pts.radii.unwrap()[3], 0.5);
        }
    }
}

#[test]
fn list_properties_in_vertex_element_are_skipped() {
    for fmt in ALL {
        let mut props = vec![P::L("tags", T::U8, T::U16)];
        props.extend(xyz(T::F32));
        props.push(P::L("more", T::I32, T::F32));
        let rows = vec![
            vec![2.0, 7.0, 8.0, 1.0, 2.0, 3.0, 0.0],
            vec![0.0, 4.0, 5.0, 6.0, 3.0, 1.0, 1.0, 1.0],
        ];
        let pts = read(&ply(fmt, &[elem("vertex", props, rows)])).unwrap();
        assert_eq!(
            pts.positions,
            vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)]
        );
    }
}

#[test]
fn ascii_whitespace_and_crlf() {
    let text =
        "ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\n\
                property float z\r\nend_header\r\n  1 2\t3  \r\n\r\n4 5 6";
    let pts = read(text.as_bytes()).unwrap();
    assert_eq!(
        pts.positions,
        vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)]
    );
}

#[test]
fn many_points_in_parallel_chunks() {
    let n = 100_003;
    let rows: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            vec![
                i as f64,
                (i % 7) as f64,
                0.5,
                1.0,
                1.0,
                0.0,
                0.01 + (i % 3) as f64,
            ]
        })
        .collect();
    for fmt in ALL {
        let pts = read(&ply(fmt, &[elem("vertex", oriented(), rows.clone())])).unwrap();
        assert_eq!(pts.len(), n);
        for i in [0, 1, 32767, 32768, 65536, n - 1] {
            assert_eq!(pts.positions[i], Vec3::new(i as f32, (i % 7) as f32, 0.5));
            assert_eq!(pts.radii.as_ref().unwrap()[i], 0.01 + (i % 3) as f32);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Errors

#[test]
fn missing_file_is_io() {
    let p = Path::new("/nonexistent/dir/cloud.ply");
    let e = read_ply(p, &PlyOptions::default()).unwrap_err();
    assert!(matches!(e, ImportError::Io { .. }), "{e}");
    assert_names_file(&e, p);
}

#[test]
fn bad_header_is_ply_error() {
    for bytes in [
        &b"not a ply file\n"[..],
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty flot x\nend_header\n1\n",
        b"ply\nelement vertex 1\nproperty float x\nend_header\n1\n",
    ] {
        let e = read(bytes).unwrap_err();
        assert!(matches!(e, ImportError::Ply { .. }), "{e}");
    }
    // Line number of the bad header line.
    let e = read(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty flot x\nend_header\n1\n")
        .unwrap_err();
    assert!(e.to_string().contains("Line 4"), "{e}");
}

#[test]
fn duplicate_property_is_rejected() {
    let text = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                property float z\nproperty float x\nend_header\n";
    let e = read(text.as_bytes()).unwrap_err();
    assert!(
        matches!(e, ImportError::Ply { .. }) && e.to_string().contains("`x` declared twice"),
        "{e}"
    );
}

#[test]
fn missing_coordinate() {
    for fmt in ALL {
        let e = read(&ply(
            fmt,
            &[elem(
                "vertex",
                vec![P::S("x", T::F32), P::S("z", T::F32)],
                vec![vec![1.0, 2.0]],
            )],
        ))
        .unwrap_err();
        assert!(
            matches!(e, ImportError::MissingProperty { property: "y", .. }),
            "{e}"
        );
        assert!(
            e.to_string()
                .ends_with("vertex element has no `y` property: x, y and z are required"),
            "{e}"
        );
    }
}

#[test]
fn partial_normals() {
    let mut props = xyz(T::F32);
    props.extend([P::S("nx", T::F32), P::S("ny", T::F32)]);
    let e = read(&ply(Fmt::Le, &[elem("vertex", props, vec![vec![0.0; 5]])])).unwrap_err();
    assert!(
        matches!(e, ImportError::MissingProperty { property: "nz", .. }),
        "{e}"
    );
}

#[test]
fn list_where_scalar_expected() {
    for fmt in ALL {
        let props = vec![
            P::S("x", T::F32),
            P::L("y", T::U8, T::F32),
            P::S("z", T::F32),
        ];
        let e = read(&ply(
            fmt,
            &[elem("vertex", props, vec![vec![1.0, 1.0, 2.0, 3.0]])],
        ))
        .unwrap_err();
        match &e {
            ImportError::ListProperty { property, .. } => assert_eq!(property, "y"),
            _ => panic!("{e}"),
        }
        assert!(e
            .to_string()
            .contains("property `y` is a list, a scalar is expected"));
    }
}

#[test]
fn no_vertex_element() {
    let e = read(&ply(
        Fmt::Le,
        &[elem(
            "face",
            vec![P::L("vertex_indices", T::U8, T::I32)],
            vec![],
        )],
    ))
    .unwrap_err();
    assert!(matches!(e, ImportError::NoVertexElement { .. }), "{e}");
}

#[test]
fn zero_vertices_is_empty() {
    for fmt in ALL {
        let e = read(&ply(fmt, &[elem("vertex", xyz(T::F32), vec![])])).unwrap_err();
        assert!(matches!(e, ImportError::Empty { .. }), "{e}");
        assert!(e.to_string().ends_with("the model has no points"));
    }
}

/// `oriented_rows(n)` with row `i` changed by `f`.
fn rows_with(n: usize, bad: &[(usize, usize, f64)]) -> Vec<Vec<f64>> {
    let mut rows = oriented_rows(n);
    for &(i, col, v) in bad {
        rows[i][col] = v;
    }
    rows
}

#[test]
fn non_finite_values() {
    for fmt in ALL {
        for (col, name, v) in [
            (0, "x", f64::NAN),
            (2, "z", f64::INFINITY),
            (4, "ny", f64::NEG_INFINITY),
        ] {
            let rows = rows_with(20, &[(13, col, v), (17, 0, f64::NAN)]);
            let e = read(&ply(fmt, &[elem("vertex", oriented(), rows)])).unwrap_err();
            match &e {
                ImportError::NonFinite {
                    index,
                    property,
                    value,
                    ..
                } => {
                    assert_eq!((*index, property.as_str()), (13, name), "{fmt:?} {e}");
                    assert!(value.is_nan() == v.is_nan() && (v.is_nan() || *value == v));
                }
                _ => panic!("{fmt:?}: {e}"),
            }
            assert!(
                e.to_string().contains(&format!("vertex 13: `{name}` is ")),
                "{e}"
            );
        }
    }
    // A double beyond the f32 range is not finite once converted.
    let e = read(&ply(
        Fmt::Le,
        &[elem("vertex", xyz(T::F64), vec![vec![0.0, 1e300, 0.0]])],
    ))
    .unwrap_err();
    assert!(
        matches!(
            e,
            ImportError::NonFinite {
                index: 0,
                value: 1e300,
                ..
            }
        ),
        "{e}"
    );
    // NaN in colors.
    let mut props = xyz(T::F32);
    props.extend([
        P::S("red", T::F32),
        P::S("green", T::F32),
        P::S("blue", T::F32),
    ]);
    let e = read(&ply(
        Fmt::Be,
        &[elem(
            "vertex",
            props,
            vec![vec![0.0; 6], vec![0.0, 0.0, 0.0, 0.1, f64::NAN, 0.0]],
        )],
    ))
    .unwrap_err();
    assert!(
        matches!(&e, ImportError::NonFinite { index: 1, property, .. } if property == "green"),
        "{e}"
    );
}

#[test]
fn zero_normal() {
    for fmt in ALL {
        let rows = rows_with(10, &[(6, 5, 0.0), (8, 5, 1e-13)]);
        let e = read(&ply(fmt, &[elem("vertex", oriented(), rows)])).unwrap_err();
        assert!(matches!(e, ImportError::ZeroNormal { index: 6, .. }), "{e}");
        assert!(e
            .to_string()
            .contains("vertex 6: the normal has zero length"));
        // Tiny but non-zero lengths above 1e-12 are normalized.
        let rows = rows_with(10, &[(6, 5, 1e-9)]);
        let pts = read(&ply(fmt, &[elem("vertex", oriented(), rows)])).unwrap();
        assert_eq!(pts.normals.unwrap()[6], Vec3::Z);
    }
}

#[test]
fn bad_radius() {
    for fmt in ALL {
        for v in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let rows = rows_with(10, &[(3, 6, v), (5, 6, -2.0)]);
            let e = read(&ply(fmt, &[elem("vertex", oriented(), rows)])).unwrap_err();
            match e {
                ImportError::BadRadius {
                    index: 3, value, ..
                } => {
                    assert!(value.is_nan() == v.is_nan() && (v.is_nan() || value == v))
                }
                _ => panic!("{fmt:?} {v}: {e}"),
            }
        }
    }
}

#[test]
fn lowest_index_wins_across_parallel_chunks() {
    let n = 150_000;
    for fmt in ALL {
        let rows = rows_with(
            n,
            &[
                (140_000, 0, f64::NAN),
                (99_999, 5, 0.0),
                (40_000, 6, -1.0),
                (70_000, 1, f64::NAN),
            ],
        );
        let e = read(&ply(fmt, &[elem("vertex", oriented(), rows)])).unwrap_err();
        assert!(
            matches!(e, ImportError::BadRadius { index: 40_000, .. }),
            "{fmt:?}: {e}"
        );
    }
}

#[test]
fn drop_invalid_counts_reasons() {
    let n = 100_000;
    let bad = [
        (5, 0, f64::NAN),
        (40_000, 1, f64::INFINITY),
        (40_001, 3, f64::NAN),
        (70_000, 5, 0.0),
        (70_001, 5, 0.0),
        (99_999, 6, 0.0),
        (99_998, 6, f64::NAN),
        (99_997, 6, -3.0),
        // Two problems: counted once, for the first.
        (12, 0, f64::NAN),
    ];
    let mut rows = rows_with(n, &bad);
    rows[12][6] = -1.0;
    for fmt in ALL {
        let pts = read_dropping(&ply(fmt, &[elem("vertex", oriented(), rows.clone())])).unwrap();
        assert_eq!(pts.dropped, 9, "{fmt:?}");
        assert_eq!(pts.len(), n - 9);
        assert_eq!(pts.normals.as_ref().unwrap().len(), n - 9);
        assert_eq!(pts.radii.as_ref().unwrap().len(), n - 9);
        let reasons: Vec<(&str, usize)> = pts
            .drop_reasons
            .iter()
            .map(|(r, c)| (r.as_str(), *c))
            .collect();
        assert_eq!(
            reasons,
            vec![
                ("non-finite position", 3),
                ("non-finite normal", 1),
                ("zero-length normal", 2),
                ("non-positive or non-finite radius", 3),
            ]
        );
        // Order of the kept points is preserved.
        assert_eq!(pts.positions[5], Vec3::new(6.0, 1.0, -2.0));
        assert!(pts.positions.iter().all(|p| p.is_finite()));
    }
}

#[test]
fn drop_invalid_everything_is_empty() {
    let rows = rows_with(3, &[(0, 0, f64::NAN), (1, 6, 0.0), (2, 5, 0.0)]);
    let e = read_dropping(&ply(Fmt::Le, &[elem("vertex", oriented(), rows)])).unwrap_err();
    assert!(matches!(e, ImportError::Empty { .. }), "{e}");
    assert!(e.to_string().starts_with("mem.ply: "));
}

#[test]
fn truncated_binary() {
    for fmt in [Fmt::Le, Fmt::Be] {
        let full = ply(fmt, &[elem("vertex", oriented(), oriented_rows(100))]);
        let cut = &full[..full.len() - 14]; // half of the last 28-byte record
        let e = read(cut).unwrap_err();
        assert!(
            matches!(
                e,
                ImportError::Truncated {
                    expected_vertices: 100,
                    read: 99,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e
            .to_string()
            .ends_with("body ends after 99 of 100 vertices"));
        // Header only.
        let e = read(&full[..full.len() - 100 * 28]).unwrap_err();
        assert!(matches!(e, ImportError::Truncated { read: 0, .. }), "{e}");
        // Header that declares more than the body holds, with a list property.
        let mut props = oriented();
        props.push(P::L("l", T::U8, T::F32));
        let rows: Vec<Vec<f64>> = oriented_rows(10)
            .into_iter()
            .map(|r| [r, vec![1.0, 0.0]].concat())
            .collect();
        let e = read(&ply(
            fmt,
            &[E {
                name: "vertex",
                props,
                rows,
                count: Some(11),
            }],
        ))
        .unwrap_err();
        assert!(
            matches!(
                e,
                ImportError::Truncated {
                    expected_vertices: 11,
                    read: 10,
                    ..
                }
            ),
            "{e}"
        );
        // A face element before the vertices that is cut short.
        let faces = E {
            name: "face",
            props: vec![P::L("vertex_indices", T::U8, T::I32)],
            rows: vec![vec![3.0, 0.0, 1.0, 2.0]],
            count: Some(2),
        };
        let vertex = E {
            name: "vertex",
            props: xyz(T::F32),
            rows: vec![],
            count: Some(3),
        };
        let e = read(&ply(fmt, &[faces, vertex])).unwrap_err();
        assert!(matches!(e, ImportError::Truncated { read: 0, .. }), "{e}");
    }
}

#[test]
fn negative_list_length_names_byte_offset() {
    let faces = || {
        elem(
            "face",
            vec![P::L("vertex_indices", T::I8, T::I32)],
            vec![vec![3.0, 0.0, 1.0, 2.0], vec![-1.0]],
        )
    };
    for fmt in [Fmt::Le, Fmt::Be] {
        let bytes = ply(
            fmt,
            &[faces(), elem("vertex", xyz(T::F32), vec![vec![0.0; 3]])],
        );
        let header_len = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        let e = read(&bytes).unwrap_err();
        assert!(matches!(e, ImportError::Ply { .. }), "{e}");
        // The second face's count follows the first face (1 + 3 × 4 bytes).
        let want = format!(
            "byte offset {}: element `face` 1: list length -1",
            header_len + 13
        );
        assert!(e.to_string().contains(&want), "{e} / {want}");
    }
}

#[test]
fn huge_declared_count_does_not_allocate() {
    let text = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000000000000\nproperty float x\n\
                property float y\nproperty float z\nend_header\n";
    let e = read(text.as_bytes()).unwrap_err();
    assert!(matches!(e, ImportError::Truncated { read: 0, .. }), "{e}");
    let text = text.replace("binary_little_endian", "ascii");
    let e = read(text.as_bytes()).unwrap_err();
    assert!(matches!(e, ImportError::Truncated { read: 0, .. }), "{e}");
}

#[test]
fn truncated_ascii() {
    let full = ply(
        Fmt::Ascii,
        &[elem("vertex", oriented(), oriented_rows(100))],
    );
    let text = String::from_utf8(full).unwrap();
    // Missing last line.
    let lines: Vec<&str> = text.lines().collect();
    let cut = lines[..lines.len() - 1].join("\n") + "\n";
    let e = read(cut.as_bytes()).unwrap_err();
    assert!(
        matches!(
            e,
            ImportError::Truncated {
                expected_vertices: 100,
                read: 99,
                ..
            }
        ),
        "{e}"
    );
    // Last line cut in the middle.
    let cut = &text[..text.len() - 6];
    let e = read(cut.as_bytes()).unwrap_err();
    assert!(
        matches!(
            e,
            ImportError::Truncated {
                expected_vertices: 100,
                read: 99,
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn malformed_ascii() {
    // Header: ply, format, comment, element, 7 properties, end_header = 12 lines.
    let full = String::from_utf8(ply(
        Fmt::Ascii,
        &[elem("vertex", oriented(), oriented_rows(10))],
    ))
    .unwrap();
    let mut lines: Vec<String> = full.lines().map(String::from).collect();
    assert_eq!(lines[11], "end_header");
    // Vertex 4 is on line 17.
    lines[16] = "4 1 -2 0 0 2x 0.5".into();
    let e = read((lines.join("\n") + "\n").as_bytes()).unwrap_err();
    assert!(matches!(e, ImportError::Ply { .. }), "{e}");
    let s = e.to_string();
    assert!(
        s.contains("line 17: vertex 4: `nz`: `2x` is not a number"),
        "{s}"
    );
    // Too few values in a middle line.
    lines[16] = "4 1 -2 0 0".into();
    let e = read((lines.join("\n") + "\n").as_bytes()).unwrap_err();
    assert!(
        matches!(e, ImportError::Ply { .. }) && e.to_string().contains("line 17: vertex 4"),
        "{e}"
    );
    // Too many.
    lines[16] = "4 1 -2 0 0 1 0.5 9".into();
    let e = read((lines.join("\n") + "\n").as_bytes()).unwrap_err();
    assert!(
        matches!(e, ImportError::Ply { .. }) && e.to_string().contains("line 17: vertex 4"),
        "{e}"
    );
    // "nan" parses, and is reported as non-finite with its index.
    lines[16] = "nan 1 -2 0 0 1 0.5".into();
    let e = read((lines.join("\n") + "\n").as_bytes()).unwrap_err();
    assert!(matches!(e, ImportError::NonFinite { index: 4, .. }), "{e}");
}

/// Decode throughput; run with
/// `cargo test --release -p pc-import --test it -- --ignored --nocapture decode_speed`.
#[test]
#[ignore]
fn decode_speed() {
    let n = 4_000_000;
    let rows: Vec<Vec<f64>> = (0..n)
        .map(|i| vec![i as f64 * 1e-3, 1.0, 2.0, 0.0, 0.6, 0.8, 0.01])
        .collect();
    for fmt in ALL {
        let bytes = ply(fmt, &[elem("vertex", oriented(), rows.clone())]);
        for threads in [1, 0] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut dt = f64::INFINITY;
            for _ in 0..3 {
                let t = std::time::Instant::now();
                let pts = pool
                    .install(|| parse_ply(&bytes, Path::new("m.ply"), &PlyOptions::default()))
                    .unwrap();
                dt = dt.min(t.elapsed().as_secs_f64());
                assert_eq!(pts.len(), n);
            }
            println!(
                "{fmt:?} threads={}: {:.1} M points/s ({:.0} MB/s)",
                pool.current_num_threads(),
                n as f64 / dt / 1e6,
                bytes.len() as f64 / dt / 1e6
            );
        }
    }
}
