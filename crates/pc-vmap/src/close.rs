//! Nodes with an occluder close by: a light hanging 1 cm under the ceiling, a ball resting on
//! the floor. Inside such a node the visibility of its splats changes sharply (the ceiling above
//! the light sees almost nothing, the ceiling beside it the whole room), so a partial link kept
//! at its level by the importance criterion spreads one visible share over both: the ceiling
//! above the reference Cornell light got a quarter of the light of the ceiling beside it, where
//! the reference has almost none, and the visible surfaces lose what the hidden ones gain.
//! docs/vmap.md, "Occluders close to a node".

use pc_artifact::octree::tangent_frame;
use pc_artifact::params::VmapParams;
use pc_gpu::GpuError;
use pc_tree::caster::Caster;
use pc_tree::rng::{pcg, rand};
use pc_tree::{Between, OctreeView, Ray};
use rayon::prelude::*;

use crate::build::{children, end_rough, sample, VNode, RAYS_PER_BATCH};
use glam::Vec3;

/// A partial pair with a marked node is refined on that node's side while its form factor is
/// at least this share of `vmap.refine_form_factor` (the importance criterion's threshold).
/// On the reference Cornell box (100k), against 1 (the rule off): per-pixel relative error
/// 0.0955 → 0.0791, pc-vmap 12.2 → 16.0 s; 0 (whatever the form factor) gave 0.0773 for 19.1 s
/// at 100k and 46.9 s instead of 39.2 s at 1M (docs/vmap.md "Occluders close to a node").
pub const REFINE_SHARE: f32 = 0.5;

/// Probe rays per child of a node.
const PROBES: u32 = 16;
/// Least difference between two groups' blocked shares that marks a node.
const STEP: f32 = 0.5;
/// Least gap between two layers of a node, in node radii (the reference Cornell light hangs
/// 1 cm under the ceiling: 0.25 radii of a 4 cm node).
const LAYER_GAP: f32 = 0.1;

/// Per node-pool slot: whether the node holds two layers, one occluding the other: a ceiling
/// and the light 1 cm in front of it, which the octree separates only in cells under 1 cm.
/// Each child of an internal node casts [`PROBES`] rays from its splats (stratified along its
/// range, cosine-distributed about the splat's normal) out to the node's radius; the probes
/// are split into a back and a front layer along the node's normal at the widest gap of their
/// heights, and the node is marked when the layers' shares of blocked probes differ by at
/// least [`STEP`]. (A second test, between the children's shares, marked room corners and
/// contacts too and changed neither reference.) Probes are cast like the V-map's rays (CPU or
/// GPU).
pub fn close_occluders(
    view: &OctreeView,
    vn: &[VNode],
    p: &VmapParams,
    caster: &dyn Caster,
) -> Result<Vec<bool>, GpuError> {
    let mut marked = vec![false; vn.len()];
    let nodes: Vec<(u32, Vec<u32>)> = (0..vn.len() as u32)
        .filter(|&a| !vn[a as usize].vleaf && vn[a as usize].count() > 0)
        .map(|a| (a, children(view, vn, a).collect::<Vec<u32>>()))
        .filter(|(_, kids)| kids.len() >= 2)
        .collect();
    let per_node = |kids: &[u32]| kids.len() as u64 * PROBES as u64;
    let mut first = 0;
    while first < nodes.len() {
        let (mut last, mut budget) = (first, 0u64);
        while last < nodes.len() && budget < RAYS_PER_BATCH {
            budget += per_node(&nodes[last].1);
            last += 1;
        }
        let batch = &nodes[first..last];
        let rays: Vec<Between> = batch
            .par_iter()
            .flat_map_iter(|(a, kids)| {
                let reach = vn[*a as usize].radius;
                kids.iter().flat_map(move |&c| {
                    (0..PROBES).map(move |k| probe(view, vn, c, (k, PROBES), reach, p))
                })
            })
            .collect();
        let visible = caster.visible_between(&rays)?;
        let mut at = 0;
        for (a, kids) in batch {
            let n = kids.len() * PROBES as usize;
            let (probes, seen) = (&rays[at..at + n], &visible[at..at + n]);
            at += n;
            marked[*a as usize] = step_between_layers(&vn[*a as usize], probes, seen);
        }
        first = last;
    }
    Ok(marked)
}

/// Whether the blocked shares of the back and the front layer of the probes (their origins'
/// heights along the node's normal, split at the widest gap) differ by at least [`STEP`]. Nodes
/// whose normals span every direction have no normal and are left to the children's test.
fn step_between_layers(v: &VNode, probes: &[Between], seen: &[bool]) -> bool {
    if v.cone_cos <= 0.0 || v.axis.length_squared() == 0.0 {
        return false;
    }
    let mut h: Vec<(f32, bool)> = probes
        .iter()
        .zip(seen)
        .map(|(r, &s)| ((r.ray.origin - v.center).dot(v.axis), s))
        .collect();
    h.sort_by(|x, y| x.0.total_cmp(&y.0));
    // Split at the widest gap between consecutive heights, with at least a quarter on each side;
    // a single surface, flat or gently curved, has no gap wider than a few percent of the node.
    let quarter = (h.len() / 4).max(1);
    let Some((at, gap)) = (quarter..=h.len().saturating_sub(quarter))
        .filter(|&i| i > 0 && i < h.len())
        .map(|i| (i, h[i].0 - h[i - 1].0))
        .max_by(|x, y| x.1.total_cmp(&y.1))
    else {
        return false;
    };
    if gap.is_nan() || gap <= LAYER_GAP * v.radius {
        return false;
    }
    let (back, front) = h.split_at(at);
    let blocked =
        |x: &[(f32, bool)]| x.iter().filter(|p| !p.1).count() as f32 / x.len().max(1) as f32;
    (blocked(back) - blocked(front)).abs() >= STEP
}

/// Probe rays per V-map leaf for its contact share ([`contact_shares`]).
const CONTACT_PROBES: u32 = 32;
/// How far a contact probe reaches, in radii of its V-map leaf.
const CONTACT_REACH: f32 = 2.0;

/// Per node-pool slot: for each V-map leaf (the topmost of a subtree; others get 0), the share
/// of [`CONTACT_PROBES`] rays from its splats (stratified along its range, cosine-distributed)
/// that another surface blocks within [`CONTACT_REACH`] of its radii: a ball resting on the
/// floor over the leaf, a box standing on it, the wall at a room's corner. Where something that
/// close stands over a leaf, what the leaf's splats see of the rest of the scene changes from
/// splat to splat, which the leaf's links, one fraction each, cannot say; pc-fmm gathers the
/// light of such leaves splat by splat (docs/fmm.md, "Final gather").
pub fn contact_shares(
    view: &OctreeView,
    vn: &[VNode],
    p: &VmapParams,
    caster: &dyn Caster,
) -> Result<Vec<f32>, GpuError> {
    let mut leaves = Vec::new();
    let mut stack: Vec<u32> = if vn.first().is_some_and(|v| v.count() > 0) {
        vec![0]
    } else {
        vec![]
    };
    while let Some(a) = stack.pop() {
        match vn[a as usize].vleaf {
            true => leaves.push(a),
            false => stack.extend(children(view, vn, a)),
        }
    }
    leaves.sort_unstable();
    let mut share = vec![0.0f32; vn.len()];
    let per_batch = (RAYS_PER_BATCH / CONTACT_PROBES as u64).max(1) as usize;
    for batch in leaves.chunks(per_batch) {
        let rays: Vec<Between> = batch
            .par_iter()
            .flat_map_iter(|&a| {
                let v = &vn[a as usize];
                let reach = CONTACT_REACH * v.radius;
                (0..CONTACT_PROBES).map(move |k| probe(view, vn, a, (k, CONTACT_PROBES), reach, p))
            })
            .collect();
        let visible = caster.visible_between(&rays)?;
        for (&a, seen) in batch.iter().zip(visible.chunks(CONTACT_PROBES as usize)) {
            share[a as usize] = seen.iter().filter(|&&s| !s).count() as f32 / seen.len() as f32;
        }
    }
    Ok(share)
}

/// The k-th of m probes of node `v` (slot `c`): from the centre of one of its splats (the k-th
/// of m strata of its range), cosine-distributed about the splat's normal, out to `reach`,
/// past the splat's own surface ([`pc_tree::between`]).
fn probe(
    view: &OctreeView,
    vn: &[VNode],
    c: u32,
    (k, m): (u32, u32),
    reach: f32,
    p: &VmapParams,
) -> Between {
    let stream = pcg(c ^ 0x27d4_eb2f);
    let (i, x, n, r) = sample(view, &vn[c as usize], p.seed ^ 0x5bd1_e995, stream, k, m);
    let (u1, u2) = (rand(p.seed, stream, k, 1), rand(p.seed, stream, k, 2));
    let (tu, tv) = tangent_frame(n.into());
    let (s, phi) = (u1.sqrt(), std::f32::consts::TAU * u2);
    let dir = (Vec3::from(tu) * (s * phi.cos())
        + Vec3::from(tv) * (s * phi.sin())
        + n * (1.0 - u1).max(0.0).sqrt())
    .normalize_or(n);
    let t_min = p.self_hit * r;
    let ray = Ray {
        origin: x,
        dir,
        t_min,
        t_max: reach.max(t_min),
    };
    Between::leaving(ray, (&view.splats[i as usize], end_rough(view, vn, i)))
}
