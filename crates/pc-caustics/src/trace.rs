//! Photon tracing (seed §8.5.4 to §8.5.7) on the CPU: the renderer's traversal
//! (`pc_tree::accel`), the normal fields and the specular bounce of `pc_tree::optics`, rays that
//! pass over the rough surface they leave within its own zone (`pc_tree::Between::leaving`, the
//! V-map's rule, where the seed has its self-hit Δ), a bounce limit. A photon is stored where
//! it first lands on the front of a non-specular splat after at least one specular bounce
//! (LS⁺D), never on specular splats.

use glam::Vec3;
use pc_artifact::octree::{class, MaterialRecord};
use pc_artifact::photons::Photon;
use pc_tree::accel::Accel;
use pc_tree::between::surface;
use pc_tree::optics::{shading_normal, specular_bounce};
use pc_tree::rng::rand;
use pc_tree::{cosine_dir, disk_point, Between, OctreeView, Ray, TraversalStats};

use crate::emit::{link_weight, Aim, Leaves, Sampling, Source};

/// Whether `ray` (from its `t_min` on) can meet a disk of the node at node-pool slot `node`:
/// it passes within the node's average-disk radius of its centroid ([`NodeInfo`]), a ball that
/// holds every disk of the node (each lies within its radius of its centre, and each centre
/// within the rest of that radius of the centroid). Padded by 10⁻⁴ of the radius and 10⁻⁵ of
/// the distance, far above the rounding of this test and of the walk's hit points. A path
/// drawn by direction toward a link's node that misses the ball cannot first land on the node:
/// most do (85 % of them on the 1M bench box), and each walk they skip is one across the
/// scene. WGSL twin: `may_meet`, shaders/caustics/photons.wgsl.
///
/// [`NodeInfo`]: pc_artifact::octree::NodeInfo
pub fn may_meet(view: &OctreeView, node: u32, ray: &Ray) -> bool {
    let info = &view.node_info[node as usize];
    let to = Vec3::from(info.centroid) - ray.origin;
    let reach = info.disk_radius * (1.0 + 1e-4) + to.length() * 1e-5;
    // The ray's point nearest the centroid, not before t_min.
    let t = to.dot(ray.dir).max(ray.t_min);
    (to - ray.dir * t).length_squared() <= reach * reach
}

/// What a photon's first hit must be.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum First {
    /// At least this far: a nearer hit hid the aim point.
    Beyond(f32),
    /// A specular splat of the data-pool range `[lo, hi)`; the photon's power is then scaled by
    /// [`link_weight`]`(cos_s, |cos θ| at the hit, the hit's distance, k)`.
    Within {
        lo: u32,
        hi: u32,
        cos_s: f32,
        k: f32,
    },
}

/// What became of a photon.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fate {
    /// Landed on a diffuse splat after ≥ 1 specular bounce.
    Stored(Photon),
    /// Its aim point was hidden: something else lay in front of it. A path drawn by direction
    /// that did not first land on its target node, whether it met something else or nothing.
    Occluded,
    /// Left the scene, or reached the bounce limit.
    Lost,
    /// Hit the back of a one-sided surface.
    Absorbed,
}

/// A photon between two walks ([`Tracer::start`], [`Tracer::step`]).
#[derive(Clone, Copy, Debug)]
pub struct InFlight {
    /// Its next walk.
    pub ray: Ray,
    /// The splat it leaves (a data-pool index), whose own zone the walk passes over.
    pub leaving: Option<u32>,
    pub power: Vec3,
    pub id: u32,
    /// Specular bounces so far.
    pub bounces: u32,
    /// What its first hit must be (read at bounce 0).
    pub first: First,
}

/// What one walk made of a photon.
#[derive(Clone, Copy, Debug)]
pub enum Step {
    Done(Fate),
    Next(InFlight),
}

/// The tracer's fixed inputs.
pub struct Tracer<'a> {
    pub view: &'a OctreeView<'a>,
    pub accel: &'a Accel<'a>,
    pub materials: &'a [MaterialRecord],
    pub leaves: &'a Leaves,
    pub max_bounces: u32,
    /// Each octree leaf's roughness ([`pc_tree::between::leaf_roughness`]): the own zone of a
    /// ray leaving a splat.
    pub rough: &'a [f32],
    pub seed: u32,
}

pub use pc_tree::between::LEAVE_EPS;

/// Random-number dimensions of photon `id`: 0..5 for the emission, then one per bounce.
const DIM_BOUNCE: u32 = 8;

impl Tracer<'_> {
    /// Trace photon `id`, the `k`-th of `aim`: [`Self::start`], then [`Self::step`] until
    /// it ends.
    pub fn photon(&self, aim: &Aim, id: u32, stats: &mut TraversalStats) -> Fate {
        let mut f = match self.start(aim, id) {
            Ok(f) => f,
            Err(fate) => return fate,
        };
        loop {
            match self.step(f, stats) {
                Step::Done(fate) => return fate,
                Step::Next(next) => f = next,
            }
        }
    }

    /// Photon `id` of `aim` before its first walk: where it starts, which way, with what power
    /// and what its first hit must be; or its fate where it ends without a walk.
    pub fn start(&self, aim: &Aim, id: u32) -> Result<InFlight, Fate> {
        let view = self.view;
        let r = |d: u32| rand(self.seed, id, 0, d);
        // Start: the light's position, or a point on an emitter splat drawn by area.
        let (origin, radius, emitter) = match aim.source {
            Source::Point(p) => (p, 0.0, None),
            Source::Area(e) => {
                let j = self.leaves.pick(view, e, r(0));
                let s = &view.splats[j as usize];
                (disk_point(s, r(1), r(2)), s.radius, Some(j))
            }
        };
        let emitter_normal = emitter.map(|j| Vec3::from(view.splats[j as usize].normal));
        let t_min = LEAVE_EPS * radius;
        let (dir, first, power) = match aim.sampling {
            Sampling::Direction { k, lo, hi, node } => {
                // A direction by cosine about the source splat; its first hit decides. (The
                // links give this strategy area sources only.)
                let Some(n) = emitter_normal else {
                    return Err(Fate::Lost);
                };
                let dir = cosine_dir(n.into(), r(3), r(4));
                let ray = Ray {
                    origin,
                    dir,
                    t_min,
                    t_max: f32::INFINITY,
                };
                if !may_meet(view, node, &ray) {
                    // Its first hit cannot be the node's: what the walk would conclude.
                    return Err(Fate::Occluded);
                }
                let cos_s = n.dot(dir);
                let first = First::Within { lo, hi, cos_s, k };
                (dir, first, Vec3::from(aim.power))
            }
            Sampling::Whole | Sampling::Area { .. } => {
                // Aim: a point on a splat of the target leaf, drawn by area.
                let j = self.leaves.pick(view, aim.target, r(3));
                let target = &view.splats[j as usize];
                let to = disk_point(target, r(4), r(5)) - origin;
                let dist = to.length();
                if dist <= t_min {
                    return Err(Fate::Occluded);
                }
                let dir = to / dist;
                if emitter_normal.is_some_and(|n| n.dot(dir) <= 0.0) {
                    // Behind the emitting splat: it sends nothing this way.
                    return Err(Fate::Occluded);
                }
                let mut power = Vec3::from(aim.power);
                if let Sampling::Area { k } = aim.sampling {
                    let cos_s = emitter_normal.map_or(1.0, |n| n.dot(dir));
                    let cos_t = Vec3::from(target.normal).dot(dir).abs();
                    power *= link_weight(cos_s, cos_t, dist, k);
                }
                // The first hit must be the aimed surface: overlapping disks of the same
                // surface lie within about a radius of the aim point along the ray.
                (dir, First::Beyond(dist - 2.0 * target.radius), power)
            }
        };
        Ok(InFlight {
            ray: Ray {
                origin,
                dir,
                t_min,
                t_max: f32::INFINITY,
            },
            leaving: emitter,
            power,
            id,
            bounces: 0,
            first,
        })
    }

    /// One walk of photon `f` and what it makes of it: its fate, or the photon after one more
    /// specular bounce. The walk leaves the splat `f.leaving` (a data-pool index) if any, past
    /// its own zone ([`Between::leaving`]); a first hit that breaks `f.first` drops it
    /// ([`Fate::Occluded`]).
    pub fn step(&self, f: InFlight, stats: &mut TraversalStats) -> Step {
        let view = self.view;
        let InFlight {
            ray,
            leaving,
            mut power,
            id,
            bounces,
            first,
        } = f;
        let found = match leaving {
            Some(j) => {
                let seg = Between::leaving(ray, surface(view, self.rough, j));
                self.accel.intersect_between(view, &seg, stats)
            }
            None => self.accel.intersect(view, &ray, stats),
        };
        let Some(hit) = found else {
            // A path drawn by direction that meets nothing missed its target, as one that
            // meets something else first did ([`may_meet`] tells them apart no better).
            return Step::Done(match (bounces, first) {
                (0, First::Within { .. }) => Fate::Occluded,
                _ => Fate::Lost,
            });
        };
        let s = &view.splats[hit.splat as usize];
        let m = &self.materials[s.material as usize];
        let specular = class::is_specular(m.class);
        if bounces == 0 {
            match first {
                First::Beyond(t) if hit.t < t => return Step::Done(Fate::Occluded),
                First::Beyond(_) => {}
                First::Within { lo, hi, cos_s, k } => {
                    if hit.splat < lo || hit.splat >= hi || !specular {
                        return Step::Done(Fate::Occluded);
                    }
                    let cos_t = ray.dir.dot(Vec3::from(s.normal)).abs();
                    power *= link_weight(cos_s, cos_t, hit.t, k);
                }
            }
        }
        let x = ray.origin + ray.dir * hit.t;
        if specular {
            if bounces == self.max_bounces {
                return Step::Done(Fate::Lost);
            }
            let u = rand(self.seed, id, 0, DIM_BOUNCE + bounces);
            let n = shading_normal(view, hit.splat, x);
            let b = specular_bounce(view, m, (hit.splat, n), ray.dir, u);
            return Step::Next(InFlight {
                ray: Ray {
                    origin: x,
                    dir: b.dir,
                    t_min: LEAVE_EPS * s.radius,
                    t_max: f32::INFINITY,
                },
                leaving: Some(hit.splat),
                power: power * b.tint,
                id,
                bounces: bounces + 1,
                first,
            });
        }
        if bounces == 0 {
            // Aimed at a specular leaf, landed on a diffuse surface in front of it.
            return Step::Done(Fate::Occluded);
        }
        if ray.dir.dot(Vec3::from(s.normal)) >= 0.0 {
            return Step::Done(Fate::Absorbed);
        }
        Step::Done(Fate::Stored(Photon {
            position: x.into(),
            splat: hit.splat,
            dir: ray.dir.into(),
            bounces,
            power: power.into(),
            _pad: 0,
        }))
    }
}
