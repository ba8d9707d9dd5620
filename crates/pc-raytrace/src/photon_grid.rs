//! The photon map as both renderers read it for the fixed-radius caustic estimate (`caustic` in
//! shaders/raytrace/render.wgsl is the GPU's twin of [`PhotonGrid::irradiance`]): a spatial hash
//! of cubic cells of side `2r`. A query at `x` scans the buckets of the 2×2×2 cells nearest `x`
//! (they cover `x ± r` on every axis), each bucket once even when two cells hash to it, and
//! keeps the photons within `r`: the same photons as a kd-tree's fixed-radius query. A lookup
//! took 454 ns against the kd-tree's 1,095 at the 1M bench scene's hits, most of which lie far
//! from every photon and find empty buckets.
//!
//! **Dense buckets hold groups.** Where a lens focuses light, a bucket holds thousands of
//! photons, and a lookup there scanned them all: on an NVIDIA H200 the one GPU thread of a pixel
//! in the glass sphere's focus held each 1 spp frame's dispatch for 8 ms, whatever the image's
//! size (docs/gpu.md). A bucket of more than [`DENSE_BUCKET`] photons is therefore kept as
//! groups: the photons of one splat, one cube of side [`MERGE_CELL`] radii and one octant of
//! directions. A group carries its photons' mean position `q`, how far they lie from it and
//! from their mean direction, and per colour channel the power moments `Σ Φᵢ`,
//! `Σ Φᵢ (pᵢ − q)` and `Σ Φᵢ |pᵢ − q|²`. Where a lookup finds every photon of a group inside
//! the radius, in front of the surface and near its tangent plane (the bounds decide it), the
//! group's share is exact in one step, because the kernel is a quadratic in the photon's
//! position: with `d = q − x`, per channel,
//!
//! `Σ Φᵢ (1 − |pᵢ − x|²/r²) = Σ Φᵢ − (Σ Φᵢ |pᵢ − q|² + 2 d · Σ Φᵢ (pᵢ − q) + |d|² Σ Φᵢ) / r²`.
//!
//! (Moments per channel: photons of different colours in one group, from coloured lights or
//! walls, keep the identity exact. One centroid weighted by total power would not.)
//!
//! Where the bounds leave it open, the lookup scans the group's photons one by one. The
//! estimate is the photon-by-photon one up to rounding; a lookup in a focus scans the groups
//! and the photons of the groups the radius's edge cuts.

use glam::{DVec3, Vec3};
use pc_artifact::photons::Photon;

use crate::caustic::accept_at;

/// Photons a bucket holds before it is kept as groups ([`PhotonGrid`]).
pub const DENSE_BUCKET: usize = 256;

/// Side of a group's cube, in radii. Smaller cubes mean more groups to read; larger ones mean
/// more photons in the groups the radius's edge cuts, which are scanned. A surface crossing a
/// bucket's cell (side `2r`) holds about 64 cubes of side `r / 4`. At the 1M bench scene's photon
/// positions the most a lookup read was 9,591 with cubes of r/16, 5,774 with r/8, **4,161 with
/// r/4**, 4,382 with 0.35 r and 5,071 with r/2, against 14,162 without groups.
pub const MERGE_CELL: f32 = 0.25;

/// A dense bucket's group of photons (WGSL twin `PhotonGroup`): where they lie and point, and
/// each colour channel's power moments about `position`, from which a lookup that the bounds
/// show takes every photon gets their kernel-weighted sum in one step ([`PhotonGroup::sum`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PhotonGroup {
    /// The photons' mean position: the moments' origin and the bounds' centre.
    pub position: [f32; 3],
    /// The farthest photon's distance from `position`.
    pub extent: f32,
    /// Their power-weighted mean direction of travel, normalised.
    pub dir: [f32; 3],
    /// The largest `|dᵢ − dir|` of the photons' directions.
    pub dir_extent: f32,
    /// Their summed power (W, linear RGB): `Σ Φᵢ`.
    pub power: [f32; 3],
    /// The photons: `PhotonGrid::photons[start..start + count]`.
    pub start: u32,
    /// Per channel, `Σ Φᵢ |pᵢ − position|²`.
    pub second: [f32; 3],
    pub count: u32,
    /// Per channel (red, green, blue), `Σ Φᵢ (pᵢ − position)`; the fourth word is padding.
    pub first: [[f32; 4]; 3],
}

/// The grid: sparse buckets' photons, dense buckets' groups.
#[derive(Clone, Debug)]
pub struct PhotonGrid {
    /// Corner of cell (0, 0, 0): the photons' lower bound.
    pub origin: [f32; 3],
    /// Cell side, `2r`.
    pub cell: f32,
    /// Buckets − 1 (a power of two minus one).
    pub mask: u32,
    /// Bucket `b` holds `photons[offsets[b]..offsets[b + 1]]` and
    /// `groups[offsets[n + b]..offsets[n + b + 1]]`, with `n = mask + 2` (one of the two is
    /// empty). One array, as the GPU reads it.
    pub offsets: Vec<u32>,
    /// The sparse buckets' photons in bucket order, then the groups' photons in group order.
    pub photons: Vec<Photon>,
    pub groups: Vec<PhotonGroup>,
    /// Density-estimate radius.
    pub radius: f32,
}

/// The hash's factor per axis ([`grid_hash`]).
const HASH: [u32; 3] = [73_856_093, 19_349_663, 83_492_791];

/// Bucket of cell (i, j, k) (WGSL twin `grid_hash`).
#[inline]
pub fn grid_hash(c: [u32; 3], mask: u32) -> u32 {
    (c[0].wrapping_mul(HASH[0]) ^ c[1].wrapping_mul(HASH[1]) ^ c[2].wrapping_mul(HASH[2])) & mask
}

impl PhotonGrid {
    /// Bucket the photons (a counting sort) for fixed-radius queries of radius `radius`; dense
    /// buckets become groups.
    pub fn new(photons: &[Photon], radius: f32) -> PhotonGrid {
        let mut lo = Vec3::splat(f32::INFINITY);
        for p in photons {
            lo = lo.min(Vec3::from(p.position));
        }
        if photons.is_empty() {
            lo = Vec3::ZERO;
        }
        let cell = 2.0 * radius;
        let buckets = photons.len().max(1).next_power_of_two();
        let mask = buckets as u32 - 1;
        let sorted = bucket_sort(photons, |p| {
            let q = ((Vec3::from(p.position) - lo) / cell)
                .floor()
                .max(Vec3::ZERO);
            grid_hash([q.x as u32, q.y as u32, q.z as u32], mask)
        });
        let mut grouping = Grouping::new(lo, MERGE_CELL * radius);
        let mut sparse = Vec::with_capacity(photons.len());
        let (mut photon_ends, mut group_ends) = (vec![0], vec![0]);
        for here in sorted.buckets(buckets) {
            match here.len() > DENSE_BUCKET {
                true => grouping.add(here),
                false => sparse.extend_from_slice(here),
            }
            photon_ends.push(sparse.len() as u32);
            group_ends.push(grouping.groups.len() as u32);
        }
        let (mut groups, members) = (grouping.groups, grouping.members);
        for g in &mut groups {
            g.start += sparse.len() as u32;
        }
        sparse.extend(members);
        photon_ends.extend(group_ends);
        PhotonGrid {
            origin: lo.into(),
            cell,
            mask,
            offsets: photon_ends,
            photons: sparse,
            groups,
            radius,
        }
    }

    /// The buckets a query at `x` scans, each once (WGSL twin in `caustic`): those of the cells
    /// `c` and `c + step` along each axis, `c` the cell of `x` and `step` towards the nearer
    /// neighbour, in the order of the bits of `i` in `0..8` (bit `a` set: axis `a` steps); cells
    /// outside `0..=u32::MAX` hold nothing and are left out.
    #[inline]
    pub fn buckets(&self, x: Vec3) -> ([u32; 8], usize) {
        let q = (x - Vec3::from(self.origin)) / self.cell;
        // Each axis's two cells' terms of the hash, or `None` where the cell does not exist.
        let terms: [[Option<u32>; 2]; 3] = std::array::from_fn(|a| {
            let c = floor(q[a]);
            let step = if q[a] - c < 0.5 { -1 } else { 1 };
            let c = c as i64; // saturating, as the cell index of a huge `q` was
            [c, c + step].map(|v| {
                (0..=u32::MAX as i64)
                    .contains(&v)
                    .then(|| (v as u32).wrapping_mul(HASH[a]))
            })
        });
        let mut out = [0u32; 8];
        let mut n = 0;
        for i in 0..8usize {
            let pick = |a: usize| terms[a][(i >> a) & 1];
            let (Some(hx), Some(hy), Some(hz)) = (pick(0), pick(1), pick(2)) else {
                continue;
            };
            let h = (hx ^ hy ^ hz) & self.mask;
            if !out[..n].contains(&h) {
                out[n] = h;
                n += 1;
            }
        }
        (out, n)
    }

    /// The fixed-radius estimate of [`crate::caustic::Caustics::irradiance`], photon by photon
    /// (the WGSL `caustic`'s twin; the CPU renderer scans four photons at a time through
    /// [`crate::photon_lanes::PhotonLanes`], the same photons and weights).
    pub fn irradiance(&self, x: Vec3, n: Vec3) -> Vec3 {
        let r = self.radius;
        let r2 = r * r;
        let scan = |photons: &[Photon]| {
            let mut e = Vec3::ZERO;
            for p in photons {
                let d = Vec3::from(p.position) - x;
                let d2 = d.length_squared();
                let counts = (d2 <= r2) & accept_at(p, d, n, r);
                let w = if counts { 1.0 - d2 / r2 } else { 0.0 };
                e += Vec3::from(p.power) * w;
            }
            e
        };
        let e = self.estimate(
            x,
            n,
            |b| scan(&self.photons[self.bucket_photons(b)]),
            |g| {
                let g = &self.groups[g];
                scan(&self.photons[g.start as usize..(g.start + g.count) as usize])
            },
        );
        e * (2.0 / (std::f32::consts::PI * r2))
    }

    /// The kernel-weighted power `Σ Φ (1 − d²/r²)` at `x` (normal `n`): the sparse photons of
    /// each bucket a lookup reads (`scan_bucket(b)`), its groups whole where their bounds allow
    /// and the photons of the others (`scan_group(g)`). The one loop of both CPU estimates.
    #[inline]
    pub(crate) fn estimate(
        &self,
        x: Vec3,
        n: Vec3,
        mut scan_bucket: impl FnMut(usize) -> Vec3,
        mut scan_group: impl FnMut(usize) -> Vec3,
    ) -> Vec3 {
        let r = self.radius;
        let (buckets, count) = self.buckets(x);
        let mut e = Vec3::ZERO;
        for &b in &buckets[..count] {
            let b = b as usize;
            e += scan_bucket(b);
            for g in self.bucket_groups(b) {
                e += match self.groups[g].fate(x, n, r) {
                    Fate::None => Vec3::ZERO,
                    Fate::All(d) => self.groups[g].sum(d, r * r),
                    Fate::Open => scan_group(g),
                };
            }
        }
        e
    }

    /// Bucket `b`'s sparse photons, as indices into [`PhotonGrid::photons`].
    #[inline]
    pub(crate) fn bucket_photons(&self, b: usize) -> std::ops::Range<usize> {
        self.offsets[b] as usize..self.offsets[b + 1] as usize
    }

    /// Bucket `b`'s groups, as indices into [`PhotonGrid::groups`].
    #[inline]
    pub(crate) fn bucket_groups(&self, b: usize) -> std::ops::Range<usize> {
        let at = self.mask as usize + 2;
        self.offsets[at + b] as usize..self.offsets[at + b + 1] as usize
    }
}

impl PhotonGrid {
    /// Photons and groups a lookup at `x` (normal `n`) reads: its cost.
    pub fn reads(&self, x: Vec3, n: Vec3) -> usize {
        let (buckets, count) = self.buckets(x);
        let mut reads = 0;
        for &b in &buckets[..count] {
            let b = b as usize;
            reads += self.bucket_photons(b).len();
            for g in &self.groups[self.bucket_groups(b)] {
                reads += 1;
                if let Fate::Open = g.fate(x, n, self.radius) {
                    reads += g.count as usize;
                }
            }
        }
        reads
    }
}

/// What a lookup at `x` (normal `n`, radius `r`) makes of a group, from its bounds.
enum Fate {
    /// No photon of the group counts.
    None,
    /// Every photon counts; the group's position less the lookup's.
    All(Vec3),
    /// The bounds leave it open: scan the photons.
    Open,
}

impl PhotonGroup {
    /// The bounds' verdict (WGSL twin in `caustic`): the photons lie within `extent` of
    /// `position` and their directions within `dir_extent` of the mean, so the triangle
    /// inequality bounds each test of [`accept_at`] and of the radius for all of them at once.
    fn fate(&self, x: Vec3, n: Vec3, r: f32) -> Fate {
        let d = Vec3::from(self.position) - x;
        let d2 = d.length_squared();
        let dist = d2.sqrt();
        let facing = Vec3::from(self.dir).dot(n);
        let off = d.dot(n).abs();
        let plane = 0.25 * r;
        if dist - self.extent > r || facing - self.dir_extent >= 0.0 || off - self.extent > plane {
            return Fate::None;
        }
        if dist + self.extent <= r && facing + self.dir_extent < 0.0 && off + self.extent <= plane {
            return Fate::All(d);
        }
        Fate::Open
    }

    /// `Σ Φᵢ (1 − |pᵢ − x|²/r²)` over the group's photons, from its moments and `d = q − x`
    /// (`q = position`; WGSL twin `group_sum`): per channel,
    /// `Σ Φᵢ |pᵢ − x|² = Σ Φᵢ |pᵢ − q|² + 2 d · Σ Φᵢ (pᵢ − q) + |d|² Σ Φᵢ`.
    pub fn sum(&self, d: Vec3, r2: f32) -> Vec3 {
        let first = Vec3::from([0, 1, 2].map(|c| {
            d.dot(Vec3::new(
                self.first[c][0],
                self.first[c][1],
                self.first[c][2],
            ))
        }));
        let power = Vec3::from(self.power);
        let spread = Vec3::from(self.second) + 2.0 * first + d.length_squared() * power;
        power - spread / r2
    }
}

/// `x.floor()` without the C library's call (x86-64's baseline has no rounding instruction):
/// exact wherever the float has a fractional part (|x| < 2²³), and `x` itself (or NaN) beyond.
#[inline(always)]
fn floor(x: f32) -> f32 {
    if x.is_nan() || x.abs() >= 8_388_608.0 {
        return x;
    }
    let t = x as i32 as f32;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// Photons sorted by bucket (a counting sort), with each bucket's start.
struct Sorted {
    photons: Vec<Photon>,
    starts: Vec<u32>,
}

fn bucket_sort(photons: &[Photon], bucket: impl Fn(&Photon) -> u32) -> Sorted {
    let n = photons.len().max(1).next_power_of_two();
    let mut starts = vec![0u32; n + 1];
    for p in photons {
        starts[bucket(p) as usize + 1] += 1;
    }
    for b in 0..n {
        starts[b + 1] += starts[b];
    }
    let mut next = starts.clone();
    let mut sorted = vec![Photon::default(); photons.len()];
    for p in photons {
        let b = bucket(p) as usize;
        sorted[next[b] as usize] = *p;
        next[b] += 1;
    }
    Sorted {
        photons: sorted,
        starts,
    }
}

impl Sorted {
    /// Each of the `n` buckets' photons, in bucket order.
    fn buckets(&self, n: usize) -> impl Iterator<Item = &[Photon]> {
        (0..n).map(|b| &self.photons[self.starts[b] as usize..self.starts[b + 1] as usize])
    }
}

/// Dense buckets made into groups: each group's photons keyed by splat, cube and direction
/// octant, in the order of their first photon.
struct Grouping {
    origin: Vec3,
    side: f32,
    groups: Vec<PhotonGroup>,
    /// The groups' photons, group by group.
    members: Vec<Photon>,
    /// Scratch: a bucket's keys and each group's photons.
    keys: std::collections::HashMap<(u32, [i64; 3], u8), usize>,
    lists: Vec<Vec<Photon>>,
}

impl Grouping {
    fn new(origin: Vec3, side: f32) -> Grouping {
        Grouping {
            origin,
            side,
            groups: Vec::new(),
            members: Vec::new(),
            keys: Default::default(),
            lists: Vec::new(),
        }
    }

    /// One dense bucket's photons, made into groups.
    fn add(&mut self, photons: &[Photon]) {
        self.keys.clear();
        let mut used = 0;
        for p in photons {
            let q = ((Vec3::from(p.position) - self.origin) / self.side).floor();
            let octant = (p.dir[0] < 0.0) as u8
                | ((p.dir[1] < 0.0) as u8) << 1
                | ((p.dir[2] < 0.0) as u8) << 2;
            let key = (p.splat, [q.x as i64, q.y as i64, q.z as i64], octant);
            let g = *self.keys.entry(key).or_insert(used);
            if g == used {
                if self.lists.len() == used {
                    self.lists.push(Vec::new());
                }
                self.lists[used].clear();
                used += 1;
            }
            self.lists[g].push(*p);
        }
        for list in &self.lists[..used] {
            self.groups.push(group(list, self.members.len() as u32));
            self.members.extend_from_slice(list);
        }
    }
}

/// The group of `photons` (at least one), its photons at `start`. The moments are summed in
/// f64 about the photons' mean position, then rounded once.
fn group(photons: &[Photon], start: u32) -> PhotonGroup {
    let at = |p: &Photon| DVec3::from(p.position.map(f64::from));
    let mean = photons.iter().map(at).sum::<DVec3>() / photons.len() as f64;
    let position = mean.as_vec3();
    let q = position.as_dvec3();
    let (mut power, mut second, mut first, mut wd) =
        (DVec3::ZERO, DVec3::ZERO, [DVec3::ZERO; 3], DVec3::ZERO);
    for p in photons {
        let phi = DVec3::from(p.power.map(f64::from));
        let d = at(p) - q;
        power += phi;
        second += phi * d.length_squared();
        for (c, f) in first.iter_mut().enumerate() {
            *f += phi[c] * d;
        }
        wd += phi.element_sum() * DVec3::from(p.dir.map(f64::from));
    }
    // Without power to weigh the directions by, or where they cancel, the first photon's.
    let dir = match wd.length() > 0.0 {
        true => wd.normalize().as_vec3(),
        false => Vec3::from(photons[0].dir),
    };
    // The bounds about the f32 centre and direction the lookup reads, widened by a rounding's
    // worth at the positions' scale so that every photon lies within them.
    let extent = photons
        .iter()
        .map(|p| (Vec3::from(p.position) - position).length())
        .fold(0.0, f32::max);
    let dir_extent = photons
        .iter()
        .map(|p| (Vec3::from(p.dir) - dir).length())
        .fold(0.0, f32::max);
    let scale = position.abs().max_element().max(extent);
    PhotonGroup {
        position: position.into(),
        extent: extent * (1.0 + 1e-5) + 1e-6 * scale,
        dir: dir.into(),
        dir_extent: dir_extent * (1.0 + 1e-5) + 1e-6,
        power: power.as_vec3().into(),
        start,
        second: second.as_vec3().into(),
        count: photons.len() as u32,
        first: first.map(|f| {
            let f = f.as_vec3();
            [f.x, f.y, f.z, 0.0]
        }),
    }
}
