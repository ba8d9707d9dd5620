//! pc-inspect's library: describe any artifact, verify it, export debug views as PLY.

use std::fmt::Write as _;
use std::path::Path;

use glam::Vec3;
use pc_artifact::octree::{class, node, OctreeMeta};
use pc_artifact::{Artifact, ArtifactKind};
use pc_scene::ply_write::{write_ply, PlyFormat, PlyPoints};
use pc_tree::OctreeView;

/// The header, provenance (metadata as JSON), and the section table.
pub fn describe(a: &Artifact) -> String {
    let h = a.header();
    let mut s = String::new();
    let _ = writeln!(s, "file        {}", a.path().display());
    let _ = writeln!(
        s,
        "kind        {} (format version {})",
        h.kind, h.format_version
    );
    let _ = writeln!(s, "made by     {} {}", h.stage, h.stage_version);
    let _ = writeln!(s, "key         {}", h.key);
    let _ = writeln!(s, "created     {} (unix seconds)", h.created_unix);
    let _ = writeln!(s, "size        {} bytes", h.file_len);
    let _ = writeln!(
        s,
        "sections    {:<12} {:>12} {:>14} {:>6} {:>18}",
        "name", "offset", "bytes", "elem", "checksum"
    );
    for sec in a.sections() {
        let _ = writeln!(
            s,
            "            {:<12} {:>12} {:>14} {:>6} {:>18}",
            sec.name,
            sec.offset,
            sec.len,
            sec.elem_size,
            format!("{:016x}", sec.checksum)
        );
    }
    s
}

/// The metadata blob as pretty JSON (every kind stores MessagePack with named fields).
pub fn metadata_json(a: &Artifact) -> anyhow::Result<String> {
    let v: serde_json::Value = rmp_serde::from_slice(a.metadata_bytes()).map_err(|e| {
        anyhow::anyhow!(
            "{}: metadata is not readable MessagePack: {e}",
            a.path().display()
        )
    })?;
    Ok(serde_json::to_string_pretty(&v)?)
}

/// Kind-specific statistics.
pub fn statistics(a: &Artifact) -> anyhow::Result<String> {
    match a.header().kind {
        ArtifactKind::Octree => octree_statistics(a),
        ArtifactKind::Vmap => vmap_statistics(a),
        ArtifactKind::Photons => photons_statistics(a),
        ArtifactKind::Radiosity => radiosity_statistics(a),
    }
}

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

fn photons_statistics(a: &Artifact) -> anyhow::Result<String> {
    use pc_artifact::photons::{archived_tree, sections, Photon, PhotonsMeta};
    let meta: PhotonsMeta = a.metadata()?;
    let photons: &[Photon] = a.section(sections::PHOTONS)?;
    let deposit: &[[f32; 3]] = a.section(sections::DEPOSIT)?;
    let tree = archived_tree(a)?;
    let mut s = String::new();
    let mut stored = [0f64; 3];
    let mut by_bounces = [0u64; 5];
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in photons {
        for k in 0..3 {
            stored[k] += p.power[k] as f64;
        }
        by_bounces[(p.bounces as usize).min(4)] += 1;
        lo = lo.min(Vec3::from(p.position));
        hi = hi.max(Vec3::from(p.position));
    }
    let _ = writeln!(
        s,
        "photons     {} stored of {} traced ({} hidden, {} lost); kd-tree of {}",
        meta.stored,
        meta.traced,
        meta.occluded,
        meta.lost,
        tree.size()
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
    let _ = writeln!(
        s,
        "parameters  budget {}, max bounces {}, self-hit {}, seed {}; {} point lights",
        meta.params.photons,
        meta.params.max_bounces,
        meta.params.self_hit,
        meta.params.seed,
        meta.lights.len()
    );
    let _ = writeln!(s, "device      {}", meta.device);
    let _ = writeln!(s, "octree      key {}", meta.octree_key);
    let _ = writeln!(s, "vmap        key {}", meta.vmap_key);
    s.push_str(&timings_line(&meta.timings));
    Ok(s)
}

fn radiosity_statistics(a: &Artifact) -> anyhow::Result<String> {
    use pc_artifact::radiosity::{sections, RadiosityMeta};
    let meta: RadiosityMeta = a.metadata()?;
    let radiance: &[[f32; 3]] = a.section(sections::RADIANCE)?;
    let source: &[[f32; 3]] = a.section(sections::SOURCE)?;
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
        "splats      {} ({} take part in the solve)",
        radiance.len(),
        meta.active_splats
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
    let _ = writeln!(s, "device      {}", meta.device);
    let _ = writeln!(s, "octree      key {}", meta.octree_key);
    let _ = writeln!(s, "vmap        key {}", meta.vmap_key);
    if let Some(k) = &meta.photons_key {
        let _ = writeln!(s, "photons     key {k} (caustic energy in the sources)");
    }
    s.push_str(&timings_line(&meta.timings));
    Ok(s)
}

fn octree_statistics(a: &Artifact) -> anyhow::Result<String> {
    let v = OctreeView::from_artifact(a)?;
    let meta: OctreeMeta = a.metadata()?;
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
    let (mut leaves, mut empty, mut internal, mut ref_only) = (0u64, 0u64, 0u64, 0u64);
    let mut per_depth = vec![0u64; f.max_depth as usize + 1];
    let mut own_hist = [0u64; 6];
    let (mut refs_total, mut refs_max) = (0u64, 0usize);
    // Walk with depth to histogram leaves.
    let mut stack = vec![(0u32, 0u32)];
    while let Some((slot, d)) = stack.pop() {
        let w = v.nodes[slot as usize];
        if node::is_empty(w) {
            empty += 1;
        } else if node::is_leaf(w) {
            leaves += 1;
            let last = per_depth.len() - 1;
            per_depth[(d as usize).min(last)] += 1;
            let (r, refs) = v.leaf(w);
            let own = (r.end - r.start) as u64;
            if own == 0 {
                ref_only += 1;
            }
            let bucket = match own {
                0 => 0,
                1..=4 => 1,
                5..=8 => 2,
                9..=16 => 3,
                17..=32 => 4,
                _ => 5,
            };
            own_hist[bucket] += 1;
            refs_total += refs.len() as u64;
            refs_max = refs_max.max(refs.len());
        } else {
            internal += 1;
            for k in 0..8 {
                stack.push((node::ptr(w) + k, d + 1));
            }
        }
    }
    let _ = writeln!(
        s,
        "nodes       {} ({} internal, {} leaves of which {} reference-only, {} empty)",
        v.nodes.len(),
        internal,
        leaves,
        ref_only,
        empty
    );
    let _ = writeln!(
        s,
        "depth       {} (leaves per depth: {})",
        f.depth,
        per_depth
            .iter()
            .enumerate()
            .filter(|(_, &c)| c > 0)
            .map(|(d, c)| format!("{d}:{c}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let _ = writeln!(
        s,
        "own splats  per leaf: 0:{} 1-4:{} 5-8:{} 9-16:{} 17-32:{} >32:{}",
        own_hist[0], own_hist[1], own_hist[2], own_hist[3], own_hist[4], own_hist[5]
    );
    let _ = writeln!(
        s,
        "references  {} extra (mean {:.2} per leaf, max {})",
        refs_total,
        refs_total as f64 / leaves.max(1) as f64,
        refs_max
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
    let mut by_class = [0u64; 4];
    let mats: &[pc_artifact::octree::MaterialRecord] = a.section("materials")?;
    for sp in v.splats {
        if let Some(m) = mats.get(sp.material as usize) {
            by_class[(m.class as usize).min(3)] += 1;
        }
    }
    let _ = writeln!(
        s,
        "classes     diffuse {} emitter {} mirror {} dielectric {}",
        by_class[0], by_class[1], by_class[2], by_class[3]
    );
    let _ = writeln!(s, "materials   {}", meta.material_names.join(", "));
    for inp in &meta.inputs {
        let _ = writeln!(
            s,
            "input       {} ({} bytes, hash {})",
            inp.path, inp.bytes, inp.hash
        );
    }
    let total: f64 = meta.timings.iter().map(|t| t.1).sum();
    let _ = writeln!(
        s,
        "build time  {:.3} s: {}",
        total,
        meta.timings
            .iter()
            .map(|(n, t)| format!("{n} {t:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(s)
}

/// The sections of a vmap artifact, checked for consistency.
pub struct VmapView<'a> {
    pub offsets: &'a [u32],
    pub links: &'a [pc_artifact::vmap::Link],
    pub light_offsets: &'a [u32],
    pub light_links: &'a [pc_artifact::vmap::Link],
    pub node_range: &'a [[u32; 2]],
}

/// Map the sections of a vmap artifact and check the CSR structure.
pub fn vmap_view(a: &Artifact) -> anyhow::Result<VmapView<'_>> {
    use pc_artifact::vmap::sections as s;
    let v = VmapView {
        offsets: a.section(s::LINK_OFFSETS)?,
        links: a.section(s::LINKS)?,
        light_offsets: a.section(s::LIGHT_OFFSETS)?,
        light_links: a.section(s::LIGHT_LINKS)?,
        node_range: a.section(s::NODE_RANGE)?,
    };
    let nodes = v.node_range.len();
    let csr_ok = |o: &[u32], len: usize| {
        o.first() == Some(&0)
            && o.windows(2).all(|w| w[0] <= w[1])
            && o.last().map(|&x| x as usize) == Some(len)
    };
    if v.offsets.len() != nodes + 1 || !csr_ok(v.offsets, v.links.len()) {
        return Err(a
            .invalid("link offsets are not a CSR index over the links")
            .into());
    }
    if !csr_ok(v.light_offsets, v.light_links.len()) {
        return Err(a
            .invalid("light offsets are not a CSR index over the light links")
            .into());
    }
    if v.links
        .iter()
        .chain(v.light_links)
        .any(|l| l.slot() as usize >= nodes || !(l.fraction > 0.0 && l.fraction <= 1.0))
    {
        return Err(a
            .invalid("a link names a node outside the octree or has a fraction outside (0, 1]")
            .into());
    }
    Ok(v)
}

fn vmap_statistics(a: &Artifact) -> anyhow::Result<String> {
    let v = vmap_view(a)?;
    let meta: pc_artifact::vmap::VmapMeta = a.metadata()?;
    let mut s = String::new();
    let near = v.links.iter().filter(|l| l.is_near()).count();
    let partial = v.links.iter().filter(|l| l.fraction < 1.0).count();
    let rows = v.offsets.windows(2).filter(|w| w[1] > w[0]).count();
    let max_row = v.offsets.windows(2).map(|w| w[1] - w[0]).max().unwrap_or(0);
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
    let _ = writeln!(
        s,
        "parameters  theta {}, rays {}, near rays {}, leaf splats {}, self-hit {}",
        meta.params.theta,
        meta.params.rays,
        meta.params.near_rays,
        meta.params.leaf_splats,
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
    Ok(s)
}

/// Full verification: the container checks done by opening, plus the kind's structural checks.
pub fn verify(path: &Path) -> anyhow::Result<String> {
    let a = Artifact::open(path)?;
    match a.header().kind {
        ArtifactKind::Octree => {
            let v = OctreeView::from_artifact(&a)?;
            // Every splat is owned by the leaf that point location finds for its centre.
            for (i, sp) in v.splats.iter().enumerate() {
                let loc = v
                    .locate(Vec3::from(sp.position))
                    .ok_or_else(|| a.invalid(format!("splat {i} lies outside the root cube")))?;
                if loc.slot != v.splat_leaf[i] {
                    return Err(a
                        .invalid(format!(
                            "splat {i}: point location finds node {}, the table says {}",
                            loc.slot, v.splat_leaf[i]
                        ))
                        .into());
                }
                let (r, _) = v.leaf(loc.node);
                if !r.contains(&(i as u32)) {
                    return Err(a
                        .invalid(format!("splat {i} is not in its leaf's own range"))
                        .into());
                }
            }
            Ok(format!(
                "{}: ok (checksums, structure, {} splats located)",
                path.display(),
                v.splats.len()
            ))
        }
        ArtifactKind::Vmap => {
            let v = vmap_view(&a)?;
            Ok(format!(
                "{}: ok (checksums, CSR structure, {} links)",
                path.display(),
                v.links.len()
            ))
        }
        ArtifactKind::Photons => {
            use pc_artifact::photons::{archived_tree, sections, Photon};
            let photons: &[Photon] = a.section(sections::PHOTONS)?;
            let deposit: &[[f32; 3]] = a.section(sections::DEPOSIT)?;
            let tree = archived_tree(&a)?;
            if tree.size() as usize != photons.len() {
                return Err(a
                    .invalid(format!(
                        "the kd-tree holds {} photons but the map {}",
                        tree.size(),
                        photons.len()
                    ))
                    .into());
            }
            // The deposit is the photons' power summed per splat.
            let mut sum = vec![[0f64; 3]; deposit.len()];
            for (i, p) in photons.iter().enumerate() {
                let finite = p.position.iter().chain(&p.dir).chain(&p.power);
                if p.splat as usize >= deposit.len() || !finite.clone().all(|x| x.is_finite()) {
                    return Err(a
                        .invalid(format!(
                            "photon {i}: splat out of range or values not finite"
                        ))
                        .into());
                }
                for k in 0..3 {
                    sum[p.splat as usize][k] += p.power[k] as f64;
                }
            }
            if let Some(j) = (0..deposit.len()).find(|&j| {
                (0..3).any(|k| {
                    (deposit[j][k] as f64 - sum[j][k]).abs() > 1e-4 * sum[j][k].abs().max(1e-12)
                })
            }) {
                return Err(a
                    .invalid(format!(
                        "splat {j}: deposit {:?} is not the power of its photons {:?}",
                        deposit[j], sum[j]
                    ))
                    .into());
            }
            Ok(format!(
                "{}: ok (checksums, kd-tree of {} photons, deposit on {} splats)",
                path.display(),
                photons.len(),
                deposit.len()
            ))
        }
        ArtifactKind::Radiosity => {
            use pc_artifact::radiosity::{sections, RadiosityMeta};
            let meta: RadiosityMeta = a.metadata()?;
            let radiance: &[[f32; 3]] = a.section(sections::RADIANCE)?;
            let source: &[[f32; 3]] = a.section(sections::SOURCE)?;
            let residuals: &[f64] = a.section(sections::RESIDUALS)?;
            if source.len() != radiance.len() {
                return Err(a
                    .invalid(format!(
                        "{} source terms for {} splats",
                        source.len(),
                        radiance.len()
                    ))
                    .into());
            }
            if let Some(i) = radiance
                .iter()
                .chain(source)
                .position(|c| c.iter().any(|x| !x.is_finite() || *x < 0.0))
            {
                return Err(a
                    .invalid(format!(
                        "splat {}: negative or non-finite radiance",
                        i % radiance.len()
                    ))
                    .into());
            }
            if residuals != meta.residuals.as_slice() {
                return Err(a
                    .invalid("the residuals section and the metadata disagree")
                    .into());
            }
            Ok(format!(
                "{}: ok (checksums, {} splats finite and non-negative, {} residuals)",
                path.display(),
                radiance.len(),
                residuals.len()
            ))
        }
    }
}

/// Debug views that can be exported.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum View {
    /// The splat centres with normals and radii, colored by material class.
    Splats,
    /// Points along the 12 edges of every leaf box, colored by depth.
    Leaves,
    /// Splat centres colored by the area each splat stands for (blue small, red large).
    Areas,
}

fn class_color(c: u32) -> Vec3 {
    match c {
        class::DIFFUSE => Vec3::new(0.8, 0.8, 0.8),
        class::EMITTER => Vec3::new(1.0, 0.9, 0.2),
        class::MIRROR => Vec3::new(0.2, 0.6, 1.0),
        class::DIELECTRIC => Vec3::new(0.2, 1.0, 0.6),
        _ => Vec3::new(1.0, 0.0, 1.0),
    }
}

fn ramp(t: f32) -> Vec3 {
    let t = t.clamp(0.0, 1.0);
    Vec3::new(t, 1.0 - (2.0 * t - 1.0).abs(), 1.0 - t)
}

/// Write the links of one V-map node as a PLY: the node's splats in white, every splat of each
/// linked node colored by the link's visible fraction (blue 0 → red 1; near-field links green).
/// `octree` is the octree artifact the V-map was made from.
pub fn export_vmap_links(
    vmap: &Artifact,
    octree: &Artifact,
    node: u32,
    out: &Path,
) -> anyhow::Result<usize> {
    let v = vmap_view(vmap)?;
    let t = OctreeView::from_artifact(octree)?;
    let meta: pc_artifact::vmap::VmapMeta = vmap.metadata()?;
    anyhow::ensure!(
        meta.octree_key == octree.header().key.to_string(),
        "{}: the V-map was made from another octree (key {}), not {}",
        vmap.path().display(),
        meta.octree_key,
        octree.path().display()
    );
    anyhow::ensure!(
        (node as usize) < v.node_range.len(),
        "node {node} is outside the octree ({} nodes)",
        v.node_range.len()
    );
    let (mut pos, mut nrm, mut rad, mut col) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut push = |range: [u32; 2], c: Vec3| {
        for i in range[0]..range[1].max(range[0]) {
            let sp = &t.splats[i as usize];
            pos.push(Vec3::from(sp.position));
            nrm.push(Vec3::from(sp.normal));
            rad.push(sp.radius);
            col.push(c);
        }
    };
    push(v.node_range[node as usize], Vec3::ONE);
    for l in &v.links[v.offsets[node as usize] as usize..v.offsets[node as usize + 1] as usize] {
        let c = if l.is_near() {
            Vec3::new(0.1, 0.9, 0.1)
        } else {
            ramp(l.fraction)
        };
        push(v.node_range[l.slot() as usize], c);
    }
    write_points(
        out,
        &pos,
        &nrm,
        &rad,
        &col,
        format!(
            "pc-inspect: links of node {node} of {}",
            vmap.path().display()
        ),
    )
}

/// Write a PLY debug view of the artifact; returns the number of points written.
pub fn export_ply(a: &Artifact, view: View, out: &Path) -> anyhow::Result<usize> {
    anyhow::ensure!(
        a.header().kind == ArtifactKind::Octree,
        "{}: --export-ply supports octree artifacts so far",
        a.path().display()
    );
    let v = OctreeView::from_artifact(a)?;
    let mats: &[pc_artifact::octree::MaterialRecord] = a.section("materials")?;
    let (mut pos, mut nrm, mut rad, mut col) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    match view {
        View::Splats | View::Areas => {
            let areas: Vec<f32> = v.splat_area.to_vec();
            let mean = areas.iter().sum::<f32>() / areas.len().max(1) as f32;
            for (i, sp) in v.splats.iter().enumerate() {
                pos.push(Vec3::from(sp.position));
                nrm.push(Vec3::from(sp.normal));
                rad.push(sp.radius);
                col.push(match view {
                    View::Areas => ramp(areas[i] / (2.0 * mean)),
                    _ => class_color(mats.get(sp.material as usize).map_or(u32::MAX, |m| m.class)),
                });
            }
        }
        View::Leaves => {
            let mut stack = vec![(0u32, 0u32, [0u32; 3])];
            while let Some((slot, d, c)) = stack.pop() {
                let w = v.nodes[slot as usize];
                if node::is_empty(w) {
                    continue;
                }
                if !node::is_leaf(w) {
                    for k in 0..8u32 {
                        stack.push((
                            node::ptr(w) + k,
                            d + 1,
                            [
                                2 * c[0] + (k & 1),
                                2 * c[1] + ((k >> 1) & 1),
                                2 * c[2] + ((k >> 2) & 1),
                            ],
                        ));
                    }
                    continue;
                }
                let (lo, hi) = pc_tree::cell_box(&v.frame, d, c);
                let color = ramp(d as f32 / v.frame.depth.max(1) as f32);
                let steps = 8;
                for e in 0..12 {
                    let (axis, a1, a2) = (e / 4, (e % 4) & 1, (e % 4) >> 1);
                    for t in 0..=steps {
                        let f = t as f32 / steps as f32;
                        let mut p = lo;
                        let size = hi - lo;
                        p[axis] += f * size[axis];
                        p[(axis + 1) % 3] += a1 as f32 * size[(axis + 1) % 3];
                        p[(axis + 2) % 3] += a2 as f32 * size[(axis + 2) % 3];
                        pos.push(p);
                        col.push(color);
                    }
                }
            }
        }
    }
    write_points(
        out,
        &pos,
        &nrm,
        &rad,
        &col,
        format!("pc-inspect {view:?} view of {}", a.path().display()),
    )
}

/// Write a debug view as a binary PLY (empty normal or radius lists are left out); returns the
/// number of points.
fn write_points(
    out: &Path,
    pos: &[Vec3],
    nrm: &[Vec3],
    rad: &[f32],
    col: &[Vec3],
    comment: String,
) -> anyhow::Result<usize> {
    let pts = PlyPoints {
        positions: pos,
        normals: (!nrm.is_empty()).then_some(nrm),
        radii: (!rad.is_empty()).then_some(rad),
        colors: Some(col),
    };
    write_ply(out, &pts, PlyFormat::BinaryLittleEndian, &[comment])
        .map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    Ok(pos.len())
}
