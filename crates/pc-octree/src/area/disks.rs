//! The area pass's disks as structure of arrays: the candidates a walk gathers ([`Disks`]) and
//! the few a splat keeps, with the terms its samples' cover counts need ([`Lanes`]).

use glam::Vec3;
use pc_artifact::octree::Splat;
use rayon::prelude::*;

use super::Duplicates;

/// Disks field by field (one array each): the whole pool ([`Disks::of_all`]), or a walk's
/// candidates copied from it a leaf's range at a time, which a splat's filter reads in vector
/// lanes.
#[derive(Default)]
pub(super) struct Disks {
    pub(super) px: Vec<f32>,
    pub(super) py: Vec<f32>,
    pub(super) pz: Vec<f32>,
    pub(super) nx: Vec<f32>,
    pub(super) ny: Vec<f32>,
    pub(super) nz: Vec<f32>,
    pub(super) radius: Vec<f32>,
    /// Each disk's slab ([`AreaPass::slabs`]).
    pub(super) slab: Vec<f32>,
    /// How far from its centre each disk can cover a point: √(radius² + slab²).
    pub(super) extent: Vec<f32>,
    pub(super) material: Vec<u32>,
    /// How many splats each disk counts for ([`Duplicates::weight`]).
    pub(super) weight: Vec<u32>,
}

impl Disks {
    pub(super) fn clear(&mut self) {
        for v in [
            &mut self.px,
            &mut self.py,
            &mut self.pz,
            &mut self.nx,
            &mut self.ny,
            &mut self.nz,
            &mut self.radius,
            &mut self.slab,
            &mut self.extent,
        ] {
            v.clear();
        }
        self.material.clear();
        self.weight.clear();
    }

    pub(super) fn len(&self) -> usize {
        self.weight.len()
    }

    /// Every splat's disk, with slab 0 ([`Self::set_slabs`] sets them) and weight
    /// [`Duplicates::weight`]: 0 for the members of a group of identical splats but its
    /// representative, so that a range of the pool can be copied whole.
    pub(super) fn of_all(splats: &[Splat], dups: &Duplicates) -> Disks {
        let field = |f: fn(&Splat) -> f32| splats.par_iter().map(f).collect::<Vec<f32>>();
        let n = splats.len();
        Disks {
            px: field(|s| s.position[0]),
            py: field(|s| s.position[1]),
            pz: field(|s| s.position[2]),
            nx: field(|s| s.normal[0]),
            ny: field(|s| s.normal[1]),
            nz: field(|s| s.normal[2]),
            radius: field(|s| s.radius),
            slab: vec![0.0; n],
            extent: field(|s| s.radius),
            material: splats.par_iter().map(|s| s.material).collect(),
            weight: (0..n as u32)
                .into_par_iter()
                .map(|j| dups.weight(j))
                .collect(),
        }
    }

    /// Sets every disk's slab, and its extent √(radius² + slab²) with it.
    pub(super) fn set_slabs(&mut self, slabs: &[f32]) {
        self.slab.copy_from_slice(slabs);
        let (radius, extent) = (&self.radius, &mut self.extent);
        extent
            .par_iter_mut()
            .zip(radius.par_iter().zip(slabs))
            .for_each(|(e, (&r, &t))| *e = (r * r + t * t).sqrt());
    }

    /// Appends the disks of `range` of `from` that can cover a point within `radius` of the
    /// box `lo..hi` of centres (world units): those whose cover box ([`cover_halves`],
    /// `halves`) meets the box widened by `radius`. A disk that fails this covers no sample of
    /// a splat centred in the box with a radius up to `radius`, so the filter changes no cover
    /// count (only lanes that count nothing go, the rest keep their order); it spares each
    /// splat's filter ([`AreaPass::near`]) the far disks of every leaf the walk reaches (on the
    /// hall scan at 20M points, 137 candidates a splat instead of 404, of which 22 are kept).
    pub(super) fn extend_reaching(
        &mut self,
        from: &Disks,
        range: std::ops::Range<u32>,
        (lo, hi): (Vec3, Vec3),
        radius: f32,
        halves: &[Vec3],
    ) {
        let range = range.start as usize..range.end as usize;
        for (j, &half) in range.clone().zip(&halves[range]) {
            let p = Vec3::new(from.px[j], from.py[j], from.pz[j]);
            let d = (lo - p).max(p - hi);
            // A hair wider than the cover test it stands in front of, against their rounding.
            let reach = (Vec3::splat(radius) + half) * (1.0 + 1e-5);
            if from.weight[j] == 0 || d.cmpgt(reach).any() {
                continue;
            }
            self.push_from(from, j);
        }
    }

    /// Appends the disks `range` of `from` whose centres lie in the box `lo..hi`, in order, and
    /// their indices to `cands`.
    pub(super) fn extend_within(
        &mut self,
        cands: &mut Vec<u32>,
        from: &Disks,
        range: std::ops::Range<u32>,
        (lo, hi): (Vec3, Vec3),
    ) {
        for j in range {
            let k = j as usize;
            let p = Vec3::new(from.px[k], from.py[k], from.pz[k]);
            if (p.cmpge(lo) & p.cmple(hi)).all() {
                cands.push(j);
                self.push_from(from, k);
            }
        }
    }

    /// Appends disk `j` of `from`, every field.
    #[inline]
    pub(super) fn push_from(&mut self, from: &Disks, j: usize) {
        self.px.push(from.px[j]);
        self.py.push(from.py[j]);
        self.pz.push(from.pz[j]);
        self.nx.push(from.nx[j]);
        self.ny.push(from.ny[j]);
        self.nz.push(from.nz[j]);
        self.radius.push(from.radius[j]);
        self.slab.push(from.slab[j]);
        self.extent.push(from.extent[j]);
        self.material.push(from.material[j]);
        self.weight.push(from.weight[j]);
    }
}

/// One disk j that may cover samples of a splat i (centre c, radius r, tangent frame u, v),
/// with what a sample x = c + r (a u + b v) needs, so that its tests are a few multiply-adds:
/// the sample's height above plane j is `h0 + a hu + b hv` and its squared distance from centre
/// j is `d0 + a du + b dv + r² (a² + b²)`.
pub(super) struct Lane {
    pub(super) h0: f32,
    pub(super) hu: f32,
    pub(super) hv: f32,
    pub(super) d0: f32,
    pub(super) du: f32,
    pub(super) dv: f32,
    /// Disk j's squared radius.
    pub(super) r2: f32,
    pub(super) slab: f32,
    pub(super) weight: u32,
}

/// A splat's [`Lane`]s, field by field, so that a sample's cover count is one vector loop.
#[derive(Default)]
pub(super) struct Lanes {
    pub(super) h0: Vec<f32>,
    pub(super) hu: Vec<f32>,
    pub(super) hv: Vec<f32>,
    pub(super) d0: Vec<f32>,
    pub(super) du: Vec<f32>,
    pub(super) dv: Vec<f32>,
    pub(super) r2: Vec<f32>,
    pub(super) slab: Vec<f32>,
    pub(super) weight: Vec<u32>,
}

impl Lanes {
    pub(super) fn clear(&mut self) {
        for v in [
            &mut self.h0,
            &mut self.hu,
            &mut self.hv,
            &mut self.d0,
            &mut self.du,
            &mut self.dv,
            &mut self.r2,
            &mut self.slab,
        ] {
            v.clear();
        }
        self.weight.clear();
    }

    pub(super) fn push(&mut self, l: Lane) {
        self.h0.push(l.h0);
        self.hu.push(l.hu);
        self.hv.push(l.hv);
        self.d0.push(l.d0);
        self.du.push(l.du);
        self.dv.push(l.dv);
        self.r2.push(l.r2);
        self.slab.push(l.slab);
        self.weight.push(l.weight);
    }

    /// Σ weight over the disks that cover the sample at tangent coordinates (a, b) (in radii of
    /// the splat) whose squared distance from the splat's centre is `rr`: within the disk's
    /// radius of its centre along its plane and within its slab of the plane.
    #[inline(always)]
    pub(super) fn cover(&self, a: f32, b: f32, rr: f32) -> u32 {
        let n = self.weight.len();
        let (h0, hu, hv) = (&self.h0[..n], &self.hu[..n], &self.hv[..n]);
        let (d0, du, dv) = (&self.d0[..n], &self.du[..n], &self.dv[..n]);
        let (r2, slab, weight) = (&self.r2[..n], &self.slab[..n], &self.weight[..n]);
        let mut sum = 0u32;
        for l in 0..n {
            let h = h0[l] + a * hu[l] + b * hv[l];
            let d2 = d0[l] + a * du[l] + b * dv[l] + rr;
            let inside = (h.abs() <= slab[l]) & (d2 - h * h <= r2[l]);
            sum += weight[l] * u32::from(inside);
        }
        sum
    }
}
