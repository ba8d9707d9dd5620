//! Photon tracing (seed §8.5.4 to §8.5.7) on the CPU: the renderer's traversal
//! (`pc_tree::accel`), the normal fields and the specular bounce of `pc_tree::optics`, the Δ
//! self-hit rule, a bounce limit. A photon is stored where it first lands on the front of a
//! non-specular splat after at least one specular bounce (LS⁺D), never on specular splats.

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_artifact::photons::Photon;
use pc_tree::accel::Accel;
use pc_tree::optics::specular_bounce;
use pc_tree::rng::rand;
use pc_tree::{disk_point, OctreeView, Ray, TraversalStats};

use crate::emit::{Aim, Leaves, Source};

/// What became of a photon.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fate {
    /// Landed on a diffuse splat after ≥ 1 specular bounce.
    Stored(Photon),
    /// Its aim point was hidden: something else lay in front of it.
    Occluded,
    /// Left the scene, or reached the bounce limit.
    Lost,
    /// Hit the back of a one-sided surface.
    Absorbed,
}

/// The tracer's fixed inputs.
pub struct Tracer<'a> {
    pub view: &'a OctreeView<'a>,
    pub accel: &'a Accel,
    pub materials: &'a [MaterialRecord],
    pub leaves: &'a Leaves,
    pub max_bounces: u32,
    /// Δ in radii of the splat a photon leaves.
    pub self_hit: f32,
    pub seed: u32,
}

/// Random-number dimensions of photon `id`: 0..5 for the emission, then one per bounce.
const DIM_BOUNCE: u32 = 8;

impl Tracer<'_> {
    /// Trace photon `id`, the `k`-th of `aim`.
    pub fn photon(&self, aim: &Aim, id: u32, stats: &mut TraversalStats) -> Fate {
        let view = self.view;
        let r = |d: u32| rand(self.seed, id, 0, d);
        // Start: the light's position, or a point on an emitter splat drawn by area.
        let (origin, t_min, emitter_normal) = match aim.source {
            Source::Point(p) => (p, 0.0, None),
            Source::Area(e) => {
                let j = self.leaves.pick(view, e, r(0));
                let s = &view.splats[j as usize];
                (
                    disk_point(s, r(1), r(2)),
                    self.self_hit * s.radius,
                    Some(Vec3::from(s.normal)),
                )
            }
        };
        // Aim: a point on a splat of the target leaf, drawn by area.
        let j = self.leaves.pick(view, aim.target, r(3));
        let target = &view.splats[j as usize];
        let to = disk_point(target, r(4), r(5)) - origin;
        let dist = to.length();
        if dist <= t_min {
            return Fate::Occluded;
        }
        let dir = to / dist;
        if emitter_normal.is_some_and(|n| n.dot(dir) <= 0.0) {
            // Behind the emitting splat: it sends nothing this way.
            return Fate::Occluded;
        }
        // The first hit must be the aimed surface: overlapping disks of the same surface lie
        // within about a radius of the aim point along the ray.
        let first_min = dist - 2.0 * target.radius;
        let mut power = Vec3::from(aim.power);
        if aim.sample_geometry {
            let ce = emitter_normal.map_or(1.0, |n| n.dot(dir));
            let ct = Vec3::from(target.normal).dot(dir).abs();
            power *= ce * ct / (dist * dist + 0.1 * target.radius * target.radius);
        }
        self.trace(
            Ray {
                origin,
                dir,
                t_min,
                t_max: f32::INFINITY,
            },
            power,
            id,
            first_min,
            stats,
        )
    }

    /// Follow a photon from `ray` with `power`; hits before `first_min` on the first segment
    /// mean its aim was hidden ([`Fate::Occluded`]).
    pub fn trace(
        &self,
        mut ray: Ray,
        mut power: Vec3,
        id: u32,
        first_min: f32,
        stats: &mut TraversalStats,
    ) -> Fate {
        let view = self.view;
        let mut bounces = 0u32;
        loop {
            let Some(hit) = self.accel.intersect(view, &ray, stats) else {
                return Fate::Lost;
            };
            let s = &view.splats[hit.splat as usize];
            let m = &self.materials[s.material as usize];
            if bounces == 0 && hit.t < first_min {
                return Fate::Occluded;
            }
            let x = ray.origin + ray.dir * hit.t;
            if class::is_specular(m.class) {
                if bounces == self.max_bounces {
                    return Fate::Lost;
                }
                let u = rand(self.seed, id, 0, DIM_BOUNCE + bounces);
                let b = specular_bounce(view, m, hit.splat, x, ray.dir, u);
                power *= b.tint;
                bounces += 1;
                ray = Ray {
                    origin: x,
                    dir: b.dir,
                    t_min: self.self_hit * s.radius,
                    t_max: f32::INFINITY,
                };
                continue;
            }
            if bounces == 0 {
                // Aimed at a specular leaf, landed on a diffuse surface in front of it.
                return Fate::Occluded;
            }
            if ray.dir.dot(Vec3::from(s.normal)) >= 0.0 {
                return Fate::Absorbed;
            }
            return Fate::Stored(Photon {
                position: x.into(),
                splat: hit.splat,
                dir: ray.dir.into(),
                bounces,
                power: power.into(),
                _pad: 0,
            });
        }
    }
}
