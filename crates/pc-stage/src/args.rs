//! The arguments every stage binary shares (`#[command(flatten)]` them into its own), and
//! loading the config they name.

use std::path::PathBuf;

use pc_config::{load_config, ConfigError, LoadedConfig};

/// The arguments every stage takes.
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
    /// Also write the run's counts and timings as JSON (for `cargo xtask bench`).
    #[arg(long, value_name = "FILE")]
    pub stats_json: Option<PathBuf>,
}

impl StageArgs {
    /// The config with the overrides applied.
    pub fn load(&self) -> Result<LoadedConfig, ConfigError> {
        load_config(&self.config, &self.set)
    }
}
