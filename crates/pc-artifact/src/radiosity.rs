//! Schema of the `radiosity` artifact written by pc-fmm (docs/fmm.md, docs/artifacts.md).
//!
//! | section     | element     | what                                                        |
//! |-------------|-------------|-------------------------------------------------------------|
//! | `radiance`  | `[f32; 3]`  | per data-pool splat: outgoing diffuse radiance, linear RGB   |
//! | `source`    | `[f32; 3]`  | per splat: the solve's source term E (emission + direct)     |
//! | `residuals` | `f64`       | relative residual after each iteration                       |
//!
//! `radiance` holds emission plus every LD⁺ bounce and the LDD bounces fed by caustic energy,
//! but not the caustic energy's own first diffuse bounce: the renderer adds that from the
//! photon map (seed §8.1, §8.5.15). Specular splats hold zero.

use serde::{Deserialize, Serialize};

pub mod sections {
    pub const RADIANCE: &str = "radiance";
    pub const SOURCE: &str = "source";
    pub const RESIDUALS: &str = "residuals";
}

/// Parameters of the solve (part of the artifact key).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct FmmParams {
    /// Taylor expansion order p.
    pub order: u32,
    /// Expansion separation: (r_a + r_b) < theta · distance.
    pub theta: f32,
    /// Largest accepted cosine-clamp error of one interaction, as a form factor.
    pub clamp_tol: f32,
    /// The solve stops once the relative residual falls below this.
    pub tolerance: f32,
    pub max_iterations: u32,
    /// Samples per splat of the emitting splats' direct light.
    pub emitter_samples: u32,
    /// Of those, the probes that cast their shadow rays first; the rest cast only in leaves
    /// where the probes disagree (0, and in artifacts made before it existed: every sample).
    #[serde(default)]
    pub emitter_probes: u32,
    /// The iterative method (absent in artifacts made before it was a choice: Jacobi).
    #[serde(default = "Solver::jacobi")]
    pub solver: Solver,
    /// GMRES took later products at a lower order as the residual fell (absent in artifacts
    /// made before it existed: every product at `order`).
    #[serde(default)]
    pub relax: bool,
}

/// The iterative method of the radiosity solve (docs/fmm.md).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum Solver {
    /// Restarted GMRES, one Krylov process per channel in lockstep.
    #[default]
    Gmres,
    /// Jacobi iteration (the Neumann series), one bounce per iteration.
    Jacobi,
}

impl Solver {
    fn jacobi() -> Solver {
        Solver::Jacobi
    }
}

/// Metadata of a radiosity artifact.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RadiosityMeta {
    /// Keys of the octree and V-map artifacts the solve used.
    pub octree_key: String,
    pub vmap_key: String,
    /// Key of the caustics artifact whose energy fed the solve, if any.
    pub photons_key: Option<String>,
    pub params: FmmParams,
    pub iterations: u32,
    pub converged: bool,
    pub residuals: Vec<f64>,
    /// Expansion order of each iteration's product (empty in artifacts made before relaxed
    /// products: all at `params.order`).
    #[serde(default)]
    pub orders: Vec<u32>,
    /// Splats that take part (diffuse and emitting).
    pub active_splats: u64,
    pub m2l: u64,
    pub p2l: u64,
    pub m2p: u64,
    pub p2p: u64,
    pub p2p_pairs: u64,
    /// Emitter samples taken over all receivers, the shadow rays they cast, and the samples
    /// settled by shaft culling, without a walk through the octree (the probes' verdict
    /// settled the others).
    #[serde(default)]
    pub emitter_samples: u64,
    #[serde(default)]
    pub emitter_rays: u64,
    #[serde(default)]
    pub emitter_settled: u64,
    pub device: String,
    pub timings: Vec<(String, f64)>,
}
