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
