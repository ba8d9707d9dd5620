//! The k nearest neighbours of every point of a cloud (all points are queries, as the import's
//! normal, radius and outlier estimates ask), exact, and the points within a ball around each
//! of a chosen set ([`Knn::map_within`]). docs/import.md, "Neighbours".
//!
//! The points are sorted along a Morton curve and cut into runs of `RUN` consecutive
//! points; a complete binary tree over the runs holds the bounding box of each subtree
//! (a linear bounding volume hierarchy). A query first reads its own run, which on a surface
//! already holds most of its neighbours and so sets a tight bound. The runs it may still need
//! were listed once for its whole run by one walk of the tree (`Search::gather`); it reads
//! those nearer than its current k-th neighbour. Where no such list is kept (a run that would
//! reach too far, or k not below a run's size) it climbs the tree from its own run, reading
//! each sibling subtree nearer child first and skipping every box at least as far as its
//! current k-th neighbour.
//! Queries run in curve order, so consecutive queries read the same runs and boxes from the
//! cache; the runs' coordinates lie apart (structure of arrays) so that a run's distances
//! are one vector loop. The answers come back in the input order.
//!
//! What it replaced: a kiddo `ImmutableKdTree` queried in input order, 4.7 µs a query of 17
//! neighbours on a 4M-point scan (BENCHMARKS.md, "Scale").

use glam::Vec3;
use rayon::prelude::*;

/// Points per run (a leaf of the tree).
const RUN: usize = 32;
const _: () = assert!(RUN <= 64, "a run's mask is a u64");

/// Runs per parallel task at least (their queries are consecutive along the curve).
const RUNS_A_TASK: usize = 128;

/// A box `[lo, hi]`; an empty one has `lo > hi` (+∞, −∞), and no point is near it.
#[derive(Clone, Copy, Debug)]
struct Aabb {
    lo: [f32; 3],
    hi: [f32; 3],
}

const EMPTY: Aabb = Aabb {
    lo: [f32::INFINITY; 3],
    hi: [f32::NEG_INFINITY; 3],
};

impl Aabb {
    fn union(a: Aabb, b: Aabb) -> Aabb {
        Aabb {
            lo: std::array::from_fn(|k| a.lo[k].min(b.lo[k])),
            hi: std::array::from_fn(|k| a.hi[k].max(b.hi[k])),
        }
    }

    /// Whether the box holds no point (a padding leaf of the tree, or above only such).
    #[inline]
    fn is_empty(&self) -> bool {
        self.lo[0] > self.hi[0]
    }

    /// Squared distance between two boxes (0 where they meet, +∞ if either is empty).
    #[inline]
    fn dist2_box(&self, o: &Aabb) -> f32 {
        let mut d2 = 0.0f32;
        for k in 0..3 {
            let d = (self.lo[k] - o.hi[k]).max(o.lo[k] - self.hi[k]).max(0.0);
            d2 += d * d;
        }
        d2
    }

    /// Squared distance from `q` to the box (0 inside, +∞ for an empty box).
    #[inline]
    fn dist2(&self, q: [f32; 3]) -> f32 {
        self.dist2_box(&Aabb { lo: q, hi: q })
    }
}

/// The search structure over one point set ([`Knn::new`]), queried by [`Knn::map`].
pub struct Knn {
    /// Coordinates along the curve, axis by axis.
    xs: Vec<f32>,
    ys: Vec<f32>,
    zs: Vec<f32>,
    /// The input index of each place along the curve.
    index: Vec<u32>,
    /// Boxes of the complete binary tree over the runs in heap order: node 0 is the root,
    /// node `m` has children `2m + 1` and `2m + 2`, and run `r` is node `leaves − 1 + r`.
    boxes: Vec<Aabb>,
    /// Leaf slots of the complete tree (a power of two, at least the number of runs).
    leaves: usize,
}

/// The points' place along a Morton curve over their bounding cube, 21 bits an axis; ties (and
/// nothing else) keep the input order.
fn curve_order(positions: &[Vec3]) -> Vec<u32> {
    let (lo, hi) = positions
        .par_iter()
        .fold(
            || (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(a, b), &p| (a.min(p), b.max(p)),
        )
        .reduce(
            || (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(a, b), (c, d)| (a.min(c), b.max(d)),
        );
    let top = ((1u32 << 21) - 1) as f32;
    let scale = top / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let mut keys: Vec<(u64, u32)> = positions
        .par_iter()
        .enumerate()
        .map(|(i, &p)| {
            let q = ((p - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(top));
            let code = spread(q.x as u32) | spread(q.y as u32) << 1 | spread(q.z as u32) << 2;
            (code, i as u32)
        })
        .collect();
    keys.par_sort_unstable();
    keys.into_iter().map(|(_, i)| i).collect()
}

/// The low 21 bits of `x` spread to every third bit.
pub(crate) fn spread(x: u32) -> u64 {
    let mut v = u64::from(x) & 0x1f_ffff;
    v = (v | v << 32) & 0x001f_0000_0000_ffff;
    v = (v | v << 16) & 0x001f_0000_ff00_00ff;
    v = (v | v << 8) & 0x100f_00f0_0f00_f00f;
    v = (v | v << 4) & 0x10c3_0c30_c30c_30c3;
    v = (v | v << 2) & 0x1249_2492_4924_9249;
    v
}

impl Knn {
    /// The structure over `positions` (finite; up to `u32::MAX` of them, copies allowed).
    pub fn new(positions: &[Vec3]) -> Knn {
        // Indices are u32 (4 bytes a point in every list); 2³² points would not fit in memory
        // here anyway.
        assert!(
            positions.len() <= u32::MAX as usize,
            "the neighbour search takes at most u32::MAX points"
        );
        let index = curve_order(positions);
        let at = |k: usize| -> Vec<f32> {
            index
                .par_iter()
                .map(|&i| positions[i as usize][k])
                .collect()
        };
        let (xs, ys, zs) = (at(0), at(1), at(2));
        let runs = index.len().div_ceil(RUN);
        let leaves = runs.next_power_of_two();
        let mut boxes = vec![EMPTY; 2 * leaves - 1];
        boxes[leaves - 1..leaves - 1 + runs]
            .par_iter_mut()
            .enumerate()
            .for_each(|(r, b)| {
                let run = r * RUN..((r + 1) * RUN).min(index.len());
                for s in run {
                    let p = [xs[s], ys[s], zs[s]];
                    *b = Aabb::union(*b, Aabb { lo: p, hi: p });
                }
            });
        for m in (0..leaves - 1).rev() {
            boxes[m] = Aabb::union(boxes[2 * m + 1], boxes[2 * m + 2]);
        }
        Knn {
            xs,
            ys,
            zs,
            index,
            boxes,
            leaves,
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// `f(i, near)` for every point `i`, in parallel, returned in input order: `near` holds
    /// the `min(k, n − 1)` points nearest to point `i` (itself excluded) as (input index,
    /// squared distance), nearest first. Among points at the same distance the k-th place
    /// goes to whichever the search meets first, always the same one.
    pub fn map<T: Send + Sync + Copy>(
        &self,
        k: usize,
        f: impl Fn(usize, &[(u32, f32)]) -> T + Sync,
    ) -> Vec<T> {
        let n = self.len();
        let k = k.min(n.saturating_sub(1));
        let along: Vec<T> = (0..n.div_ceil(RUN))
            .into_par_iter()
            .with_min_len(RUNS_A_TASK)
            .map_init(Search::default, |search, run| {
                search.gather(self, run, k);
                let slots = run * RUN..((run + 1) * RUN).min(n);
                slots
                    .map(|slot| {
                        search.run(self, slot, k);
                        f(self.index[slot] as usize, &search.near)
                    })
                    .collect::<Vec<T>>()
            })
            .flatten_iter()
            .collect();
        self.to_input_order(&along)
    }

    /// Run `r`'s slots `lo..hi` and their squared distances from `q`, one vector loop (the
    /// lanes past `hi` of a short last run +∞).
    #[inline]
    fn run_distances(&self, r: usize, q: [f32; 3]) -> (usize, usize, [f32; RUN]) {
        let (lo, hi) = (r * RUN, ((r + 1) * RUN).min(self.len()));
        let mut d2 = [f32::INFINITY; RUN];
        for (d, s) in d2.iter_mut().zip(lo..hi) {
            let (dx, dy, dz) = (self.xs[s] - q[0], self.ys[s] - q[1], self.zs[s] - q[2]);
            *d = dx * dx + dy * dy + dz * dz;
        }
        (lo, hi, d2)
    }

    /// Values in curve order, put back in input order.
    fn to_input_order<T: Send + Sync + Copy>(&self, along: &[T]) -> Vec<T> {
        let mut place = vec![0u32; self.len()];
        for (slot, &i) in self.index.iter().enumerate() {
            place[i as usize] = slot as u32;
        }
        place.par_iter().map(|&s| along[s as usize]).collect()
    }
}

impl Knn {
    /// `f(i, inside, offsets)` for every point `i` with `reach2[i] > 0` (`reach2` in input
    /// order), in parallel, returned in input order (`None` for the others): `inside` holds
    /// every other point whose squared distance from point `i` is below `reach2[i]`, as
    /// (input index, squared distance), in no particular order, and `offsets` their positions
    /// less point `i`'s, read from the search's own copy in curve order (so a caller need not
    /// gather them from the input order). A ball holding more than `most` points is given up
    /// (`None`): a stray point's reach, sized by its far neighbours, may span the cloud. A
    /// ball's points come from the runs whose boxes it meets, listed once per run as [`Knn::map`] does, or by a walk of the tree from
    /// the root where that list would be long.
    pub fn map_within<T: Send + Sync + Copy>(
        &self,
        reach2: &[f32],
        most: usize,
        f: impl Fn(usize, &[(u32, f32)], &[[f32; 3]]) -> T + Sync,
    ) -> Vec<Option<T>> {
        assert_eq!(reach2.len(), self.len(), "one reach a point");
        let n = self.len();
        let along: Vec<Option<T>> = (0..n.div_ceil(RUN))
            .into_par_iter()
            .with_min_len(RUNS_A_TASK)
            .map_init(Search::default, |search, run| {
                let slots = run * RUN..((run + 1) * RUN).min(n);
                let reach_of = |slot: usize| reach2[self.index[slot] as usize];
                let widest = slots.clone().map(reach_of).fold(0.0f32, f32::max);
                if widest > 0.0 {
                    search.list_runs(self, run, widest, true);
                }
                slots
                    .map(|slot| {
                        let r2 = reach_of(slot);
                        let whole = r2 > 0.0 && search.ball(self, slot, r2, most);
                        whole.then(|| f(self.index[slot] as usize, &search.near, &search.offsets))
                    })
                    .collect::<Vec<_>>()
            })
            .flatten_iter()
            .collect();
        self.to_input_order(&along)
    }
}

/// Pushes internal node `m`'s two children with their squared distances from `home`, the
/// nearer on top of the stack.
fn push_children(stack: &mut Vec<(u32, f32)>, boxes: &[Aabb], m: usize, home: &Aabb) {
    let (a, b) = (2 * m + 1, 2 * m + 2);
    let (da, db) = (home.dist2_box(&boxes[a]), home.dist2_box(&boxes[b]));
    let (near, far) = if da <= db {
        ((a, da), (b, db))
    } else {
        ((b, db), (a, da))
    };
    stack.push((far.0 as u32, far.1));
    stack.push((near.0 as u32, near.1));
}

/// Runs that one run's queries may read ([`Search::gather`], [`Search::list_runs`]) beyond
/// this many are not listed: each query then searches the tree on its own.
const MAX_CANDIDATES: usize = 256;

/// A query's state, reused from query to query.
#[derive(Default)]
struct Search {
    /// The nearest found so far, (input index, squared distance), nearest first; for a ball
    /// ([`Self::ball`]), the points inside it in no order.
    near: Vec<(u32, f32)>,
    /// For a ball ([`Self::ball`]): the offsets of the points in `near` from the query.
    offsets: Vec<[f32; 3]>,
    stack: Vec<(u32, f32)>,
    /// The runs within reach of every query of the current run (its own excluded for the k
    /// nearest, included for balls), nearer first, when `listed`; not kept when there are too
    /// many or the reach is unbounded.
    list: Vec<u32>,
    listed: bool,
    /// Each query of the current run: its `k` nearest within the run, as `near` holds them
    /// (made by [`Self::gather`] on the way to the run's reach; empty where it made none).
    own: Vec<(u32, f32)>,
}

impl Search {
    /// Lists the runs that the queries of run `r` can take a neighbour from. Each query's k-th
    /// nearest within its own run bounds its search; the largest of those bounds, taken from
    /// the run's box, reaches every run that any of them needs. One walk of the tree for the
    /// run then serves all its queries, where a walk for each would repeat the same descent.
    fn gather(&mut self, t: &Knn, r: usize, k: usize) {
        self.listed = false;
        self.own.clear();
        let (lo, hi) = (r * RUN, ((r + 1) * RUN).min(t.len()));
        if k == 0 || hi - lo <= k {
            return; // a run of at most k points bounds nothing
        }
        let mut reach = 0.0f32;
        for slot in lo..hi {
            let q = [t.xs[slot], t.ys[slot], t.zs[slot]];
            // The others' squared distances with their places in the run.
            let mut d = [(f32::INFINITY, u32::MAX); RUN];
            for ((d, s), j) in d.iter_mut().zip(lo..hi).zip(0u32..) {
                let (dx, dy, dz) = (t.xs[s] - q[0], t.ys[s] - q[1], t.zs[s] - q[2]);
                *d = (dx * dx + dy * dy + dz * dz, j);
            }
            d[slot - lo] = (f32::INFINITY, u32::MAX);
            // The k nearest, nearer first and among equal distances the earlier in the run:
            // what [`Self::scan`] of the run keeps, met in run order.
            let by = |a: &(f32, u32), b: &(f32, u32)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
            let (near, kth, _) = d.select_nth_unstable_by(k - 1, by);
            reach = reach.max(kth.0);
            let mut nearest = [(0.0f32, 0u32); RUN];
            nearest[..k - 1].copy_from_slice(near);
            nearest[k - 1] = *kth;
            nearest[..k].sort_unstable_by(by);
            let index = |j: u32| t.index[lo + j as usize];
            self.own
                .extend(nearest[..k].iter().map(|&(d2, j)| (index(j), d2)));
        }
        if !reach.is_finite() {
            return; // distances past f32's range: no box prunes, each query walks
        }
        self.list_runs(t, r, reach, false);
    }

    /// Lists (nearer first) the runs whose boxes lie within squared distance `reach` of run
    /// `r`'s box, the run itself only `with_own`, and sets `listed`; leaves it unset where
    /// they would pass [`MAX_CANDIDATES`].
    fn list_runs(&mut self, t: &Knn, r: usize, reach: f32, with_own: bool) {
        self.listed = false;
        let own = t.leaves - 1 + r;
        let home = t.boxes[own];
        self.list.clear();
        self.stack.clear();
        self.stack.push((0, home.dist2_box(&t.boxes[0])));
        while let Some((m, d2)) = self.stack.pop() {
            if d2 >= reach {
                continue;
            }
            let m = m as usize;
            if m >= t.leaves - 1 {
                if with_own || m != own {
                    if self.list.len() == MAX_CANDIDATES {
                        return;
                    }
                    self.list.push((m + 1 - t.leaves) as u32);
                }
                continue;
            }
            push_children(&mut self.stack, &t.boxes, m, &home);
        }
        self.listed = true;
    }

    /// Every point but the one at `slot` nearer than squared distance `reach` into
    /// `self.near` and `self.offsets`: from the listed runs ([`Self::list_runs`], own run
    /// included), or a walk of the tree from the root. False, the lists left partial, once
    /// they pass `most` points.
    fn ball(&mut self, t: &Knn, slot: usize, reach: f32, most: usize) -> bool {
        self.near.clear();
        self.offsets.clear();
        let q = [t.xs[slot], t.ys[slot], t.zs[slot]];
        if self.listed {
            for c in 0..self.list.len() {
                let r = self.list[c] as usize;
                if t.boxes[t.leaves - 1 + r].dist2(q) < reach {
                    self.collect(t, r, slot, q, reach);
                    if self.near.len() > most {
                        return false;
                    }
                }
            }
            return true;
        }
        self.stack.clear();
        self.stack.push((0, t.boxes[0].dist2(q)));
        while let Some((m, d2)) = self.stack.pop() {
            if d2 >= reach {
                continue;
            }
            let m = m as usize;
            if m >= t.leaves - 1 {
                self.collect(t, m + 1 - t.leaves, slot, q, reach);
                if self.near.len() > most {
                    return false;
                }
                continue;
            }
            for c in [2 * m + 1, 2 * m + 2] {
                self.stack.push((c as u32, t.boxes[c].dist2(q)));
            }
        }
        true
    }

    /// Appends run `r`'s points (but `skip`) nearer to `q` than squared distance `reach`.
    fn collect(&mut self, t: &Knn, r: usize, skip: usize, q: [f32; 3], reach: f32) {
        let (lo, hi, d2) = t.run_distances(r, q);
        let mut mask = d2
            .iter()
            .enumerate()
            .fold(0u64, |m, (j, &d)| m | u64::from(d < reach) << j);
        if (lo..hi).contains(&skip) {
            mask &= !(1u64 << (skip - lo));
        }
        while mask != 0 {
            let j = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let s = lo + j;
            self.near.push((t.index[s], d2[j]));
            self.offsets
                .push([t.xs[s] - q[0], t.ys[s] - q[1], t.zs[s] - q[2]]);
        }
    }

    /// The `k` nearest of the point at `slot` (along the curve) into `self.near`: its own run
    /// first, which on a surface holds most of them, then the runs [`Self::gather`] listed
    /// (or, without a list, the tree) that lie nearer than the k-th found so far.
    fn run(&mut self, t: &Knn, slot: usize, k: usize) {
        self.near.clear();
        if k == 0 {
            return;
        }
        let q = [t.xs[slot], t.ys[slot], t.zs[slot]];
        let own = slot / RUN;
        match self.own.is_empty() {
            // Its own run's k nearest, as the run's gather found them.
            false => {
                let at = (slot - own * RUN) * k;
                self.near.extend_from_slice(&self.own[at..at + k]);
            }
            true => self.scan(t, own, slot, q, k),
        }
        if self.listed {
            for c in 0..self.list.len() {
                let r = self.list[c] as usize;
                if t.boxes[t.leaves - 1 + r].dist2(q) < self.bound(k) {
                    self.scan(t, r, slot, q, k);
                }
            }
            return;
        }
        // Up from the own run: at each ancestor, the other child's subtree.
        let mut m = t.leaves - 1 + own;
        while m > 0 {
            let other = if m % 2 == 1 { m + 1 } else { m - 1 };
            self.descend(t, other, slot, q, k);
            m = (m - 1) / 2;
        }
    }

    /// Offers the points of the subtree at node `top` nearer than the k-th found, nearer boxes
    /// first.
    fn descend(&mut self, t: &Knn, top: usize, slot: usize, q: [f32; 3], k: usize) {
        self.stack.clear();
        self.stack.push((top as u32, t.boxes[top].dist2(q)));
        while let Some((m, d2)) = self.stack.pop() {
            let m = m as usize;
            // Once k are found, the bound prunes (an empty box is +∞ away); before, only
            // emptiness does.
            let pruned = match self.near.len() == k {
                true => d2 >= self.bound(k),
                false => t.boxes[m].is_empty(),
            };
            if pruned {
                continue;
            }
            if m >= t.leaves - 1 {
                self.scan(t, m + 1 - t.leaves, slot, q, k);
                continue;
            }
            push_children(&mut self.stack, &t.boxes, m, &Aabb { lo: q, hi: q });
        }
    }

    /// The k-th distance found, or +∞ while fewer than k are found: once k are found, a box or
    /// point at least this far cannot enter.
    #[inline]
    fn bound(&self, k: usize) -> f32 {
        if self.near.len() < k {
            f32::INFINITY
        } else {
            self.near[k - 1].1
        }
    }

    /// Offers run `r`'s points (but `skip`, the query itself) to the nearest `k` of `q`.
    fn scan(&mut self, t: &Knn, r: usize, skip: usize, q: [f32; 3], k: usize) {
        let (lo, hi, d2) = t.run_distances(r, q);
        // The points that may enter as a mask (one vector compare): a run far from the query
        // costs no branch a point. Until k are found every point may (even one whose squared
        // distance overflows to +∞).
        let mut mask = if self.near.len() < k {
            u64::MAX >> (64 - (hi - lo))
        } else {
            // Padding lanes are +∞, never below a bound.
            let bound = self.bound(k);
            d2.iter()
                .enumerate()
                .fold(0u64, |m, (j, &d)| m | u64::from(d < bound) << j)
        };
        if (lo..hi).contains(&skip) {
            mask &= !(1u64 << (skip - lo)); // the query itself
        }
        while mask != 0 {
            let j = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            if self.near.len() < k || d2[j] < self.bound(k) {
                self.insert((t.index[lo + j], d2[j]), k);
            }
        }
    }

    /// Inserts `c` (nearer than the k-th) in distance order, after any at the same distance,
    /// dropping the k-th.
    #[inline]
    fn insert(&mut self, c: (u32, f32), k: usize) {
        if self.near.len() == k {
            self.near.pop();
        }
        self.near.push(c);
        let mut at = self.near.len() - 1;
        while at > 0 && self.near[at - 1].1 > c.1 {
            self.near[at] = self.near[at - 1];
            at -= 1;
        }
        self.near[at] = c;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Every point's k nearest by brute force: (index, d2) sorted by distance.
    fn brute(p: &[Vec3], k: usize) -> Vec<Vec<(u32, f32)>> {
        (0..p.len())
            .map(|i| {
                let mut all: Vec<(u32, f32)> = (0..p.len())
                    .filter(|&j| j != i)
                    .map(|j| {
                        let d = p[j] - p[i];
                        (j as u32, d.x * d.x + d.y * d.y + d.z * d.z)
                    })
                    .collect();
                if all.len() > k && k > 0 {
                    all.select_nth_unstable_by(k - 1, |a, b| a.1.total_cmp(&b.1));
                }
                all.truncate(k);
                all.sort_by(|a, b| a.1.total_cmp(&b.1));
                all
            })
            .collect()
    }

    /// The search's answers have brute force's distances, and each named neighbour is at its
    /// stated distance (ties may name different points).
    fn check(p: &[Vec3], k: usize) {
        let knn = Knn::new(p);
        let got: Vec<Vec<(u32, f32)>> = {
            let rows = knn.map(k, |i, near| {
                let mut row = [(u32::MAX, 0.0f32); 48];
                row[..near.len()].copy_from_slice(near);
                (i, near.len(), row)
            });
            rows.into_iter()
                .enumerate()
                .map(|(i, (j, len, row))| {
                    assert_eq!(i, j, "answers come back in input order");
                    row[..len].to_vec()
                })
                .collect()
        };
        for (i, (g, b)) in got.iter().zip(brute(p, k)).enumerate() {
            let gd: Vec<f32> = g.iter().map(|x| x.1).collect();
            let bd: Vec<f32> = b.iter().map(|x| x.1).collect();
            assert_eq!(gd, bd, "point {i}: distances");
            for &(j, d) in g {
                assert_ne!(j as usize, i, "point {i} is its own neighbour");
                let e = p[j as usize] - p[i];
                assert_eq!(d, e.x * e.x + e.y * e.y + e.z * e.z);
            }
            let mut ids: Vec<u32> = g.iter().map(|x| x.0).collect();
            ids.sort_unstable();
            ids.dedup();
            assert_eq!(ids.len(), g.len(), "point {i}: a neighbour twice");
        }
    }

    /// A point uniform in the cube `[0, side)³`.
    fn in_cube(rng: &mut impl Rng, side: f32) -> Vec3 {
        Vec3::new(rng.random(), rng.random(), rng.random()) * side
    }

    #[test]
    fn random_points_match_brute_force() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let p: Vec<Vec3> = (0..3000).map(|_| in_cube(&mut rng, 1.0)).collect();
        [1, 8, 17, 24].into_iter().for_each(|k| check(&p, k));
    }

    #[test]
    fn a_surface_with_clusters_and_outliers_matches_brute_force() {
        // A wavy sheet, a dense blob, far outliers: runs of very different sizes.
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let mut p: Vec<Vec3> = (0..2500)
            .map(|_| {
                let (u, v): (f32, f32) = (rng.random(), rng.random());
                Vec3::new(u * 4.0, v * 2.0, 0.1 * (u * 9.0).sin())
            })
            .collect();
        p.extend((0..400).map(|_| in_cube(&mut rng, 1e-3)));
        p.extend((0..20).map(|_| in_cube(&mut rng, 1e3)));
        check(&p, 16);
    }

    #[test]
    fn grids_and_copies_with_tied_distances_match_brute_force() {
        // An exact grid ties every distance; copies put many points at distance zero.
        let mut p: Vec<Vec3> = (0..20 * 20 * 3)
            .map(|i| Vec3::new((i % 20) as f32, (i / 20 % 20) as f32, (i / 400) as f32))
            .collect();
        p.extend(std::iter::repeat_n(Vec3::new(3.0, 4.0, 1.0), 100));
        [4, 8, 17].into_iter().for_each(|k| check(&p, k));
    }

    #[test]
    fn many_runs_outliers_and_large_k_match_brute_force() {
        // Over 256 runs with far outliers among them: a run holding an outlier reaches too many
        // runs to list, and k above a run's size bounds nothing; both search the tree per
        // query.
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let mut p: Vec<Vec3> = (0..9000)
            .map(|i| {
                let (x, y) = ((i % 100) as f32, (i / 100) as f32);
                Vec3::new(
                    x + 0.3 * rng.random::<f32>(),
                    y + 0.3 * rng.random::<f32>(),
                    0.0,
                )
            })
            .collect();
        for i in (0..9000).step_by(300) {
            p[i] = in_cube(&mut rng, 500.0);
        }
        [16, 40].into_iter().for_each(|k| check(&p, k));
    }

    #[test]
    fn distances_past_the_f32_range_still_count() {
        // Squared distances that overflow to +∞ are still distances: every point gets its
        // min(k, n − 1) neighbours.
        let mut p: Vec<Vec3> = (0..40).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        p.extend([Vec3::new(3e19, 0.0, 0.0), Vec3::new(0.0, -3e19, 1.0)]);
        [1, 4, 41].into_iter().for_each(|k| check(&p, k));
        let two = [Vec3::ZERO, Vec3::new(2e19, 0.0, 0.0)];
        let got = Knn::new(&two).map(1, |_, near| near[0]);
        assert_eq!(got, vec![(1, f32::INFINITY), (0, f32::INFINITY)]);
    }

    #[test]
    fn small_sets_give_every_other_point() {
        for n in 0..5usize {
            let p: Vec<Vec3> = (0..n).map(|i| Vec3::splat(i as f32)).collect();
            let counts = Knn::new(&p).map(8, |_, near| near.len());
            assert_eq!(counts, vec![n.saturating_sub(1); n]);
        }
    }
    #[test]
    fn balls_match_brute_force() {
        // A sheet with far strays (their runs reach too far to list, so those queries walk the
        // tree), reaches of every size, and points asked for nothing.
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let mut p: Vec<Vec3> = (0..9000)
            .map(|i| {
                Vec3::new(
                    (i % 100) as f32,
                    (i / 100) as f32,
                    rng.random::<f32>() * 0.2,
                )
            })
            .collect();
        for i in (0..9000).step_by(450) {
            p[i] = in_cube(&mut rng, 800.0);
        }
        let reach2: Vec<f32> = (0..p.len())
            .map(|i| match i % 5 {
                0 => 0.0,
                1 => 1.5,
                2 => 9.0,
                3 => 40.0,
                _ => rng.random::<f32>() * 4.0,
            })
            .collect();
        let knn = Knn::new(&p);
        let got = knn.map_within(&reach2, usize::MAX, |i, inside, offsets| {
            for (&(j, _), o) in inside.iter().zip(offsets) {
                assert_eq!(Vec3::from(*o), p[j as usize] - p[i]);
            }
            let mut v = inside.to_vec();
            v.sort_by_key(|&(j, _)| j);
            (
                v.len(),
                v.iter()
                    .map(|&(j, d)| j as u64 + d.to_bits() as u64)
                    .sum::<u64>(),
            )
        });
        for (i, g) in got.iter().enumerate() {
            let want = (reach2[i] > 0.0).then(|| {
                let v: Vec<(u32, f32)> = (0..p.len())
                    .filter(|&j| j != i)
                    .map(|j| {
                        let e = p[j] - p[i];
                        (j as u32, e.x * e.x + e.y * e.y + e.z * e.z)
                    })
                    .filter(|&(_, d)| d < reach2[i])
                    .collect();
                (
                    v.len(),
                    v.iter()
                        .map(|&(j, d)| j as u64 + d.to_bits() as u64)
                        .sum::<u64>(),
                )
            });
            assert_eq!(*g, want, "point {i}, reach² {}", reach2[i]);
        }
        // A ball of more than `most` points is given up; one of at most `most` is not.
        let counts = knn.map_within(&reach2, 20, |_, inside, _| inside.len());
        for (c, g) in counts.iter().zip(&got) {
            match g {
                Some((n, _)) if *n <= 20 => assert_eq!(*c, Some(*n)),
                _ => assert_eq!(*c, None),
            }
        }
    }
}
