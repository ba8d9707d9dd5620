//! The caustic term of a diffuse hit (seed §8.5.8): a density estimate over the photon map of
//! pc-caustics, queried in place in the memory-mapped artifact's kd-tree.
//!
//! Fixed radius (default): the irradiance at `x` is `E = Σ Φ_p w(d_p)` over the photons within
//! `r`, with the 2-D Epanechnikov kernel `w(d) = 2 (1 − d²/r²) / (π r²)` (it integrates to 1
//! over the disk of radius `r`, so a uniform photon density gives the same irradiance as a
//! box kernel, with less noise at the caustic's edges). k-nearest (`caustic_k` > 0): the k
//! nearest photons within `r`, the distance `r_k` of the farthest as the radius, and
//! `E = Σ Φ_p / (π r_k²)`. Photons that arrived from behind the surface, or lie off its
//! tangent plane by more than a quarter radius (a photon on the other side of a thin wall, or
//! on a neighbouring surface at a crease), do not count. The reflected radiance is
//! `ρ E / π`.

use std::num::NonZeroUsize;

use glam::Vec3;
use kiddo::SquaredEuclidean;
use pc_artifact::photons::{ArchivedPhotonTree, Photon};

/// A photon map ready for lookups.
pub struct Caustics<'a> {
    pub photons: &'a [Photon],
    pub tree: &'a ArchivedPhotonTree,
    /// Density-estimate radius (scene units).
    pub radius: f32,
    /// k of the k-nearest estimate; 0 for the fixed radius.
    pub k: u32,
}

impl Caustics<'_> {
    /// Caustic irradiance (W/m², RGB) at `x` on a surface with unit normal `n` (its front).
    pub fn irradiance(&self, x: Vec3, n: Vec3) -> Vec3 {
        let r = self.radius;
        let q: [f32; 3] = x.into();
        let accept = |p: &Photon| {
            Vec3::from(p.dir).dot(n) < 0.0 && (Vec3::from(p.position) - x).dot(n).abs() <= 0.25 * r
        };
        if let Some(k) = NonZeroUsize::new(self.k as usize) {
            let found = self
                .tree
                .query(&q)
                .nearest_n::<SquaredEuclidean<f32>>(k)
                .within(r * r)
                .execute();
            let mut e = Vec3::ZERO;
            let mut r2 = 0.0f32;
            for it in &found {
                let p = &self.photons[it.item as usize];
                if accept(p) {
                    e += Vec3::from(p.power);
                    r2 = r2.max(it.distance);
                }
            }
            if r2 <= 0.0 {
                return Vec3::ZERO;
            }
            return e / (std::f32::consts::PI * r2);
        }
        let found = self
            .tree
            .query(&q)
            .within::<SquaredEuclidean<f32>>(r * r)
            .execute();
        let mut e = Vec3::ZERO;
        for it in &found {
            let p = &self.photons[it.item as usize];
            if accept(p) {
                e += Vec3::from(p.power) * (1.0 - it.distance / (r * r)).max(0.0);
            }
        }
        e * (2.0 / (std::f32::consts::PI * r * r))
    }
}
