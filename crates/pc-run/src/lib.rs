//! The pipeline driver: the five stage binaries run as separate processes in dependency order,
//! each one skipped when the artifact it would make is already there with the same key.
//!
//! The driver itself knows nothing about keys: every stage binary computes the key of what it
//! would make (its version, its parameters, the keys of its input artifacts, the content of its
//! input files), compares it with the output already on disk when given `--if-stale`, and says
//! what it did in a `--report` file. Deciding there, in the stage, keeps one definition of each
//! key; the driver only orders the stages, forces the ones asked for, and times them. A stage
//! killed halfway leaves its previous output in place (outputs are renamed into place whole),
//! whose key then does not match, so the next run redoes it.

use std::fmt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use serde::Deserialize;

/// The stages, in dependency order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Stage {
    Octree,
    Vmap,
    Caustics,
    Fmm,
    Raytrace,
    /// The lit cloud (pc-bake): after the render, run only when asked (`--until pc-bake`).
    Bake,
}

impl Stage {
    /// Every stage, in the order they run.
    pub const ALL: [Stage; 6] = [
        Stage::Octree,
        Stage::Vmap,
        Stage::Caustics,
        Stage::Fmm,
        Stage::Raytrace,
        Stage::Bake,
    ];

    /// The stage's binary.
    pub fn bin(self) -> &'static str {
        match self {
            Stage::Octree => "pc-octree",
            Stage::Vmap => "pc-vmap",
            Stage::Caustics => "pc-caustics",
            Stage::Fmm => "pc-fmm",
            Stage::Raytrace => "pc-raytrace",
            Stage::Bake => "pc-bake",
        }
    }

    /// A stage by its binary's name (`pc-fmm`) or short name (`fmm`).
    pub fn parse(name: &str) -> Result<Stage> {
        let short = name.strip_prefix("pc-").unwrap_or(name);
        Stage::ALL
            .into_iter()
            .find(|s| &s.bin()[3..] == short)
            .with_context(|| {
                format!(
                    "`{name}` is not a stage (one of: {})",
                    Stage::ALL.map(Stage::bin).join(", ")
                )
            })
    }
}

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.bin())
    }
}

/// What to run.
#[derive(Clone, Debug)]
pub struct Options {
    /// The pipeline description.
    pub config: PathBuf,
    /// `KEY=VALUE` overrides passed to every stage.
    pub sets: Vec<String>,
    /// Stages that run even when up to date.
    pub force: Vec<Stage>,
    /// The first stage to consider: earlier ones are neither checked nor run (their
    /// artifacts are used as they are).
    pub from: Stage,
    /// The last stage to consider (default pc-raytrace: pc-bake runs when asked for).
    pub until: Stage,
    /// The folder holding the stage binaries.
    pub bin_dir: PathBuf,
    /// Pass `--quiet` to the stages (no progress bars).
    pub quiet: bool,
}

impl Options {
    /// Every stage of `config`, with the binaries in `bin_dir`.
    pub fn new(config: impl Into<PathBuf>, bin_dir: impl Into<PathBuf>) -> Options {
        Options {
            config: config.into(),
            sets: Vec::new(),
            force: Vec::new(),
            from: Stage::Octree,
            until: Stage::Raytrace,
            bin_dir: bin_dir.into(),
            quiet: false,
        }
    }
}

/// Whether a stage did its work.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    Ran,
    UpToDate,
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Status::Ran => "ran",
            Status::UpToDate => "up to date",
        })
    }
}

/// What one stage did.
#[derive(Clone, Debug)]
pub struct StageRun {
    pub stage: Stage,
    pub status: Status,
    /// Wall time of the stage's process (up-to-date checks included).
    pub seconds: f64,
    /// The key of its output (artifact header, or the EXR's `pcgiKey` attribute).
    pub key: String,
    /// Its output file.
    pub output: PathBuf,
    /// The stage process's peak resident memory in bytes (0 where unknown).
    pub peak_rss_bytes: u64,
    /// Where its GPU time went (`pc_gpu::GpuTimes::json`), when it used a GPU.
    pub gpu: Option<serde_json::Value>,
}

/// A stage's `--report` file.
#[derive(Deserialize)]
struct Report {
    stage: String,
    status: String,
    output: PathBuf,
    key: String,
    #[serde(default)]
    peak_rss_bytes: u64,
    #[serde(default)]
    gpu: Option<serde_json::Value>,
}

/// The folder of the running executable (where `cargo build` puts the stage binaries too).
pub fn own_bin_dir() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("finding this executable's folder")?;
    Ok(exe
        .parent()
        .context("this executable lies in no folder")?
        .to_path_buf())
}

/// Run the stages `opts.from..=opts.until` in order; `on_done` hears of each as it finishes.
/// Stops at the first stage that fails (the artifacts before it are kept).
pub fn run(opts: &Options, on_done: &mut dyn FnMut(&StageRun)) -> Result<Vec<StageRun>> {
    if opts.from > opts.until {
        bail!(
            "--from {} comes after --until {}: nothing to run",
            opts.from,
            opts.until
        );
    }
    if !opts.config.is_file() {
        bail!("{}: no such config file", opts.config.display());
    }
    let reports = tempfile::tempdir().context("making a folder for the stage reports")?;
    let mut done = Vec::new();
    for stage in Stage::ALL
        .into_iter()
        .filter(|s| (opts.from..=opts.until).contains(s))
    {
        let bin = opts.bin_dir.join(stage.bin());
        if !bin.is_file() {
            bail!(
                "{}: no such binary (build the stage binaries first: cargo build --release --bins)",
                bin.display()
            );
        }
        let report = reports.path().join(format!("{stage}.json"));
        let mut cmd = Command::new(&bin);
        cmd.arg("--config").arg(&opts.config);
        for s in &opts.sets {
            cmd.arg("--set").arg(s);
        }
        if opts.quiet {
            cmd.arg("--quiet");
        }
        if !opts.force.contains(&stage) {
            cmd.arg("--if-stale");
        }
        cmd.arg("--report").arg(&report);
        let t = Instant::now();
        let status = cmd
            .status()
            .with_context(|| format!("starting {}", bin.display()))?;
        let seconds = t.elapsed().as_secs_f64();
        if !status.success() {
            bail!(
                "{stage} failed ({status}); the stages before it are done and their artifacts kept"
            );
        }
        let r = read_report(&report, stage)?;
        let run = StageRun {
            stage,
            status: match r.status.as_str() {
                "ran" => Status::Ran,
                "up to date" => Status::UpToDate,
                other => bail!("{}: unknown status `{other}`", report.display()),
            },
            seconds,
            key: r.key,
            output: r.output,
            peak_rss_bytes: r.peak_rss_bytes,
            gpu: r.gpu,
        };
        on_done(&run);
        done.push(run);
    }
    Ok(done)
}

fn read_report(path: &Path, stage: Stage) -> Result<Report> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{stage} wrote no report to {}", path.display()))?;
    let r: Report = serde_json::from_str(&text)
        .with_context(|| format!("{}: {stage}'s report does not parse", path.display()))?;
    if r.stage != stage.bin() {
        bail!(
            "{}: a report of {}, not of {stage}",
            path.display(),
            r.stage
        );
    }
    Ok(r)
}

/// One line: which stages ran and which were up to date, with their times.
pub fn summary(runs: &[StageRun], total_seconds: f64) -> String {
    let parts: Vec<String> = runs
        .iter()
        .map(|r| match r.status {
            Status::Ran => format!(
                "{} ran ({:.2} s, {})",
                r.stage,
                r.seconds,
                memory(r.peak_rss_bytes)
            ),
            Status::UpToDate => format!("{} up to date", r.stage),
        })
        .collect();
    let ran = runs.iter().filter(|r| r.status == Status::Ran).count();
    format!(
        "{} ran, {} up to date in {total_seconds:.2} s: {}",
        ran,
        runs.len() - ran,
        parts.join(", ")
    )
}

/// A peak memory for people: `412 MB`, `11.3 GB`.
fn memory(bytes: u64) -> String {
    let mb = bytes as f64 / 1e6;
    match mb {
        m if m >= 1000.0 => format!("{:.1} GB", m / 1000.0),
        m => format!("{m:.0} MB"),
    }
}

/// The runs as JSON (for scripts and tests): a list of {stage, status, seconds, key, output,
/// peak_rss_bytes, gpu}.
pub fn to_json(runs: &[StageRun]) -> String {
    let list: Vec<serde_json::Value> = runs
        .iter()
        .map(|r| {
            serde_json::json!({
                "stage": r.stage.bin(),
                "status": r.status.to_string(),
                "seconds": r.seconds,
                "key": r.key,
                "output": r.output.display().to_string(),
                "peak_rss_bytes": r.peak_rss_bytes,
                "gpu": r.gpu,
            })
        })
        .collect();
    serde_json::to_string_pretty(&list).expect("plain JSON values") + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_parse_by_either_name() {
        assert_eq!(Stage::parse("pc-fmm").unwrap(), Stage::Fmm);
        assert_eq!(Stage::parse("vmap").unwrap(), Stage::Vmap);
        assert_eq!(Stage::parse("bake").unwrap(), Stage::Bake);
        let e = Stage::parse("pc-render").unwrap_err().to_string();
        assert_eq!(
            e,
            "`pc-render` is not a stage (one of: pc-octree, pc-vmap, pc-caustics, pc-fmm, pc-raytrace, pc-bake)"
        );
    }

    #[test]
    fn stages_are_in_dependency_order() {
        let mut sorted = Stage::ALL;
        sorted.sort();
        assert_eq!(sorted, Stage::ALL);
        assert!(Stage::Caustics < Stage::Fmm, "pc-fmm reads the photon map");
    }

    #[test]
    fn from_after_until_is_refused() {
        let mut o = Options::new("pipeline.toml", "bin");
        o.from = Stage::Fmm;
        o.until = Stage::Vmap;
        let e = run(&o, &mut |_| {}).unwrap_err().to_string();
        assert_eq!(
            e,
            "--from pc-fmm comes after --until pc-vmap: nothing to run"
        );
    }

    #[test]
    fn summary_names_every_stage() {
        let runs = vec![
            StageRun {
                stage: Stage::Octree,
                status: Status::UpToDate,
                seconds: 0.01,
                key: String::new(),
                output: PathBuf::new(),
                peak_rss_bytes: 1_500_000_000,
                gpu: None,
            },
            StageRun {
                stage: Stage::Raytrace,
                status: Status::Ran,
                seconds: 1.5,
                key: String::new(),
                output: PathBuf::new(),
                peak_rss_bytes: 1_500_000_000,
                gpu: None,
            },
        ];
        assert_eq!(
            summary(&runs, 1.6),
            "1 ran, 1 up to date in 1.60 s: pc-octree up to date, pc-raytrace ran (1.50 s, 1.5 GB)"
        );
    }
}
