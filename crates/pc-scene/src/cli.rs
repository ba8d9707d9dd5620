//! What every stage binary's command line shares: `--config`, `--set`, `--quiet`, loading the
//! config, and mapping an error to its message and exit code 2 (ripgrep's convention).

use std::path::PathBuf;
use std::process::ExitCode;

use crate::config::{load_config, LoadedConfig};
use crate::SceneError;

/// The arguments every stage takes (`#[command(flatten)]` them into a binary's own).
#[derive(Clone, Debug, clap::Args)]
pub struct StageArgs {
    /// The pipeline description.
    #[arg(long, default_value = "pipeline.toml")]
    pub config: PathBuf,
    /// Override a config key, e.g. `--set octree.max_leaf_points=8` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// No progress display.
    #[arg(long, short)]
    pub quiet: bool,
}

impl StageArgs {
    /// The config with the overrides applied.
    pub fn load(&self) -> Result<LoadedConfig, SceneError> {
        load_config(&self.config, &self.set)
    }
}

/// Run a stage's body: on error print `NAME: error: <chain>` to stderr and exit with 2.
pub fn exit(name: &str, result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{name}: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

/// The materials of the config, checked against the ones the octree was built with: names and
/// classes must match (colors may change without rebuilding the octree).
pub fn current_materials(
    cfg: &LoadedConfig,
    octree: &pc_artifact::Artifact,
) -> anyhow::Result<Vec<pc_artifact::octree::MaterialRecord>> {
    let meta: pc_artifact::octree::OctreeMeta = octree.metadata()?;
    let materials: Vec<(String, crate::config::MaterialConfig)> = cfg
        .config
        .materials
        .iter()
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    let names: Vec<String> = materials.iter().map(|m| m.0.clone()).collect();
    if names != meta.material_names {
        anyhow::bail!(
            "{}: the octree was built with materials [{}] but {} now defines [{}]: rerun pc-octree",
            octree.path().display(),
            meta.material_names.join(", "),
            cfg.path.display(),
            names.join(", ")
        );
    }
    let table = crate::load::material_table(&materials);
    let built: &[pc_artifact::octree::MaterialRecord] = octree.section("materials")?;
    for (i, (m, b)) in table.iter().zip(built).enumerate() {
        if m.class != b.class || m.per_point_color != b.per_point_color {
            anyhow::bail!(
                "{}: material `{}` changed class since the octree was built: rerun pc-octree",
                octree.path().display(),
                names[i]
            );
        }
    }
    Ok(table)
}
