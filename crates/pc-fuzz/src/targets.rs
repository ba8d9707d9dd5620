//! One target per input kind. Each returns normally on any input (an error is a fine answer),
//! telling whether the input was accepted, and panics only when pcgi misbehaves: a reader
//! panicking, a stage panicking on what its reader accepted, or an answer that breaks the
//! reader's own promises.

use std::cell::RefCell;
use std::path::{Path, PathBuf};

use glam::Vec3;
use pc_artifact::octree::{OctreeFile, OctreeView};
use pc_artifact::photons::{PhotonMapFile, PhotonMapView, PhotonsFile};
use pc_artifact::radiosity::RadiosityFile;
use pc_artifact::vmap::{VmapFile, VmapView};
use pc_artifact::{Artifact, ArtifactKind, ArtifactWriter};
use pc_import::ply::{parse_ply, PlyOptions};
use pc_tree::{Ray, TraversalStats};

use crate::seeds::seeds;

/// Any bytes as a PLY model. What the reader returns holds its promises: as many normals,
/// radii and colors as points, every value finite, normals of unit length, radii positive.
pub fn ply(data: &[u8]) -> bool {
    let mut accepted = false;
    for drop_invalid in [false, true] {
        let Ok(p) = parse_ply(data, Path::new("fuzz.ply"), &PlyOptions { drop_invalid }) else {
            continue;
        };
        accepted = true;
        let n = p.positions.len();
        assert!(n > 0, "an accepted model has points");
        assert!(
            p.positions.iter().all(|x| x.is_finite()),
            "positions finite"
        );
        if let Some(nrm) = &p.normals {
            assert_eq!(nrm.len(), n);
            assert!(nrm
                .iter()
                .all(|v| v.is_finite() && (v.length() - 1.0).abs() < 1e-3));
        }
        if let Some(r) = &p.radii {
            assert_eq!(r.len(), n);
            assert!(
                r.iter().all(|&r| r.is_finite() && r > 0.0),
                "radii positive"
            );
        }
        if let Some(c) = &p.colors {
            assert_eq!(c.len(), n);
            assert!(c.iter().all(|v| v.is_finite()));
        }
    }
    accepted
}

/// Any bytes as pipeline.toml. An accepted config writes back as TOML that loads as the same
/// config, and its material table can be built.
pub fn config(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    let Ok(cfg) = pc_config::parse_config(text, Path::new("/nonexistent-fuzz")) else {
        return false;
    };
    let _ = pc_config::material_table(cfg.config.materials.values());
    let again = pc_config::to_toml(&cfg.config).expect("an accepted config writes as TOML");
    let back = pc_config::parse_config(&again, Path::new("/nonexistent-fuzz"))
        .unwrap_or_else(|e| panic!("the config written back does not load: {e}\n{again}"));
    assert_eq!(back.config, cfg.config, "the config written back differs");
    true
}

/// The scan formats (the virtual scanner's), by the extension their reader is chosen by.
pub use pc_sample::scan::ScanFormat;

/// Any bytes as a LAS, LAZ or E57 model. What the reader returns holds its promises: points,
/// every offset and the origin finite, attributes one per point in their ranges, stations
/// named by each point valid.
///
/// E57 pages are given valid checksums first, so that mutations reach the parser behind them
/// (the checksum check itself is tested on a real corrupt file in pc-import).
pub fn scan(format: ScanFormat, data: &[u8]) -> bool {
    let name = format!("fuzz.{}", format.extension());
    let fixed;
    let data = if format == ScanFormat::E57 {
        fixed = e57_checksums(data);
        &fixed
    } else {
        data
    };
    let read = with_named_file(&name, data, |path| {
        pc_import::points::read_points(path, &PlyOptions::default())
    });
    let Ok(p) = read else {
        return false;
    };
    let n = p.positions.len();
    assert!(n > 0, "an accepted model has points");
    assert!(p.origin.is_finite(), "the origin is finite");
    assert!(p.positions.iter().all(|x| x.is_finite()), "offsets finite");
    let unit = |v: &f32| (0.0..=1.0).contains(v);
    if let Some(c) = &p.colors {
        assert_eq!(c.len(), n);
        assert!(
            c.iter().all(|v| v.to_array().iter().all(unit)),
            "colors in [0, 1]"
        );
    }
    if let Some(i) = &p.intensity {
        assert_eq!(i.len(), n);
        assert!(i.iter().all(unit), "intensity in [0, 1]");
    }
    if let Some(c) = &p.classes {
        assert_eq!(c.len(), n);
    }
    if let Some(of) = &p.station_of {
        assert_eq!(of.len(), n);
        assert!(
            of.iter().all(|&s| (s as usize) < p.stations.len()),
            "stations valid"
        );
        assert!(p.stations.iter().all(|s| s.is_finite()), "stations finite");
    }
    true
}

/// `data` with every whole E57 page's checksum recomputed: CRC-32C of the page but its last
/// four bytes, stored there big-endian (the page size is the header's, at byte 40, when it is
/// sane, else 1024).
pub fn e57_checksums(data: &[u8]) -> Vec<u8> {
    let mut out = data.to_vec();
    let page = data
        .get(40..48)
        .map(|b| u64::from_le_bytes(b.try_into().expect("eight bytes")))
        .filter(|&p| (64..=1 << 20).contains(&p))
        .unwrap_or(1024) as usize;
    for chunk in out.chunks_exact_mut(page) {
        let (body, sum) = chunk.split_at_mut(page - 4);
        sum.copy_from_slice(&crc32c(body).to_be_bytes());
    }
    out
}

/// CRC-32C (Castagnoli), bit by bit: the fuzzer's inputs are small.
fn crc32c(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x82F6_3B78
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// A temporary file per thread, for the readers, which read files.
fn with_file<R>(bytes: &[u8], f: impl FnOnce(&Path) -> R) -> R {
    with_named_file("fuzz.pcgi", bytes, f)
}

/// [`with_file`] under a given name (the scan readers choose by extension).
fn with_named_file<R>(name: &str, bytes: &[u8], f: impl FnOnce(&Path) -> R) -> R {
    thread_local! {
        static DIR: RefCell<Option<tempfile::TempDir>> = const { RefCell::new(None) };
    }
    let path: PathBuf = DIR.with(|d| {
        let mut d = d.borrow_mut();
        let dir = d.get_or_insert_with(|| tempfile::tempdir().expect("a temporary folder"));
        dir.path().join(name)
    });
    std::fs::write(&path, bytes).expect("the temporary file is written");
    f(&path)
}

/// Any bytes as an artifact file: the container and every kind's reader refuse it or accept
/// it; what they accept, the stages can use.
pub fn artifact(data: &[u8]) -> bool {
    with_file(data, |path| match Artifact::open(path) {
        Ok(a) => use_artifact(a),
        Err(_) => false,
    })
}

/// Hands an opened artifact to its kind's reader and, when it accepts, uses the view as the
/// stages do; whether it was accepted.
fn use_artifact(a: Artifact) -> bool {
    match a.kind() {
        ArtifactKind::Octree => OctreeFile::from_artifact(a).map(|f| use_octree(&f)).is_ok(),
        ArtifactKind::Vmap => VmapFile::from_artifact(a)
            .map(|f| use_vmap(&f.view(), None))
            .is_ok(),
        ArtifactKind::Photons => PhotonsFile::from_artifact(a)
            .map(|f| use_photons(f.view().map()))
            .is_ok(),
        ArtifactKind::Radiosity => RadiosityFile::from_artifact(a)
            .map(|f| use_radiosity(&f))
            .is_ok(),
    }
}

/// What the renderer does with a radiosity: reads every splat's radiance.
fn use_radiosity(f: &RadiosityFile) {
    let sum: f32 = f.view().radiance.iter().flatten().sum();
    assert!(!sum.is_nan(), "accepted radiance is a number");
}

/// What the stages do with an octree: point location, rays through it (the walk and the packed
/// lists), subtree ranges and cones, V-map nodes, the FMM's tree.
fn use_octree(f: &OctreeFile) {
    let v = f.view();
    let ranges = pc_tree::nodes::subtree_ranges(&v);
    let _ = pc_tree::nodes::normal_cones(&v, &ranges);
    let _ = pc_vmap::build::vnodes(&v, 16);
    // The packed lists built from the tree agree with the walk; the artifact's own (mapped
    // where it has them: checked structure, coordinates as written) must only never panic.
    let accel = pc_tree::accel::Accel::build(&v);
    let mapped = pc_tree::accel::Accel::new(&v);
    let o = Vec3::from(v.frame.origin);
    let size = v.frame.size;
    let mut st = TraversalStats::default();
    for k in 0..24 {
        let t = k as f32 / 24.0;
        let p = o + Vec3::new(t, (t * 7.0).fract(), (t * 13.0).fract()) * size;
        let _ = v.locate(p);
        let dir = Vec3::new((t * 11.0).sin(), (t * 5.0).cos(), 0.3).normalize();
        let ray = Ray::new(p - dir * size, dir);
        let a = pc_tree::intersect(&v, &ray, &mut st);
        let b = accel.intersect(&v, &ray, &mut st);
        assert_eq!(
            a.map(|h| h.splat),
            b.map(|h| h.splat),
            "the walk and the packed lists agree"
        );
        let _ = pc_tree::occluded(&v, &ray, &mut st);
        let _ = mapped.intersect(&v, &ray, &mut st);
        let _ = mapped.occluded(&v, &ray, &mut st);
    }
    let _ = pc_fmm::tree::build(&v, f.materials());
}

/// What the stages do with a V-map: every node's links and every light's list, indices used.
fn use_vmap(v: &VmapView, octree: Option<&OctreeView>) {
    let nodes = v.node_range.len();
    for slot in 0..nodes {
        for l in v.links_of(slot) {
            assert!((l.slot() as usize) < nodes);
            let [lo, hi] = v.node_range[l.slot() as usize];
            assert!(lo <= hi);
        }
    }
    for l in 0..v.light_offsets.len().saturating_sub(1) {
        for link in v.light_list(l) {
            assert!((link.slot() as usize) < nodes);
        }
    }
    if let Some(o) = octree {
        let splats = o.splats.len();
        assert!(v.node_range.iter().all(|r| r[1] as usize <= splats));
    }
}

/// What the renderer does with a photon map (read without its specular links): its grid and
/// kd-tree built and queried (both estimates).
fn use_photons(v: PhotonMapView) {
    for k in [0, 8] {
        let c = pc_raytrace::caustic::Caustics::new(v.photons, 0.05, k);
        for p in v.photons.iter().take(8) {
            let e = c.irradiance(Vec3::from(p.position), -Vec3::from(p.dir));
            assert!(
                !e.is_nan(),
                "the irradiance from an accepted map is a number"
            );
            assert!((p.splat as usize) < v.deposit.len());
        }
    }
}

/// Which seed artifact a patched target starts from.
#[derive(Clone, Copy, Debug)]
pub enum Kind {
    Octree,
    Vmap,
    Photons,
    Radiosity,
}

/// A valid artifact of `kind` with its sections (and metadata) patched by `data`, written again
/// with valid checksums: the kind's reader, with the upstream checks the stages use, must
/// refuse it or hand out a view the stages can use. `data` is read as patches of 6 bytes:
/// which part (a section, or the metadata), where (a 32-bit word), and a value from a table of
/// values that break arithmetic or a random word.
pub fn patched(kind: Kind, data: &[u8]) -> bool {
    let s = seeds();
    let seed = match kind {
        Kind::Octree => &s.octree,
        Kind::Vmap => &s.vmap,
        Kind::Photons => &s.photons,
        Kind::Radiosity => &s.radiosity,
    };
    let bytes = with_file(seed, |p| rewrite(p, data));
    with_file(&bytes, |path| {
        let octree = OctreeFile::open(&s.octree_path).expect("the seed octree opens");
        match kind {
            Kind::Octree => OctreeFile::open(path).map(|f| use_octree(&f)).is_ok(),
            Kind::Vmap => {
                let Ok(f) = VmapFile::open(path, &octree.id(), &s.lights) else {
                    return false;
                };
                {
                    use_vmap(&f.view(), Some(&octree.view()));
                    let (tree, pts) = pc_fmm::tree::build(&octree.view(), octree.materials());
                    let v = f.view();
                    let _ = pc_fmm::plan::build(
                        &tree,
                        &pts,
                        v.link_offsets,
                        v.links,
                        pc_fmm::PlanParams {
                            theta: 0.5,
                            clamp_tol: 1e-4,
                        },
                    );
                }
                true
            }
            Kind::Photons => {
                let map = PhotonMapFile::open(path, &octree.id()).map(|f| use_photons(f.view()));
                let whole = PhotonsFile::open(path, &octree.id());
                // The renderer's reader checks a part of what pc-fmm's checks.
                assert!(
                    whole.is_err() || map.is_ok(),
                    "a photon map accepted whole is accepted for its photons"
                );
                whole.is_ok()
            }
            Kind::Radiosity => RadiosityFile::open(path, &octree.id())
                .map(|f| {
                    assert_eq!(f.view().radiance.len(), octree.view().splats.len());
                    use_radiosity(&f)
                })
                .is_ok(),
        }
    })
}

/// The artifact at `path` written again with its parts patched by `data` (see [`patched`]).
fn rewrite(path: &Path, data: &[u8]) -> Vec<u8> {
    let a = Artifact::open(path).expect("the seed artifact opens");
    let mut parts: Vec<(String, u32, Vec<u8>)> = a
        .sections()
        .iter()
        .map(|s| {
            let bytes = a.section_bytes(&s.name).expect("a seed section").to_vec();
            (s.name.clone(), s.elem_size, bytes)
        })
        .collect();
    let mut meta = a.metadata_bytes().to_vec();
    const VALUES: [u32; 12] = [
        0,
        1,
        0xFFFF_FFFF,
        0x7FFF_FFFF,
        0x8000_0000,
        0x7FC0_0000,
        0x7F80_0000,
        0xFF80_0000,
        0x7F7F_FFFF,
        0x3F80_0000,
        0xBF80_0000,
        0x4000_0000,
    ];
    for p in data.chunks_exact(6) {
        let which = p[0] as usize % (parts.len() + 1);
        let at = u32::from_le_bytes([p[1], p[2], p[3], 0]) as usize;
        let value = match p[4] {
            v if (v as usize) < VALUES.len() * 16 => VALUES[v as usize % VALUES.len()],
            v => u32::from_le_bytes([v, p[5], p[5].rotate_left(3), p[4] ^ p[5]]),
        };
        let is_meta = which == parts.len();
        let target = if is_meta {
            &mut meta
        } else {
            &mut parts[which].2
        };
        let len = target.len();
        if len >= 4 {
            if is_meta && p[5] & 0x80 != 0 {
                // Metadata: a single byte, MessagePack is byte-oriented.
                target[at % len] = value as u8;
            } else {
                let i = (at % (len / 4)) * 4;
                target[i..i + 4].copy_from_slice(&value.to_le_bytes());
            }
        }
    }
    let h = a.header();
    let out = path.with_file_name("patched.pcgi");
    let mut w =
        ArtifactWriter::create(&out, h.kind, &h.stage, &h.stage_version, h.key).expect("a writer");
    for (name, elem, bytes) in &parts {
        w.section_bytes(name, *elem, bytes)
            .expect("a section of the seed's size");
    }
    w.metadata_raw(meta);
    w.finish().expect("the patched artifact is written");
    std::fs::read(&out).expect("the patched artifact reads")
}
