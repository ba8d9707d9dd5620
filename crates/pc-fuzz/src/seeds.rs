//! The valid inputs the fuzzers start from: a small sampled Cornell box with a glass and a
//! mirror sphere and a point light, written as PLY files, a pipeline.toml, and every artifact
//! kind made by the stages' own runs. Made once per process.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use pc_artifact::PointLight;
use pc_config::{load_config, Backend};
use pc_import::ply_write::{write_ply_to, PlyFormat};
use pc_sample::{cornell, write_scene, SampleParams};
use pc_stage::Silent;

/// Everything the targets start from.
pub struct Seeds {
    /// Keeps the files alive while the process runs.
    _dir: tempfile::TempDir,
    /// PLY models: the scene's shapes in binary little-endian, one in big-endian and ASCII.
    pub plys: Vec<Vec<u8>>,
    /// A whole pipeline.toml (the scene's tables and every stage's).
    pub config: String,
    pub octree: Vec<u8>,
    pub vmap: Vec<u8>,
    pub photons: Vec<u8>,
    pub radiosity: Vec<u8>,
    /// The artifacts on disk, for the upstream checks of the downstream readers.
    pub octree_path: PathBuf,
    pub lights: Vec<PointLight>,
}

/// Real scan files (pc-import's test data): LAS, LAZ and E57, good ones only.
pub const SCANS: &[(&str, &[u8])] = &[
    (
        "autzen.las",
        include_bytes!("../../pc-import/tests/data/scans/autzen.las"),
    ),
    (
        "extrabytes.laz",
        include_bytes!("../../pc-import/tests/data/scans/extrabytes.laz"),
    ),
    (
        "32-1-472-150-76.laz",
        include_bytes!("../../pc-import/tests/data/scans/32-1-472-150-76.laz"),
    ),
    (
        "tinyCartesianFloatRgb.e57",
        include_bytes!("../../pc-import/tests/data/scans/tinyCartesianFloatRgb.e57"),
    ),
    (
        "tiny_spherical.e57",
        include_bytes!("../../pc-import/tests/data/scans/tiny_spherical.e57"),
    ),
];

/// The scan seeds of one extension.
pub fn scans(ext: &str) -> Vec<&'static [u8]> {
    SCANS
        .iter()
        .filter(|(name, _)| name.ends_with(ext))
        .map(|(_, b)| *b)
        .collect()
}

/// The stage tables and the light of the seeds' pipeline: small, fast settings.
const STAGES: &str = "[output]\ndir = \"out\"\n\n[[lights]]\nposition = [0.0, 0.9, 0.2]\nintensity = [1.0, 0.9, 0.8]\n\n[octree]\nmax_leaf_points = 8\n\n[vmap]\nrays = 4\nnear_rays = 4\nheavy_rays = 0\n\n[caustics]\nphotons = 20000\n\n[fmm]\nemitter_samples = 4\nemitter_probes = 0\nmax_iterations = 3\n\n[raytrace]\nspp = 1\n";

/// The seeds, made on first use.
pub fn seeds() -> &'static Seeds {
    static SEEDS: OnceLock<Seeds> = OnceLock::new();
    SEEDS.get_or_init(|| make().unwrap_or_else(|e| panic!("making the fuzzing seeds: {e}")))
}

fn make() -> Result<Seeds, Box<dyn std::error::Error>> {
    let dir = tempfile::Builder::new().prefix("pcgi-fuzz-").tempdir()?;
    let scene = cornell(&SampleParams::with_points(1500), true);
    let scene_toml = write_scene(&scene, dir.path())?;
    let mut plys = Vec::new();
    for shape in &scene.shapes {
        plys.push(std::fs::read(dir.path().join(scene.file_name(shape)))?);
    }
    for format in [PlyFormat::BinaryBigEndian, PlyFormat::Ascii] {
        let mut bytes = Vec::new();
        write_ply_to(&mut bytes, &scene.shapes[0].ply_points(), format, &[])?;
        plys.push(bytes);
    }
    let config = format!("{}\n{STAGES}", std::fs::read_to_string(&scene_toml)?);
    let path = dir.path().join("pipeline.toml");
    std::fs::write(&path, &config)?;
    let cfg = load_config(&path, &[])?;
    let (octree, vmap) = (cfg.octree_path(), cfg.vmap_path());
    let (photons, radiosity) = (cfg.photons_path(), cfg.radiosity_path());
    pc_octree::stage::run(&cfg, &octree, &Silent)?;
    pc_vmap::stage::run(&cfg, &octree, &vmap, Backend::Cpu, &Silent)?;
    pc_caustics::stage::run(&cfg, &octree, &vmap, &photons, Backend::Cpu, &Silent)?;
    let inputs = pc_fmm::stage::Inputs::new(&cfg, None, None, None);
    pc_fmm::stage::run(&cfg, &inputs, &radiosity, Backend::Cpu, &Silent)?;
    let read = |p: &Path| std::fs::read(p);
    Ok(Seeds {
        plys,
        config,
        octree: read(&octree)?,
        vmap: read(&vmap)?,
        photons: read(&photons)?,
        radiosity: read(&radiosity)?,
        octree_path: octree,
        lights: cfg.config.lights.clone(),
        _dir: dir,
    })
}

/// Writes the seeds as libFuzzer corpora under `root` (cargo-fuzz reads `fuzz/corpus/<target>`):
/// `ply/` the models, `config/` the pipeline.toml, `artifact/` the four artifacts. The patched
/// targets need none (their input is a list of patches). Returns the files written.
pub fn write_corpus(root: &Path) -> std::io::Result<Vec<PathBuf>> {
    let s = seeds();
    let mut files: Vec<(PathBuf, &[u8])> = s
        .plys
        .iter()
        .enumerate()
        .map(|(i, b)| (root.join("ply").join(format!("seed-{i}.ply")), b.as_slice()))
        .collect();
    files.push((root.join("config/pipeline.toml"), s.config.as_bytes()));
    for (name, bytes) in SCANS {
        let target = name
            .rsplit('.')
            .next()
            .expect("a scan file has an extension");
        files.push((root.join(target).join(name), bytes));
    }
    for (name, bytes) in [
        ("octree", &s.octree),
        ("vmap", &s.vmap),
        ("photons", &s.photons),
        ("radiosity", &s.radiosity),
    ] {
        files.push((root.join("artifact").join(format!("{name}.pcgi")), bytes));
    }
    for (path, bytes) in &files {
        std::fs::create_dir_all(path.parent().expect("a corpus file lies in a folder"))?;
        std::fs::write(path, bytes)?;
    }
    Ok(files.into_iter().map(|(p, _)| p).collect())
}
