//! pc-vmap: view-independent visibility between octree nodes (seed §7.2, §7.3) and the nodes
//! each point light sees (§8.5.3). See docs/vmap.md.

pub mod build;
pub mod close;
pub mod error;
pub mod smear;
pub mod stage;
