//! The caustic term of a diffuse hit (seed §8.5.8): a density estimate over the photon map of
//! pc-caustics, through a kd-tree built over the mapped photons' positions when the map is
//! opened (the artifact stores none, docs/caustics.md).
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

/// A photon map ready for lookups.
pub struct Caustics<'a> {
    pub photons: &'a [Photon],
    tree: PhotonTree,
    /// Density-estimate radius (scene units).
    pub radius: f32,
    /// k of the k-nearest estimate; 0 for the fixed radius.
    pub k: u32,
    /// Which cells hold a photon ([`Occupied`]): most shaded hits lie far from every photon
    /// and skip the tree.
    occupied: Occupied,
}

/// A conservative set of the cubic cells (side a little over `2r`) that hold a photon, as bits
/// of a hash of the cell: a query at `x` looks only where one of the at most 2×2×2 cells
/// reaching `x ± r` (padded past the rounding of the tree's distances) has its bit. Collisions
/// only cost a lookup; no photon within `r` is ever skipped.
struct Occupied {
    /// Cell side; 0 where the radius is not a positive finite number (no filter).
    side: f32,
    bits: Vec<u64>,
}

impl Occupied {
    const BITS: u64 = 1 << 20;

    fn new(photons: &[Photon], radius: f32) -> Occupied {
        let side = if radius.is_finite() && radius > 0.0 {
            2.01 * radius
        } else {
            0.0
        };
        let mut o = Occupied {
            side,
            bits: vec![0; (Self::BITS / 64) as usize],
        };
        if side > 0.0 {
            for p in photons {
                let c = Vec3::from(p.position) / side;
                let b = Self::bit([c.x, c.y, c.z].map(|v| v.floor() as i64));
                o.bits[(b / 64) as usize] |= 1 << (b % 64);
            }
        }
        o
    }

    fn bit(c: [i64; 3]) -> u64 {
        let h = (c[0] as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
            ^ (c[1] as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
            ^ (c[2] as u64).wrapping_mul(0x1656_67b1_9e37_79f9);
        (h ^ (h >> 29)) % Self::BITS
    }

    /// Whether a photon may lie within `r` of `x`.
    fn maybe(&self, x: Vec3, r: f32) -> bool {
        if self.side <= 0.0 {
            return true;
        }
        let (lo, hi) = ((x - 1.001 * r) / self.side, (x + 1.001 * r) / self.side);
        let (lo, hi) = (lo.floor().to_array(), hi.floor().to_array());
        let within = |k: usize| (hi[k] - lo[k]).partial_cmp(&1.0).is_some_and(|o| o.is_le());
        if !(0..3).all(within) {
            return true; // rounding far from the origin, or not finite: ask the tree
        }
        let range = |k: usize| lo[k] as i64..=hi[k] as i64;
        range(0).any(|i| {
            range(1).any(|j| {
                range(2).any(|k| {
                    let b = Self::bit([i, j, k]);
                    self.bits[(b / 64) as usize] & (1 << (b % 64)) != 0
                })
            })
        })
    }
}

/// Whether photon `p` counts at `x` (normal `n`, radius `r`): it arrived from the front and lies
/// within a quarter radius of the tangent plane.
#[inline]
fn accept(p: &Photon, x: Vec3, n: Vec3, r: f32) -> bool {
    Vec3::from(p.dir).dot(n) < 0.0 && (Vec3::from(p.position) - x).dot(n).abs() <= 0.25 * r
}

impl<'a> Caustics<'a> {
    /// Lookups in `photons` (a checked map: at most `u32::MAX` of them, finite positions) with
    /// the density-estimate `radius` and k-nearest `k` (0: fixed radius). Builds the kd-tree:
    /// 50 ms for 750k photons on two cores.
    pub fn new(photons: &'a [Photon], radius: f32, k: u32) -> Caustics<'a> {
        let positions: Vec<[f32; 3]> = photons.iter().map(|p| p.position).collect();
        let tree = PhotonTree::new_from_slice(&positions)
            .expect("a photon map holds at most u32::MAX photons (PhotonsFile checks it)");
        Caustics {
            photons,
            tree,
            radius,
            k,
            occupied: Occupied::new(photons, radius),
        }
    }

    /// The kd-tree over the photons' positions (item: index into `photons`).
    pub fn tree(&self) -> &PhotonTree {
        &self.tree
    }

    /// Caustic irradiance (W/m², RGB) at `x` on a surface with unit normal `n` (its front).
    pub fn irradiance(&self, x: Vec3, n: Vec3) -> Vec3 {
        let r = self.radius;
        if !self.occupied.maybe(x, r) {
            return Vec3::ZERO;
        }
        let q: [f32; 3] = x.into();
        let accept = |p: &Photon| accept(p, x, n, r);
        if let Some(k) = NonZeroUsize::new(self.k as usize) {
            let found = self
                .tree
                .query(&q)
                .nearest_n::<SquaredEuclidean<f32>>(k)
                .within(r * r)
                .execute();
            let mut e = Vec3::ZERO;
            for it in &found {
                let p = &self.photons[it.item as usize];
                if accept(p) {
                    e += Vec3::from(p.power);
                }
            }
            // The k-th neighbour's distance when k were found; fewer than k within `r` means
            // the photons are sparser than k per disk of radius `r`, and `r` is the radius. (The
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
            return e / (std::f32::consts::PI * r2);
        }
        // Visited in traversal order, without collecting a result vector.
        let mut e = Vec3::ZERO;
        self.tree
            .query(&q)
            .within::<SquaredEuclidean<f32>>(r * r)
            .unsorted()
            .visit(|it| {
                let p = &self.photons[it.item as usize];
                if accept(p) {
                    e += Vec3::from(p.power) * (1.0 - it.distance / (r * r)).max(0.0);
                }
            });
        e * (2.0 / (std::f32::consts::PI * r * r))
    }
}

/// The photon map as the GPU renderer reads it (`caustic` in shaders/raytrace/render.wgsl): a
/// spatial hash of cubic cells of side `2r`, the photons sorted by bucket. A query at `x` scans
/// the buckets of the 2×2×2 cells nearest `x` (they cover `x ± r` on every axis), each bucket
/// once even when two cells hash to it, and keeps the photons within `r`: the same photons as the
/// kd-tree's fixed-radius query, so [`PhotonGrid::irradiance`] equals
/// [`Caustics::irradiance`] up to the order of the sum. The kd-tree stays the artifact's index
/// (queried in place on the CPU, k-nearest included); the grid is built at load time in O(n)
/// because walking kiddo's archived layout in WGSL would tie the shader to kiddo's internals.
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
