//! Consistent orientation of normals by propagation over the neighbour graph ([`propagate`]):
//! a minimum spanning tree grown from a seed per connected part, the seed oriented outward.

use glam::Vec3;

/// Orient `normals` consistently; `graph` holds `kg` neighbour indices per point (u32::MAX for
/// none). See [`estimate_normals`].
pub(super) fn propagate(positions: &[Vec3], normals: &mut [Vec3], graph: &[u32], kg: usize) {
    let n = positions.len();
    if kg == 0 {
        // One point at most per component: orient each as a seed.
        for i in 0..n {
            orient_seed(positions, normals, &[i as u32]);
        }
        return;
    }
    let row = |i: usize| {
        graph[i * kg..(i + 1) * kg]
            .iter()
            .copied()
            .filter(|&j| j != u32::MAX)
    };
    // Make the graph symmetric: store the reverse edges j -> i that j's own list lacks.
    let mut rev_count = vec![0u32; n + 1];
    let mutual = |i: usize, j: usize| graph[j * kg..(j + 1) * kg].contains(&(i as u32));
    for i in 0..n {
        for j in row(i) {
            if !mutual(i, j as usize) {
                rev_count[j as usize + 1] += 1;
            }
        }
    }
    for i in 0..n {
        rev_count[i + 1] += rev_count[i];
    }
    let rev_start = rev_count;
    let mut fill = rev_start.clone();
    let mut rev = vec![0u32; rev_start[n] as usize];
    for i in 0..n {
        for j in row(i) {
            if !mutual(i, j as usize) {
                let f = &mut fill[j as usize];
                rev[*f as usize] = i as u32;
                *f += 1;
            }
        }
    }
    let adj = |i: usize| {
        row(i).chain(
            rev[rev_start[i] as usize..rev_start[i + 1] as usize]
                .iter()
                .copied(),
        )
    };

    let mut seen = vec![false; n]; // component labelling
    let mut done = vec![false; n]; // oriented
    let mut stack: Vec<u32> = Vec::new();
    let mut comp: Vec<u32> = Vec::new();
    let mut queue = BucketQueue::new();
    let mut best = vec![u16::MAX; n]; // best queued weight bucket per point
    for start in 0..n {
        if seen[start] {
            continue;
        }
        // The component of `start`.
        comp.clear();
        stack.push(start as u32);
        seen[start] = true;
        while let Some(i) = stack.pop() {
            comp.push(i);
            for j in adj(i as usize) {
                if !seen[j as usize] {
                    seen[j as usize] = true;
                    stack.push(j);
                }
            }
        }
        let seed = orient_seed(positions, normals, &comp);
        // Prim's MST from the seed, orienting each point from the tree edge that reaches it.
        let mut push = |queue: &mut BucketQueue, normals: &[Vec3], done: &[bool], i: u32| {
            let ni = normals[i as usize];
            for j in adj(i as usize) {
                if !done[j as usize] {
                    let b = weight_bucket(ni.dot(normals[j as usize]));
                    if b < best[j as usize] {
                        best[j as usize] = b;
                        queue.push(b, j, i);
                    }
                }
            }
        };
        done[seed as usize] = true;
        push(&mut queue, normals, &done, seed);
        while let Some((j, from)) = queue.pop() {
            if done[j as usize] {
                continue;
            }
            done[j as usize] = true;
            if normals[j as usize].dot(normals[from as usize]) < 0.0 {
                normals[j as usize] = -normals[j as usize];
            }
            push(&mut queue, normals, &done, j);
        }
    }
}

/// Buckets of the Prim queue.
const BUCKETS: usize = 1024;

/// The MST edge weight `1 - |cos|`, quantized monotonically: `sqrt(1 - |cos|)` is nearly
/// proportional to the angle between the normals (≈ θ/√2), so one bucket is ≈ 0.08°.
#[inline]
fn weight_bucket(cos: f32) -> u16 {
    let w = (1.0 - cos.abs()).max(0.0);
    ((w.sqrt() * (BUCKETS - 1) as f32).round() as usize).min(BUCKETS - 1) as u16
}

/// A priority queue over small integer keys (a bucket queue): O(1) push, pop scans forward
/// from the lowest possibly non-empty bucket. Entries are (point, the point it is reached
/// from). Within a bucket the order is last-in first-out.
struct BucketQueue {
    buckets: Vec<Vec<(u32, u32)>>,
    low: usize,
    len: usize,
}

impl BucketQueue {
    fn new() -> Self {
        Self {
            buckets: (0..BUCKETS).map(|_| Vec::new()).collect(),
            low: BUCKETS,
            len: 0,
        }
    }

    fn push(&mut self, key: u16, j: u32, from: u32) {
        let k = key as usize;
        self.buckets[k].push((j, from));
        self.low = self.low.min(k);
        self.len += 1;
    }

    fn pop(&mut self) -> Option<(u32, u32)> {
        if self.len == 0 {
            self.low = BUCKETS;
            return None;
        }
        while self.buckets[self.low].is_empty() {
            self.low += 1;
        }
        self.len -= 1;
        self.buckets[self.low].pop()
    }
}

/// Pick the seed of a component (see [`estimate_normals`]), orient its normal outward, and
/// return its index.
fn orient_seed(positions: &[Vec3], normals: &mut [Vec3], comp: &[u32]) -> u32 {
    let mut best = (comp[0], Vec3::X, f32::NEG_INFINITY);
    for axis in 0..3 {
        for sign in [1.0f32, -1.0] {
            let ext = *comp
                .iter()
                .max_by(|&&a, &&b| {
                    (sign * positions[a as usize][axis])
                        .total_cmp(&(sign * positions[b as usize][axis]))
                })
                .unwrap();
            let mut dir = Vec3::ZERO;
            dir[axis] = sign;
            let score = normals[ext as usize].dot(dir).abs();
            if score > best.2 {
                best = (ext, dir, score);
            }
        }
    }
    let (seed, dir, _) = best;
    if normals[seed as usize].dot(dir) < 0.0 {
        normals[seed as usize] = -normals[seed as usize];
    }
    seed
}
