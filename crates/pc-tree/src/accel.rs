//! A render-time packed copy of the leaf lists for faster traversal on the CPU.
//!
//! The artifact's leaves reach their splats through the begin/end table: own splats are a
//! contiguous run of 64-byte records, referenced ones are scattered across the data pool, and a
//! record straddles two cache lines half the time. Traversal is bound by those loads (about 60
//! splat tests per primary ray). `Accel` copies, for every leaf, the intersection data of its
//! listed splats (own, then referenced, the same order as the table) into one contiguous run of
//! 48-byte records (centre, radius², normal, index, border clip): each leaf's tests then stream
//! through consecutive cache lines. Hits are
//! identical to [`OctreeView::intersect`] (same splats, same order, same arithmetic).
//! Memory: 48 bytes per listed splat (about 3 listings per splat on scans), built in parallel.

use glam::Vec3;
use pc_artifact::octree::{node, within_clip};
use rayon::prelude::*;

use crate::ray::{Hit, Ray, TraversalStats};
use crate::OctreeView;

/// One listed splat: centre, squared radius, normal, data-pool index, border clip.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Packed {
    pub position: [f32; 3],
    pub radius2: f32,
    pub normal: [f32; 3],
    pub splat: u32,
    pub clip: [f32; 4],
}

/// Packed leaf lists, indexed through the begin/end offset a leaf's node word holds.
pub struct Accel {
    packed: Vec<Packed>,
    /// For each begin/end table offset that starts a leaf: its run in `packed` (start); the run
    /// length is the leaf's own plus referenced count.
    start: Vec<u32>,
}

impl Accel {
    pub fn new(view: &OctreeView) -> Accel {
        // Leaf offsets in table order (the table lists leaves in SFC order).
        let mut offsets = Vec::new();
        let t = view.begin_end;
        let mut o = 0usize;
        while o + 2 < t.len() {
            offsets.push(o as u32);
            o += 2 + t[o + 1] as usize;
        }
        let counts: Vec<u32> = offsets
            .iter()
            .map(|&o| {
                let (r, refs) = view.leaf(node::leaf(o));
                (r.end - r.start) + refs.len() as u32
            })
            .collect();
        let mut start = vec![0u32; t.len()];
        let mut acc = 0u32;
        let mut firsts = Vec::with_capacity(offsets.len());
        for (&o, &c) in offsets.iter().zip(&counts) {
            start[o as usize] = acc;
            firsts.push(acc);
            acc += c;
        }
        let mut packed = vec![Packed::default(); acc as usize];
        // Fill each leaf's run in parallel: runs are disjoint.
        let mut runs: Vec<&mut [Packed]> = Vec::with_capacity(offsets.len());
        let mut rest = &mut packed[..];
        for &c in &counts {
            let (a, b) = rest.split_at_mut(c as usize);
            runs.push(a);
            rest = b;
        }
        runs.into_par_iter()
            .zip(offsets.par_iter())
            .for_each(|(run, &o)| {
                let (r, refs) = view.leaf(node::leaf(o));
                for (slot, i) in run.iter_mut().zip(r.chain(refs.iter().copied())) {
                    let s = &view.splats[i as usize];
                    *slot = Packed {
                        position: s.position,
                        radius2: s.radius * s.radius,
                        normal: s.normal,
                        splat: i,
                        clip: s.clip,
                    };
                }
            });
        Accel { packed, start }
    }

    /// Bytes held.
    pub fn memory(&self) -> usize {
        self.packed.len() * std::mem::size_of::<Packed>() + self.start.len() * 4
    }

    #[inline(always)]
    fn test(
        &self,
        view: &OctreeView,
        ray: &Ray,
        w: u32,
        limit: f32,
        any: bool,
        stats: &mut TraversalStats,
    ) -> Option<Hit> {
        let (r, refs) = view.leaf(w);
        let n = (r.end - r.start) as usize + refs.len();
        let s = self.start[node::ptr(w) as usize] as usize;
        stats.splat_tests += n as u64;
        let mut best: Option<Hit> = None;
        for p in &self.packed[s..s + n] {
            let nrm = Vec3::from(p.normal);
            let denom = ray.dir.dot(nrm);
            if denom.abs() < 1e-8 {
                continue;
            }
            let c = Vec3::from(p.position);
            let th = (c - ray.origin).dot(nrm) / denom;
            if th >= ray.t_min && th <= limit && best.is_none_or(|b| th < b.t) {
                let x = ray.origin + ray.dir * th;
                if (x - c).length_squared() <= p.radius2
                    && within_clip(p.position, p.normal, p.clip, x.into())
                {
                    best = Some(Hit {
                        t: th,
                        splat: p.splat,
                        leaf: w,
                    });
                    if any {
                        return best;
                    }
                }
            }
        }
        best
    }

    /// Same as [`OctreeView::intersect`].
    pub fn intersect(
        &self,
        view: &OctreeView,
        ray: &Ray,
        stats: &mut TraversalStats,
    ) -> Option<Hit> {
        crate::ray::walk_with(view, ray, stats, |w, limit, st| {
            self.test(view, ray, w, limit, false, st)
        })
    }

    /// Visibility of many rays (rayon across rays): `true` where nothing blocks the ray.
    pub fn visible(&self, view: &OctreeView, rays: &[Ray]) -> Vec<bool> {
        rays.par_iter()
            .map_init(TraversalStats::default, |st, r| !self.occluded(view, r, st))
            .collect()
    }

    /// Same as [`OctreeView::occluded`].
    pub fn occluded(&self, view: &OctreeView, ray: &Ray, stats: &mut TraversalStats) -> bool {
        crate::ray::walk_with(view, ray, stats, |w, limit, st| {
            self.test(view, ray, w, limit, true, st)
        })
        .is_some()
    }
}
