//! Debug views of artifacts as PLY files, for a point-cloud viewer (CloudCompare, MeshLab).

use std::path::Path;

use glam::Vec3;
use pc_artifact::octree::{class, node, OctreeFile};
use pc_artifact::vmap::VmapFile;
use pc_import::ply_write::{write_ply, PlyFormat, PlyPoints};

use crate::InspectError;

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
    vmap: &VmapFile,
    octree: &OctreeFile,
    node: u32,
    out: &Path,
) -> Result<usize, InspectError> {
    let (v, t) = (vmap.view(), octree.view());
    if vmap.meta().octree_key != octree.key().to_string() {
        return Err(InspectError::Usage(format!(
            "{}: the V-map was made from another octree (key {}), not {}",
            vmap.path().display(),
            vmap.meta().octree_key,
            octree.path().display()
        )));
    }
    if node as usize >= v.node_range.len() {
        return Err(InspectError::Usage(format!(
            "node {node} is outside the octree ({} nodes)",
            v.node_range.len()
        )));
    }
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
    for l in v.links_of(node as usize) {
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

/// Write a PLY debug view of an octree; returns the number of points written.
pub fn export_ply(a: &OctreeFile, view: View, out: &Path) -> Result<usize, InspectError> {
    let v = a.view();
    let mats = a.materials();
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
) -> Result<usize, InspectError> {
    let pts = PlyPoints {
        positions: pos,
        normals: (!nrm.is_empty()).then_some(nrm),
        radii: (!rad.is_empty()).then_some(rad),
        colors: Some(col),
    };
    write_ply(out, &pts, PlyFormat::BinaryLittleEndian, &[comment]).map_err(|source| {
        InspectError::Write {
            path: out.to_path_buf(),
            source,
        }
    })?;
    Ok(pos.len())
}
