//! What pc-inspect prints about each kind of artifact: counts, ranges, parameters, timings.

use std::fmt::Write as _;

use glam::Vec3;
use pc_artifact::octree::{node, MaterialRecord, OctreeFile, OctreeView};
use pc_artifact::photons::PhotonsFile;
use pc_artifact::radiosity::RadiosityFile;
use pc_artifact::vmap::VmapFile;

fn timings_line(t: &[(String, f64)]) -> String {
    // Derived entries ("per iteration") are not part of the total.
    let total: f64 = t
        .iter()
        .filter(|t| !t.0.starts_with("per "))
        .map(|t| t.1)
        .sum();
    format!(
        "time        {:.3} s: {}\n",
        total,
        t.iter()
            .map(|(n, t)| format!("{n} {t:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

fn rgb(c: [f64; 3]) -> String {
    format!("({:.4}, {:.4}, {:.4})", c[0], c[1], c[2])
}

pub(crate) fn photons(f: &PhotonsFile) -> String {
    let (meta, v) = (f.meta(), f.view());
    let (photons, deposit) = (v.photons, v.deposit);
    let mut s = String::new();
    let mut stored = [0f64; 3];
    let mut by_bounces = [0u64; 5];
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in photons {
        for (s, &w) in stored.iter_mut().zip(&p.power) {
            *s += w as f64;
        }
        by_bounces[(p.bounces as usize).min(4)] += 1;
        lo = lo.min(Vec3::from(p.position));
        hi = hi.max(Vec3::from(p.position));
    }
    let _ = writeln!(
        s,
        "photons     {} stored of {} traced ({} hidden, {} lost); {} in the map",
        meta.stored,
        meta.traced,
        meta.occluded,
        meta.lost,
        photons.len()
    );
    let _ = writeln!(
        s,
        "bounces     1: {}, 2: {}, 3: {}, 4+: {}",
        by_bounces[1], by_bounces[2], by_bounces[3], by_bounces[4]
    );
    if !photons.is_empty() {
        let _ = writeln!(s, "extent      {:?} to {:?}", lo.to_array(), hi.to_array());
    }
    let _ = writeln!(
        s,
        "power       emitted {} W, aimed at specular leaves {} W, stored {} W",
        rgb(meta.emitted_power),
        rgb(meta.aimed_power),
        rgb(stored)
    );
    let lit = deposit
        .iter()
        .filter(|d| d.iter().any(|&x| x > 0.0))
        .count();
    let _ = writeln!(
        s,
        "deposit     {} of {} splats receive photons",
        lit,
        deposit.len()
    );
    let sp = &meta.specular;
    let _ = writeln!(
        s,
        "specular    {} links paths kept of {} traced ({} hidden, {} lost){}; {} bins, {} flux, {} smoothing and {} gather links",
        sp.stored,
        sp.paths,
        sp.occluded,
        sp.lost,
        if sp.reused { ", reused" } else { "" },
        sp.bins,
        sp.flux_links,
        sp.smooth_links,
        sp.gather_links
    );
    let _ = writeln!(
        s,
        "parameters  budget {}, max bounces {}, seed {}, specular paths {}, gather {}; {} point lights",
        meta.params.photons,
        meta.params.max_bounces,
        meta.params.seed,
        meta.params.specular_paths,
        meta.params.specular_gather,
        meta.lights.len()
    );
    let _ = writeln!(s, "device      {}", meta.device);
    let _ = writeln!(s, "octree      key {}", meta.octree_key);
    let _ = writeln!(s, "vmap        key {}", meta.vmap_key);
    s.push_str(&timings_line(&meta.timings));
    s
}

pub(crate) fn radiosity(f: &RadiosityFile) -> String {
    let (meta, v) = (f.meta(), f.view());
    let (radiance, source) = (v.radiance, v.source);
    let mut s = String::new();
    let stats = |v: &[[f32; 3]]| {
        let mut mean = [0f64; 3];
        let mut max = [0f64; 3];
        for x in v {
            for k in 0..3 {
                mean[k] += x[k] as f64;
                max[k] = max[k].max(x[k] as f64);
            }
        }
        let n = v.len().max(1) as f64;
        (mean.map(|m| m / n), max)
    };
    let _ = writeln!(
        s,
        "splats      {} ({} take part in the solve{})",
        radiance.len(),
        meta.active_splats,
        match meta.elements {
            0 => String::new(),
            e => format!(", solved as {e} elements"),
        }
    );
    let (m, x) = stats(radiance);
    let _ = writeln!(s, "radiance    mean {}, max {}", rgb(m), rgb(x));
    let (m, x) = stats(source);
    let _ = writeln!(s, "source      mean {}, max {}", rgb(m), rgb(x));
    let _ = writeln!(
        s,
        "solve       {} iterations, {}, last residual {:.3e} (tolerance {})",
        meta.iterations,
        if meta.converged {
            "converged"
        } else {
            "NOT converged"
        },
        meta.residuals.last().copied().unwrap_or(f64::NAN),
        meta.params.tolerance
    );
    let _ = writeln!(
        s,
        "residuals   {}",
        meta.residuals
            .iter()
            .map(|r| format!("{r:.2e}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    if !meta.orders.is_empty() {
        let _ = writeln!(
            s,
            "orders      {}{}",
            meta.orders
                .iter()
                .map(|o| o.to_string())
                .collect::<Vec<_>>()
                .join(" "),
            if meta.params.relax {
                " (relaxed products)"
            } else {
                ""
            }
        );
    }
    let _ = writeln!(
        s,
        "operator    {} M2L, {} P2L, {} M2P, {} P2P ({} splat pairs)",
        meta.m2l, meta.p2l, meta.m2p, meta.p2p, meta.p2p_pairs
    );
    let _ = writeln!(
        s,
        "parameters  order {}, theta {}, clamp tol {}, emitter samples {} ({} probes)",
        meta.params.order,
        meta.params.theta,
        meta.params.clamp_tol,
        meta.params.emitter_samples,
        meta.params.emitter_probes
    );
    if meta.emitter_samples > 0 {
        let _ = writeln!(
            s,
            "emitters    {} samples: {} settled by shaft culling ({:.1} %), {} shadow rays through the octree ({:.1} %), the probes' verdict for the rest",
            meta.emitter_samples,
            meta.emitter_settled,
            100.0 * meta.emitter_settled as f64 / meta.emitter_samples as f64,
            meta.emitter_rays,
            100.0 * meta.emitter_rays as f64 / meta.emitter_samples as f64
        );
    }
    if meta.gather_candidates > 0 {
        let _ = writeln!(
            s,
            "gather      {} of the {} splats of the candidate leaves ({} piloted) took their light from rays of their own ({} rays with the pilot's; final gather)",
            meta.gathered_splats, meta.gather_candidates, meta.gather_piloted, meta.gather_rays_cast
        );
    }
    let _ = writeln!(s, "device      {}", meta.device);
    let _ = writeln!(s, "octree      key {}", meta.octree_key);
    let _ = writeln!(s, "vmap        key {}", meta.vmap_key);
    if let Some(k) = &meta.photons_key {
        let _ = writeln!(s, "photons     key {k} (caustic energy in the sources)");
    }
    s.push_str(&timings_line(&meta.timings));
    s
}

pub(crate) fn octree(file: &OctreeFile) -> String {
    let (v, meta) = (file.view(), file.meta());
    let mut s = String::new();
    let f = &v.frame;
    let _ = writeln!(s, "root cube   origin {:?}, size {}", f.origin, f.size);
    let _ = writeln!(
        s,
        "splats      {} (k = {}, max depth {})",
        v.splats.len(),
        f.max_leaf_points,
        f.max_depth
    );
    let t = TreeCounts::of(&v);
    let _ = writeln!(
        s,
        "nodes       {} ({} internal, {} leaves of which {} reference-only, {} empty)",
        v.nodes.len(),
        t.internal,
        t.leaves,
        t.ref_only,
        t.empty
    );
    let _ = writeln!(
        s,
        "depth       {} (leaves per depth: {})",
        f.depth,
        t.per_depth
            .iter()
            .enumerate()
            .filter(|(_, &c)| c > 0)
            .map(|(d, c)| format!("{d}:{c}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let h = &t.own_hist;
    let _ = writeln!(
        s,
        "own splats  per leaf: 0:{} 1-4:{} 5-8:{} 9-16:{} 17-32:{} >32:{}",
        h[0], h[1], h[2], h[3], h[4], h[5]
    );
    let _ = writeln!(
        s,
        "references  {} extra (mean {:.2} per leaf, max {})",
        t.refs_total,
        t.refs_total as f64 / t.leaves.max(1) as f64,
        t.refs_max
    );
    let area: f64 = v.splat_area.iter().map(|&x| x as f64).sum();
    let disks: f64 = v
        .splats
        .iter()
        .map(|x| std::f64::consts::PI * (x.radius as f64).powi(2))
        .sum();
    let _ = writeln!(
        s,
        "area        {area:.6} (sum of disk areas {disks:.6}, overlap {:.2}x)",
        disks / area.max(1e-30)
    );
    let c = class_counts(&v, file.materials());
    let _ = writeln!(
        s,
        "classes     diffuse {} emitter {} mirror {} dielectric {}",
        c[0], c[1], c[2], c[3]
    );
    let _ = writeln!(s, "materials   {}", meta.material_names.join(", "));
    for inp in &meta.inputs {
        let _ = writeln!(
            s,
            "input       {} ({} bytes, hash {})",
            inp.path, inp.bytes, inp.hash
        );
    }
    let total: f64 = meta.stats.timings.iter().map(|t| t.1).sum();
    let _ = writeln!(
        s,
        "build time  {:.3} s: {}",
        total,
        meta.stats
            .timings
            .iter()
            .map(|(n, t)| format!("{n} {t:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    s
}

/// An octree's nodes counted by a walk from the root: internal, leaves (per depth, by their
/// own splats, reference-only) and empty ones, and the leaves' references.
struct TreeCounts {
    leaves: u64,
    empty: u64,
    internal: u64,
    ref_only: u64,
    per_depth: Vec<u64>,
    /// Leaves with 0, 1-4, 5-8, 9-16, 17-32 and more own splats.
    own_hist: [u64; 6],
    refs_total: u64,
    refs_max: usize,
}

impl TreeCounts {
    fn of(v: &OctreeView) -> TreeCounts {
        let mut t = TreeCounts {
            leaves: 0,
            empty: 0,
            internal: 0,
            ref_only: 0,
            per_depth: vec![0; v.frame.max_depth as usize + 1],
            own_hist: [0; 6],
            refs_total: 0,
            refs_max: 0,
        };
        let mut stack = vec![(0u32, 0u32)];
        while let Some((slot, d)) = stack.pop() {
            let w = v.nodes[slot as usize];
            if node::is_empty(w) {
                t.empty += 1;
            } else if node::is_leaf(w) {
                t.leaves += 1;
                let last = t.per_depth.len() - 1;
                t.per_depth[(d as usize).min(last)] += 1;
                let (r, refs) = v.leaf(w);
                let own = (r.end - r.start) as u64;
                t.ref_only += (own == 0) as u64;
                let bucket = match own {
                    0 => 0,
                    1..=4 => 1,
                    5..=8 => 2,
                    9..=16 => 3,
                    17..=32 => 4,
                    _ => 5,
                };
                t.own_hist[bucket] += 1;
                t.refs_total += refs.len() as u64;
                t.refs_max = t.refs_max.max(refs.len());
            } else {
                t.internal += 1;
                for k in 0..8 {
                    stack.push((node::ptr(w) + k, d + 1));
                }
            }
        }
        t
    }
}

/// Splats per material class (diffuse, emitter, mirror, dielectric).
fn class_counts(v: &OctreeView, mats: &[MaterialRecord]) -> [u64; 4] {
    let mut by_class = [0u64; 4];
    for sp in v.splats {
        if let Some(m) = mats.get(sp.material as usize) {
            by_class[(m.class as usize).min(3)] += 1;
        }
    }
    by_class
}

pub(crate) fn vmap(f: &VmapFile) -> String {
    let (v, meta) = (f.view(), f.meta());
    let mut s = String::new();
    let near = v.links.iter().filter(|l| l.is_near()).count();
    let partial = v.links.iter().filter(|l| l.fraction < 1.0).count();
    let rows = v.link_offsets.windows(2).filter(|w| w[1] > w[0]).count();
    let max_row = v
        .link_offsets
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or(0);
    let _ = writeln!(
        s,
        "links       {} stored ({} far, {} near; both directions), {} partially visible",
        v.links.len(),
        v.links.len() - near,
        near,
        partial
    );
    let _ = writeln!(
        s,
        "nodes       {} with links (mean {:.1}, max {} links per node)",
        rows,
        v.links.len() as f64 / rows.max(1) as f64,
        max_row
    );
    let _ = writeln!(
        s,
        "lights      {} ({} nodes seen in all)",
        v.light_offsets.len().saturating_sub(1),
        v.light_links.len()
    );
    s.push_str(&smear_line(&v));
    let _ = writeln!(
        s,
        "parameters  theta {}, rays {}, near rays {}, leaf splats {} (used {}), self-hit {}",
        meta.params.theta,
        meta.params.rays,
        meta.params.near_rays,
        meta.params.leaf_splats,
        meta.leaf_splats_used,
        meta.params.self_hit
    );
    let _ = writeln!(
        s,
        "work        {} node pairs tested, {} rays on {}{}",
        meta.pairs_tested,
        meta.rays_cast,
        meta.device,
        if meta.links_reused {
            " (links reused)"
        } else {
            ""
        }
    );
    let _ = writeln!(s, "octree      key {}", meta.octree_key);
    s.push_str(&timings_line(&meta.timings));
    s
}

/// The V-map leaves with a surface close over them (contact shares) and the splats they hold,
/// and the nodes whose links misstate their light beyond 2 % at 3 deviations (the `smear`
/// section, which pc-fmm's final gather reads).
fn smear_line(v: &pc_artifact::vmap::VmapView) -> String {
    let mut at = [0u64; 3];
    let mut splats = [0u64; 3];
    let mut leaves = 0u64;
    for (slot, m) in v.smear.iter().enumerate() {
        if v.vnode[slot] == 0 || m.contact == 0.0 && m.transfer == 0.0 {
            continue;
        }
        let [lo, hi] = v.node_range[slot];
        leaves += (m.contact > 0.0) as u64;
        for (k, t) in [0.25f32, 0.5, 0.75].iter().enumerate() {
            if m.contact >= *t {
                at[k] += 1;
                splats[k] += (hi - lo) as u64;
            }
        }
    }
    let misstated = v.smear.iter().filter(|m| m.exceeds(0.02, 3.0)).count();
    format!(
        "contact     V-map leaves with a contact share of at least 0.25 / 0.5 / 0.75: {} / {} / {} ({} / {} / {} splats; {leaves} with any); {misstated} nodes misstated beyond 2 %\n",
        at[0], at[1], at[2], splats[0], splats[1], splats[2]
    )
}
