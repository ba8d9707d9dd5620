//! The life of a stage binary, written once: load the config, make the stage, take the output
//! folder's lock, print the key or skip when up to date, run with progress, print one summary
//! line, write the report; any error is `NAME: error: <chain>` on stderr and exit code 2.

use std::io::Write;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use pc_artifact::{ArtifactKind, Key};
use pc_config::LoadedConfig;

use crate::lock::OutputLock;
use crate::progress::{Bar, Progress};
use crate::StageArgs;

/// A stage as its binary runs it. The stage library implements it; the binary's `main` parses
/// its arguments and calls [`main`] with them.
pub trait Stage {
    /// The binary's name ("pc-vmap"): the first word of every line it prints.
    const NAME: &'static str;
    /// What a run does, for the context of an error ("computing the V-map").
    const DOING: &'static str;
    /// The kind of artifact a run writes; `None` for other outputs (the render's images), whose
    /// stage says how to read the key of the output there ([`Stage::existing_key`]).
    const KIND: Option<ArtifactKind>;
    /// What a run returns for its summary (counts, timings).
    type Made;
    type Error: std::error::Error + Send + Sync + 'static;

    /// The file a run writes (its artifact, or its EXR).
    fn output(&self) -> &Path;
    /// Every file a run publishes (the render writes a PNG beside its EXR): the temporary
    /// files a killed run left of each are removed before the next run.
    fn outputs(&self) -> Vec<std::path::PathBuf> {
        vec![self.output().to_path_buf()]
    }
    /// The key of what a run would make now, from its inputs and parameters; computes nothing
    /// else. The same function stamps the output, so this is what decides "up to date".
    fn key(&self) -> Result<Key, Self::Error>;
    /// The key of the output already there, `None` when it is missing or damaged.
    fn existing_key(&self) -> Option<Key> {
        Self::KIND.and_then(|kind| artifact_key(self.output(), kind))
    }
    /// Do the work and publish the output.
    fn run(&self, progress: &dyn Progress) -> Result<Self::Made, Self::Error>;
    /// The line printed after a run: what was written, with the figures that matter.
    fn summary(&self, made: &Self::Made, seconds: f64) -> String;
    /// The run's counts and timings for `--stats-json`.
    fn stats(&self, made: &Self::Made, seconds: f64) -> serde_json::Value {
        let _ = made;
        serde_json::json!({ "stage": Self::NAME, "total_seconds": seconds })
    }
}

/// The key of the artifact at `path` when it opens as a valid artifact of `kind`, else `None`
/// ([`Stage::existing_key`] of the artifact stages).
pub fn artifact_key(path: &Path, kind: ArtifactKind) -> Option<Key> {
    pc_artifact::Artifact::open_kind(path, kind)
        .ok()
        .map(|a| a.key())
}

/// Prints a line on stdout. A closed or full stdout (`| head`, `> /dev/full`) does not fail the
/// run: the output is already published by then.
pub fn say(line: &str) {
    let mut out = std::io::stdout().lock();
    if let Err(e) = writeln!(out, "{line}").and_then(|()| out.flush()) {
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            eprintln!("warning: cannot print to stdout: {e}");
        }
    }
}

/// Runs a stage binary: `make` builds the stage from the loaded config. Returns the process's
/// exit code (2 on any error, after printing `NAME: error: <chain>`).
pub fn main<S: Stage>(
    args: &StageArgs,
    make: impl FnOnce(LoadedConfig) -> anyhow::Result<S>,
) -> ExitCode {
    exit(
        S::NAME,
        crate::threads::start().and_then(|_| run(args, make)),
    )
}

/// `result` as an exit code: on error print `name: error: <chain>` on stderr and return 2.
/// First waits for a look for a GPU still running on its own thread ([`crate::look_early`]).
pub fn exit(name: &str, result: anyhow::Result<()>) -> ExitCode {
    pc_gpu::GpuContext::done_looking();
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{name}: error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run<S: Stage>(
    args: &StageArgs,
    make: impl FnOnce(LoadedConfig) -> anyhow::Result<S>,
) -> anyhow::Result<()> {
    let config = args.config.display().to_string();
    let context = || format!("{} for {config}", S::DOING);
    let stage = make(args.load()?).with_context(context)?;
    let out = stage.output().to_path_buf();
    if args.print_key {
        say(&stage.key().with_context(context)?.to_string());
        return Ok(());
    }
    let _lock = OutputLock::acquire(&out, |locked| {
        eprintln!(
            "{}: waiting for another pcgi run that holds the lock on {}",
            S::NAME,
            locked.display()
        )
    })
    .with_context(|| format!("{}: cannot lock the output folder", out.display()))?;
    for file in stage.outputs() {
        pc_artifact::atomic::remove_stale_temps(&file)
            .with_context(|| format!("{}: cannot remove old temporary files", file.display()))?;
    }
    let key = stage.key().with_context(context)?;
    let started = Instant::now();
    if args.if_stale && stage.existing_key() == Some(key) {
        say(&format!(
            "{}: {} is up to date (key {key})",
            S::NAME,
            out.display()
        ));
        return report(args, S::NAME, "up to date", &out, &key, 0.0);
    }
    let bar = Bar::new(S::NAME, args.quiet);
    let made = stage.run(&bar).with_context(context);
    bar.finish();
    let made = made?;
    let seconds = started.elapsed().as_secs_f64();
    let gpu = pc_gpu::times();
    say(&with_gpu_times(stage.summary(&made, seconds)));
    if let Some(path) = &args.stats_json {
        let mut stats = stage.stats(&made, seconds);
        if let (Some(t), Some(map)) = (gpu, stats.as_object_mut()) {
            map.insert("gpu".into(), t.json());
        }
        let json = format!("{stats}\n");
        pc_artifact::write_file_atomically(path, json.as_bytes())
            .with_context(|| format!("{}: cannot write the stats", path.display()))?;
    }
    report(args, S::NAME, "ran", &out, &key, seconds)
}

/// A summary line with where the GPU's time went appended, when this process used one:
/// `... [GPU: 3 kernels built in 0.41 s, ...]` (one line still).
pub fn with_gpu_times(summary: String) -> String {
    match pc_gpu::times() {
        Some(t) => format!("{summary} [{t}]"),
        None => summary,
    }
}

/// Peak resident memory of this process so far (Linux: `VmHWM` in /proc/self/status; `None`
/// where that is not available).
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Writes the `--report` JSON, if asked for: stage, status, output, key, seconds, and the
/// process's peak resident memory.
fn report(
    args: &StageArgs,
    stage: &str,
    status: &str,
    output: &Path,
    key: &Key,
    seconds: f64,
) -> anyhow::Result<()> {
    let Some(path) = &args.report else {
        return Ok(());
    };
    let json = serde_json::json!({
        "stage": stage,
        "status": status,
        "output": output.display().to_string(),
        "key": key.to_string(),
        "seconds": seconds,
        "peak_rss_bytes": peak_rss_bytes().unwrap_or(0),
        "gpu": pc_gpu::times().map(|t| t.json()),
    });
    pc_artifact::write_file_atomically(path, format!("{json}\n").as_bytes())
        .with_context(|| format!("{}: cannot write the report", path.display()))
}
