//! The pc-octree stage: config → scene import → build → `octree` artifact, with its key.

use std::path::{Path, PathBuf};
use std::time::Instant;

use pc_artifact::octree::{sections, InputFile, OctreeMeta};
use pc_artifact::{ArtifactKind, ArtifactWriter, Key, KeyHasher};
use pc_scene::config::{LoadedConfig, MaterialConfig};
use pc_scene::load::{load_scene, material_table, model_path, LoadedScene};

use crate::build::{build, BuildInput, BuildParams, Octree};

/// The producing stage's name and version, written into every artifact header.
pub const STAGE: &str = "pc-octree";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// The octree artifact's key: this stage's version, the octree and import parameters, each
/// model's transform, material name and class, and the content of each PLY. Material colors,
/// lights and the camera are deliberately left out: they do not change the tree.
pub fn octree_key(cfg: &LoadedConfig) -> Result<Key, anyhow::Error> {
    let c = &cfg.config;
    let mut h = KeyHasher::new();
    h.update_str(STAGE);
    h.update_str(STAGE_VERSION);
    h.update_key(&pc_artifact::build_id());
    h.update_serialize(&(
        c.octree.max_leaf_points,
        c.octree.max_depth,
        c.octree.area_samples,
    ));
    h.update_serialize(&c.import);
    for m in &c.models {
        let mat = &c.materials[&m.material];
        let cls = match mat {
            MaterialConfig::Diffuse { .. } => "diffuse",
            MaterialConfig::Emitter { .. } => "emitter",
            MaterialConfig::Mirror { .. } => "mirror",
            MaterialConfig::Dielectric { .. } => "dielectric",
        };
        h.update_serialize(&(
            &m.material,
            cls,
            mat.wants_vertex_colors(),
            m.translate,
            m.rotate,
            m.scale,
        ));
        let path = model_path(cfg, m);
        h.update_file(&path)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    // Material indices are positions in the sorted name list: the set of names matters too.
    h.update_serialize(&c.materials.keys().collect::<Vec<_>>());
    Ok(h.finish())
}

/// What one run of the stage made.
#[derive(Debug)]
pub struct Summary {
    pub path: PathBuf,
    pub octree: Octree,
    pub import_seconds: f64,
    pub build_seconds: f64,
    pub write_seconds: f64,
    pub dropped: usize,
}

/// Import the scene of `cfg`.
pub fn import(
    cfg: &LoadedConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<LoadedScene, anyhow::Error> {
    Ok(load_scene(cfg, progress)?)
}

/// Build the octree of a loaded scene with the config's parameters.
pub fn build_scene(
    cfg: &LoadedConfig,
    scene: &LoadedScene,
    phase: &mut dyn FnMut(&str),
) -> Result<Octree, anyhow::Error> {
    let records = material_table(&scene.materials);
    let classes: Vec<u32> = records.iter().map(|m| m.class).collect();
    let s = &scene.splats;
    let input = BuildInput {
        positions: &s.positions,
        normals: &s.normals,
        radii: &s.radii,
        albedo: &s.albedo,
        material: &s.material,
        material_class: &classes,
    };
    let o = &cfg.config.octree;
    let params = BuildParams {
        max_leaf_points: o.max_leaf_points,
        max_depth: o.max_depth,
        area_samples: o.area_samples,
    };
    Ok(build(&input, &params, phase)?)
}

/// Write an octree artifact atomically.
pub fn write(
    path: &Path,
    key: Key,
    octree: &Octree,
    scene: &LoadedScene,
    cfg: &LoadedConfig,
) -> Result<(), anyhow::Error> {
    let records = material_table(&scene.materials);
    let st = &octree.stats;
    let inputs = cfg
        .config
        .models
        .iter()
        .map(|m| {
            let p = model_path(cfg, m);
            let bytes = std::fs::metadata(&p).map(|md| md.len()).unwrap_or(0);
            let mut h = KeyHasher::new();
            let _ = h.update_file(&p);
            InputFile {
                path: p.display().to_string(),
                bytes,
                hash: h.finish().to_string(),
            }
        })
        .collect();
    let meta = OctreeMeta {
        config: cfg.text.clone(),
        inputs,
        max_leaf_points: octree.frame.max_leaf_points,
        max_depth: octree.frame.max_depth,
        splats: st.splats,
        nodes: st.nodes,
        leaves: st.leaves,
        empty_nodes: st.empty_nodes,
        ref_leaves: st.ref_leaves,
        extra_refs: st.extra_refs,
        depth: st.depth,
        leaves_at_max_depth: st.leaves_at_max_depth,
        material_names: scene.materials.iter().map(|(n, _)| n.clone()).collect(),
        timings: st.timings.clone(),
        dropped_points: scene.dropped() as u64,
    };
    let mut w = ArtifactWriter::create(path, ArtifactKind::Octree, STAGE, STAGE_VERSION, key)?;
    w.section(sections::FRAME, std::slice::from_ref(&octree.frame))?;
    w.section(sections::NODES, &octree.nodes)?;
    w.section(sections::BEGIN_END, &octree.begin_end)?;
    w.section(sections::SPLATS, &octree.splats)?;
    w.section(sections::NODE_INFO, &octree.node_info)?;
    w.section(sections::SPLAT_AREA, &octree.splat_area)?;
    w.section(sections::SPLAT_LEAF, &octree.splat_leaf)?;
    w.section(sections::MATERIALS, &records)?;
    w.metadata(&meta)?;
    w.finish()?;
    Ok(())
}

/// Run the whole stage: import, build, write. Progress goes through the two callbacks.
pub fn run(
    cfg: &LoadedConfig,
    out: &Path,
    import_progress: &mut dyn FnMut(usize, usize),
    phase: &mut dyn FnMut(&str),
) -> Result<Summary, anyhow::Error> {
    let key = octree_key(cfg)?;
    let t = Instant::now();
    let scene = import(cfg, import_progress)?;
    let import_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let octree = build_scene(cfg, &scene, phase)?;
    let build_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    phase("write");
    write(out, key, &octree, &scene, cfg)?;
    let write_seconds = t.elapsed().as_secs_f64();
    Ok(Summary {
        path: out.to_path_buf(),
        octree,
        import_seconds,
        build_seconds,
        write_seconds,
        dropped: scene.dropped(),
    })
}
