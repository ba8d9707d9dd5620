//! Integration tests of pc-import, one binary; each module tests one part of the crate.

mod estimate;
mod ply;
mod scan;
