//! pc-fmm: diffuse global illumination of point models by the Fast Multipole Method (seed §7.1,
//! §7.3, §8.1, §8.5.15; docs/fmm.md).
//!
//! Radiance of every diffuse splat, `L = E + ρ ∘ T L` with
//! `(T L)_i = Σ_j f_ij K(i, j) A_j L_j` over the pairs the V-map links, the point-to-point form
//! factor kernel `K = cos θ_i cos θ_j / (π r²)` and each link's visible fraction `f`. Each
//! product `T L` is an FMM over the octree with Cartesian Taylor expansions of the kernel's
//! tensor form ([`expansion`]), on an interaction plan refined from the V-map's links
//! ([`plan`]); [`cpu`] runs it with rayon and [`gpu`] with WGSL compute shaders.

pub mod cluster;
pub mod cpu;
pub mod emitter;
pub mod error;
pub mod expansion;
pub mod gather;
pub mod gpu;
pub mod gpu_wgsl;
pub mod gpu_work;
pub mod lanes;
pub(crate) mod par;
pub mod plan;
pub mod pool;
pub mod solve;
pub mod specular;
pub mod stage;
pub mod system;
pub mod tree;

pub use cpu::CpuFmm;
pub use error::FmmError;
pub use expansion::Basis;
pub use plan::{Plan, PlanParams};
pub use solve::{Operator, Solution};
pub use system::System;
pub use tree::{Points, Tree};

/// The CPU operator as a solver [`Operator`], with accumulated phase timings.
pub struct CpuOperator<'a> {
    pub fmm: CpuFmm<'a>,
    pub times: cpu::PhaseTimes,
    pub applications: u32,
}

impl Operator for CpuOperator<'_> {
    fn apply_relaxed(
        &mut self,
        radiance: &[[f32; 3]],
        out: &mut [[f32; 3]],
        relax: f64,
    ) -> Result<u32, FmmError> {
        let order = self.fmm.order_within(relax);
        self.fmm.apply_order(order, radiance, out, &mut self.times);
        self.applications += 1;
        Ok(order as u32)
    }
    fn order(&self) -> u32 {
        self.fmm.basis.order as u32
    }
    fn device(&self) -> String {
        format!("CPU ({} threads)", rayon::current_num_threads())
    }
}
