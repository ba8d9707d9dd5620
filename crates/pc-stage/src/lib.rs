//! What every stage binary shares around its algorithm, written once: the command line
//! ([`StageArgs`]), the life of a run ([`Stage`], [`main`]: config, output lock, up-to-date
//! gate, progress, summary, report, exit code), the device choice with its fallback
//! ([`device`]) and the progress interface the stage libraries report to ([`Progress`]).
//!
//! Like a binary, this crate reports errors with anyhow; the stage libraries return their own
//! typed errors, which [`main`] prints with their chain.

pub mod args;
pub mod device;
pub mod input;
pub mod lock;
pub mod oom;
pub mod progress;
pub mod stage;
pub mod threads;

pub use args::StageArgs;
pub use device::{gpu_for, gpu_or_cpu, look_early, Work};
pub use input::OptionalInput;
pub use progress::{Progress, Silent};
pub use stage::{artifact_key, exit, main, peak_rss_bytes, say, with_gpu_times, Stage};
