//! pc-caustics: the caustic photon map of a point model (seed §8.1, §8.4, §8.5.2 to §8.5.7;
//! docs/caustics.md).
//!
//! 1. [`emit`]: the lights (point lights and emitting splats) aim photons only at the specular
//!    leaves they see (the V-map's light lists and links), as many per leaf as its share of the
//!    lights' power (solid angle), each carrying the lights' total power over the budget.
//! 2. [`trace`]: each photon is traced through the octree with the renderer's traversal and
//!    specular bounces (`pc_tree::optics`), and stored where it first lands on a diffuse splat
//!    after at least one specular bounce (LS⁺D).
//!    [`gpu`] is the same tracer as a WGSL kernel (`shaders/caustics/photons.wgsl`).
//! 3. [`stage`]: the photons and the power deposited per splat go into the `photons` artifact
//!    (the renderer builds its kd-tree over them).

pub mod emit;
pub mod error;
pub mod gpu;
pub mod links;
pub mod stage;
pub mod trace;
