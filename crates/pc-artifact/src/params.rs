//! Every parameter block that shapes an artifact, defined once.
//!
//! `pipeline.toml`'s `[octree]`, `[vmap]`, `[caustics]` and `[fmm]` tables deserialize into these
//! structs (pc-config adds each stage's `backend` and `file` around them), the artifact's
//! metadata embeds the same struct, and the stage's key hashes it. A field's doc comment here is
//! its definition; its default is in the `Default` impl and its accepted range in `validate`,
//! next to each other, so a new parameter is one field, one default and one range
//! (docs/pipeline.md lists them for users).
//!
//! Every numeric value has an upper bound as well as a lower one: a bound keeps one run within
//! memory and time (a sample count of four billion is refused up front instead of running
//! for days), or states where the method stops making sense (a form factor above 1).

use std::fmt;
use std::ops::RangeInclusive;

use serde::{Deserialize, Serialize};

/// A parameter outside its documented range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{key} must {expected}, got {got}")]
pub struct ParamError {
    /// The config key, `table.field`.
    pub key: String,
    /// What is accepted, in words ("lie in 1..=4096", "be finite and lie in [0, 1]").
    pub expected: String,
    /// The value found.
    pub got: String,
}

/// Checks an integer against an inclusive range.
pub fn int(key: &str, value: impl Into<u64>, range: RangeInclusive<u64>) -> Result<(), ParamError> {
    let v = value.into();
    let (lo, hi) = (*range.start(), *range.end());
    let expected = if v < lo {
        format!("be at least {lo} (it lies in {lo}..={hi})")
    } else if v > hi {
        format!("be at most {hi} (it lies in {lo}..={hi})")
    } else {
        return Ok(());
    };
    Err(ParamError {
        key: key.to_string(),
        expected,
        got: v.to_string(),
    })
}

/// One end of a real interval: included (`[`) or excluded (`(`).
#[derive(Clone, Copy, Debug)]
pub enum End {
    Incl(f32),
    Excl(f32),
}

/// Checks a real number: finite and within `lo`..`hi`.
pub fn real(key: &str, value: f32, lo: End, hi: End) -> Result<(), ParamError> {
    let above = match lo {
        End::Incl(l) => value >= l,
        End::Excl(l) => value > l,
    };
    let below = match hi {
        End::Incl(h) => value <= h,
        End::Excl(h) => value < h,
    };
    if value.is_finite() && above && below {
        return Ok(());
    }
    let (open, l) = match lo {
        End::Incl(l) => ('[', l),
        End::Excl(l) => ('(', l),
    };
    let (close, h) = match hi {
        End::Incl(h) => (']', h),
        End::Excl(h) => (')', h),
    };
    Err(ParamError {
        key: key.to_string(),
        expected: format!("be finite and lie in {open}{l}, {h}{close}"),
        got: value.to_string(),
    })
}

/// A check of its own kind: `expected` says what is accepted.
pub fn require(
    key: &str,
    ok: bool,
    expected: &str,
    got: impl fmt::Display,
) -> Result<(), ParamError> {
    if ok {
        return Ok(());
    }
    Err(ParamError {
        key: key.to_string(),
        expected: expected.to_string(),
        got: got.to_string(),
    })
}

use End::{Excl, Incl};

/// The octree's shape (pc-octree, seed §8.5.1; docs/octree.md). `[octree]` in pipeline.toml.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OctreeParams {
    /// k: a node is split while it owns more splats than this (§8.5.1). 1..=4096.
    pub max_leaf_points: u32,
    /// Deepest level (root = 0); leaves there may exceed k or mix classes. 1..=21 (the Morton
    /// code's bits per axis).
    pub max_depth: u32,
    /// Sample points per splat disk for the splat-area estimate (partition of unity). 1..=64.
    pub area_samples: u32,
}

impl Default for OctreeParams {
    fn default() -> Self {
        OctreeParams {
            max_leaf_points: 16,
            max_depth: 21,
            area_samples: 8,
        }
    }
}

impl OctreeParams {
    /// Every value within its documented range.
    pub fn validate(&self) -> Result<(), ParamError> {
        int("octree.max_leaf_points", self.max_leaf_points, 1..=4096)?;
        int("octree.max_depth", self.max_depth, 1..=21)?;
        int("octree.area_samples", self.area_samples, 1..=64)
    }
}

/// What shapes the V-map's links (pc-vmap, seed §7.2; docs/vmap.md). `[vmap]` in
/// pipeline.toml; the links key hashes it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VmapParams {
    /// Opening criterion: two nodes are well separated when (R_a + R_b) / distance < theta.
    /// (0, 2).
    pub theta: f32,
    /// Visibility rays per far-field node pair (and per node for the light lists). 1..=4096.
    pub rays: u32,
    /// Near-field pairs of V-map leaves: every splat pair up to this many, else this many
    /// samples. 1..=4096: with none, near pairs would get no link and their light would be lost.
    pub near_rays: u32,
    /// Nodes with at most this many splats are V-map leaves (their pairs are near-field).
    /// 1..=65536. Above `full_resolution_splats` splats it grows with the scan (see there).
    pub leaf_splats: u32,
    /// Up to this many splats visibility is resolved at `leaf_splats`; a larger octree of N
    /// splats gets V-map leaves of `leaf_splats · ⌈N / full_resolution_splats⌉` splats, so the
    /// number of V-map leaves, and with it the pairs and rays per splat, stops growing
    /// (docs/vmap.md, "Scale"). 1,000..=4,000,000,000.
    pub full_resolution_splats: u64,
    /// Self-hit distance in radii of the splat a visibility ray leaves or reaches (§8.5.6).
    /// [0, 100].
    pub self_hit: f32,
    /// Partly visible node pairs exchanging a smaller form factor than this (either way) keep a
    /// partial link instead of being refined to V-map leaves; 0 always refines. [0, 1].
    pub refine_form_factor: f32,
    /// Far-field pairs exchanging at least `heavy_form_factor` (either way) are tested with
    /// `heavy_rays` rays instead of `rays`: a pair that all of a few rays find unoccluded is
    /// linked whole, so the pairs that carry the most light get the most rays (0 or at most
    /// `rays`: off). 0..=4096.
    pub heavy_rays: u32,
    /// See `heavy_rays`. [0, 1].
    pub heavy_form_factor: f32,
    /// Seed of the visibility rays' sample pattern.
    pub seed: u32,
}

impl Default for VmapParams {
    fn default() -> Self {
        VmapParams {
            theta: 0.5,
            rays: 16,
            near_rays: 64,
            leaf_splats: 64,
            full_resolution_splats: 1_000_000,
            self_hit: 0.5,
            refine_form_factor: 1e-3,
            heavy_rays: 64,
            heavy_form_factor: 3e-3,
            seed: 0,
        }
    }
}

impl VmapParams {
    /// The V-map leaf size used on an octree of `splats` splats: `leaf_splats` up to
    /// `full_resolution_splats`, then in proportion.
    pub fn leaf_splats_for(&self, splats: usize) -> u32 {
        let scale = (splats as u64)
            .div_ceil(self.full_resolution_splats.max(1))
            .max(1);
        (self.leaf_splats as u64 * scale).min(u32::MAX as u64) as u32
    }

    /// Every value within its documented range.
    pub fn validate(&self) -> Result<(), ParamError> {
        real("vmap.theta", self.theta, Excl(0.0), Excl(2.0))?;
        int("vmap.rays", self.rays, 1..=4096)?;
        int("vmap.near_rays", self.near_rays, 1..=4096)?;
        int("vmap.leaf_splats", self.leaf_splats, 1..=65536)?;
        int(
            "vmap.full_resolution_splats",
            self.full_resolution_splats,
            1_000..=4_000_000_000,
        )?;
        real("vmap.self_hit", self.self_hit, Incl(0.0), Incl(100.0))?;
        real(
            "vmap.refine_form_factor",
            self.refine_form_factor,
            Incl(0.0),
            Incl(1.0),
        )?;
        int("vmap.heavy_rays", self.heavy_rays, 0..=4096)?;
        real(
            "vmap.heavy_form_factor",
            self.heavy_form_factor,
            Incl(0.0),
            Incl(1.0),
        )
    }
}

/// The caustic photon pass (pc-caustics, seed §8.5.2-7; docs/caustics.md). `[caustics]` in
/// pipeline.toml.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CausticsParams {
    /// Photon budget n_e over the whole sphere of every light: each photon carries the lights'
    /// power over n_e, and only those aimed at specular leaves are traced (§8.5.3).
    /// 0..=100,000,000 (0: no photons); at 0.5 M photons/s on two cores the largest budget
    /// takes minutes, and each stored photon 48 bytes.
    pub photons: u32,
    /// Most specular bounces a photon makes before it is dropped. 1..=64.
    pub max_bounces: u32,
    /// Seed of the photons' random numbers.
    pub seed: u32,
    /// Paths traced for the specular links (diffuse light through mirrors and glass onto
    /// diffuse surfaces, docs/caustics.md "Specular links"), shared among the (diffuse leaf,
    /// specular leaf) pairs the V-map links; 0: no links (the seed's §8.1 split, which loses
    /// that light). 0..=100,000,000; each path is one chain of rays, like a photon. 4M: with
    /// 1M the ceiling of `cornell-mirror-glass` moved by ±3 % with the seed (BENCHMARKS.md).
    pub specular_paths: u32,
    /// Paths' worth of deposits each splat's estimate of that light gathers at least (the
    /// kernel widens until it holds them): the noise of the estimate is about 1/√ of it.
    /// 1..=1,000,000.
    pub specular_gather: u32,
}

impl Default for CausticsParams {
    fn default() -> Self {
        CausticsParams {
            photons: 8_000_000,
            max_bounces: 8,
            seed: 0,
            specular_paths: 4_000_000,
            specular_gather: 400,
        }
    }
}

impl CausticsParams {
    /// Every value within its documented range.
    pub fn validate(&self) -> Result<(), ParamError> {
        int("caustics.photons", self.photons, 0..=100_000_000)?;
        int("caustics.max_bounces", self.max_bounces, 1..=64)?;
        int(
            "caustics.specular_paths",
            self.specular_paths,
            0..=100_000_000,
        )?;
        int(
            "caustics.specular_gather",
            self.specular_gather,
            1..=1_000_000,
        )
    }
}

/// The iterative method of the radiosity solve (docs/fmm.md).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum Solver {
    /// Restarted GMRES, one Krylov process per channel in lockstep.
    #[default]
    Gmres,
    /// Jacobi iteration (the Neumann series), one bounce per iteration.
    Jacobi,
}

/// The radiosity solve (pc-fmm, seed §7.1, §7.3, §8.1; docs/fmm.md). `[fmm]` in pipeline.toml.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct FmmParams {
    /// Taylor expansion order p of the far field. 0..=12 (the GPU's kernels are generated up
    /// to order 8).
    pub order: u32,
    /// Expansion separation: two clusters interact through expansions when
    /// (r_a + r_b) < theta · distance. (0, 1).
    pub theta: f32,
    /// Largest accepted cosine-clamp error of one interaction, as a form factor. [0, 1].
    pub clamp_tol: f32,
    /// The solve stops when the relative residual falls below this. (0, 1).
    pub tolerance: f32,
    /// The solve stops after this many iterations even if not converged. 1..=10000.
    pub max_iterations: u32,
    /// Samples per splat of the direct light of the emitting splats (0: none). 0..=4096: each
    /// sample may cast a shadow ray, so the bound keeps the source term within minutes.
    pub emitter_samples: u32,
    /// Of those, how many probe visibility first: a leaf whose probes all agree gives the other
    /// samples their answer without rays (0, or at least `emitter_samples`: every sample casts
    /// its ray). 0..=4096.
    pub emitter_probes: u32,
    /// The iterative method: "gmres" (default) or "jacobi".
    pub solver: Solver,
    /// GMRES: later products at a lower order as the residual falls (relaxed products).
    pub relax: bool,
    /// The solve's unknowns: up to this many active splats each splat is one; above, the
    /// splats of the smallest octree nodes are merged into clusters of like normal (at most
    /// about this many, never coarser than a V-map leaf), solved for, and every splat gets its
    /// own direct light plus its cluster's gathered light (docs/fmm.md, "Scale").
    /// 1,000..=4,000,000,000.
    pub max_elements: u64,
    /// Final gather (docs/fmm.md, "Final gather"): rays per gathered splat's footprint, which
    /// the gathered splats within its disk share ("Pooled rays"); each casts a stratified grid of
    /// cosine directions, √n × √n (rounded down to a square) where it is alone, fewer among
    /// others; 0: no final gather.
    /// 0..=65,536.
    pub gather_rays: u32,
    /// A V-map leaf's splats are gathered when its links' shared fractions misstate the light
    /// of some node in it by more than this share of that light, beyond three standard
    /// deviations of the V-map's sampling (pc-vmap's `smear` section). (0, 1].
    pub gather_error: f32,
    /// A V-map leaf's splats are gathered, too, when at least this share of its probes finds
    /// another surface close over it (pc-vmap's `smear` section: a ball resting on it, a box
    /// standing on it), where what its splats see changes from splat to splat. (0, 1].
    pub gather_contact: f32,
    /// At most this share of the active splats is gathered, the most misstated V-map leaves
    /// first. [0, 1].
    pub gather_share: f32,
}

impl Default for FmmParams {
    fn default() -> Self {
        FmmParams {
            order: 3,
            theta: 0.5,
            clamp_tol: 1e-4,
            tolerance: 1e-3,
            max_iterations: 200,
            emitter_samples: 64,
            emitter_probes: 16,
            solver: Solver::Gmres,
            relax: true,
            max_elements: 250_000,
            gather_rays: 256,
            gather_error: 0.02,
            gather_contact: 0.25,
            gather_share: 0.02,
        }
    }
}

impl FmmParams {
    /// Every value within its documented range.
    pub fn validate(&self) -> Result<(), ParamError> {
        int("fmm.order", self.order, 0..=12)?;
        real("fmm.theta", self.theta, Excl(0.0), Excl(1.0))?;
        real("fmm.clamp_tol", self.clamp_tol, Incl(0.0), Incl(1.0))?;
        real("fmm.tolerance", self.tolerance, Excl(0.0), Excl(1.0))?;
        int("fmm.max_iterations", self.max_iterations, 1..=10_000)?;
        int("fmm.emitter_samples", self.emitter_samples, 0..=4096)?;
        int("fmm.emitter_probes", self.emitter_probes, 0..=4096)?;
        int("fmm.max_elements", self.max_elements, 1_000..=4_000_000_000)?;
        int("fmm.gather_rays", self.gather_rays, 0..=65_536)?;
        real("fmm.gather_error", self.gather_error, Excl(0.0), Incl(1.0))?;
        real(
            "fmm.gather_contact",
            self.gather_contact,
            Excl(0.0),
            Incl(1.0),
        )?;
        real("fmm.gather_share", self.gather_share, Incl(0.0), Incl(1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        OctreeParams::default().validate().unwrap();
        VmapParams::default().validate().unwrap();
        CausticsParams::default().validate().unwrap();
        FmmParams::default().validate().unwrap();
    }

    #[test]
    fn messages_name_the_key_the_range_and_the_value() {
        let v = VmapParams {
            near_rays: 0,
            ..Default::default()
        };
        assert_eq!(
            v.validate().unwrap_err().to_string(),
            "vmap.near_rays must be at least 1 (it lies in 1..=4096), got 0"
        );
        let v = VmapParams {
            refine_form_factor: -1.0,
            ..Default::default()
        };
        assert_eq!(
            v.validate().unwrap_err().to_string(),
            "vmap.refine_form_factor must be finite and lie in [0, 1], got -1"
        );
        let f = FmmParams {
            theta: f32::NAN,
            ..Default::default()
        };
        assert!(f.validate().unwrap_err().to_string().contains("fmm.theta"));
    }

    #[test]
    fn missing_keys_take_the_defaults_and_unknown_ones_are_refused() {
        let empty = rmp_serde::to_vec_named(&std::collections::BTreeMap::<String, u32>::new());
        let p: FmmParams = rmp_serde::from_slice(&empty.unwrap()).unwrap();
        assert_eq!(p, FmmParams::default());
        #[derive(Serialize)]
        struct Extra {
            orderr: u32,
        }
        let bytes = rmp_serde::to_vec_named(&Extra { orderr: 2 }).unwrap();
        assert!(rmp_serde::from_slice::<FmmParams>(&bytes).is_err());
    }
}
