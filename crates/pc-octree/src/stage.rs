//! The pc-octree stage: config → scene import → build → `octree` artifact, with its key.

use std::path::{Path, PathBuf};
use std::time::Instant;

use pc_artifact::octree::{sections, InputFile, MaterialRecord, OctreeMeta};
use pc_artifact::{ArtifactKind, ArtifactWriter, Key, KeyHasher};
use pc_config::{material_table, LoadedConfig, MaterialConfig};
use pc_import::load::{load_scene, model_path, LoadedScene, ModelReport, SceneSplats};
use pc_stage::{Progress, Stage};

use pc_tree::accel::Accel;

use crate::build::{tree_from, BuildInput, Octree, Tree};
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

/// The tree of a loaded scene with the config's parameters, before its splats' areas
/// ([`crate::build::Tree`]); `records` is the scene's material table.
pub fn build_tree(
    cfg: &LoadedConfig,
    scene: &mut LoadedScene,
    records: &[MaterialRecord],
    phase: &mut dyn FnMut(&str),
) -> Result<Tree, OctreeError> {
    let classes: Vec<u32> = records.iter().map(|m| m.class).collect();
    // The scene's splat arrays go to the build, which frees them once they are in its data
    // pool; the scene keeps its materials, models and origin for the artifact's metadata.
    let owned = (std::mem::take(&mut scene.splats), classes);
    tree_from(owned, scene_input, &cfg.config.octree.params, phase).map_err(|error| {
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

/// The octree of `tree`, its artifact written on the way: the sections the splats' areas do
/// not change (the tree, the materials and the walk's packed copy, `accel`) go to the disk
/// from a thread of their own while [`Tree::surfaces`] computes the areas, the clips and the
/// node statistics; then the rest. The areas take longer than the disk needs for those
/// sections, so the stage no longer waits for it at the end (docs/octree.md, "Writing").
/// Returns the octree and the seconds spent computing the surfaces.
fn surfaces_and_write(
    out: &Path,
    key: Key,
    tree: Tree,
    accel: Accel<'static>,
    (cfg, scene, records): (&LoadedConfig, &LoadedScene, &[MaterialRecord]),
    progress: &dyn Progress,
) -> Result<(Octree, f64), OctreeError> {
    let (surfaces, early, seconds) = std::thread::scope(|s| {
        let early = s.spawn(|| -> Result<ArtifactWriter, OctreeError> {
            let mut w =
                ArtifactWriter::create(out, ArtifactKind::Octree, STAGE, STAGE_VERSION, key)?;
            w.section(sections::FRAME, std::slice::from_ref(&tree.frame))?;
            w.section(sections::NODES, tree.nodes())?;
            w.section(sections::BEGIN_END, &tree.begin_end)?;
            w.section(sections::SPLAT_LEAF, &tree.splat_leaf)?;
            w.section(sections::MATERIALS, records)?;
            // The CPU walk's packed copy, mapped by every later stage instead of built by each.
            // (Its flags of the clipped splats wait for the clips: below.)
            pc_artifact::walk::write_tree(&mut w, &accel.walk())?;
            drop(accel);
            w.sync_written()?;
            Ok(w)
        });
        let t = Instant::now();
        let mut phase = |name: &str| progress.phase(&format!("build: {name}"));
        let surfaces = tree.surfaces(&cfg.config.octree.params, &mut phase);
        let seconds = t.elapsed().as_secs_f64();
        (surfaces, early.join(), seconds)
    });
    let mut w = early.unwrap_or_else(|panic| std::panic::resume_unwind(panic))?;
    let octree = tree.finish(surfaces);
    progress.phase("write");
    w.section(sections::SPLATS, &octree.splats)?;
    w.section(sections::NODE_INFO, &octree.node_info)?;
    w.section(sections::SPLAT_AREA, &octree.splat_area)?;
    pc_artifact::walk::write_clipped(&mut w, &pc_artifact::walk::clipped_bits(&octree.splats))?;
    w.metadata(&metadata(&octree, scene, cfg))?;
    w.finish()?;
    Ok((octree, seconds))
}

/// The octree artifact's metadata: the config, each model file's size and hash, the build's
/// parameters and statistics, the material names, the points left out and the scene's origin.
fn metadata(octree: &Octree, scene: &LoadedScene, cfg: &LoadedConfig) -> OctreeMeta {
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
    OctreeMeta {
        config: cfg.text.clone(),
        inputs,
        params: cfg.config.octree.params,
        stats: octree.stats.clone(),
        material_names: scene.materials.iter().map(|(n, _)| n.clone()).collect(),
        dropped_points: scene.dropped() as u64,
        origin: scene.origin.to_array(),
    }
}

/// Run the whole stage: import, build, write; `progress` hears of each model and phase.
///
/// `build_seconds` counts the tree and its surfaces (areas, clips, node statistics), as the
/// benchmarks' build rate does; `write_seconds` the walk's packed copy and what of the write
/// was left after the surfaces.
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
    let mut phase = |name: &str| progress.phase(&format!("build: {name}"));
    let t = Instant::now();
    let records = material_table(scene.materials.iter().map(|(_, m)| m));
    let tree = build_tree(cfg, &mut scene, &records, &mut phase)?;
    let tree_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    phase("walk");
    let accel = Accel::build(&tree.walk_view());
    let walk_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let (octree, surfaces_seconds) =
        surfaces_and_write(out, key, tree, accel, (cfg, &scene, &records), progress)?;
    let write_seconds = walk_seconds + t.elapsed().as_secs_f64() - surfaces_seconds;
    Ok(Summary {
        path: out.to_path_buf(),
        octree,
        import_seconds,
        build_seconds: tree_seconds + surfaces_seconds,
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
