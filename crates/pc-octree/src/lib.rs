//! pc-octree: the adaptive, Morton-ordered octree over the splats and its GPU layout.
//!
//! Seed §8.5.1 (split while a node holds more than k splats or mixes diffuse and specular
//! ones), §8.5.5 (per-leaf average disk and normal field), §8.5.10-§8.5.12 (node pool of 32-bit
//! nodes with 8 contiguous children in SFC order, begin/end table, data pool), §8.5.13 (splats
//! referenced by every leaf they overlap). The binary `pc-octree` is a thin wrapper around
//! [`stage::OctreeStage`]. See docs/octree.md.

pub mod area;
pub mod build;
pub mod error;
pub mod gpu;
pub mod morton;
pub mod refs;
pub mod stage;
pub mod stats;

pub use build::{build, build_from, BuildError, BuildInput, Octree};
pub use pc_artifact::octree::OctreeStats;
pub use pc_artifact::params::OctreeParams;
pub use pc_tree::field_normal;
