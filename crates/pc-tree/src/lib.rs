//! The queries every stage makes of an octree: the ray traversal and ray-splat intersection
//! ([`ray`]), subtree ranges and normal cones ([`nodes`]), cell boxes, normal fields, disk
//! samples, the batch visibility interface with its CPU and GPU casters ([`caster`]), the one
//! upload of the octree to the GPU ([`gpu::GpuOctree`]) and the specular bounce ([`optics`]).
//!
//! The renderer, the V-map, the photon tracer and the FMM's shadow rays all walk the same node
//! pool through this crate (shared code, not copies). The view itself, its structural checks
//! and point location (seed §8.5.11) are the octree reader's, in pc-artifact.

use glam::Vec3;
use pc_artifact::octree::{tangent_frame, Frame, NodeInfo, Splat};

pub mod accel;
pub mod between;
pub mod caster;
pub mod gpu;
pub mod nodes;
pub mod optics;
pub mod ray;
pub mod rng;
pub mod shaft;
pub use between::Between;

/// Whether this CPU has AVX2, for the loops built for it beside the baseline's and chosen at
/// run time (the walk's eight-lane disk tests here, pc-octree's area pass, pc-vmap's sample
/// indices): false off x86-64. The same results either way (Rust fuses no multiply-add).
#[inline]
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

pub use pc_artifact::octree::{locate_normalized, Located, OctreeView};
pub use ray::{
    covering, intersect, intersect_splat, occluded, occluded_between, Hit, Ray, TraversalStats,
};

/// Axis-aligned box of the cell at `depth` with integer coordinates `cell` in the root frame.
pub fn cell_box(frame: &Frame, depth: u32, cell: [u32; 3]) -> (Vec3, Vec3) {
    let size = frame.size / (1u64 << depth) as f32;
    let lo =
        Vec3::from(frame.origin) + Vec3::new(cell[0] as f32, cell[1] as f32, cell[2] as f32) * size;
    (lo, lo + Vec3::splat(size))
}

/// The normal of a leaf's linear normal field (§8.5.5) at `x`, unit length. See
/// docs/octree.md: n(x) = normalize(n̄ + ν ((x − c)·û) û + ω ((x − c)·v̂) v̂).
pub fn field_normal(info: &NodeInfo, x: Vec3) -> Vec3 {
    let n = Vec3::from(info.normal);
    let (u, v) = tangent_frame(info.normal);
    let (u, v) = (Vec3::from(u), Vec3::from(v));
    let d = x - Vec3::from(info.centroid);
    (n + u * (info.tilt[0] * d.dot(u)) + v * (info.tilt[1] * d.dot(v))).normalize_or(n)
}

/// A direction about the unit normal `n` with density `cos θ / π` (per steradian) for the
/// random numbers `u1`, `u2` ∈ [0, 1). WGSL twin: `cosine_dir` in shaders/common/optics.wgsl.
#[inline]
pub fn cosine_dir(n: [f32; 3], u1: f32, u2: f32) -> Vec3 {
    let (tu, tv) = tangent_frame(n);
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let z = (1.0 - u1).max(0.0).sqrt();
    (Vec3::from(tu) * (r * phi.cos()) + Vec3::from(tv) * (r * phi.sin()) + Vec3::from(n) * z)
        .normalize_or(Vec3::from(n))
}

/// A point uniform on splat `s`'s disk for the random numbers `u1`, `u2` ∈ [0, 1), folded into
/// its border clip (so it lands on the part of the disk the splat stands for).
#[inline]
pub fn disk_point(s: &Splat, u1: f32, u2: f32) -> Vec3 {
    let (tu, tv) = tangent_frame(s.normal);
    let r = u1.sqrt() * s.radius;
    let phi = std::f32::consts::TAU * u2;
    let y = Vec3::from(s.position) + (Vec3::from(tu) * phi.cos() + Vec3::from(tv) * phi.sin()) * r;
    Vec3::from(s.fold_into_clip(y.into()))
}
