//! Integration tests of pc-scene, one binary; each module tests one part of the crate.

mod estimate;
mod ply;
