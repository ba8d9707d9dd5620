//! Photon emission (seed §8.5.3): each light aims photons only at the specular leaves it sees,
//! as many per leaf as the leaf's share of the lights' power.
//!
//! * A point light `l` (position `P`, intensity `I`, W/sr) sees the nodes of its V-map light
//!   list. A specular octree leaf `L` under them gets the expected power `I · ω_L` with
//!   `ω_L = Σ_s A_s cos θ_s / d_s²` over its splats facing the light (`A_s` the splat's area,
//!   `splat_area`): the solid angle of the leaf's surface. The seed uses the leaf's average disk,
//!   `π r² cos θ / d²`; its radius bounds the leaf's splats, so neighbouring disks overlap and
//!   their solid angles would add up to more than the surface's (docs/caustics.md).
//! * An emitting splat is an area light with radiant intensity `Lₑ A cos θₑ`. The emitter
//!   leaves and the specular leaves meet through the V-map's links (each pair of splats lies
//!   under exactly one link), and the pair (emitter leaf `E`, specular leaf `L`) gets
//!   `Lₑ A_E cos θ_E · A_L cos θ_L / d²`, from the two leaves' centroids and mean normals.
//!
//! The budget `n_e` stands for the whole sphere of every light: the lights' total power is
//! `Φ = Σ 4π I + Σ π Lₑ A`, and a pair with expected power `P` gets `n_e · |P| / |Φ|` photons
//! (|·| the mean over RGB), rounded stochastically, each carrying `P / (n_e |P| / |Φ|)`, which
//! is `Φ / n_e` for white light. Whether a photon really reaches its leaf is left to the photon's
//! own ray (a photon stopped short of its aim point is dropped): the light lists only say where
//! to aim.

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_artifact::vmap::VmapView;
use pc_artifact::PointLight;
use pc_tree::rng::rand;
use pc_tree::OctreeView;
use rayon::prelude::*;

/// Where photons of one aim start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Source {
    /// A point light: position.
    Point(Vec3),
    /// An emitter leaf: index into [`Leaves::leaves`].
    Area(u32),
}

/// Photons from one source to one specular leaf.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aim {
    pub source: Source,
    /// The specular leaf: index into [`Leaves::leaves`].
    pub target: u32,
    /// Photons to trace.
    pub photons: u32,
    /// Power of each (W, RGB).
    pub power: [f32; 3],
    /// How the power follows each photon's own points.
    pub sampling: Sampling,
}

/// How a photon of an [`Aim`] is drawn and weighted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sampling {
    /// Aim point by area on the target leaf; `power` is the pair's whole (the lights).
    Whole,
    /// Aim point by area on the target leaf; the photon carries `power` times
    /// [`link_weight`] of its two points (a specular link's area strategy, [`crate::links`]).
    Area { k: f32 },
    /// Direction by cosine about the source splat's normal; the photon counts only if its first
    /// hit is a specular splat of the data-pool range `[lo, hi)` (the link's target node, at
    /// node-pool slot `node`), and carries `power` times [`link_weight`] of its two points (the
    /// link's direction strategy).
    Direction { k: f32, lo: u32, hi: u32, node: u32 },
}

/// A specular-link path's geometry under the two strategies' balance heuristic:
/// `c_s c_t / (d² + k c_s c_t)`, for the cosines at the source and target points and their
/// distance `d`. `k` = 0 is the bare point-to-point geometry; `k` > 0 bounds it by `1 / k`
/// where the points touch (docs/caustics.md "Specular links"). WGSL twin: `link_weight` in
/// shaders/caustics/photons.wgsl.
#[inline]
pub fn link_weight(cos_s: f32, cos_t: f32, d: f32, k: f32) -> f32 {
    let g = cos_s * cos_t;
    if g <= 0.0 {
        return 0.0;
    }
    g / (d * d + k * g)
}

/// One octree leaf's own splats, and their aggregate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Leaf {
    /// Its own splats `[lo, hi)` in the data pool.
    pub lo: u32,
    pub hi: u32,
    pub class: u32,
    /// Area-weighted centroid and mean normal (normalised; zero when they cancel).
    pub centroid: Vec3,
    pub normal: Vec3,
    /// Sum of its splats' areas.
    pub area: f32,
    /// Area-weighted emitted radiance (emitter leaves).
    pub radiance: Vec3,
}

/// The octree leaves that own splats, ordered by their data-pool range.
pub struct Leaves {
    pub leaves: Vec<Leaf>,
}

impl Leaves {
    pub fn new(view: &OctreeView, materials: &[MaterialRecord]) -> Leaves {
        let mut leaves: Vec<Leaf> = Vec::new();
        let n = view.splats.len();
        let mut i = 0;
        while i < n {
            let owner = view.splat_leaf[i];
            let lo = i;
            while i < n && view.splat_leaf[i] == owner {
                i += 1;
            }
            let mut leaf = Leaf {
                lo: lo as u32,
                hi: i as u32,
                class: materials[view.splats[lo].material as usize].class,
                ..Default::default()
            };
            for j in lo..i {
                let s = &view.splats[j];
                let a = view.splat_area[j];
                leaf.area += a;
                leaf.centroid += a * Vec3::from(s.position);
                leaf.normal += a * Vec3::from(s.normal);
                leaf.radiance += a * Vec3::from(materials[s.material as usize].radiance);
            }
            if leaf.area > 0.0 {
                leaf.centroid /= leaf.area;
                leaf.radiance /= leaf.area;
            } else {
                leaf.centroid = Vec3::from(view.splats[lo].position);
            }
            leaf.normal = leaf.normal.normalize_or_zero();
            leaves.push(leaf);
        }
        Leaves { leaves }
    }

    /// Indices of the leaves whose range lies in `[lo, hi)` (leaves never straddle a node's
    /// range).
    pub fn within(&self, lo: u32, hi: u32) -> std::ops::Range<usize> {
        let a = self.leaves.partition_point(|l| l.lo < lo);
        let b = self.leaves.partition_point(|l| l.lo < hi);
        a..b
    }

    /// The index of the leaf that owns `splat`.
    pub fn leaf_of(&self, splat: u32) -> usize {
        self.leaves
            .partition_point(|l| l.lo <= splat)
            .saturating_sub(1)
    }

    /// A splat of leaf `l` drawn in proportion to area, for `u` ∈ [0, 1).
    pub fn pick(&self, view: &OctreeView, l: u32, u: f32) -> u32 {
        let leaf = &self.leaves[l as usize];
        let mut t = u * leaf.area;
        for j in leaf.lo..leaf.hi {
            t -= view.splat_area[j as usize];
            if t < 0.0 {
                return j;
            }
        }
        leaf.hi - 1
    }
}

/// The mean of the three channels, the scalar the photon budget is shared by.
pub fn level(c: Vec3) -> f32 {
    (c.x + c.y + c.z) / 3.0
}

/// The expected power of every (source, specular leaf) pair, before the budget is shared out.
#[derive(Clone, Debug, Default)]
pub struct Plan {
    /// (source, target leaf, expected power W RGB).
    pub pairs: Vec<(Source, u32, Vec3)>,
    /// Total emitted power of every light (W, RGB).
    pub emitted: Vec3,
}

/// Find the (source, specular leaf) pairs and their expected power.
pub fn plan(
    view: &OctreeView,
    materials: &[MaterialRecord],
    leaves: &Leaves,
    lights: &[PointLight],
    v: &VmapView,
) -> Plan {
    let mut out = Plan::default();
    let spec = |c: u32| class::is_specular(c);
    // Point lights.
    for (l, light) in lights.iter().enumerate() {
        let (pos, intensity) = (Vec3::from(light.position), Vec3::from(light.intensity));
        out.emitted += 4.0 * std::f32::consts::PI * intensity;
        let list = v.light_list(l);
        let mut omega: Vec<(u32, f32)> = Vec::new();
        for link in list.iter().filter(|k| k.fraction > 0.0) {
            let [lo, hi] = v.node_range[link.slot() as usize];
            for li in leaves.within(lo, hi) {
                let leaf = &leaves.leaves[li];
                if !spec(leaf.class) {
                    continue;
                }
                let mut w = 0.0f32;
                for j in leaf.lo..leaf.hi {
                    let s = &view.splats[j as usize];
                    let d = pos - Vec3::from(s.position);
                    let r2 = d.length_squared();
                    if r2 <= 0.0 {
                        continue;
                    }
                    // Either side: a dielectric is entered from both.
                    let cos = Vec3::from(s.normal).dot(d).abs() / r2.sqrt();
                    w += view.splat_area[j as usize] * cos / r2;
                }
                if w > 0.0 {
                    omega.push((li as u32, w));
                }
            }
        }
        omega.sort_by_key(|x| x.0);
        omega.dedup_by_key(|x| x.0);
        out.pairs.extend(
            omega
                .into_iter()
                .map(|(li, w)| (Source::Point(pos), li, intensity * w)),
        );
    }
    // Emitting splats.
    for (j, s) in view.splats.iter().enumerate() {
        let m = &materials[s.material as usize];
        if m.class == class::EMITTER {
            out.emitted += std::f32::consts::PI * Vec3::from(m.radiance) * view.splat_area[j];
        }
    }
    let area_pairs: Vec<(u32, u32, Vec3)> = leaf_pairs(leaves, v, &|l| l.class == class::EMITTER)
        .into_iter()
        .map(|(e, t, g)| (e, t, leaves.leaves[e as usize].radiance * g))
        .collect();
    out.pairs.extend(
        area_pairs
            .into_iter()
            .map(|(e, t, p)| (Source::Area(e), t, p)),
    );
    out
}

/// Every (source leaf, specular leaf) pair that meets under a V-map link, once, with its
/// geometric factor `A_S cos θ_S · A_L |cos θ_L| / d²` between the leaves' centroids and mean
/// normals (the flux per unit radiance of the source leaf; the specular side either way, since
/// a dielectric is entered from both). Sources are the leaves `is_source` accepts that face the
/// specular leaf. Each pair of splats lies under exactly one link.
pub fn leaf_pairs(
    leaves: &Leaves,
    v: &VmapView,
    is_source: &(dyn Fn(&Leaf) -> bool + Sync),
) -> Vec<(u32, u32, f32)> {
    let count_of = |want: &dyn Fn(&Leaf) -> bool| {
        let mut pre = vec![0u32; leaves.leaves.len() + 1];
        for (i, l) in leaves.leaves.iter().enumerate() {
            pre[i + 1] = pre[i] + want(l) as u32;
        }
        pre
    };
    let source_pre = count_of(is_source);
    let spec_pre = count_of(&|l| class::is_specular(l.class));
    // Node by node in parallel, collected in node order; sorted stably (in parallel: a stable
    // sort's order is the serial one's) and the first of each pair kept.
    let node_pairs = |x: usize| {
        let mut pairs: Vec<(u32, u32, f32)> = Vec::new();
        let row = &v.links[v.link_offsets[x] as usize..v.link_offsets[x + 1] as usize];
        if row.is_empty() {
            return pairs;
        }
        let [xlo, xhi] = v.node_range[x];
        let xr = leaves.within(xlo, xhi);
        if source_pre[xr.end] == source_pre[xr.start] {
            return pairs;
        }
        for link in row.iter().filter(|k| k.fraction > 0.0) {
            let [ylo, yhi] = v.node_range[link.slot() as usize];
            let yr = leaves.within(ylo, yhi);
            if spec_pre[yr.end] == spec_pre[yr.start] {
                continue;
            }
            for ei in xr.clone() {
                let e = &leaves.leaves[ei];
                if !is_source(e) {
                    continue;
                }
                for si in yr.clone() {
                    let t = &leaves.leaves[si];
                    if !class::is_specular(t.class) {
                        continue;
                    }
                    let d = t.centroid - e.centroid;
                    let r2 = d.length_squared();
                    if r2 <= 0.0 {
                        continue;
                    }
                    let dir = d / r2.sqrt();
                    let ce = e.normal.dot(dir);
                    let ct = t.normal.dot(dir).abs();
                    if ce <= 0.0 {
                        continue;
                    }
                    pairs.push((ei as u32, si as u32, e.area * ce * t.area * ct / r2));
                }
            }
        }
        pairs
    };
    let mut pairs: Vec<(u32, u32, f32)> = (0..v.node_range.len())
        .into_par_iter()
        .flat_map_iter(node_pairs)
        .collect();
    pairs.par_sort_by_key(|x| (x.0, x.1));
    pairs.dedup_by_key(|x| (x.0, x.1));
    pairs
}

/// Each aim's first photon id (its photons' ids run on from it), and last the total: the
/// prefix sums of the aims' photon counts, in parallel (the specular links plan millions of
/// aims).
pub fn first_ids(aims: &[Aim]) -> Vec<u64> {
    const BLOCK: usize = 1 << 14;
    let sums: Vec<u64> = aims
        .par_chunks(BLOCK)
        .map(|c| c.iter().map(|a| a.photons as u64).sum())
        .collect();
    let mut total = 0;
    let starts: Vec<u64> = sums
        .iter()
        .map(|&s| {
            total += s;
            total - s
        })
        .collect();
    let mut first = vec![0u64; aims.len() + 1];
    first[..aims.len()]
        .par_chunks_mut(BLOCK)
        .zip(aims.par_chunks(BLOCK))
        .zip(&starts)
        .for_each(|((f, c), &start)| {
            let mut at = start;
            for (f, a) in f.iter_mut().zip(c) {
                *f = at;
                at += a.photons as u64;
            }
        });
    first[aims.len()] = total;
    first
}

/// Share the budget out: `n_e |P| / |Φ|` photons per pair, rounded stochastically.
pub fn aims(plan: &Plan, budget: u32, seed: u32) -> Vec<Aim> {
    let total = level(plan.emitted);
    if total <= 0.0 || budget == 0 {
        return Vec::new();
    }
    plan.pairs
        .iter()
        .enumerate()
        .filter_map(|(i, &(source, target, p))| {
            let n = budget as f64 * level(p) as f64 / total as f64;
            if n <= 0.0 {
                return None;
            }
            let u = rand(seed, 0x0a11_7e5e, i as u32, 0) as f64;
            let count = (n.floor() + (u < n.fract()) as u32 as f64) as u32;
            (count > 0).then(|| Aim {
                source,
                target,
                photons: count,
                power: (p / n as f32).into(),
                sampling: Sampling::Whole,
            })
        })
        .collect()
}
