//! The stage: artifact contents, keys, and links reused when only the lights move.

use pc_artifact::vmap::{sections, Link, VmapMeta};
use pc_artifact::{Artifact, ArtifactKind};
use pc_config::Backend;
use pc_import::ply_write::{write_ply, PlyFormat, PlyPoints};

fn scene(dir: &std::path::Path) -> std::path::PathBuf {
    let s = crate::room(0.08);
    let pts = PlyPoints {
        positions: &s.p,
        normals: Some(&s.n),
        radii: Some(&s.r),
        colors: None,
    };
    write_ply(
        &dir.join("room.ply"),
        &pts,
        PlyFormat::BinaryLittleEndian,
        &[],
    )
    .unwrap();
    let cfg = dir.join("pipeline.toml");
    std::fs::write(
        &cfg,
        "[output]\ndir = \"out\"\n[materials.white]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n[[models]]\nfile = \"room.ply\"\nmaterial = \"white\"\n[[lights]]\nposition = [0.0, 0.8, 0.0]\nintensity = [1.0, 1.0, 1.0]\n[vmap]\nleaf_splats = 16\n",
    )
    .unwrap();
    cfg
}

fn run(cfg: &std::path::Path, set: &[&str]) -> (VmapMeta, std::path::PathBuf) {
    let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
    let c = pc_config::load_config(cfg, &set).unwrap();
    let octree = c.octree_path();
    pc_octree::stage::run(&c, &octree, &pc_stage::Silent).unwrap();
    let s =
        pc_vmap::stage::run(&c, &octree, &c.vmap_path(), Backend::Cpu, &pc_stage::Silent).unwrap();
    (s.meta, s.path)
}

#[test]
fn moving_a_light_reuses_the_links() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = scene(dir.path());
    let (m1, path) = run(&cfg, &[]);
    assert!(!m1.links_reused && m1.far_links > 0);
    let a1 = Artifact::open_kind(&path, ArtifactKind::Vmap).unwrap();
    let links1: Vec<Link> = a1.section::<Link>(sections::LINKS).unwrap().to_vec();
    let key1 = a1.header().key;
    drop(a1);
    // Move the light: same links, new light lists, new artifact key.
    let (m2, _) = run(&cfg, &["lights.0.position=[0.3, 0.8, -0.2]"]);
    assert!(m2.links_reused, "links were recomputed");
    assert_eq!(m2.links_key, m1.links_key);
    let a2 = Artifact::open_kind(&path, ArtifactKind::Vmap).unwrap();
    assert_ne!(a2.header().key, key1);
    assert_eq!(a2.section::<Link>(sections::LINKS).unwrap(), &links1[..]);
    let offs: &[u32] = a2.section(sections::LIGHT_OFFSETS).unwrap();
    assert_eq!(offs.len(), 2);
    assert!(offs[1] > 0, "the light sees nothing");
    drop(a2);
    // A V-map parameter changes the links.
    let (m3, _) = run(&cfg, &["vmap.rays=8"]);
    assert!(!m3.links_reused);
    assert_ne!(m3.links_key, m1.links_key);
}

#[test]
fn links_are_symmetric_and_csr_is_consistent() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = scene(dir.path());
    let (_, path) = run(&cfg, &[]);
    let a = Artifact::open_kind(&path, ArtifactKind::Vmap).unwrap();
    let offsets: &[u32] = a.section(sections::LINK_OFFSETS).unwrap();
    let links: &[Link] = a.section(sections::LINKS).unwrap();
    assert_eq!(*offsets.last().unwrap() as usize, links.len());
    let row = |x: usize| &links[offsets[x] as usize..offsets[x + 1] as usize];
    for x in 0..offsets.len() - 1 {
        for l in row(x) {
            assert!(l.fraction > 0.0 && l.fraction <= 1.0);
            let back = row(l.slot() as usize)
                .iter()
                .find(|b| b.slot() as usize == x);
            let back = back.unwrap_or_else(|| panic!("link {x} -> {} has no reverse", l.slot()));
            assert_eq!(back.fraction, l.fraction);
            assert_eq!(back.is_near(), l.is_near());
        }
    }
}
