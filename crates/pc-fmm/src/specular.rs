//! The specular links in the solve (docs/caustics.md "Specular links"): the light diffuse
//! splats reflect that reaches other diffuse splats through mirrors and glass, added to every
//! product of the transport operator as a sparse term, so the solve includes it at every
//! bounce (`L = E + ρ ∘ (T + S)(L − Lₑ)`).
//!
//! `S` is three sparse maps traced by pc-caustics ([`pc_artifact::specular`]): the flux each
//! bin receives from the sending splats, each bin's density estimate over the bins around it,
//! and each splat's interpolation between those. It acts on the reflected radiance only, as `T` does: the lights'
//! own emission through mirrors and glass is the caustic photon map's (no light counted
//! twice). It runs on the CPU after the FMM's product on either device: it is a few sparse
//! passes, small beside the product.

use glam::Vec3;
use pc_artifact::specular::SpecularView;
use rayon::prelude::*;

use crate::cluster::Clustering;
use crate::error::FmmError;
use crate::solve::Operator;
use crate::tree::Points;

/// The sparse transfer `S` over splats, or over the elements of a clustered solve.
pub struct SpecularTransfer<'a> {
    links: SpecularView<'a>,
    /// The splats: their areas and whether they take part.
    pts: &'a Points,
    /// The element of every splat (`None`: the unknowns are the splats).
    of: Option<&'a [u32]>,
    /// Summed splat area of every element.
    element_area: Vec<f32>,
}

impl<'a> SpecularTransfer<'a> {
    /// The transfer of `links` for the unknowns of `clusters` (or the splats of `pts`); `None`
    /// when there are no links.
    pub fn new(
        links: SpecularView<'a>,
        pts: &'a Points,
        clusters: Option<&'a Clustering>,
    ) -> Option<SpecularTransfer<'a>> {
        if links.is_empty() || links.gather_offsets.len() != pts.pos.len() + 1 {
            return None;
        }
        let of = clusters.map(|c| c.of.as_slice());
        let mut element_area = vec![0.0f32; clusters.map_or(0, |c| c.points.pos.len())];
        if let Some(of) = of {
            for (i, &e) in of.iter().enumerate() {
                if let Some(a) = element_area.get_mut(e as usize) {
                    *a += pts.area[i];
                }
            }
        }
        Some(SpecularTransfer {
            links,
            pts,
            of,
            element_area,
        })
    }

    /// The unknown that holds splat `i`'s radiance, if it takes part.
    fn unknown(&self, i: usize) -> Option<usize> {
        if !self.pts.active[i] {
            return None;
        }
        match self.of {
            None => Some(i),
            Some(of) => of
                .get(i)
                .map(|&e| e as usize)
                .filter(|&e| e < self.element_area.len()),
        }
    }

    /// Each bin's density estimate of the light `radiance` (reflected radiance of the unknowns)
    /// sends through the specular chains (what [`SpecularTransfer::at_splats`] reads).
    pub fn density(&self, radiance: &[[f32; 3]]) -> Vec<Vec3> {
        let l = &self.links;
        let sent = |j: u32| {
            self.unknown(j as usize)
                .map_or(Vec3::ZERO, |u| Vec3::from(radiance[u]))
        };
        let flux: Vec<Vec3> = (0..l.bins())
            .into_par_iter()
            .map(|b| {
                l.flux_of(b)
                    .iter()
                    .map(|f| Vec3::from(f.weight) * sent(f.sender))
                    .sum()
            })
            .collect();
        (0..l.bins())
            .into_par_iter()
            .map(|b| {
                l.smooth_of(b)
                    .iter()
                    .map(|g| g.weight * flux[g.bin as usize])
                    .sum()
            })
            .collect()
    }

    /// What splat `i` gathers of the bins' `density`.
    fn gathered(&self, density: &[Vec3], i: usize) -> Vec3 {
        self.links
            .gather_of(i)
            .iter()
            .map(|g| g.weight * density[g.bin as usize])
            .sum()
    }

    /// `(S radiance)` at each of `splats` (splat indices, also in a clustered solve), from the
    /// bins' [`SpecularTransfer::density`] of `radiance`.
    pub fn at_splats(&self, density: &[Vec3], splats: &[u32]) -> Vec<[f32; 3]> {
        splats
            .par_iter()
            .map(|&i| self.gathered(density, i as usize).into())
            .collect()
    }

    /// `out += S radiance` (reflected radiance of the unknowns).
    pub fn add(&self, radiance: &[[f32; 3]], out: &mut [[f32; 3]]) {
        let density = self.density(radiance);
        let gathered = |i: usize| self.gathered(&density, i);
        match self.of {
            None => out.par_iter_mut().enumerate().for_each(|(i, o)| {
                if self.pts.active[i] {
                    *o = (Vec3::from(*o) + gathered(i)).into();
                }
            }),
            Some(_) => {
                let per: Vec<Vec3> = (0..self.pts.pos.len())
                    .into_par_iter()
                    .map(gathered)
                    .collect();
                for (i, t) in per.into_iter().enumerate() {
                    if let Some(e) = self.unknown(i) {
                        let w = self.pts.area[i] / self.element_area[e];
                        out[e] = (Vec3::from(out[e]) + w * t).into();
                    }
                }
            }
        }
    }
}

/// An operator and the specular transfer: `T + S`.
pub struct WithSpecular<'a> {
    pub inner: Box<dyn Operator + 'a>,
    pub transfer: &'a SpecularTransfer<'a>,
}

impl Operator for WithSpecular<'_> {
    fn apply_relaxed(
        &mut self,
        radiance: &[[f32; 3]],
        out: &mut [[f32; 3]],
        relax: f64,
    ) -> Result<u32, FmmError> {
        let order = self.inner.apply_relaxed(radiance, out, relax)?;
        self.transfer.add(radiance, out);
        Ok(order)
    }

    fn order(&self) -> u32 {
        self.inner.order()
    }

    fn device(&self) -> String {
        self.inner.device()
    }
}
