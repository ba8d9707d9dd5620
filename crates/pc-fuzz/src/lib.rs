//! Fuzzing pcgi's readers: every input a user or a killed run can hand pcgi (PLY models,
//! pipeline.toml, every artifact kind) must give a result or a clear error, never a panic, a
//! hang or undefined behaviour, and whatever a reader accepts must be safe for the stages to
//! use as they use it.
//!
//! [`targets`] holds one function per input kind; each panics only when pcgi misbehaves. The
//! same functions run two ways:
//!
//! * in `cargo test` (`tests/fuzz.rs`): [`mutate::Mutator`] derives a bounded number of inputs
//!   from the [`seeds`] with a fixed seed, so CI runs the same cases every time;
//!   `PC_FUZZ_CASES=N` runs more (docs/artifacts.md, "Fuzzing");
//! * under libFuzzer (`fuzz/`, `cargo fuzz run <target>`), coverage-guided, for as long as one
//!   wants.
//!
//! Artifacts are fuzzed twice: as raw bytes (what a corrupted file looks like: the container
//! must refuse it, mostly by its checksums) and by patching the sections of a valid artifact
//! and writing it again with valid checksums (what a writer bug or a malicious file looks
//! like: the kind's reader must then refuse it or hand out a view the stages can use).

pub mod mutate;
pub mod seeds;
pub mod targets;
