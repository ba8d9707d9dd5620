//! Specular interactions shared by the renderer and the photon tracer (seed §8.5.6): mirror
//! reflection, refraction with Snell's law, total internal reflection, the Fresnel choice of a
//! dielectric, and the normal at a point of a specular splat from its leaf's normal field
//! (§8.5.5). The WGSL twin is in `shaders/common/optics.wgsl`.

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};

use crate::{field_normal, OctreeView};

/// Mirror reflection of `d` about `n`.
#[inline]
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Refraction of unit `d` through a surface with unit normal `n` facing the incoming side
/// (`d·n < 0`), relative index `eta = n1 / n2` (§8.5.6). `None` on total internal reflection.
#[inline]
pub fn refract(d: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = -d.dot(n);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return None;
    }
    Some(eta * d + (eta * cos_i - (1.0 - sin2_t).sqrt()) * n)
}

/// Unpolarised Fresnel reflectance of a dielectric interface; 1 under total internal reflection.
#[inline]
pub fn fresnel(cos_i: f32, eta: f32) -> f32 {
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// The field normal is used only within this cosine (about 26°) of the splat's own normal: a
/// leaf that straddles a sharp edge (a mirror box's front and top faces) fits one field to
/// both faces, and its blended normal made the edge reflect the light where it is black
/// (issue 21); a smooth surface's field turns far less within a leaf. WGSL twin:
/// `FIELD_MIN_COS` in shaders/common/optics.wgsl.
pub const FIELD_MIN_COS: f32 = 0.9;

/// A leaf's field is trusted for a splat only where, at the splat's own centre, it gives back
/// the splat's own normal within this cosine (about 5.7°). The linear field fits a sphere's
/// normals exactly (they are linear in the position), so a curved surface passes; a leaf that
/// straddles a sharp edge fits one tilted field to both faces, which fails at every splat.
/// Without this the mirror box's front face, tilted up to [`FIELD_MIN_COS`] towards its side
/// and top faces within a pixel of the edge, reflected the walls where the reference shows the
/// black open front (cornell-mirror-glass). WGSL twin: `FIELD_RESIDUAL_COS` in
/// shaders/common/optics.wgsl.
pub const FIELD_RESIDUAL_COS: f32 = 0.995;

/// The normal at point `x` of specular splat `splat`: the normal field of the leaf that owns the
/// splat (§8.5.5, §8.5.6 Fig. 17(a)), or the splat's own normal when the leaf has no field, the
/// field misses the splat's own normal at its centre ([`FIELD_RESIDUAL_COS`]), or it turns more
/// than [`FIELD_MIN_COS`] away from it at `x` (a sharp edge, or the other side).
#[inline]
pub fn shading_normal(view: &OctreeView, splat: u32, x: Vec3) -> Vec3 {
    let s = &view.splats[splat as usize];
    let ns = Vec3::from(s.normal);
    let info = &view.node_info[view.splat_leaf[splat as usize] as usize];
    if info.normal == [0.0; 3]
        || field_normal(info, Vec3::from(s.position)).dot(ns) < FIELD_RESIDUAL_COS
    {
        return ns;
    }
    let n = field_normal(info, x);
    if n.dot(ns) < FIELD_MIN_COS {
        ns
    } else {
        n
    }
}

/// What a specular splat does to a ray or photon arriving along unit `dir` at `x`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounce {
    /// The new unit direction.
    pub dir: Vec3,
    /// The factor the throughput (or the photon's power) is multiplied by: the mirror's
    /// reflectance, the dielectric's tint when transmitted, 1 when a dielectric reflects.
    pub tint: Vec3,
    /// Whether the path was transmitted (refracted).
    pub transmitted: bool,
}

/// The specular bounce on splat `splat` of material `m` (mirror or dielectric) where its
/// shading normal is `n` ([`shading_normal`] at the hit, which the caller has for its own use
/// too): mirrors reflect and tint; dielectrics reflect with the Fresnel probability (always
/// under total internal reflection) and otherwise refract, tinted, with `u` ∈ [0, 1) the random
/// choice. The side comes from the splat's own normal (entering when `dir` opposes it), the
/// direction from `n`. WGSL twin: `specular_bounce` in shaders/common/optics.wgsl.
#[inline]
pub fn specular_bounce(
    view: &OctreeView,
    m: &MaterialRecord,
    (splat, n): (u32, Vec3),
    dir: Vec3,
    u: f32,
) -> Bounce {
    let color = Vec3::from(m.color) * Vec3::from(view.splats[splat as usize].albedo);
    let i = Interface::at(view, m, (splat, n), dir);
    if m.class == class::MIRROR {
        return Bounce {
            dir: reflect(dir, i.nf),
            tint: color,
            transmitted: false,
        };
    }
    match i.refracted {
        Some(t) if u >= i.f => Bounce {
            dir: t.normalize(),
            tint: color,
            transmitted: true,
        },
        _ => Bounce {
            dir: reflect(dir, i.nf),
            tint: Vec3::ONE,
            transmitted: false,
        },
    }
}

/// Both ways out of a dielectric at once, each weighted by its share, where
/// [`specular_bounce`] chooses one by a random number: the reflection, tinted by the Fresnel
/// reflectance `f`, and the refraction, tinted by `(1 − f)` and the dielectric's color; None
/// under total internal reflection (the only way out is the reflection, untinted, as
/// [`specular_bounce`] gives it). The renderer splits its paths here once (docs/raytrace.md,
/// "Splitting at glass"); the photon tracer keeps the random choice. `n` is the shading normal
/// at the hit, as for [`specular_bounce`]. WGSL twin: `dielectric_split` in
/// shaders/common/optics.wgsl.
#[inline]
pub fn dielectric_split(
    view: &OctreeView,
    m: &MaterialRecord,
    (splat, n): (u32, Vec3),
    dir: Vec3,
) -> Option<[Bounce; 2]> {
    let color = Vec3::from(m.color) * Vec3::from(view.splats[splat as usize].albedo);
    let i = Interface::at(view, m, (splat, n), dir);
    let t = i.refracted?;
    Some([
        Bounce {
            dir: reflect(dir, i.nf),
            tint: Vec3::splat(i.f),
            transmitted: false,
        },
        Bounce {
            dir: t.normalize(),
            tint: (1.0 - i.f) * color,
            transmitted: true,
        },
    ])
}

/// What a ray along unit `dir` meets on specular splat `splat` where its shading normal is `n`:
/// that normal facing the ray, and for a dielectric the Fresnel reflectance and the refracted
/// direction (None under total internal reflection, where the reflectance is 1). WGSL twin:
/// `interface_at`.
struct Interface {
    nf: Vec3,
    f: f32,
    refracted: Option<Vec3>,
}

impl Interface {
    #[inline]
    fn at(view: &OctreeView, m: &MaterialRecord, (splat, n): (u32, Vec3), dir: Vec3) -> Interface {
        let ns = Vec3::from(view.splats[splat as usize].normal);
        let nf = if dir.dot(n) < 0.0 { n } else { -n };
        if m.class == class::MIRROR {
            return Interface {
                nf,
                f: 1.0,
                refracted: None,
            };
        }
        let entering = dir.dot(ns) < 0.0;
        let eta = if entering { 1.0 / m.ior } else { m.ior };
        let cos_i = (-dir.dot(nf)).clamp(0.0, 1.0);
        Interface {
            nf,
            f: fresnel(cos_i, eta),
            refracted: refract(dir, nf, eta),
        }
    }
}
