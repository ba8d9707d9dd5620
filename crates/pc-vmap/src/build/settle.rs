//! What a pair's rays decide: probes first, the rest where the probes disagree, the shaft
//! test that spares a far pair its rays, and the link's visible fraction and form factor.

use glam::Vec3;
use pc_artifact::params::VmapParams;
use pc_artifact::vmap::Link;
use pc_tree::shaft::{Aabb, DiskBoxes, Shaft};
use pc_tree::{Between, OctreeView};
use rayon::prelude::*;

use pc_gpu::GpuError;

use super::rays::{gather_rays, offsets, pair_rays, Sample};
use super::vnode::{children, VNode};
use super::{split, Caster, Links, Segments};

/// Rays `pair_rays` makes for a pair (an upper bound: back-facing samples are skipped).
pub(super) fn ray_count(vn: &[VNode], a: u32, b: u32, near: bool, p: &VmapParams) -> u32 {
    let (na, nb) = (vn[a as usize].count() as u64, vn[b as usize].count() as u64);
    if near && na * nb <= p.near_rays as u64 {
        (na * nb) as u32
    } else if near {
        p.near_rays
    } else {
        p.rays
    }
}

/// Rays cast first for a far pair (spread over its stratified samples): when they already
/// disagree, the pair is partly visible whatever the others say.
pub(super) const PROBE_RAYS: usize = 4;

/// What a partly visible far pair becomes; known before any ray, from the nodes, the close
/// occluders and the sample weights.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum Partly {
    /// Both are V-map leaves: the exhaustive pass.
    Exact,
    /// An occluder close to this node: refine it.
    Refine(u32),
    /// Too little light flows to resolve the shadow edge: a partial link with its fraction.
    Keep,
    /// Finer pairs.
    Split,
}

pub(super) fn partly(
    vn: &[VNode],
    p: &VmapParams,
    close: &[bool],
    (a, b): (u32, u32),
    r: &[Sample],
) -> Partly {
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    if va.vleaf && vb.vleaf {
        return Partly::Exact;
    }
    let least = p.refine_form_factor * crate::close::REFINE_SHARE;
    if let Some(x) = [a, b]
        .into_iter()
        .find(|&x| close[x as usize] && !vn[x as usize].vleaf)
        .filter(|_| form_factors(va, vb, r) >= least)
    {
        // An occluder close to one of the two changes its splats' visibility sharply
        // (crate::close): refine that one down to a smaller form factor.
        return Partly::Refine(x);
    }
    if p.refine_form_factor > 0.0 && form_factors(va, vb, r) < p.refine_form_factor {
        // Hierarchical radiosity's importance criterion.
        return Partly::Keep;
    }
    Partly::Split
}

/// The indices of a far pair's probe rays: [`PROBE_RAYS`] spread over its samples.
pub(super) fn probes(n: usize) -> impl Iterator<Item = usize> {
    let k = PROBE_RAYS.min(n);
    (0..k).map(move |i| i * n / k)
}

pub(super) fn is_probe(i: usize, n: usize) -> bool {
    probes(n).any(|j| j == i)
}

/// Cast the rays of `tested` pairs and decide each: a link, nothing, finer pairs (returned), or
/// a partially visible pair of V-map leaves for the exhaustive pass (returned).
///
/// In two casts. A far pair's probe rays go first; where they disagree (some visible with
/// light-carrying weight, some blocked) and the pair's fate needs no fraction (finer pairs or the
/// exhaustive pass), its other rays are never cast. Every other ray is cast in the second, so
/// the links are exactly those of casting every ray at once (docs/vmap.md, "Cost"). What each
/// pair's rays say (its probes' verdict, its outcome) is worked out in parallel over the pairs;
/// the outcomes are applied in the pairs' order (the links, the finer pairs and the smear's
/// sums come out as from one loop).
// (The round's inputs, its output and its reused buffers: eight arguments.)
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn decide(
    view: &OctreeView,
    vn: &[VNode],
    p: &VmapParams,
    caster: &dyn Caster,
    culls: &mut Culls,
    tested: &[(u32, u32, bool)],
    links: &mut Links,
    segs: &mut Segments,
) -> Result<(Vec<(u32, u32)>, Vec<(u32, u32)>), GpuError> {
    let (close, shafts) = (&culls.close[..], culls.shafts.as_ref());
    let per_pair: Vec<PairRays> = tested
        .par_iter()
        .map_init(Vec::new, |stack, &(a, b, near)| {
            let mut r = Vec::with_capacity(p.rays as usize);
            let mut drawn = pair_rays(view, vn, (a, b), near, p.rays, p, &mut r);
            // A pair that all of a few rays find unoccluded is linked whole: a partial occluder
            // slips through with probability (1 − blocked share)^rays, and every miss brightens
            // the receiver. The pairs that carry the most light get more rays.
            if !near
                && p.heavy_rays > p.rays
                && form_factors(&vn[a as usize], &vn[b as usize], &r) >= p.heavy_form_factor
            {
                r.clear();
                drawn = pair_rays(view, vn, (a, b), near, p.heavy_rays, p, &mut r);
            }
            let fate = if near {
                Partly::Keep
            } else {
                partly(vn, p, close, (a, b), &r)
            };
            let open = !near && shafts.is_some_and(|d| shaft_open(view, d, &r, stack));
            let wsum = r.iter().map(|x| x.weight).sum();
            PairRays {
                r,
                drawn,
                fate,
                open,
                wsum,
            }
        })
        .collect();
    if culls.shafts.is_some() {
        culls.tried += tested.iter().filter(|x| !x.2).count() as u64;
        culls.settled += per_pair.iter().filter(|x| x.open).count() as u64;
    }
    // 1. Probes: every ray of a near pair or of one whose partial fate needs its fraction, the
    //    probe rays of the others; none of a pair whose shaft is empty.
    let first = &mut segs.first;
    let starts = gather_rays(&per_pair, |_, x| Some(x.first_rays()), first);
    let seen_first = caster.visible_between(first)?;
    let mut probed: Vec<(Vec<bool>, bool)> = per_pair
        .par_iter()
        .zip(&starts)
        .map(|(x, &at)| x.after_probes(&seen_first[at..]))
        .collect();
    // 2. The rest, where the probes do not settle the pair.
    let unsettled = |x: &PairRays, done: bool| x.probing() && !done;
    let rest = &mut segs.rest;
    let starts = gather_rays(
        &per_pair,
        |k, x| unsettled(x, probed[k].1).then(|| x.rest_rays()),
        rest,
    );
    let seen_rest = caster.visible_between(rest)?;
    probed
        .par_iter_mut()
        .zip(&per_pair)
        .zip(&starts)
        .filter(|(((_, done), x), _)| unsettled(x, *done))
        .for_each(|(((vis, _), x), &at)| {
            for (k, i) in x.rest_rays().enumerate() {
                vis[i] = seen_rest[at + k];
            }
        });
    links.pairs_tested += tested.len() as u64;
    links.rays += (first.len() + rest.len()) as u64;
    // 3. Decide each pair, then apply the outcomes in order.
    let outcomes: Vec<Outcome> = tested
        .par_iter()
        .zip(&per_pair)
        .zip(&probed)
        .map(|((&pair, x), (vis, done))| outcome(vn, p, pair, x, vis, *done))
        .collect();
    let mut next = Vec::new();
    let mut partial = Vec::new();
    let pairs = tested.iter().zip(&per_pair).zip(&probed);
    for (((&(a, b, _), x), (vis, _)), &outcome) in pairs.zip(&outcomes) {
        let (va, vb) = (&vn[a as usize], &vn[b as usize]);
        match outcome {
            Outcome::Nothing => {}
            Outcome::Near(fraction) => {
                let l = |x: u32| Link::near(x, fraction);
                links.pairs.push((a, l(b)));
                if a != b {
                    links.pairs.push((b, l(a)));
                }
                links.near += 1;
                links.smear.add((va, vb), x.drawn, &x.r, vis, fraction);
            }
            Outcome::Far(fraction) => {
                links.pairs.push((a, Link::far(b, fraction)));
                links.pairs.push((b, Link::far(a, fraction)));
                links.far += 1;
                links.smear.add((va, vb), x.drawn, &x.r, vis, fraction);
            }
            Outcome::Exact => partial.push((a, b)),
            Outcome::Refine(n) => {
                let other = if n == a { b } else { a };
                next.extend(children(view, vn, n).map(|c| (c.min(other), c.max(other))));
            }
            Outcome::Split => split(view, vn, a, b, &mut next),
        }
    }
    // Freed where they were made (one allocation a pair), not one by one on this thread.
    (per_pair, probed).into_par_iter().for_each(drop);
    Ok((next, partial))
}

/// What [`decide`] makes of a tested pair.
#[derive(Clone, Copy)]
pub(super) enum Outcome {
    Nothing,
    /// A near-field link with this fraction.
    Near(f32),
    /// A far-field link with this fraction.
    Far(f32),
    /// Partly visible V-map leaves, for the exhaustive pass.
    Exact,
    /// Finer pairs of this node (an occluder close to it) with the other.
    Refine(u32),
    /// Finer pairs ([`split`]).
    Split,
}

/// A tested pair's outcome from its rays' visibility (`done`: its probes settled it partly
/// visible).
pub(super) fn outcome(
    vn: &[VNode],
    p: &VmapParams,
    (a, b, near): (u32, u32, bool),
    x: &PairRays,
    vis: &[bool],
    done: bool,
) -> Outcome {
    let (r, fate) = (&x.r, x.fate);
    let total = r.len();
    let (va, vb) = (&vn[a as usize], &vn[b as usize]);
    if total == 0 {
        return Outcome::Nothing; // no sample pair faces each other
    }
    if !done {
        let seen = vis.iter().filter(|&&v| v).count();
        if seen == 0 {
            // All rays blocked. With at least half the samples carrying light, a visible
            // share above about a tenth would have shown (0.9^16 < 0.2): drop the pair.
            // With fewer informative samples (nodes whose splats mostly face away), refine
            // instead, unless both are V-map leaves or the pair's form factor is below the
            // importance threshold (what a partly visible pair would keep unrefined): two
            // patches of one rough surface, whose few facing samples graze it.
            let refine = !near
                && total * 2 < p.rays as usize
                && !(va.vleaf && vb.vleaf)
                && form_factors(va, vb, r) >= p.refine_form_factor;
            return match refine {
                true => Outcome::Split,
                false => Outcome::Nothing,
            };
        }
        let (wvis, wsum) = weights(r, vis);
        let Some(fraction) = link_fraction(wvis, wsum, seen, total) else {
            return Outcome::Nothing; // the visible samples carry no weight: no light flows
        };
        if near {
            return Outcome::Near(fraction);
        }
        if seen == total || fate == Partly::Keep {
            return Outcome::Far(fraction);
        }
    }
    // Partly visible, a fate without a fraction (`Keep` is never settled by its probes).
    match fate {
        Partly::Exact => Outcome::Exact,
        Partly::Refine(n) => Outcome::Refine(n),
        Partly::Keep | Partly::Split => Outcome::Split,
    }
}

/// A tested pair's sample rays, how many sample pairs were drawn ([`pair_rays`]), what it
/// becomes if partly visible, whether its shaft is empty ([`shaft_open`]), and its samples'
/// summed weight.
pub(super) struct PairRays {
    pub(super) r: Vec<Sample>,
    pub(super) drawn: u32,
    pub(super) fate: Partly,
    pub(super) open: bool,
    pub(super) wsum: f32,
}

impl PairRays {
    /// Whether the pair casts its probe rays first and the rest only where they do not settle
    /// it ([`decide`]): a far pair whose partial fate needs no fraction.
    pub(super) fn probing(&self) -> bool {
        !self.open && self.fate != Partly::Keep && self.r.len() > PROBE_RAYS
    }

    /// The indices of the rays the pair casts first: its probes, or every ray, or none where
    /// its shaft is empty.
    pub(super) fn first_rays(&self) -> impl Iterator<Item = usize> {
        let n = self.r.len();
        let k = match (self.open, self.probing()) {
            (true, _) => 0,
            (false, true) => PROBE_RAYS.min(n),
            (false, false) => n,
        };
        // [`probes`], which for k = n is every ray.
        (0..k).map(move |i| i * n / k)
    }

    /// The rays a probing pair casts second, where its probes do not settle it.
    pub(super) fn rest_rays(&self) -> impl Iterator<Item = usize> {
        let n = self.r.len();
        (0..n).filter(move |&i| !is_probe(i, n))
    }

    /// The visibility of the pair's rays as far as its first cast tells (`seen` from its first
    /// ray on), and whether the probes settle it partly visible: some visible with
    /// light-carrying weight (which keeps the whole pair's fraction above zero, as casting
    /// every ray would find), some blocked.
    pub(super) fn after_probes(&self, seen: &[bool]) -> (Vec<bool>, bool) {
        let r = &self.r;
        if self.open {
            // Every ray open: what casting them would find.
            return (vec![true; r.len()], false);
        }
        if !self.probing() {
            return (seen[..r.len()].to_vec(), false);
        }
        let mut vis = vec![false; r.len()];
        let (mut any_seen, mut any_blocked, mut weight) = (false, false, 0.0f32);
        for (k, i) in probes(r.len()).enumerate() {
            vis[i] = seen[k];
            any_seen |= vis[i];
            any_blocked |= !vis[i];
            weight += if vis[i] { r[i].weight } else { 0.0 };
        }
        let wsum = self.wsum;
        let done = any_seen && any_blocked && wsum.is_finite() && weight / wsum > 0.0;
        (vis, done)
    }
}

/// What settles a pair without rays, besides its nodes: the nodes with an occluder close by
/// ([`crate::close`]) and the disks' boxes for shaft culling ([`shaft_open`]).
pub(crate) struct Culls {
    pub close: Vec<bool>,
    /// The disks' boxes while far pairs try their shafts: a rough scan's own noise stands
    /// inside nearly every shaft, and there the descents cost pc-vmap 2-4 % for nothing, so
    /// they are dropped once not worth trying ([`Culls::give_up_unless_worth`]; 52 bytes a
    /// node, 285 MB on the 20M hall scan). The links never depend on it, only the time.
    pub shafts: Option<DiskBoxes>,
    /// Far pairs that tried their shafts so far, and those settled.
    pub tried: u64,
    pub settled: u64,
}

impl Culls {
    /// Shafts are tried until [`SHAFT_TRIAL`] far pairs have, and then while they settle at
    /// least one in [`SHAFT_WORTH`]; once they do not, the disks' boxes go.
    pub(super) fn give_up_unless_worth(&mut self) {
        if self.tried >= SHAFT_TRIAL && self.settled * SHAFT_WORTH < self.tried {
            self.shafts = None;
        }
    }
}

/// Far pairs that try their shafts before [`Culls::give_up_unless_worth`] judges by their
/// record.
pub(super) const SHAFT_TRIAL: u64 = 20_000;
/// The least share (one in this many) of far pairs that shafts must settle to be tried on.
pub(super) const SHAFT_WORTH: u64 = 50;

/// Whether shaft culling proves every ray of `r` (one far pair's) open: no disk's box meets the
/// shaft from the box of their near ends to the box of their far ends, over the part of each
/// segment where a hit counts (pc_tree::shaft, Haines and Wallace's shaft culling). Casting
/// them would find each visible, so the pair's decision is the same without a ray (hits an end's
/// own zone ignores only make a ray more visible). docs/vmap.md, "Empty shafts".
pub(super) fn shaft_open(
    view: &OctreeView,
    shafts: &DiskBoxes,
    r: &[Sample],
    stack: &mut Vec<u32>,
) -> bool {
    if r.is_empty() {
        return false;
    }
    let (mut a, mut b) = (Aabb::EMPTY, Aabb::EMPTY);
    let (mut t_min, mut end) = (f32::INFINITY, f32::INFINITY);
    for s in r {
        // The ray starts at the near end's centre.
        let (xa, xb) = (
            s.ray.ray.origin,
            Vec3::from(view.splats[s.ends[1] as usize].position),
        );
        a.grow(xa);
        b.grow(xb);
        t_min = t_min.min(s.ray.ray.t_min);
        end = end.min((xb - xa).length() - s.ray.ray.t_max);
    }
    Shaft::new(a, b, t_min, end).is_some_and(|shaft| !shafts.any_meets(view, &shaft, stack))
}

/// A far pair's rays (`p.rays` of them, those that carry light) and whether shaft culling
/// proves them all open ([`shaft_open`]); what [`build_links`] decides a far pair on before
/// any ray is cast.
pub fn far_pair_shaft(
    view: &OctreeView,
    vn: &[VNode],
    shafts: &DiskBoxes,
    p: &VmapParams,
    (a, b): (u32, u32),
) -> (bool, Vec<Between>) {
    let mut r = Vec::new();
    pair_rays(view, vn, (a, b), false, p.rays, p, &mut r);
    let open = shaft_open(view, shafts, &r, &mut Vec::new());
    (open, r.iter().map(|x| x.ray).collect())
}

/// The exhaustive pass over partially visible pairs of V-map leaves: their fraction is the only
/// estimate the links carry, so every splat pair (up to `near_rays`) is cast, like the near field.
pub(super) fn exact_partial(
    view: &OctreeView,
    vn: &[VNode],
    p: &VmapParams,
    caster: &dyn Caster,
    partial: &[(u32, u32)],
    links: &mut Links,
) -> Result<(), GpuError> {
    {
        let per_pair: Vec<(Vec<Sample>, u32)> = partial
            .par_iter()
            .map(|&(a, b)| {
                let mut r = Vec::new();
                let drawn = pair_rays(view, vn, (a, b), true, p.rays, p, &mut r);
                (r, drawn)
            })
            .collect();
        let mut rays: Vec<Between> = Vec::new();
        rays.par_extend(
            per_pair
                .par_iter()
                .flat_map_iter(|r| r.0.iter().map(|r| r.ray)),
        );
        let visible = caster.visible_between(&rays)?;
        links.rays += rays.len() as u64;
        let starts = offsets(per_pair.iter().map(|r| r.0.len()));
        let fractions: Vec<Option<f32>> = per_pair
            .par_iter()
            .zip(&starts)
            .map(|((r, _), &at)| {
                let vis = &visible[at..at + r.len()];
                let (wvis, wsum) = weights(r, vis);
                let seen = vis.iter().filter(|&&v| v).count();
                let weighed = wvis > 0.0 && wsum > 0.0;
                link_fraction(wvis, wsum, seen, r.len()).filter(|_| weighed)
            })
            .collect();
        let each = partial.iter().zip(&per_pair).zip(&starts).zip(&fractions);
        for (((&(a, b), (r, drawn)), &at), f) in each {
            if let &Some(f) = f {
                links.pairs.push((a, Link::far(b, f)));
                links.pairs.push((b, Link::far(a, f)));
                links.far += 1;
                let (va, vb) = (&vn[a as usize], &vn[b as usize]);
                links
                    .smear
                    .add((va, vb), *drawn, r, &visible[at..at + r.len()], f);
            }
        }
        per_pair.into_par_iter().for_each(drop);
    }
    Ok(())
}

/// The summed weights of a pair's visible samples and of all its samples.
pub(super) fn weights(samples: &[Sample], visible: &[bool]) -> (f32, f32) {
    let all = samples.iter().map(|x| x.weight).sum();
    let seen = samples
        .iter()
        .zip(visible)
        .filter(|(_, &v)| v)
        .map(|(x, _)| x.weight)
        .sum();
    (seen, all)
}

/// A link's fraction from its samples: the visible share of their weights, in (0, 1]; the share
/// of rays where no sample has weight (or the weights overflowed); `None` where the visible
/// samples carry no weight at all (splats of zero area: on a 20M-point scan quantised to a
/// millimetre, coincident points share their area and some get none), which the artifact's
/// readers would refuse as a fraction of 0.
pub(super) fn link_fraction(wvis: f32, wsum: f32, seen: usize, total: usize) -> Option<f32> {
    if seen == total {
        return Some(1.0);
    }
    let by_rays = seen as f32 / total as f32;
    let f = match wsum > 0.0 && (wvis / wsum).is_finite() {
        true => (wvis / wsum).min(1.0),
        false => by_rays,
    };
    (f > 0.0).then_some(f)
}

/// The larger of the two form factors F_AB, F_BA estimated from a pair's sample weights: the
/// mean weight times the number of splat pairs over π estimates Σ A_i A_j cos cos / (π r²), the
/// area-weighted form factor between the nodes; divide by each node's area.
pub(super) fn form_factors(va: &VNode, vb: &VNode, samples: &[Sample]) -> f32 {
    if samples.is_empty() {
        return 0.0;
    }
    let mean = samples.iter().map(|s| s.weight as f64).sum::<f64>() / samples.len() as f64;
    let pairs = va.count() as f64 * vb.count() as f64;
    let total = mean * pairs / std::f64::consts::PI;
    let area = |v: &VNode| v.area.max(1e-30);
    (total / area(va)).max(total / area(vb)) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_link_fraction_lies_in_zero_one_or_there_is_no_link() {
        assert_eq!(link_fraction(3.0, 3.0, 16, 16), Some(1.0));
        assert_eq!(link_fraction(1.0, 4.0, 8, 16), Some(0.25));
        // Visible samples of zero weight (splats of zero area): no light flows, no link.
        assert_eq!(link_fraction(0.0, 4.0, 8, 16), None);
        // No weight anywhere, or weights that overflowed: the share of rays.
        assert_eq!(link_fraction(0.0, 0.0, 4, 16), Some(0.25));
        assert_eq!(
            link_fraction(f32::INFINITY, f32::INFINITY, 8, 16),
            Some(0.5)
        );
        assert_eq!(link_fraction(f32::NAN, 1.0, 8, 16), Some(0.5));
    }
}
