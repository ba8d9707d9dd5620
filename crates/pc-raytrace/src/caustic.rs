//! The caustic term of a diffuse hit (seed §8.5.8): a density estimate over the photon map of
//! pc-caustics, through a hashed grid of the photons (fixed radius, the GPU renderer's too) or a
//! kd-tree over their positions (k-nearest), both built when the map is opened (the artifact
//! stores neither, docs/caustics.md).
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
use pc_artifact::photons::Photon;

pub use crate::photon_grid::PhotonGrid;
use crate::photon_lanes::PhotonLanes;

/// The photon kd-tree: kiddo's immutable tree over `f32` positions, items are photon indices.
pub type PhotonTree = kiddo::ImmutableKdTree<f32, 3>;

/// A photon map ready for lookups: the fixed-radius estimate through the hashed grid the GPU
/// renderer reads too ([`PhotonGrid`]), the k-nearest one through a kd-tree.
pub struct Caustics<'a> {
    pub photons: &'a [Photon],
    /// Built on the first k-nearest lookup.
    tree: std::sync::OnceLock<PhotonTree>,
    grid: PhotonGrid,
    /// The grid's photons four to a record, for the CPU's scan.
    lanes: PhotonLanes,
    /// Density-estimate radius (scene units).
    pub radius: f32,
    /// k of the k-nearest estimate; 0 for the fixed radius.
    pub k: u32,
}

/// Whether photon `p` counts at `x` (normal `n`, radius `r`): it arrived from the front and lies
/// within a quarter radius of the tangent plane.
#[inline]
pub(crate) fn accept(p: &Photon, x: Vec3, n: Vec3, r: f32) -> bool {
    accept_at(p, Vec3::from(p.position) - x, n, r)
}

/// [`accept`] with the photon's offset `d` from the lookup's point; both tests evaluated, so
/// that a scan decides without a branch.
#[inline]
pub(crate) fn accept_at(p: &Photon, d: Vec3, n: Vec3, r: f32) -> bool {
    (Vec3::from(p.dir).dot(n) < 0.0) & (d.dot(n).abs() <= 0.25 * r)
}

impl<'a> Caustics<'a> {
    /// Lookups in `photons` (a checked map: at most `u32::MAX` of them, finite positions) with
    /// the density-estimate `radius` (positive) and k-nearest `k` (0: fixed radius). Builds the
    /// grid (0.06 s for 750k photons); the kd-tree of the k-nearest estimate waits for its
    /// first lookup (0.05 s).
    pub fn new(photons: &'a [Photon], radius: f32, k: u32) -> Caustics<'a> {
        let grid = PhotonGrid::new(photons, radius);
        Caustics {
            photons,
            tree: std::sync::OnceLock::new(),
            lanes: PhotonLanes::new(&grid),
            grid,
            radius,
            k,
        }
    }

    /// The kd-tree over the photons' positions (item: index into `photons`).
    pub fn tree(&self) -> &PhotonTree {
        self.tree.get_or_init(|| {
            let positions: Vec<[f32; 3]> = self.photons.iter().map(|p| p.position).collect();
            PhotonTree::new_from_slice(&positions)
                .expect("a photon map holds at most u32::MAX photons (PhotonsFile checks it)")
        })
    }

    /// Caustic irradiance (W/m², RGB) at `x` on a surface with unit normal `n` (its front).
    pub fn irradiance(&self, x: Vec3, n: Vec3) -> Vec3 {
        let Some(k) = NonZeroUsize::new(self.k as usize) else {
            return self.lanes.irradiance(&self.grid, x, n);
        };
        let r = self.radius;
        let q: [f32; 3] = x.into();
        let found = self
            .tree()
            .query(&q)
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .within(r * r)
            .execute();
        let mut e = Vec3::ZERO;
        for it in &found {
            let p = &self.photons[it.item as usize];
            if accept(p, x, n, r) {
                e += Vec3::from(p.power);
            }
        }
        // The k-th neighbour's distance when k were found; fewer than k within `r` means the
        // photons are sparser than k per disk of radius `r`, and `r` is the radius. (The
        // farthest of a few found made one photon beside a point a bright spot: on
        // cornell-mirror-glass, k 100 lit the floor 4 % and a ceiling region 12 % too bright.)
        let r2 = if found.len() == k.get() {
            found.iter().map(|f| f.distance).fold(0.0, f32::max)
        } else {
            r * r
        };
        if r2 <= 0.0 {
            return Vec3::ZERO;
        }
        e / (std::f32::consts::PI * r2)
    }
}
