//! What every stage binary's command line shares: `--config`, `--set`, `--quiet`, loading the
//! config, and mapping an error to its message and exit code 2 (ripgrep's convention).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use pc_artifact::Key;

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
    /// Print the key of what this run would make (hashed from the stage's version, its
    /// parameters, the keys of its input artifacts and the content of its input files) and exit.
    #[arg(long)]
    pub print_key: bool,
    /// Do nothing when the output exists, is intact and has that key already (up to date).
    #[arg(long)]
    pub if_stale: bool,
    /// Also write what happened as JSON: stage, status ("ran" or "up to date"), output, key,
    /// seconds.
    #[arg(long, value_name = "FILE")]
    pub report: Option<PathBuf>,
}

/// What a stage binary does after [`StageArgs::gate`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gate {
    /// Do the work.
    Run,
    /// Nothing to do: the key was printed, or the output is up to date.
    Done,
}

impl StageArgs {
    /// The config with the overrides applied.
    pub fn load(&self) -> Result<LoadedConfig, SceneError> {
        load_config(&self.config, &self.set)
    }

    /// Before the work: `--print-key` prints `key` and is done; `--if-stale` is done when
    /// `existing(output)` (the key of the output already there, `None` when it is missing or
    /// damaged) equals `key`, and says so.
    pub fn gate(
        &self,
        stage: &str,
        output: &Path,
        key: &Key,
        existing: impl FnOnce(&Path) -> Option<Key>,
    ) -> anyhow::Result<Gate> {
        if self.print_key {
            println!("{key}");
            return Ok(Gate::Done);
        }
        if self.if_stale && existing(output).as_ref() == Some(key) {
            println!("{stage}: {} is up to date (key {key})", output.display());
            self.finish(stage, "up to date", output, key, 0.0)?;
            return Ok(Gate::Done);
        }
        Ok(Gate::Run)
    }

    /// [`StageArgs::gate`] for a stage whose output is an artifact of `kind`.
    pub fn gate_artifact(
        &self,
        stage: &str,
        output: &Path,
        key: &Key,
        kind: pc_artifact::ArtifactKind,
    ) -> anyhow::Result<Gate> {
        self.gate(stage, output, key, |p| artifact_key(p, kind))
    }

    /// After the work (or when up to date): write the `--report` JSON, if asked for.
    pub fn finish(
        &self,
        stage: &str,
        status: &str,
        output: &Path,
        key: &Key,
        seconds: f64,
    ) -> anyhow::Result<()> {
        let Some(path) = &self.report else {
            return Ok(());
        };
        let json = serde_json::json!({
            "stage": stage,
            "status": status,
            "output": output.display().to_string(),
            "key": key.to_string(),
            "seconds": seconds,
        });
        pc_artifact::write_file_atomically(path, format!("{json}\n").as_bytes())
            .map_err(|e| anyhow::anyhow!("{}: cannot write the report: {e}", path.display()))
    }
}

/// The key of the artifact at `path` when it opens as a valid artifact of `kind`, else `None`.
pub fn artifact_key(path: &Path, kind: pc_artifact::ArtifactKind) -> Option<Key> {
    pc_artifact::Artifact::open_kind(path, kind)
        .ok()
        .map(|a| a.key())
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
