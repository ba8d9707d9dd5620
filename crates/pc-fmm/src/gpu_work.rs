//! How the GPU kernels of [`crate::gpu`] divide one product's work between invocations
//! (docs/fmm.md, "On the GPU").
//!
//! The plan gives each receiver (a node for M2L/P2L, a splat for M2P/P2P) its tasks, and their
//! number varies by orders of magnitude: at 1M splats most splats sum a few hundred source
//! splats point to point, a few sum tens of thousands. One invocation per receiver would leave
//! a warp (or an llvmpipe lane group) waiting on its longest lane, and on llvmpipe it ends the
//! shader after 65535 loop iterations per invocation group. So each receiver's task list is cut
//! into **work items** of bounded cost, in order:
//! - a splat's items ([`SplatItem`]): first the P2P tasks to its whole leaf (listed once, under
//!   the leaf's first splat), then its own M2P and P2P tasks; the first item also does the L2P.
//!   Each item writes a partial sum; the `gather` kernel adds a splat's partials in order.
//! - a node's items ([`NodeItem`]): runs of its M2L-then-P2L tasks. The first writes the node's
//!   own local expansion, the others spare expansions (a buffer of their own) that
//!   `m2l_gather` adds to it in order.
//!
//! A receiver with a single item is computed exactly as the CPU twin computes it; one cut into
//! several sums the same terms in parts (a difference of f32 rounding).

use crate::error::FmmError;
use crate::plan::{NodeTask, Plan, POINT};
use crate::tree::{Points, Tree};

/// A leaf task as its receiving splat sees it (WGSL `SplatTask`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SplatTask {
    pub src_lo: u32,
    pub src_hi: u32,
    pub fraction: f32,
    pub kind: u32,
}

pub const KIND_M2P: u32 = 0;
pub const KIND_P2P: u32 = 1;
pub const KIND_P2P_RANGE: u32 = 2;

/// Cost of one source splat summed point to point: the unit of a splat item's budget.
const P2P_COST: u64 = 1;
/// Cost of one M2P task (the kernel's coefficients and a dot product per coefficient: about
/// 50 exact pairs at order 3, `plan::DIRECT_ONE_SIDED`), and of one task an item skips (a
/// non-range task of the leaf's first splat, seen from another splat).
const M2P_COST: u64 = 32;
const SKIP_COST: u64 = 1;
/// Budget of one splat item. A task is never cut, so an item costs at most this plus its last
/// task's (a P2P task's sources are a few leaves').
pub const SPLAT_ITEM_BUDGET: u64 = 1024;
/// Cost of an M2L and a P2L task, and the budget of one node item (128 M2L tasks: at 1M
/// splats a node receives 58 on average).
const M2L_COST: u64 = 4;
const P2L_COST: u64 = 1;
pub const NODE_ITEM_BUDGET: u64 = 512;
/// Flag of a [`NodeItem`]'s `dst` that is a spare expansion.
pub const SPARE: u32 = 1 << 31;

/// Flags of a [`SplatItem`].
pub const ITEM_L2P: u32 = 1;
/// The item's tasks are the leaf's first splat's: only its [`KIND_P2P_RANGE`] tasks count.
pub const ITEM_RANGE: u32 = 2;

/// Part of one splat's leaf phase: tasks `lo..hi` of the splat tasks (WGSL `SplatItem`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SplatItem {
    pub splat: u32,
    pub lo: u32,
    pub hi: u32,
    pub flags: u32,
}

/// Part of one compact node's M2L/P2L work: node tasks `lo..hi`, the M2L ones below `split`,
/// accumulated into expansion `dst`: the node's own (its compact index), or spare expansion
/// `dst & !SPARE` (WGSL `NodeItem`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct NodeItem {
    pub node: u32,
    pub lo: u32,
    pub hi: u32,
    pub split: u32,
    pub dst: u32,
}

/// A node whose tasks were cut: spare expansions `lo..hi` add to its own (WGSL `NodeGather`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct NodeGather {
    pub node: u32,
    pub lo: u32,
    pub hi: u32,
}

/// The plan's leaf tasks regrouped by receiving splat: CSR offsets over splats and the tasks.
/// Each splat's block keeps the plan's order. A P2P task to a whole leaf is listed once, under
/// the leaf's first splat, as [`KIND_P2P_RANGE`]; a P2P task to part of a leaf (the plan merges
/// tasks, [`crate::plan`]) once under each of its splats, as [`KIND_P2P`]; every other task has
/// one receiving splat. Errs on a receiver range outside its leaf.
pub fn splat_tasks(
    tree: &Tree,
    points: &Points,
    plan: &Plan,
) -> Result<(Vec<u32>, Vec<SplatTask>), FmmError> {
    let n = points.pos.len();
    let mut count = vec![0u32; n + 1];
    for (li, w) in plan.leaf_offsets.windows(2).enumerate() {
        let leaf = tree.leaves[li] as usize;
        let (lo, hi) = (tree.lo[leaf], tree.hi[leaf]);
        for t in &plan.leaf_tasks[w[0] as usize..w[1] as usize] {
            let end = if t.is_m2p() { t.recv_lo + 1 } else { t.recv_hi };
            if t.recv_lo < lo || end > hi || end <= t.recv_lo {
                return Err(FmmError::GpuPlan(format!(
                    "a leaf task to splats {}..{end} of the leaf of splats {lo}..{hi}: the receivers must lie in the leaf",
                    t.recv_lo
                )));
            }
            if t.is_m2p() || (t.recv_lo, t.recv_hi) == (lo, hi) {
                count[t.recv_lo as usize + 1] += 1;
            } else {
                for i in t.recv_lo..t.recv_hi {
                    count[i as usize + 1] += 1;
                }
            }
        }
    }
    for i in 0..n {
        count[i + 1] += count[i];
    }
    let offsets = count.clone();
    let mut next = count;
    let mut tasks = vec![SplatTask::default(); offsets[n] as usize];
    // A stable scatter keeps each splat's block in the plan's order.
    for (li, w) in plan.leaf_offsets.windows(2).enumerate() {
        let leaf = tree.leaves[li] as usize;
        let (lo, hi) = (tree.lo[leaf], tree.hi[leaf]);
        for t in &plan.leaf_tasks[w[0] as usize..w[1] as usize] {
            let (kind, receivers) = if t.is_m2p() {
                (KIND_M2P, t.recv_lo..t.recv_lo + 1)
            } else if (t.recv_lo, t.recv_hi) == (lo, hi) && hi - lo > 1 {
                (KIND_P2P_RANGE, t.recv_lo..t.recv_lo + 1)
            } else {
                (KIND_P2P, t.recv_lo..t.recv_hi)
            };
            for i in receivers {
                let at = &mut next[i as usize];
                tasks[*at as usize] = SplatTask {
                    src_lo: t.src_lo,
                    src_hi: t.src_hi,
                    fraction: t.fraction,
                    kind,
                };
                *at += 1;
            }
        }
    }
    Ok((offsets, tasks))
}

/// Per compact node, the index of its first P2L task (its M2L tasks come first). Errs when a
/// node's tasks are not in that order.
pub fn node_split(plan: &Plan) -> Result<Vec<u32>, FmmError> {
    plan.node_offsets
        .windows(2)
        .map(|w| {
            let tasks: &[NodeTask] = &plan.node_tasks[w[0] as usize..w[1] as usize];
            let m2l = tasks.iter().take_while(|t| t.src & POINT == 0).count();
            if tasks[m2l..].iter().any(|t| t.src & POINT == 0) {
                return Err(FmmError::GpuPlan(
                    "a node's M2L tasks must precede its P2L tasks".to_string(),
                ));
            }
            Ok(w[0] + m2l as u32)
        })
        .collect()
}

/// Cuts `tasks` (costs in order) into runs of at most `budget` (a task over it alone), calling
/// `emit(lo, hi)` per run; an empty list makes one empty run when `always`.
fn cut(
    lo: u32,
    hi: u32,
    budget: u64,
    always: bool,
    cost: impl Fn(u32) -> u64,
    mut emit: impl FnMut(u32, u32),
) {
    if lo == hi {
        if always {
            emit(lo, hi);
        }
        return;
    }
    let (mut start, mut acc) = (lo, 0u64);
    for t in lo..hi {
        let c = cost(t);
        if acc > 0 && acc + c > budget {
            emit(start, t);
            (start, acc) = (t, 0);
        }
        acc += c;
    }
    emit(start, hi);
}

/// One dispatch over items `first..first + count` whose tasks lie in records `base..end` of
/// their array: the kernel binds that window of it (a device binds at most so many bytes at
/// once: 128 MiB on llvmpipe, which the 1M-splat plan's splat tasks exceed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    pub first: u32,
    pub count: u32,
    pub base: u32,
    pub end: u32,
}

/// Cuts consecutive items (the task spans `lo..hi` of each, in order, over an array of `total`
/// records) into windows of at most `max` records from a base that is a multiple of `step`.
/// An item without tasks joins any window. Errs when one item alone spans more than `max`.
pub fn windows(
    spans: impl Iterator<Item = (u32, u32)>,
    total: u32,
    max: u32,
    step: u32,
) -> Result<Vec<Window>, FmmError> {
    let step = step.max(1);
    let down = |x: u32| x - x % step;
    let mut out: Vec<Window> = Vec::new();
    // The open window: first item, items, and its tasks' span (lo > hi while it has none).
    let (mut first, mut count, mut lo, mut hi) = (0u32, 0u32, u32::MAX, 0u32);
    let mut close = |first: u32, count: u32, lo: u32, hi: u32| {
        if count > 0 {
            let (base, end) = if lo < hi {
                (down(lo), hi)
            } else {
                (0, total.min(1))
            };
            out.push(Window {
                first,
                count,
                base,
                end,
            });
        }
    };
    for (k, (a, b)) in spans.enumerate() {
        let k = k as u32;
        if a < b {
            if b - down(a) > max {
                return Err(FmmError::GpuPlan(format!(
                    "one work item spans {} task records, over the {max} one binding holds",
                    b - down(a)
                )));
            }
            let (nlo, nhi) = (lo.min(a), hi.max(b));
            if nhi - down(nlo) > max {
                close(first, count, lo, hi);
                (first, count, lo, hi) = (k, 0, a, b);
            } else {
                (lo, hi) = (nlo, nhi);
            }
        }
        count += 1;
    }
    close(first, count, lo, hi);
    Ok(out)
}

/// The work items of one product on the GPU.
#[derive(Clone, Debug, Default)]
pub struct Work {
    /// [`splat_tasks`].
    pub splat_offsets: Vec<u32>,
    pub splat_tasks: Vec<SplatTask>,
    /// Splat items, each splat's contiguous and in order; CSR offsets per splat (an inactive
    /// splat has none: its output is zero).
    pub splat_items: Vec<SplatItem>,
    pub splat_item_offsets: Vec<u32>,
    /// Node items (at least one per compact node, its first writing the node's own expansion)
    /// and the nodes with spare expansions to add.
    pub node_items: Vec<NodeItem>,
    pub node_gathers: Vec<NodeGather>,
    /// Spare expansions.
    pub spares: u32,
}

impl Work {
    pub fn new(tree: &Tree, points: &Points, plan: &Plan) -> Result<Work, FmmError> {
        let (splat_offsets, splat_tasks) = splat_tasks(tree, points, plan)?;
        let split = node_split(plan)?;
        let n = points.pos.len();
        let p2p = |t: &SplatTask| (t.src_hi - t.src_lo) as u64 * P2P_COST;
        let mut splat_items = Vec::with_capacity(n + n / 8);
        let mut splat_item_offsets = Vec::with_capacity(n + 1);
        splat_item_offsets.push(0u32);
        for i in 0..n {
            if points.active[i] {
                let first = splat_items.len();
                let leaf_lo = tree.lo[points.leaf[i] as usize] as usize;
                if i != leaf_lo {
                    let (lo, hi) = (splat_offsets[leaf_lo], splat_offsets[leaf_lo + 1]);
                    let range = |t: u32| {
                        let task = &splat_tasks[t as usize];
                        if task.kind == KIND_P2P_RANGE {
                            p2p(task)
                        } else {
                            SKIP_COST
                        }
                    };
                    // Only ranges with a task to the whole leaf make items.
                    if splat_tasks[lo as usize..hi as usize]
                        .iter()
                        .any(|t| t.kind == KIND_P2P_RANGE)
                    {
                        cut(lo, hi, SPLAT_ITEM_BUDGET, false, range, |lo, hi| {
                            splat_items.push(SplatItem {
                                splat: i as u32,
                                lo,
                                hi,
                                flags: ITEM_RANGE,
                            })
                        });
                    }
                }
                let own = |t: u32| {
                    let task = &splat_tasks[t as usize];
                    if task.kind == KIND_M2P {
                        M2P_COST
                    } else {
                        p2p(task)
                    }
                };
                let (lo, hi) = (splat_offsets[i], splat_offsets[i + 1]);
                let always = splat_items.len() == first;
                cut(lo, hi, SPLAT_ITEM_BUDGET, always, own, |lo, hi| {
                    splat_items.push(SplatItem {
                        splat: i as u32,
                        lo,
                        hi,
                        flags: 0,
                    })
                });
                splat_items[first].flags |= ITEM_L2P;
            }
            splat_item_offsets.push(splat_items.len() as u32);
        }

        let nodes = tree.nodes.len();
        let mut node_items = Vec::with_capacity(nodes + nodes / 16);
        let mut node_gathers = Vec::new();
        let mut spares = 0u32;
        for (c, &s) in split.iter().enumerate().take(nodes) {
            let (lo, hi) = (plan.node_offsets[c], plan.node_offsets[c + 1]);
            let cost = |t: u32| if t < s { M2L_COST } else { P2L_COST };
            let first = node_items.len();
            cut(lo, hi, NODE_ITEM_BUDGET, true, cost, |lo, hi| {
                node_items.push(NodeItem {
                    node: c as u32,
                    lo,
                    hi,
                    split: s.clamp(lo, hi),
                    dst: c as u32,
                })
            });
            let extra = (node_items.len() - first - 1) as u32;
            if extra > 0 {
                let at = spares;
                for (k, item) in node_items[first + 1..].iter_mut().enumerate() {
                    item.dst = SPARE | (at + k as u32);
                }
                node_gathers.push(NodeGather {
                    node: c as u32,
                    lo: at,
                    hi: at + extra,
                });
                spares += extra;
            }
        }
        Ok(Work {
            splat_offsets,
            splat_tasks,
            splat_items,
            splat_item_offsets,
            node_items,
            node_gathers,
            spares,
        })
    }

    /// Upper bound of the loop iterations of one llvmpipe invocation group of `lanes` invocations
    /// (consecutive lanes run in lockstep: a loop runs as often as its longest lane, a nested
    /// loop at most the sum of the lanes) per kernel whose loops grow with the data, as
    /// (kernel, bound), in dispatch order.
    pub fn loop_bounds(&self, tree: &Tree, lanes: usize) -> Vec<(&'static str, u64)> {
        let group_max = |len: usize, f: &dyn Fn(usize) -> u64| {
            (0..len)
                .step_by(lanes)
                .map(|g| (g..(g + lanes).min(len)).map(f).max().unwrap_or(0))
                .max()
                .unwrap_or(0)
        };
        let leaves = &tree.leaves;
        let p2m = group_max(leaves.len(), &|k| {
            let l = leaves[k] as usize;
            (tree.hi[l] - tree.lo[l]) as u64
        });
        let items = &self.node_items;
        let m2l = group_max(items.len(), &|k| (items[k].split - items[k].lo) as u64)
            + group_max(items.len(), &|k| (items[k].hi - items[k].split) as u64);
        let gathers = &self.node_gathers;
        let m2l_gather = group_max(gathers.len(), &|k| (gathers[k].hi - gathers[k].lo) as u64);
        let si = &self.splat_items;
        let tasks = &self.splat_tasks;
        let mut splat = 0u64;
        for g in (0..si.len()).step_by(lanes) {
            let group = &si[g..(g + lanes).min(si.len())];
            let outer = group.iter().map(|it| (it.hi - it.lo) as u64).max();
            let inner: u64 = group
                .iter()
                .map(|it| {
                    tasks[it.lo as usize..it.hi as usize]
                        .iter()
                        .filter(|t| {
                            if it.flags & ITEM_RANGE != 0 {
                                t.kind == KIND_P2P_RANGE
                            } else {
                                t.kind != KIND_M2P
                            }
                        })
                        .map(|t| (t.src_hi - t.src_lo) as u64)
                        .sum::<u64>()
                })
                .sum();
            splat = splat.max(outer.unwrap_or(0) + inner);
        }
        let offs = &self.splat_item_offsets;
        let gather = group_max(offs.len() - 1, &|i| (offs[i + 1] - offs[i]) as u64);
        vec![
            ("p2m", p2m),
            ("m2l", m2l),
            ("m2l_gather", m2l_gather),
            ("splat", splat),
            ("gather", gather),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::LeafTask;

    /// A leaf task of fraction 1 (an M2P when `recv_hi` is 0).
    fn task(recv_lo: u32, recv_hi: u32, src_lo: u32, src_hi: u32) -> LeafTask {
        LeafTask {
            recv_lo,
            recv_hi,
            src_lo,
            src_hi,
            fraction: 1.0,
        }
    }

    #[test]
    fn splat_tasks_keep_each_receivers_order() {
        // One leaf of splats 0..3 in slot 0.
        let tree = Tree {
            slots: 1,
            lo: vec![0],
            hi: vec![3],
            leaves: vec![0],
            ..Default::default()
        };
        let points = Points {
            pos: vec![[0.0; 3]; 3],
            leaf: vec![0; 3],
            ..Default::default()
        };
        let plan = Plan {
            leaf_offsets: vec![0, 5],
            leaf_tasks: vec![
                task(0, 3, 5, 9),
                task(0, 1, 12, 13),
                task(2, 0, 7, 0),
                task(2, 3, 20, 21),
                // Part of the leaf (a merged task): under each of its splats.
                task(1, 3, 30, 34),
            ],
            ..Default::default()
        };
        let (offsets, tasks) = splat_tasks(&tree, &points, &plan).unwrap();
        assert_eq!(offsets, vec![0, 2, 3, 6]);
        let kinds: Vec<(u32, u32)> = tasks.iter().map(|t| (t.kind, t.src_lo)).collect();
        assert_eq!(
            kinds,
            vec![
                (KIND_P2P_RANGE, 5),
                (KIND_P2P, 12),
                (KIND_P2P, 30),
                (KIND_M2P, 7),
                (KIND_P2P, 20),
                (KIND_P2P, 30)
            ]
        );
        let bad = Plan {
            leaf_offsets: vec![0, 1],
            leaf_tasks: vec![task(1, 4, 5, 9)],
            ..Default::default()
        };
        assert!(splat_tasks(&tree, &points, &bad).is_err());
    }

    #[test]
    fn windows_hold_their_items_tasks_from_aligned_bases() {
        let spans = [(0, 3), (3, 3), (3, 9), (2, 4), (9, 14), (14, 14), (15, 16)];
        let w = windows(spans.into_iter(), 16, 8, 2).unwrap();
        let want = [
            Window {
                first: 0,
                count: 2,
                base: 0,
                end: 3,
            },
            // (3, 9) from base 2, and (2, 4) inside it.
            Window {
                first: 2,
                count: 2,
                base: 2,
                end: 9,
            },
            Window {
                first: 4,
                count: 3,
                base: 8,
                end: 16,
            },
        ];
        assert_eq!(w, want);
        // Every item's tasks inside its window, within the budget.
        for win in &w {
            assert!(win.base % 2 == 0 && win.end - win.base <= 8);
            for &(a, b) in &spans[win.first as usize..(win.first + win.count) as usize] {
                assert!(a == b || (win.base <= a && b <= win.end));
            }
        }
        // Items without tasks only: one window of the first record.
        assert_eq!(
            windows([(5, 5), (5, 5)].into_iter(), 9, 8, 4).unwrap(),
            vec![Window {
                first: 0,
                count: 2,
                base: 0,
                end: 1
            }]
        );
        assert!(windows([(1, 9)].into_iter(), 9, 8, 1).is_ok());
        assert!(windows([(1, 9)].into_iter(), 9, 8, 2).is_err());
        assert_eq!(windows(std::iter::empty(), 0, 8, 1).unwrap(), vec![]);
    }

    #[test]
    fn runs_stay_within_the_budget_unless_one_task_exceeds_it() {
        let costs = [3u64, 4, 2, 9, 1, 1, 1];
        let mut runs = Vec::new();
        cut(
            10,
            17,
            6,
            false,
            |t| costs[t as usize - 10],
            |lo, hi| runs.push((lo, hi)),
        );
        assert_eq!(runs, vec![(10, 11), (11, 13), (13, 14), (14, 17)]);
        let mut empty = Vec::new();
        cut(4, 4, 6, true, |_| 1, |lo, hi| empty.push((lo, hi)));
        cut(5, 5, 6, false, |_| 1, |lo, hi| empty.push((lo, hi)));
        assert_eq!(empty, vec![(4, 4)]);
    }

    /// Two leaves: a heavy splat's tasks and a heavy node's tasks are cut into items that cover
    /// every task once, in order, with the flags and spare expansions the kernels expect.
    #[test]
    fn items_cover_every_task_once_in_order() {
        // Root slot 0 (compact 0) with leaves in slots 1 (splats 0..3) and 2 (splats 3..4).
        let tree = Tree {
            slots: 3,
            lo: vec![0, 0, 3],
            hi: vec![4, 3, 4],
            leaves: vec![1, 2],
            nodes: vec![0, 1, 2],
            ..Default::default()
        };
        let points = Points {
            pos: vec![[0.0; 3]; 4],
            leaf: vec![1, 1, 1, 2],
            active: vec![true, true, false, true],
            ..Default::default()
        };
        let mut leaf_tasks = Vec::new();
        // Leaf 1: 3 tasks to the whole leaf of 600 sources each (cut 1 + 1 + 1), an M2P to
        // splat 1.
        for _ in 0..3 {
            leaf_tasks.push(task(0, 3, 1000, 1600));
        }
        leaf_tasks.push(task(1, 0, 0, 0));
        // Leaf 2: 40 M2P tasks to splat 3 (32 each: 32 per item, so 2 items).
        let leaf1 = leaf_tasks.len() as u32;
        for _ in 0..40 {
            leaf_tasks.push(task(3, 0, 1, 0));
        }
        // Node 0: 200 M2L (128 per item) then 10 P2L; node 1 none; node 2 one M2L.
        let mut node_tasks = vec![
            NodeTask {
                src: 1,
                fraction: 1.0
            };
            200
        ];
        node_tasks.extend((0..10).map(|j| NodeTask {
            src: POINT | j,
            fraction: 1.0,
        }));
        node_tasks.push(NodeTask {
            src: 1,
            fraction: 1.0,
        });
        let plan = Plan {
            node_offsets: vec![0, 210, 210, 211],
            node_tasks,
            leaf_offsets: vec![0, leaf1, leaf1 + 40],
            leaf_tasks,
            ..Default::default()
        };
        let w = Work::new(&tree, &points, &plan).unwrap();
        let items: Vec<(u32, u32, u32, u32)> = w
            .splat_items
            .iter()
            .map(|it| (it.splat, it.lo, it.hi, it.flags))
            .collect();
        assert_eq!(
            items,
            vec![
                // Splat 0 lists the leaf's three range tasks itself.
                (0, 0, 1, ITEM_L2P),
                (0, 1, 2, 0),
                (0, 2, 3, 0),
                // Splat 1 reads them from splat 0's block (all three), then its own M2P.
                (1, 0, 1, ITEM_RANGE | ITEM_L2P),
                (1, 1, 2, ITEM_RANGE),
                (1, 2, 3, ITEM_RANGE),
                (1, 3, 4, 0),
                // Splat 2 is inactive: no items. Splat 3: 40 M2P in two items.
                (3, 4, 36, ITEM_L2P),
                (3, 36, 44, 0),
            ]
        );
        assert_eq!(w.splat_item_offsets, vec![0, 3, 7, 7, 9]);
        let nodes: Vec<(u32, u32, u32, u32, u32)> = w
            .node_items
            .iter()
            .map(|it| (it.node, it.lo, it.hi, it.split, it.dst))
            .collect();
        assert_eq!(
            nodes,
            vec![
                (0, 0, 128, 128, 0),
                (0, 128, 210, 200, SPARE),
                (1, 210, 210, 210, 1),
                (2, 210, 211, 211, 2),
            ]
        );
        assert_eq!(w.spares, 1);
        assert_eq!(
            w.node_gathers,
            vec![NodeGather {
                node: 0,
                lo: 0,
                hi: 1
            }]
        );
        let bounds = w.loop_bounds(&tree, 8);
        assert_eq!(
            bounds,
            vec![
                ("p2m", 3),
                ("m2l", 128 + 10),
                ("m2l_gather", 1),
                // One group: longest outer loop 32, the inner P2P sums 6 × 600.
                ("splat", 32 + 3600),
                ("gather", 4),
            ]
        );
    }
}
