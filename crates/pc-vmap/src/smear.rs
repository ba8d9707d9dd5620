//! What a link's one fraction misstates within its nodes (docs/vmap.md, "Visibility within a
//! V-map leaf"): the FMM gives every splat of a node the visible share its link measured over
//! the whole node, but where an occluder is close (a ball resting on the floor) visibility
//! changes from splat to splat. The rays a link was decided on already say how: each sample
//! pair (s, t) of a pair (A, B) linked with fraction `f` stands for `σ w` of the two nodes'
//! area-weighted form factor (`w` its weight in the form-factor sum, `σ = N_A N_B / (n π)` for
//! `n` samples drawn, halved for a node paired with itself, whose samples come in both orders),
//! and `σ w (V − f)` is what the shared fraction gets wrong about that sample at both its ends.
//!
//! Summed over a node's splats, the *error* estimates how much more (or less) light its
//! splats really receive than the links give them, under light of the same radiance from
//! everywhere; the *transfer* (`Σ σ w f`) is what the links give, and the *variance* (`Σ (σ w
//! (V − f))²`) says whether the error stands out of the sampling noise. pc-fmm gathers the
//! light of the nodes where it does, splat by splat (docs/fmm.md, "Final gather").

use pc_artifact::vmap::Smear as NodeSmear;
use rayon::prelude::*;

use crate::build::{Sample, VNode};

/// Per splat (data-pool order): error, transfer and variance of the links' fractions.
#[derive(Debug, Default)]
pub struct Smear {
    per_splat: Vec<[f32; 3]>,
}

impl Smear {
    pub fn new(splats: usize) -> Smear {
        Smear {
            per_splat: vec![[0.0; 3]; splats],
        }
    }

    /// The samples of a pair (A, B), `drawn` of them drawn (the cast ones in `samples`, with
    /// their visibility `visible`), linked with `fraction`.
    pub(crate) fn add(
        &mut self,
        (a, b): (&VNode, &VNode),
        drawn: u32,
        samples: &[Sample],
        visible: &[bool],
        fraction: f32,
    ) {
        if self.per_splat.is_empty() || drawn == 0 {
            return;
        }
        let pairs = a.count() as f64 * b.count() as f64;
        let same = a.lo == b.lo && a.hi == b.hi;
        let sigma =
            (pairs / (drawn as f64 * std::f64::consts::PI)) as f32 * if same { 0.5 } else { 1.0 };
        for (s, &v) in samples.iter().zip(visible) {
            let x = sigma * s.weight;
            let err = x * (v as u32 as f32 - fraction);
            if !(err * err).is_finite() || !(x * fraction).is_finite() {
                continue; // a pair of splats nearly on top of each other: no estimate
            }
            for end in s.ends {
                let acc = &mut self.per_splat[end as usize];
                acc[0] += err;
                acc[1] += x * fraction;
                acc[2] += err * err;
            }
        }
    }

    /// The sums over each node-pool slot's subtree (`vn`'s ranges), with each slot's share of
    /// probes blocked close by (`contact`, empty for none).
    pub fn per_node(&self, vn: &[VNode], contact: &[f32]) -> Vec<NodeSmear> {
        let mut prefix = vec![[0.0f64; 3]; self.per_splat.len() + 1];
        for (i, s) in self.per_splat.iter().enumerate() {
            prefix[i + 1] = std::array::from_fn(|k| prefix[i][k] + s[k] as f64);
        }
        // (Each slot from the prefix sums alone: in parallel.)
        vn.par_iter()
            .enumerate()
            .map(|(slot, v)| {
                let (lo, hi) = (v.lo as usize, v.hi as usize);
                if hi <= lo || hi >= prefix.len() {
                    return NodeSmear::default();
                }
                // Sums past f32's range (the reader refuses what is not finite) say nothing.
                let d = |k: usize| {
                    Some((prefix[hi][k] - prefix[lo][k]) as f32)
                        .filter(|v| v.is_finite())
                        .unwrap_or(0.0)
                };
                NodeSmear {
                    error: d(0),
                    transfer: d(1).max(0.0),
                    variance: d(2).max(0.0),
                    contact: contact.get(slot).copied().unwrap_or(0.0),
                }
            })
            .collect()
    }
}
