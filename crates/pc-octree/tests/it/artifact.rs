//! The stage end to end: PLY files + pipeline.toml → octree artifact; keys; corrupted artifacts.

use std::path::{Path, PathBuf};

use pc_artifact::{Artifact, ArtifactError, ArtifactKind};
use pc_import::ply_write::{write_ply, PlyFormat, PlyPoints};
use pc_octree::stage;

use crate::{mixed_scene, Soa};

fn write_scene(dir: &Path) -> PathBuf {
    let (s, _) = mixed_scene(0.08);
    let names = ["walls", "mirror", "glass"];
    for (m, name) in names.iter().enumerate() {
        let idx: Vec<usize> = (0..s.p.len()).filter(|&i| s.m[i] == m as u32).collect();
        let sub = Soa {
            p: idx.iter().map(|&i| s.p[i]).collect(),
            n: idx.iter().map(|&i| s.n[i]).collect(),
            r: idx.iter().map(|&i| s.r[i]).collect(),
            m: vec![],
        };
        let pts = PlyPoints {
            positions: &sub.p,
            normals: Some(&sub.n),
            radii: Some(&sub.r),
            colors: None,
        };
        write_ply(
            &dir.join(format!("{name}.ply")),
            &pts,
            PlyFormat::BinaryLittleEndian,
            &[],
        )
        .unwrap();
    }
    let toml = r#"
[output]
dir = "out"
[materials.white]
type = "diffuse"
albedo = [0.7, 0.7, 0.7]
[materials.chrome]
type = "mirror"
reflectance = [0.9, 0.9, 0.9]
[materials.glass]
type = "dielectric"
ior = 1.5
[[models]]
file = "walls.ply"
material = "white"
[[models]]
file = "mirror.ply"
material = "chrome"
[[models]]
file = "glass.ply"
material = "glass"
[octree]
max_leaf_points = 8
area_samples = 4
"#;
    let path = dir.join("pipeline.toml");
    std::fs::write(&path, toml).unwrap();
    path
}

fn run_stage(config: &Path, overrides: &[&str]) -> (stage::Summary, pc_config::LoadedConfig) {
    let set: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let cfg = pc_config::load_config(config, &set).unwrap();
    let out = cfg.octree_path();
    let summary = stage::run(&cfg, &out, &pc_stage::Silent).unwrap();
    (summary, cfg)
}

#[test]
fn stage_writes_an_artifact_that_maps_back_identically() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_scene(dir.path());
    let (summary, cfg) = run_stage(&config, &[]);
    let a = Artifact::open_kind(&summary.path, ArtifactKind::Octree).unwrap();
    assert_eq!(a.header().stage, "pc-octree");
    assert_eq!(a.header().key, stage::octree_key(&cfg).unwrap());
    let file = pc_artifact::octree::OctreeFile::open(&summary.path).unwrap();
    let view = file.view();
    let o = &summary.octree;
    assert_eq!(view.nodes, &o.nodes[..]);
    assert_eq!(view.begin_end, &o.begin_end[..]);
    assert_eq!(view.splats, &o.splats[..]);
    assert_eq!(view.node_info, &o.node_info[..]);
    // Written in two halves (the tree while the areas are computed, then the rest).
    assert_eq!(view.splat_area, &o.splat_area[..]);
    assert_eq!(view.splat_leaf, &o.splat_leaf[..]);
    let meta: pc_artifact::octree::OctreeMeta = a.metadata().unwrap();
    assert_eq!(meta.stats.splats, o.splats.len() as u64);
    assert_eq!(meta.material_names, vec!["chrome", "glass", "white"]);
    assert_eq!(meta.inputs.len(), 3);
    // The material table carries the classes; the splats reference it.
    let mats: &[pc_artifact::octree::MaterialRecord] = a.section("materials").unwrap();
    assert_eq!(mats.len(), 3);
    assert!((mats[1].ior - 1.5).abs() < 1e-6);
    // No temporary file is left behind.
    let leftovers: Vec<_> = std::fs::read_dir(cfg.out_dir())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().extension().is_some_and(|x| x == "tmp"))
        .collect();
    assert!(leftovers.is_empty());
}

#[test]
fn key_follows_what_changes_the_tree_only() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_scene(dir.path());
    let key = |over: &[&str]| {
        let set: Vec<String> = over.iter().map(|s| s.to_string()).collect();
        stage::octree_key(&pc_config::load_config(&config, &set).unwrap()).unwrap()
    };
    let base = key(&[]);
    assert_eq!(base, key(&[]));
    // Albedo, camera and lights do not change the tree.
    assert_eq!(base, key(&["materials.white.albedo=[0.2, 0.3, 0.4]"]));
    assert_eq!(base, key(&["camera.origin=[1, 1, 5]"]));
    // Parameters, transforms, classes and file contents do.
    assert_ne!(base, key(&["octree.max_leaf_points=9"]));
    assert_ne!(base, key(&["models.0.translate=[0, 0.1, 0]"]));
    assert_ne!(base, key(&["models.1.material=glass"]));
    let before = key(&[]);
    let mut bytes = std::fs::read(dir.path().join("walls.ply")).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(dir.path().join("walls.ply"), bytes).unwrap();
    assert_ne!(before, key(&[]));
}

#[test]
fn corrupted_octree_artifacts_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_scene(dir.path());
    let (summary, _) = run_stage(&config, &[]);
    let good = std::fs::read(&summary.path).unwrap();
    let bad = dir.path().join("bad.pcgi");
    let a = Artifact::open(&summary.path).unwrap();
    // Flip a byte in the middle of every section.
    for s in a.sections() {
        if s.len == 0 {
            continue;
        }
        let mut b = good.clone();
        b[(s.offset + s.len / 2) as usize] ^= 0x40;
        std::fs::write(&bad, &b).unwrap();
        match Artifact::open(&bad) {
            Err(ArtifactError::Checksum { section, .. }) => assert_eq!(section, s.name),
            Err(e) => panic!("section {}: unexpected error {e}", s.name),
            Ok(_) => panic!("section {}: corruption not detected", s.name),
        }
    }
    // Truncate at many lengths.
    for len in [
        0,
        1,
        100,
        256,
        good.len() / 3,
        good.len() / 2,
        good.len() - 1,
    ] {
        std::fs::write(&bad, &good[..len]).unwrap();
        let e = Artifact::open(&bad)
            .err()
            .unwrap_or_else(|| panic!("truncated to {len} accepted"));
        assert!(e.to_string().contains("bad.pcgi"), "{e}");
    }
    // Right container, wrong kind.
    match Artifact::open_kind(&summary.path, ArtifactKind::Vmap) {
        Err(ArtifactError::WrongKind { .. }) => {}
        other => panic!("{:?}", other.map(|_| ())),
    }
}

#[test]
fn structural_check_rejects_a_tampered_node_pool() {
    // A node pool whose checksums are right but whose pointers are wrong (a buggy writer)
    // must be rejected by the view, not crash a traversal.
    let dir = tempfile::tempdir().unwrap();
    let config = write_scene(dir.path());
    let (summary, _) = run_stage(&config, &[]);
    let mut o = summary.octree.clone();
    o.nodes[0] = pc_artifact::octree::node::internal(o.nodes.len() as u32 + 5);
    assert!(o.view().check().unwrap_err().contains("children"));
    let mut o = summary.octree.clone();
    let last = o.begin_end.len() - 1;
    o.begin_end[last] = o.splats.len() as u32 + 1;
    assert!(o.view().check().is_err());
}

/// The artifact at `from` rewritten to `to` (fresh checksums), each section passed through
/// `edit` (its name, element size and bytes; `None` drops it).
fn rewrite(
    from: &Path,
    to: &Path,
    mut edit: impl FnMut(&str, u32, Vec<u8>) -> Option<Vec<u8>>,
) -> PathBuf {
    let a = Artifact::open(from).unwrap();
    let h = a.header();
    let mut w =
        pc_artifact::ArtifactWriter::create(to, h.kind, &h.stage, &h.stage_version, h.key).unwrap();
    for s in a.sections() {
        let bytes = a.section_bytes(&s.name).unwrap().to_vec();
        if let Some(bytes) = edit(&s.name, s.elem_size, bytes) {
            w.section_bytes(&s.name, s.elem_size, &bytes).unwrap();
        }
    }
    w.metadata_raw(a.metadata_bytes().to_vec());
    w.finish().unwrap()
}

#[test]
fn the_packed_walk_is_written_once_and_mapped_by_every_reader() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_scene(dir.path());
    let (summary, _) = run_stage(&config, &[]);
    let file = pc_artifact::octree::OctreeFile::open(&summary.path).unwrap();
    let view = file.view();
    let walk = view.walk.expect("pc-octree writes the packed walk");
    let mapped = pc_tree::accel::Accel::new(&view);
    assert!(mapped.is_mapped());
    // Byte for byte the copy a reader would build from the tree itself.
    let built = pc_tree::accel::Accel::build(&view);
    let b = built.walk();
    assert_eq!(walk.slabs, b.slabs);
    assert_eq!(walk.blocks, b.blocks);
    assert_eq!(walk.leaves, b.leaves);
    assert_eq!(walk.chunks, b.chunks);
    // Each lane names its splat; the flags mark exactly the splats with a border clip,
    // though the tree's sections were written before the clips were made.
    for c in walk.chunks {
        for l in 0..pc_artifact::walk::LANES {
            if c.cold[l] == pc_artifact::walk::PADDING {
                assert!(c.r2[l] < 0.0);
                continue;
            }
            let s = &view.splats[c.cold[l] as usize];
            assert_eq!(c.r2[l], s.radius * s.radius);
        }
    }
    assert_eq!(walk.clipped, b.clipped);
    let clipped = (0..view.splats.len() as u32)
        .filter(|&i| pc_artifact::walk::is_clipped(walk.clipped, i))
        .count();
    let with_clip = view.splats.iter().filter(|s| s.clip != [0.0; 4]).count();
    assert_eq!(clipped, with_clip);
    assert!(
        with_clip > 0 && with_clip < view.splats.len(),
        "{with_clip} clipped"
    );
    // A reader that casts no rays opens the tree alone.
    let lean = pc_artifact::octree::OctreeFile::open_without_walk(&summary.path).unwrap();
    assert!(lean.view().walk.is_none());
    assert_eq!(lean.view().splats, view.splats);
    // Without the sections (an octree written before them) the reader builds the same copy.
    let bare = rewrite(&summary.path, &dir.path().join("bare.pcgi"), |n, _, b| {
        (!n.starts_with("walk_")).then_some(b)
    });
    let file = pc_artifact::octree::OctreeFile::open(&bare).unwrap();
    let view = file.view();
    assert!(view.walk.is_none());
    let own = pc_tree::accel::Accel::new(&view);
    assert!(!own.is_mapped());
    assert_eq!(own.walk().chunks, b.chunks);
    // Nor is a walk of another layout read: it is built instead.
    let other = rewrite(
        &summary.path,
        &dir.path().join("other.pcgi"),
        |n, _, mut b| {
            if n == "walk_info" {
                b[..4].copy_from_slice(&(pc_artifact::walk::LAYOUT + 1).to_le_bytes());
            }
            Some(b)
        },
    );
    let file = pc_artifact::octree::OctreeFile::open(&other).unwrap();
    assert!(file.view().walk.is_none());
}

#[test]
fn a_packed_walk_that_points_outside_is_rejected_when_opened() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_scene(dir.path());
    let (summary, _) = run_stage(&config, &[]);
    // Fresh checksums over wrong words (a buggy writer): the structural check must catch each.
    let cases: [(&str, usize, u32, &str); 3] = [
        // The root word, pointing past the blocks.
        (
            "walk_blocks",
            0,
            pc_artifact::octree::node::internal(1 << 20),
            "walk_blocks",
        ),
        // A lane naming a splat that does not exist (chunk 0's first index, after its 28
        // floats).
        ("walk_chunks", 28, 1 << 29, "walk_chunks: chunk 0, lane 0"),
        // A leaf's run ending past the chunks.
        ("walk_leaves", 1, u32::MAX, "walk_chunks"),
    ];
    for (k, (section, word, value, says)) in cases.into_iter().enumerate() {
        let to = dir.path().join(format!("bad{k}.pcgi"));
        let bad = rewrite(&summary.path, &to, |n, _, mut b| {
            if n == section {
                b[word * 4..word * 4 + 4].copy_from_slice(&value.to_le_bytes());
            }
            Some(b)
        });
        let err = pc_artifact::octree::OctreeFile::open(&bad)
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(err.contains(says), "{section}: {err}");
        assert!(err.contains(&format!("bad{k}.pcgi")), "{err}");
    }
}
