//! Per-node statistics (§8.5.5): the average disk, normal, area and class of a node's splats,
//! and a leaf's linear normal field.

use glam::Vec3;
use pc_artifact::octree::{class, tangent_frame, NodeInfo, Splat};

/// Average disk (Fig. 13), normal, area, count and class of the splats of one node (`own`,
/// with `areas`), and for leaves the normal field of §8.5.5, fitted over the leaf's own splats
/// and the disks it references (indices into `all`) of its own surface ([`field_disks`]).
pub(crate) fn node_info(
    (splats, referenced, all): (&[Splat], &[u32], &[Splat]),
    areas: &[f32],
    material_class: &[u32],
    is_leaf: bool,
) -> NodeInfo {
    let total: f32 = areas.iter().sum();
    let weight = |i: usize| if total > 0.0 { areas[i] } else { 1.0 };
    let wsum: f32 = (0..splats.len()).map(weight).sum();
    let centroid = splats
        .iter()
        .enumerate()
        .map(|(i, s)| Vec3::from(s.position) * weight(i))
        .sum::<Vec3>()
        / wsum;
    let nsum = splats
        .iter()
        .enumerate()
        .map(|(i, s)| Vec3::from(s.normal) * weight(i))
        .sum::<Vec3>();
    let normal = if nsum.length() > 1e-3 * wsum {
        nsum.normalize()
    } else {
        Vec3::ZERO
    };
    let disk_radius = splats
        .iter()
        .map(|s| (Vec3::from(s.position) - centroid).length() + s.radius)
        .fold(0.0f32, f32::max);
    let c0 = material_class[splats[0].material as usize];
    let cls = if splats
        .iter()
        .all(|s| material_class[s.material as usize] == c0)
    {
        c0
    } else {
        class::MIXED
    };
    let mut tilt = if is_leaf && normal != Vec3::ZERO {
        let disks = field_disks(splats, referenced, all, normal);
        normal_field(&disks, centroid, normal)
    } else {
        [0.0; 2]
    };
    // A field that misses one of the leaf's own normals by more than the renderer trusts is a
    // leaf straddling a sharp edge (one tilted field fitted to two faces): flatten it, so that
    // every splat of such a leaf shades with its own normal (the renderer's residual rule,
    // pc_tree::optics::FIELD_RESIDUAL_COS, then rejects the flat mean of the two faces). A
    // sphere's field fits its normals exactly and keeps its tilt.
    if tilt != [0.0; 2] {
        let field = NodeInfo {
            centroid: centroid.into(),
            normal: normal.into(),
            tilt,
            ..NodeInfo::default()
        };
        let misses = splats.iter().any(|s| {
            pc_tree::field_normal(&field, Vec3::from(s.position)).dot(Vec3::from(s.normal))
                < pc_tree::optics::FIELD_RESIDUAL_COS
        });
        if misses {
            tilt = [0.0; 2];
        }
    }
    NodeInfo {
        centroid: centroid.into(),
        disk_radius,
        normal: normal.into(),
        area: total,
        tilt,
        count: splats.len() as u32,
        class: cls,
    }
}

/// The disks a leaf's normal field is fitted over: its own splats, and the disks it references
/// of its own surface (a material of its own splats, the normal within [`FIELD_COS`] of the
/// leaf's mean `normal`). A leaf of one to three splats (a small `octree.max_leaf_points`, or
/// the last splats of a surface) has no spread of its own to fit a tilt to: on
/// cornell-mirror-glass at k = 4 the glass ball shaded flat, leaf by leaf, and its reflection
/// in the mirror box moved its highlight (per-pixel relative error 0.087 against 0.068 at
/// k = 8). The disks it references lie around it on the same surface.
fn field_disks(own: &[Splat], referenced: &[u32], all: &[Splat], normal: Vec3) -> Vec<Splat> {
    let same_surface = |s: &Splat| {
        own.iter().any(|o| o.material == s.material)
            && Vec3::from(s.normal).dot(normal) >= FIELD_COS
    };
    own.iter()
        .copied()
        .chain(
            referenced
                .iter()
                .map(|&j| all[j as usize])
                .filter(|s| same_surface(s)),
        )
        .collect()
}

/// The least cosine between a referenced disk's normal and a leaf's mean normal for the disk to
/// join the leaf's field fit: the renderer's own bound on how far a field may turn
/// (`pc_tree::optics::FIELD_MIN_COS`, about 26°), so a box's other face stays out.
const FIELD_COS: f32 = pc_tree::optics::FIELD_MIN_COS;

/// Least-squares tilt factors (ν, ω) of the linear normal field n(x) = n̄ + ν ((x − c)·û) û +
/// ω ((x − c)·v̂) v̂ over a leaf's average disk (§8.5.5 with u_j = r û, v_j = r v̂, the disk
/// radius cancels). Each axis is an independent one-unknown least-squares problem:
/// ν = Σ d_u (n_l·û) / (Σ d_u² + λ), d_u = (p_l − c)·û, with a small ridge term λ (below).
/// For a sphere of radius R, ν = ω ≈ 1/R.
pub fn normal_field(splats: &[Splat], c: Vec3, n: Vec3) -> [f32; 2] {
    let (u, v) = tangent_frame(n.into());
    let (u, v) = (Vec3::from(u), Vec3::from(v));
    let (mut nu_num, mut nu_den, mut om_num, mut om_den) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for s in splats {
        let d = Vec3::from(s.position) - c;
        let nl = Vec3::from(s.normal);
        let (du, dv) = (d.dot(u) as f64, d.dot(v) as f64);
        nu_num += du * nl.dot(u) as f64;
        nu_den += du * du;
        om_num += dv * nl.dot(v) as f64;
        om_den += dv * dv;
    }
    // Ridge regularisation towards a flat field: a leaf whose points spread along one direction
    // only (a row of splats) leaves the other factor undetermined, and a plain quotient of two
    // tiny sums would tilt the normal arbitrarily. λ is 2 % of the splats' mean squared
    // radius per splat: negligible once the points spread over a few radii.
    let mean_r2 = splats
        .iter()
        .map(|s| (s.radius as f64).powi(2))
        .sum::<f64>()
        / splats.len().max(1) as f64;
    let lambda = 0.02 * mean_r2 * splats.len() as f64;
    let solve = |num: f64, den: f64| {
        if den + lambda > 1e-30 {
            (num / (den + lambda)) as f32
        } else {
            0.0
        }
    };
    [solve(nu_num, nu_den), solve(om_num, om_den)]
}
