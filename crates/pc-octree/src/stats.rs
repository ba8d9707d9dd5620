//! Per-node statistics (§8.5.5): the average disk, normal, area and class of a node's splats,
//! and a leaf's linear normal field.

use glam::Vec3;
use pc_artifact::octree::{class, tangent_frame, NodeInfo, Splat};

/// Average disk (Fig. 13), normal, area, count and class of the splats of one node, and for
/// leaves the normal field of §8.5.5.
pub(crate) fn node_info(
    splats: &[Splat],
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
        normal_field(splats, centroid, normal)
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
