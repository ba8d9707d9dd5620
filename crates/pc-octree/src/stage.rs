//! The pc-octree stage: config → scene import → build → `octree` artifact, with its key.

use std::path::{Path, PathBuf};
use std::time::Instant;

use pc_artifact::octree::{sections, InputFile, OctreeMeta};
use pc_artifact::{ArtifactKind, ArtifactWriter, Key, KeyHasher};
use pc_config::{material_table, LoadedConfig, MaterialConfig};
use pc_import::load::{load_scene, model_path, LoadedScene, ModelReport, SceneSplats};
use pc_stage::{Progress, Stage};

use crate::build::{build_from, BuildInput, Octree};
use crate::error::OctreeError;

/// The producing stage's name and version, written into every artifact header.
pub const STAGE: &str = "pc-octree";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// The octree artifact's key: this stage's version, the octree and import parameters, each
/// model's transform, material names and classes (its own and its `classes`'), color scale and
/// scanner, and the content of each model file. Material
/// colors, lights and the camera are deliberately left out: they do not change the tree.
pub fn octree_key(cfg: &LoadedConfig) -> Result<Key, OctreeError> {
    let c = &cfg.config;
    let mut h = KeyHasher::new();
    h.update_str(STAGE);
    h.update_str(STAGE_VERSION);
    h.update_key(&pc_artifact::build_id());
    h.update_serialize(&c.octree.params);
    h.update_serialize(&c.import);
    // What the tree takes from a material: its class, and whether it reads the file's colors.
    let identity = |name: &String| {
        let mat = &c.materials[name];
        let cls = match mat {
            MaterialConfig::Diffuse { .. } => "diffuse",
            MaterialConfig::Emitter { .. } => "emitter",
            MaterialConfig::Mirror { .. } => "mirror",
            MaterialConfig::Dielectric { .. } => "dielectric",
        };
        (name.clone(), cls, mat.wants_vertex_colors())
    };
    for m in &c.models {
        h.update_serialize(&(identity(&m.material), m.translate, m.rotate, m.scale));
        let classes: Vec<_> = m
            .classes
            .iter()
            .flatten()
            .map(|(code, name)| (code, identity(name)))
            .collect();
        h.update_serialize(&(classes, m.albedo_scale, &m.scanners));
        let path = model_path(cfg, m);
        h.update_file(&path)
            .map_err(|source| OctreeError::Model { path, source })?;
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
    /// What import did to each model.
    pub models: Vec<ModelReport>,
    /// The scene's origin in the models' coordinates.
    pub origin: glam::DVec3,
}

/// Build the octree of a loaded scene with the config's parameters.
pub fn build_scene(
    cfg: &LoadedConfig,
    scene: &mut LoadedScene,
    phase: &mut dyn FnMut(&str),
) -> Result<Octree, OctreeError> {
    let records = material_table(scene.materials.iter().map(|(_, m)| m));
    let classes: Vec<u32> = records.iter().map(|m| m.class).collect();
    // The scene's splat arrays go to the build, which frees them once they are in its data
    // pool; the scene keeps its materials, models and origin for the artifact's metadata.
    let owned = (std::mem::take(&mut scene.splats), classes);
    build_from(owned, scene_input, &cfg.config.octree.params, phase).map_err(|error| {
        OctreeError::Build {
            config: cfg.path.clone(),
            error,
        }
    })
}

/// The build's view of a scene's splats and its materials' classes.
fn scene_input((s, classes): &(SceneSplats, Vec<u32>)) -> BuildInput<'_> {
    BuildInput {
        positions: &s.positions,
        normals: &s.normals,
        radii: &s.radii,
        albedo: &s.albedo,
        material: &s.material,
        material_class: classes,
    }
}

/// Write an octree artifact atomically.
pub fn write(
    path: &Path,
    key: Key,
    octree: &Octree,
    scene: &LoadedScene,
    cfg: &LoadedConfig,
) -> Result<(), OctreeError> {
    let records = material_table(scene.materials.iter().map(|(_, m)| m));
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
        params: cfg.config.octree.params,
        stats: octree.stats.clone(),
        material_names: scene.materials.iter().map(|(n, _)| n.clone()).collect(),
        dropped_points: scene.dropped() as u64,
        origin: scene.origin.to_array(),
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
    // The CPU walk's packed copy, mapped by every later stage instead of built by each.
    let accel = pc_tree::accel::Accel::build(&octree.view());
    pc_artifact::walk::write(&mut w, &accel.walk())?;
    drop(accel);
    w.metadata(&meta)?;
    w.finish()?;
    Ok(())
}

/// Run the whole stage: import, build, write; `progress` hears of each model and phase.
pub fn run(
    cfg: &LoadedConfig,
    out: &Path,
    progress: &dyn Progress,
) -> Result<Summary, OctreeError> {
    let key = octree_key(cfg)?;
    let t = Instant::now();
    progress.phase("import");
    progress.total(cfg.config.models.len() as u64);
    let mut scene = load_scene(cfg, &mut |_, _| progress.advance(1))?;
    let import_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let octree = build_scene(cfg, &mut scene, &mut |name| {
        progress.phase(&format!("build: {name}"))
    })?;
    let build_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    progress.phase("write");
    write(out, key, &octree, &scene, cfg)?;
    let write_seconds = t.elapsed().as_secs_f64();
    Ok(Summary {
        path: out.to_path_buf(),
        octree,
        import_seconds,
        build_seconds,
        write_seconds,
        dropped: scene.dropped(),
        models: scene.models,
        origin: scene.origin,
    })
}

/// pc-octree as its binary runs it.
pub struct OctreeStage {
    pub cfg: LoadedConfig,
    pub output: PathBuf,
}

impl Stage for OctreeStage {
    const NAME: &'static str = STAGE;
    const DOING: &'static str = "building the octree";
    const KIND: Option<ArtifactKind> = Some(ArtifactKind::Octree);
    type Made = Summary;
    type Error = OctreeError;

    fn output(&self) -> &Path {
        &self.output
    }

    fn key(&self) -> Result<Key, OctreeError> {
        octree_key(&self.cfg)
    }

    fn run(&self, progress: &dyn Progress) -> Result<Summary, OctreeError> {
        run(&self.cfg, &self.output, progress)
    }

    fn summary(&self, summary: &Summary, seconds: f64) -> String {
        let s = &summary.octree.stats;
        let dropped = match summary.dropped {
            0 => String::new(),
            1 => ", left out 1 point".to_string(),
            n => format!(", left out {n} points"),
        };
        // A line per model that import changed (scans, estimated normals, points left out),
        // the scene's origin when it moved, then the summary.
        let mut lines: Vec<String> = summary
            .models
            .iter()
            .filter(|m| m.format.is_scan() || m.dropped > 0 || m.estimated_normals)
            .map(|m| format!("{STAGE}: {}", m.describe()))
            .collect();
        if summary.origin != glam::DVec3::ZERO {
            let o = summary.origin;
            lines.push(format!(
                "{STAGE}: scene origin ({}, {}, {}) in the models' coordinates; camera and lights are relative to it",
                o.x, o.y, o.z
            ));
        }
        lines.push(format!(
            "pc-octree: wrote {} ({} splats, {} nodes, {} leaves, depth {}, {} extra refs{dropped}) in {:.2} s (import {:.2} s, build {:.2} s, {:.1} M splats/s)",
            summary.path.display(),
            s.splats,
            s.nodes,
            s.leaves,
            s.depth,
            s.extra_refs,
            seconds,
            summary.import_seconds,
            summary.build_seconds,
            s.splats as f64 / summary.build_seconds.max(1e-9) / 1e6
        ));
        lines.join("\n")
    }

    fn stats(&self, summary: &Summary, seconds: f64) -> serde_json::Value {
        let s = &summary.octree.stats;
        let phases: Vec<serde_json::Value> = s
            .timings
            .iter()
            .map(|(n, t)| serde_json::json!({ "phase": n, "seconds": t }))
            .collect();
        serde_json::json!({
            "splats": s.splats,
            "nodes": s.nodes,
            "leaves": s.leaves,
            "extra_refs": s.extra_refs,
            "depth": s.depth,
            "import_seconds": summary.import_seconds,
            "build_seconds": summary.build_seconds,
            "write_seconds": summary.write_seconds,
            "total_seconds": seconds,
            "peak_rss_bytes": pc_stage::peak_rss_bytes().unwrap_or(0),
            "threads": rayon::current_num_threads(),
            "phases": phases,
        })
    }
}
