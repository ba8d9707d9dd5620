//! Schema of the specular links, the light-independent part of the `photons` artifact
//! (pc-caustics; docs/caustics.md "Specular links"): how the reflected light of diffuse splats
//! reaches other diffuse splats through mirrors and glass (paths D S⁺ D).
//!
//! The transfer is a product of three sparse maps, applied by pc-fmm to the reflected
//! radiance `L` of every splat in each product of the solve:
//!
//! 1. **flux**: `Φ_b = Σ w ⊙ L_s` over the links `(s, w)` of bin `b`, the flux that arrives in
//!    bin `b` (an octree leaf of diffuse splats) through specular chains from sending splats `s`;
//! 2. **smooth**: `E_b = Σ g Φ_b'` over the links `(b', g)` of bin `b`, the density estimate of
//!    the irradiance over π in bin `b` (a kernel over the nearby bins of its surface);
//! 3. **gather**: `T_i = Σ w E_b` over the links `(b, w)` of splat `i`, an interpolation
//!    between the bins around it (weights summing to one).
//!
//! | section               | element          | what |
//! |-----------------------|------------------|------|
//! | `spec_flux_offsets`   | `u32`            | CSR row starts, one per bin plus one (empty: no links) |
//! | `spec_flux`           | [`FluxLink`]     | per bin: the senders whose light reaches it, and the weight |
//! | `spec_smooth_offsets` | `u32`            | CSR row starts, one per bin plus one (empty: no links) |
//! | `spec_smooth`         | [`GatherLink`]   | per bin: the bins of its density estimate, and their weights |
//! | `spec_gather_offsets` | `u32`            | CSR row starts, one per data-pool splat plus one (empty: no links) |
//! | `spec_gather`         | [`GatherLink`]   | per splat: the bins it interpolates, and their weights |

use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};

use crate::reader::any_where;
use crate::{Artifact, ArtifactError};

pub mod sections {
    pub const FLUX_OFFSETS: &str = "spec_flux_offsets";
    pub const FLUX: &str = "spec_flux";
    pub const SMOOTH_OFFSETS: &str = "spec_smooth_offsets";
    pub const SMOOTH: &str = "spec_smooth";
    pub const GATHER_OFFSETS: &str = "spec_gather_offsets";
    pub const GATHER: &str = "spec_gather";
}

/// Flux into a bin per unit reflected radiance of the sending splat (area · sr, RGB: the
/// specular chains' tint): `Φ_b += weight ⊙ L_sender`; `sender` is a data-pool index.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FluxLink {
    pub sender: u32,
    pub weight: [f32; 3],
}

/// One bin of a density estimate (`E_b += weight · Φ_bin`, 1 / area) or of a splat's
/// interpolation (`T_i += weight · E_bin`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GatherLink {
    pub bin: u32,
    pub weight: f32,
}

/// What the specular links were made from and how many there are.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(default)]
pub struct SpecularMeta {
    /// Key of the links alone: the octree, the V-map's links key, the parameters that shape
    /// them and the materials; lights do not enter it, so moving a light reuses them.
    pub key: String,
    /// Paths traced from diffuse leaves toward the specular leaves they see.
    pub paths: u64,
    /// Paths that landed on a diffuse splat after ≥ 1 specular bounce.
    pub stored: u64,
    /// Paths whose aim point was hidden (another surface in front of it).
    pub occluded: u64,
    /// Paths that left the scene, hit a back face or reached the bounce limit.
    pub lost: u64,
    pub bins: u64,
    pub flux_links: u64,
    pub smooth_links: u64,
    pub gather_links: u64,
    /// Whether the links were copied from the previous artifact (same key).
    pub reused: bool,
    pub seconds: f64,
}

/// The specular links' sections, checked.
#[derive(Clone, Copy, Debug, Default)]
pub struct SpecularView<'a> {
    pub flux_offsets: &'a [u32],
    pub flux: &'a [FluxLink],
    pub smooth_offsets: &'a [u32],
    pub smooth: &'a [GatherLink],
    pub gather_offsets: &'a [u32],
    pub gather: &'a [GatherLink],
}

impl<'a> SpecularView<'a> {
    /// The sections of `a`; an artifact written before the links existed has none: no links.
    pub fn sections(a: &'a Artifact) -> Result<SpecularView<'a>, ArtifactError> {
        if !a.has_section(sections::FLUX_OFFSETS) {
            return Ok(SpecularView::default());
        }
        Ok(SpecularView {
            flux_offsets: a.section(sections::FLUX_OFFSETS)?,
            flux: a.section(sections::FLUX)?,
            smooth_offsets: a.section(sections::SMOOTH_OFFSETS)?,
            smooth: a.section(sections::SMOOTH)?,
            gather_offsets: a.section(sections::GATHER_OFFSETS)?,
            gather: a.section(sections::GATHER)?,
        })
    }

    /// Whether there is any transfer to apply.
    pub fn is_empty(&self) -> bool {
        self.flux.is_empty() || self.gather.is_empty()
    }

    /// The number of bins.
    pub fn bins(&self) -> usize {
        self.flux_offsets.len().saturating_sub(1)
    }

    /// The flux links of bin `b`.
    pub fn flux_of(&self, b: usize) -> &'a [FluxLink] {
        &self.flux[self.flux_offsets[b] as usize..self.flux_offsets[b + 1] as usize]
    }

    /// The smoothing links of bin `b`.
    pub fn smooth_of(&self, b: usize) -> &'a [GatherLink] {
        &self.smooth[self.smooth_offsets[b] as usize..self.smooth_offsets[b + 1] as usize]
    }

    /// The gather links of splat `i`.
    pub fn gather_of(&self, i: usize) -> &'a [GatherLink] {
        &self.gather[self.gather_offsets[i] as usize..self.gather_offsets[i + 1] as usize]
    }

    /// The structure every reader relies on, for a data pool of `splats` splats: CSR indices
    /// (empty or complete), senders within the pool, bins that exist, finite
    /// non-negative weights.
    pub fn check(&self, splats: usize) -> Result<(), String> {
        // Empty, or complete.
        let csr = |o: &[u32], rows: usize, len: usize| {
            (o.is_empty() && len == 0) || crate::reader::is_csr(o, rows, len)
        };
        let bins = self.bins();
        if !csr(self.flux_offsets, bins, self.flux.len()) {
            return Err("specular flux offsets are not a CSR index over the flux links".into());
        }
        if !csr(self.smooth_offsets, bins, self.smooth.len())
            || (self.smooth_offsets.is_empty() != self.flux_offsets.is_empty())
        {
            return Err("specular smoothing offsets are not a CSR index over the bins".into());
        }
        if !csr(self.gather_offsets, splats, self.gather.len()) {
            return Err(format!(
                "specular gather offsets are not a CSR index over the gather links of {splats} splats"
            ));
        }
        let weight_ok = |w: f32| w.is_finite() && w >= 0.0;
        if any_where(self.flux, |l| {
            l.sender as usize >= splats || !l.weight.iter().all(|&w| weight_ok(w))
        }) {
            return Err(
                "a specular flux link names a sender that does not exist or has a weight that is not finite and non-negative".into(),
            );
        }
        let bad_gather = |g: &GatherLink| g.bin as usize >= bins || !weight_ok(g.weight);
        if any_where(self.gather, bad_gather) || any_where(self.smooth, bad_gather) {
            return Err(
                "a specular gather link names a bin that does not exist or has a weight that is not finite and non-negative".into(),
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view<'a>(
        fo: &'a [u32],
        flux: &'a [FluxLink],
        go: &'a [u32],
        gather: &'a [GatherLink],
    ) -> SpecularView<'a> {
        let smooth: &'static [GatherLink] = &[GatherLink {
            bin: 0,
            weight: 1.0,
        }];
        let so: &'static [u32] = if fo.is_empty() { &[] } else { &[0, 1] };
        SpecularView {
            flux_offsets: fo,
            flux,
            smooth_offsets: so,
            smooth: if fo.is_empty() { &[] } else { smooth },
            gather_offsets: go,
            gather,
        }
    }

    #[test]
    fn the_check_names_what_is_wrong() {
        let flux = [FluxLink {
            sender: 2,
            weight: [1.0; 3],
        }];
        let gather = [GatherLink {
            bin: 0,
            weight: 2.0,
        }];
        let go = [0, 1, 1, 1];
        assert!(view(&[0, 1], &flux, &go, &gather).check(3).is_ok());
        assert!(view(&[], &[], &[], &[]).check(3).is_ok());
        let e = view(&[0, 1], &flux, &go, &gather).check(4).unwrap_err();
        assert!(e.contains("gather offsets"), "{e}");
        let far = [FluxLink {
            sender: 3,
            weight: [1.0; 3],
        }];
        let e = view(&[0, 1], &far, &go, &gather).check(3).unwrap_err();
        assert!(e.contains("names a sender that does not exist"), "{e}");
        let nan = [FluxLink {
            sender: 0,
            weight: [f32::NAN, 0.0, 0.0],
        }];
        let e = view(&[0, 1], &nan, &go, &gather).check(3).unwrap_err();
        assert!(e.contains("flux link"), "{e}");
        let bad_bin = [GatherLink {
            bin: 1,
            weight: 1.0,
        }];
        let e = view(&[0, 1], &flux, &go, &bad_bin).check(3).unwrap_err();
        assert!(e.contains("gather link"), "{e}");
        assert_eq!(std::mem::size_of::<FluxLink>(), 16);
        assert_eq!(std::mem::size_of::<GatherLink>(), 8);
    }
}
