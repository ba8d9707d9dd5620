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

/// The photon kd-tree: kiddo's immutable tree over `f32` positions, items are photon indices.
pub type PhotonTree = kiddo::ImmutableKdTree<f32, 3>;

/// A photon map ready for lookups: the fixed-radius estimate through the hashed grid the GPU
/// renderer reads too ([`PhotonGrid`]), the k-nearest one through a kd-tree.
pub struct Caustics<'a> {
    pub photons: &'a [Photon],
    /// Built on the first k-nearest lookup.
    tree: std::sync::OnceLock<PhotonTree>,
    grid: PhotonGrid,
    /// Density-estimate radius (scene units).
    pub radius: f32,
    /// k of the k-nearest estimate; 0 for the fixed radius.
    pub k: u32,
}

/// Whether photon `p` counts at `x` (normal `n`, radius `r`): it arrived from the front and lies
/// within a quarter radius of the tangent plane.
#[inline]
fn accept(p: &Photon, x: Vec3, n: Vec3, r: f32) -> bool {
    Vec3::from(p.dir).dot(n) < 0.0 && (Vec3::from(p.position) - x).dot(n).abs() <= 0.25 * r
}

impl<'a> Caustics<'a> {
    /// Lookups in `photons` (a checked map: at most `u32::MAX` of them, finite positions) with
    /// the density-estimate `radius` (positive) and k-nearest `k` (0: fixed radius). Builds the
    /// grid (0.06 s for 750k photons); the kd-tree of the k-nearest estimate waits for its
    /// first lookup (0.05 s).
    pub fn new(photons: &'a [Photon], radius: f32, k: u32) -> Caustics<'a> {
        Caustics {
            photons,
            tree: std::sync::OnceLock::new(),
            grid: PhotonGrid::new(photons, radius),
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
            return self.grid.irradiance(x, n);
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

/// The photon map as the GPU renderer reads it (`caustic` in shaders/raytrace/render.wgsl): a
/// spatial hash of cubic cells of side `2r`, the photons sorted by bucket. A query at `x` scans
/// the buckets of the 2×2×2 cells nearest `x` (they cover `x ± r` on every axis), each bucket
/// once even when two cells hash to it, and keeps the photons within `r`: the same photons as a
/// kd-tree's fixed-radius query. The CPU renderer uses it too ([`Caustics::irradiance`]): a
/// lookup took 454 ns against the kd-tree's 1,095 at the 1M bench scene's hits, most of which
/// lie far from every photon and find empty buckets.
#[derive(Clone, Debug)]
pub struct PhotonGrid {
    /// Corner of cell (0, 0, 0): the photons' lower bound.
    pub origin: [f32; 3],
    /// Cell side, `2r`.
    pub cell: f32,
    /// Buckets − 1 (a power of two minus one).
    pub mask: u32,
    /// Bucket `b` holds `photons[offsets[b]..offsets[b + 1]]`.
    pub offsets: Vec<u32>,
    /// The photons, sorted by bucket.
    pub photons: Vec<Photon>,
    /// Density-estimate radius.
    pub radius: f32,
}

/// Bucket of cell (i, j, k) (WGSL twin `grid_hash`).
#[inline]
pub fn grid_hash(c: [u32; 3], mask: u32) -> u32 {
    (c[0].wrapping_mul(73_856_093) ^ c[1].wrapping_mul(19_349_663) ^ c[2].wrapping_mul(83_492_791))
        & mask
}

impl PhotonGrid {
    /// Bucket the photons (a counting sort) for fixed-radius queries of radius `radius`.
    pub fn new(photons: &[Photon], radius: f32) -> PhotonGrid {
        let mut lo = Vec3::splat(f32::INFINITY);
        for p in photons {
            lo = lo.min(Vec3::from(p.position));
        }
        if photons.is_empty() {
            lo = Vec3::ZERO;
        }
        let cell = 2.0 * radius;
        let buckets = photons.len().max(1).next_power_of_two() as u32;
        let mask = buckets - 1;
        let bucket = |p: &Photon| {
            let q = ((Vec3::from(p.position) - lo) / cell)
                .floor()
                .max(Vec3::ZERO);
            grid_hash([q.x as u32, q.y as u32, q.z as u32], mask)
        };
        let mut offsets = vec![0u32; buckets as usize + 1];
        for p in photons {
            offsets[bucket(p) as usize + 1] += 1;
        }
        for b in 0..buckets as usize {
            offsets[b + 1] += offsets[b];
        }
        let mut next = offsets.clone();
        let mut sorted = vec![Photon::default(); photons.len()];
        for p in photons {
            let b = bucket(p) as usize;
            sorted[next[b] as usize] = *p;
            next[b] += 1;
        }
        PhotonGrid {
            origin: lo.into(),
            cell,
            mask,
            offsets,
            photons: sorted,
            radius,
        }
    }

    /// The buckets a query at `x` scans, each once (WGSL twin in `caustic`).
    pub fn buckets(&self, x: Vec3) -> ([u32; 8], usize) {
        let q = (x - Vec3::from(self.origin)) / self.cell;
        let c = q.floor();
        let f = q - c;
        let mut out = [0u32; 8];
        let mut n = 0;
        for i in 0..8u32 {
            let mut cc = [0i64; 3];
            for a in 0..3 {
                let step = if f[a] < 0.5 { -1 } else { 1 };
                cc[a] = c[a] as i64 + if (i >> a) & 1 == 1 { step } else { 0 };
            }
            if cc.iter().any(|&v| v < 0 || v > u32::MAX as i64) {
                continue;
            }
            let h = grid_hash([cc[0] as u32, cc[1] as u32, cc[2] as u32], self.mask);
            if !out[..n].contains(&h) {
                out[n] = h;
                n += 1;
            }
        }
        (out, n)
    }

    /// The fixed-radius estimate of [`Caustics::irradiance`] through the grid (CPU twin of the
    /// WGSL `caustic`).
    pub fn irradiance(&self, x: Vec3, n: Vec3) -> Vec3 {
        let r = self.radius;
        let (buckets, count) = self.buckets(x);
        let mut e = Vec3::ZERO;
        for &b in &buckets[..count] {
            let (lo, hi) = (self.offsets[b as usize], self.offsets[b as usize + 1]);
            for p in &self.photons[lo as usize..hi as usize] {
                let d2 = (Vec3::from(p.position) - x).length_squared();
                if d2 <= r * r && accept(p, x, n, r) {
                    e += Vec3::from(p.power) * (1.0 - d2 / (r * r)).max(0.0);
                }
            }
        }
        e * (2.0 / (std::f32::consts::PI * r * r))
    }
}
