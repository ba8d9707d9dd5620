//! The V-map build (seed §7.2, §7.3 phases 2 and 3): a dual traversal of the octree that finds,
//! for every pair of nodes, the coarsest level at which they see each other, with the visible
//! fraction; and the nodes each point light sees. See docs/vmap.md.
//!
//! The traversal is level-synchronous: every round classifies a frontier of node pairs in
//! parallel, casts all the visibility rays the round needs in one batch (CPU or GPU, the same
//! rays), then turns each pair into a link, nothing, or finer pairs for the next round.
//!
//! Here the traversal (`build_links`) and the lights' lists; `build/vnode.rs` the nodes and the
//! tests that need no ray, `build/rays.rs` the pairs' samples and the rounds' ray batches,
//! `build/settle.rs` what the rays decide.

use glam::Vec3;
use pc_artifact::params::VmapParams;
use pc_artifact::vmap::Link;
use pc_tree::rng::pcg;
use pc_tree::shaft::DiskBoxes;
use pc_tree::{Between, OctreeView, Ray};
use rayon::prelude::*;

// The casters live in pc-tree, shared with pc-fmm's shadow rays; re-exported here, where the
// V-map's callers have always found them.
use pc_gpu::GpuError;
pub use pc_tree::caster::{Caster, CpuCaster, GpuCaster};

use crate::smear::Smear;

mod rays;
mod settle;
mod vnode;

pub(crate) use rays::{sample, Sample, RAYS_PER_BATCH};
pub use settle::far_pair_shaft;
use settle::{decide, exact_partial, ray_count, Culls};
pub(crate) use vnode::end_rough;
use vnode::faces;
pub use vnode::{children, may_face, vnodes, well_separated, VNode};

/// Result of a build.
#[derive(Debug, Default)]
pub struct Links {
    /// (node, link) pairs, both directions of every link.
    pub pairs: Vec<(u32, Link)>,
    pub far: u64,
    pub near: u64,
    pub pairs_tested: u64,
    pub rays: u64,
    /// Nodes with an occluder close by ([`crate::close`]).
    pub close: u64,
    /// What the links' shared fractions misstate of each splat's visible transfer.
    pub smear: Smear,
    /// Per node-pool slot: the share of a V-map leaf's probes that a surface close over it
    /// blocks ([`crate::close::contact_shares`]).
    pub contact: Vec<f32>,
}

#[derive(Clone, Copy)]
enum Step {
    Drop,
    Split(u32, u32),
    Rays { near: bool },
}

/// Classify a pair without rays.
fn classify(view: &OctreeView, vn: &[VNode], a: u32, b: u32, theta: f32) -> Step {
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    if a == b {
        return if va.vleaf {
            Step::Rays { near: true }
        } else {
            Step::Split(a, b)
        };
    }
    if !may_face(va, vb) {
        return Step::Drop;
    }
    if well_separated(va, vb, theta) {
        return Step::Rays { near: false };
    }
    if va.vleaf && vb.vleaf {
        return Step::Rays { near: true };
    }
    let _ = view;
    Step::Split(a, b)
}

/// The finer pairs of (a, b): all child pairs of a self pair, else the children of the larger
/// non-leaf node against the other.
fn split(view: &OctreeView, vn: &[VNode], a: u32, b: u32, out: &mut Vec<(u32, u32)>) {
    if a == b {
        let kids: Vec<u32> = children(view, vn, a).collect();
        for (i, &x) in kids.iter().enumerate() {
            for &y in &kids[i..] {
                out.push((x, y));
            }
        }
        return;
    }
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    let split_a = !va.vleaf && (vb.vleaf || va.radius >= vb.radius);
    if split_a {
        out.extend(children(view, vn, a).map(|c| (c.min(b), c.max(b))));
    } else {
        out.extend(children(view, vn, b).map(|c| (c.min(a), c.max(a))));
    }
}

/// The segments of a batch's two casts, kept from batch to batch: allocated afresh, a
/// batch's few hundred megabytes came from the system as new pages each time, and faulting them
/// in cost as much as filling them.
#[derive(Default)]
struct Segments {
    first: Vec<Between>,
    rest: Vec<Between>,
}

/// Build the links of the octree. `round` is called after each round with the frontier size.
pub fn build_links(
    view: &OctreeView,
    vn: &[VNode],
    p: &VmapParams,
    caster: &dyn Caster,
    round: &mut dyn FnMut(usize, usize),
) -> Result<Links, GpuError> {
    let mut links = Links {
        smear: Smear::new(view.splats.len()),
        ..Default::default()
    };
    if vn[0].count() == 0 {
        return Ok(links);
    }
    let close = crate::close::close_occluders(view, vn, p, caster)?;
    links.close = close.iter().filter(|&&c| c).count() as u64;
    let mut culls = Culls {
        close,
        shafts: Some(DiskBoxes::new(view)),
        tried: 0,
        settled: 0,
    };
    links.contact = crate::close::contact_shares(view, vn, p, caster)?;
    let mut frontier: Vec<(u32, u32)> = vec![(0, 0)];
    let mut segs = Segments::default();
    let mut level = 0;
    while !frontier.is_empty() {
        level += 1;
        // 1. Classify in parallel; collect finer pairs and the pairs that need rays.
        let steps: Vec<Step> = frontier
            .par_iter()
            .map(|&(a, b)| classify(view, vn, a, b, p.theta))
            .collect();
        let mut next: Vec<(u32, u32)> = Vec::new();
        let mut tested: Vec<(u32, u32, bool)> = Vec::new();
        let mut partial: Vec<(u32, u32)> = Vec::new();
        for (&(a, b), s) in frontier.iter().zip(&steps) {
            match *s {
                Step::Drop => {}
                Step::Split(a, b) => split(view, vn, a, b, &mut next),
                Step::Rays { near } => tested.push((a, b, near)),
            }
        }
        // 2.-4. Rays for the tested pairs, in chunks of bounded size (memory), then decide.
        let mut first = 0;
        while first < tested.len() {
            let mut last = first;
            let mut budget = 0u64;
            while last < tested.len() && budget < RAYS_PER_BATCH {
                let (a, b, near) = tested[last];
                budget += ray_count(vn, a, b, near, p) as u64;
                last += 1;
            }
            culls.give_up_unless_worth();
            let (more, part) = decide(
                view,
                vn,
                p,
                caster,
                &mut culls,
                &tested[first..last],
                &mut links,
                &mut segs,
            )?;
            next.extend(more);
            partial.extend(part);
            first = last;
        }
        let mut first = 0;
        while first < partial.len() {
            let last = (first + (RAYS_PER_BATCH / p.near_rays.max(1) as u64).max(1) as usize)
                .min(partial.len());
            exact_partial(view, vn, p, caster, &partial[first..last], &mut links)?;
            first = last;
        }
        round(level, next.len());
        frontier = next;
    }
    Ok(links)
}

/// For each point light, the V-map leaves it sees, with the fraction of their sample rays that
/// reach it.
pub fn light_lists(
    view: &OctreeView,
    vn: &[VNode],
    lights: &[Vec3],
    p: &VmapParams,
    caster: &dyn Caster,
) -> Result<Vec<Vec<Link>>, GpuError> {
    let mut out = Vec::with_capacity(lights.len());
    for (li, &pos) in lights.iter().enumerate() {
        // Descend by geometry alone: every V-map leaf whose splats may face the light. Rays
        // decide only at the leaves: a few samples of a large node cannot prove it unlit (a
        // sun seen through a skylight lights a small patch of a large room, which its samples
        // miss), nor fully lit (a shadow can cover a corner the samples missed).
        let mut leaves = Vec::new();
        let mut frontier: Vec<u32> = if vn[0].count() > 0 { vec![0] } else { vec![] };
        while let Some(a) = frontier.pop() {
            let v = &vn[a as usize];
            let d = pos - v.center;
            let dist = d.length();
            if !(dist <= v.radius || faces(v, d / dist, (v.radius / dist).min(1.0).asin())) {
                continue;
            }
            if v.vleaf {
                leaves.push(a);
            } else {
                frontier.extend(children(view, vn, a));
            }
        }
        leaves.sort_unstable();
        let per: Vec<Vec<Between>> = leaves
            .par_iter()
            .map(|&a| {
                let v = &vn[a as usize];
                let stream = pcg(a ^ pcg(0x5151 + li as u32));
                let mut r = Vec::new();
                for k in 0..p.rays {
                    let (i, x, n, rad) = sample(view, v, p.seed, stream, k, p.rays);
                    let d = pos - x;
                    let len = d.length();
                    if len <= 1e-9 || n.dot(d) <= 0.0 {
                        continue;
                    }
                    let ray = Ray {
                        origin: x,
                        dir: d / len,
                        t_min: p.self_hit * rad,
                        t_max: len * (1.0 - 1e-4),
                    };
                    r.push(Between::leaving(
                        ray,
                        (&view.splats[i as usize], end_rough(view, vn, i)),
                    ));
                }
                r
            })
            .collect();
        let mut list = Vec::new();
        let rays: Vec<Between> = per.iter().flatten().copied().collect();
        let visible = caster.visible_between(&rays)?;
        let mut at = 0;
        for (&a, r) in leaves.iter().zip(&per) {
            let total = r.len();
            let seen = visible[at..at + total].iter().filter(|&&v| v).count();
            at += total;
            if seen > 0 {
                list.push(Link::far(a, seen as f32 / total as f32));
            }
        }
        list.sort_by_key(|l| l.node);
        out.push(list);
    }
    Ok(out)
}

/// CSR of the links: row offsets per node-pool slot (+1) and the links sorted by row.
pub fn csr(nodes: usize, mut pairs: Vec<(u32, Link)>) -> (Vec<u32>, Vec<Link>) {
    pairs.par_sort_unstable_by_key(|&(a, l)| (a, l.node));
    let mut offsets = vec![0u32; nodes + 1];
    for &(a, _) in &pairs {
        offsets[a as usize + 1] += 1;
    }
    for i in 0..nodes {
        offsets[i + 1] += offsets[i];
    }
    (offsets, pairs.into_iter().map(|p| p.1).collect())
}
