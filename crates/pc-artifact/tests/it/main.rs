//! Integration tests of the artifact container: round trips, the atomic writer, keys, and corrupt files.

mod common;
mod corrupt;
mod input_key;
mod key;
mod roundtrip;
mod writer;
