//! Scene samplers: analytic surfaces (rectangles, boxes, spheres) turned into jittered-grid splats, and the built-in scenes.
//!
//! Every surface is cut into a grid of near-square cells whose size is close to one global
//! target spacing `h`, chosen so that the whole scene gets (almost exactly) the requested number
//! of splats (`h ≈ sqrt(total_area / N)`). Each cell gets one splat at its center moved by a
//! uniform random offset of at most `jitter / 2` of a cell along each grid axis; its normal is
//! the exact analytic normal and its radius is the cell size times `radius_factor`, so with the
//! defaults (jitter 0.2, factor 1.0) neighbouring disks overlap and the disks cover the surface.
//!
//! Spheres use a cube-sphere (equal-angle) mapping: six faces of `k × k` cells each, the radius
//! of each splat taken from its own cell's corner spacing.
//!
//! Sampling is deterministic for a given seed: every grid row draws from its own PCG stream
//! derived from (seed, shape name, patch, row), so the result does not depend on the rayon
//! schedule. Shapes, patches and rows are generated in parallel.

mod geometry;
mod grid;
pub mod scan;
mod scenes;
mod write;

pub use geometry::{BoxShape, Geometry, Rect, Sphere};
pub use grid::{
    choose_spacing, plan_grids, sample_shape, sample_shapes, GridPlan, SampledShape, ShapeSpec,
};
pub use scenes::{
    build_scene, cornell, cornell_specs, glass_box, glass_box_specs, sphere, SampledScene,
    SceneKind,
};
pub use write::{write_scene, write_scene_with_format};

use pc_artifact::params::{int, real, End, ParamError};

/// Sampling parameters shared by all scenes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleParams {
    /// Requested total number of splats in the scene.
    pub points: usize,
    pub seed: u64,
    /// Maximum jitter as a fraction of a cell (the offset along each grid axis is uniform in
    /// `[-jitter/2, jitter/2]` cells). In `[0, 1]`.
    pub jitter: f32,
    /// Splat radius divided by the cell size.
    pub radius_factor: f32,
}

impl Default for SampleParams {
    fn default() -> Self {
        SampleParams {
            points: 100_000,
            seed: 0,
            jitter: 0.2,
            radius_factor: 1.0,
        }
    }
}

impl SampleParams {
    /// Parameters for `points` splats, other fields at their defaults.
    pub fn with_points(points: usize) -> Self {
        SampleParams {
            points,
            ..Default::default()
        }
    }

    /// Checks the ranges (points in 1..=1e9, jitter in [0, 1], radius factor in (0, 100]).
    pub fn validate(&self) -> Result<(), ParamError> {
        int("points", self.points as u64, 1..=1_000_000_000)?;
        real("jitter", self.jitter, End::Incl(0.0), End::Incl(1.0))?;
        real(
            "radius factor",
            self.radius_factor,
            End::Excl(0.0),
            End::Incl(100.0),
        )
    }
}

#[cfg(test)]
mod tests;
