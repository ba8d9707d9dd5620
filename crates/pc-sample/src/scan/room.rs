//! The interior the virtual scanner scans: a grotto-like hall (z up, metres) with a skylight
//! (the opening for light), four columns, and a niche in the back wall holding a statue-like
//! figure on a pedestal. Surfaces are analytic, so a ray's first hit is exact.

use glam::{Vec2, Vec3};

/// One analytic surface, seen from both sides.
#[derive(Clone, Debug)]
pub enum Prim {
    /// The parallelogram `o + s u + t v`, `s, t` in [0, 1], less its holes (`[s0, s1, t0, t1]`).
    Rect {
        o: Vec3,
        u: Vec3,
        v: Vec3,
        holes: Vec<[f32; 4]>,
    },
    /// The side of an upright cylinder (axis along z).
    Cylinder {
        c: Vec2,
        r: f32,
        z0: f32,
        z1: f32,
    },
    Sphere {
        c: Vec3,
        r: f32,
    },
}

/// A surface with what a scanner records of it.
#[derive(Clone, Debug)]
pub struct Surface {
    pub prim: Prim,
    /// sRGB color, 8-bit.
    pub color: [u8; 3],
    /// LAS classification code (2 ground, 6 building, 1 unclassified).
    pub class: u8,
}

/// The first surface a ray meets.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    pub surface: usize,
    /// The unit normal facing the ray's origin.
    pub normal: Vec3,
}

/// Rays closer than this to their origin do not hit (metres).
const T_MIN: f32 = 1e-3;

impl Prim {
    /// The distance along `d` (unit) from `p` to this surface, and its normal there.
    pub fn intersect(&self, p: Vec3, d: Vec3) -> Option<(f32, Vec3)> {
        match self {
            Prim::Rect { o, u, v, holes } => {
                let n = u.cross(*v).normalize();
                let den = d.dot(n);
                if den.abs() < 1e-9 {
                    return None;
                }
                let t = (*o - p).dot(n) / den;
                if t <= T_MIN {
                    return None;
                }
                let q = p + d * t - *o;
                let s = q.dot(*u) / u.length_squared();
                let w = q.dot(*v) / v.length_squared();
                let inside = |a: f32| (0.0..=1.0).contains(&a);
                let in_hole = holes
                    .iter()
                    .any(|h| s > h[0] && s < h[1] && w > h[2] && w < h[3]);
                (inside(s) && inside(w) && !in_hole).then_some((t, n))
            }
            Prim::Cylinder { c, r, z0, z1 } => {
                let o = Vec2::new(p.x, p.y) - *c;
                let dd = Vec2::new(d.x, d.y);
                let a = dd.length_squared();
                if a < 1e-12 {
                    return None;
                }
                let b = o.dot(dd);
                let disc = b * b - a * (o.length_squared() - r * r);
                if disc < 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                [(-b - sq) / a, (-b + sq) / a]
                    .into_iter()
                    .filter(|&t| t > T_MIN)
                    .find(|&t| (*z0..=*z1).contains(&(p.z + d.z * t)))
                    .map(|t| {
                        let q = o + dd * t;
                        (t, Vec3::new(q.x, q.y, 0.0) / *r)
                    })
            }
            Prim::Sphere { c, r } => {
                let o = p - *c;
                let b = o.dot(d);
                let disc = b * b - (o.length_squared() - r * r);
                if disc < 0.0 {
                    return None;
                }
                let sq = disc.sqrt();
                [-b - sq, -b + sq]
                    .into_iter()
                    .find(|&t| t > T_MIN)
                    .map(|t| (t, (o + d * t) / *r))
            }
        }
    }
}

/// The scanned interior.
#[derive(Clone, Debug)]
pub struct Room {
    pub surfaces: Vec<Surface>,
}

impl Room {
    /// The first hit of the ray from `p` along the unit `d`, if it meets anything (rays leaving
    /// through the skylight meet nothing).
    pub fn trace(&self, p: Vec3, d: Vec3) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        for (i, s) in self.surfaces.iter().enumerate() {
            if let Some((t, n)) = s.prim.intersect(p, d) {
                if best.is_none_or(|b| t < b.t) {
                    let normal = if n.dot(d) > 0.0 { -n } else { n };
                    best = Some(Hit {
                        t,
                        surface: i,
                        normal,
                    });
                }
            }
        }
        best
    }

    /// The hall: 10 × 8 × 4 m, floor at z = 0, centred on the z axis.
    pub fn hall() -> Room {
        let mut s = Vec::new();
        shell(&mut s);
        niche(&mut s);
        columns(&mut s);
        figure(&mut s);
        Room { surfaces: s }
    }
}

/// Half extents of the hall and its height (m).
const HALL: (f32, f32, f32) = (5.0, 4.0, 4.0);
/// The niche's opening in the back wall: bottom and top (z), and its depth (m).
const NICHE_Z: (f32, f32) = (0.5, 2.5);
const NICHE_DEPTH: f32 = 0.8;

/// sRGB colors of the surfaces.
mod color {
    pub const FLOOR: [u8; 3] = [178, 158, 128];
    pub const WALL: [u8; 3] = [206, 194, 172];
    pub const CEILING: [u8; 3] = [190, 182, 166];
    pub const COLUMN: [u8; 3] = [222, 216, 204];
    pub const NICHE: [u8; 3] = [164, 68, 52];
    pub const PEDESTAL: [u8; 3] = [118, 118, 124];
    pub const FIGURE: [u8; 3] = [88, 132, 104];
}

/// A rectangle `o + s u + t v` with holes, as a surface of `color` and LAS `class`.
fn rect(o: Vec3, u: Vec3, v: Vec3, holes: Vec<[f32; 4]>, color: [u8; 3], class: u8) -> Surface {
    Surface {
        prim: Prim::Rect { o, u, v, holes },
        color,
        class,
    }
}

/// Floor, walls, and the ceiling with its 2 × 1.5 m skylight (x in [0.5, 2.5], y in
/// [-0.75, 0.75]); the back wall (y = +4) has the niche's opening (x in [-1, 1]).
fn shell(s: &mut Vec<Surface>) {
    let (x, y, h) = HALL;
    let (dx, dy) = (Vec3::X * 2.0 * x, Vec3::Y * 2.0 * y);
    let sky = [
        (0.5 + x) / (2.0 * x),
        (2.5 + x) / (2.0 * x),
        (y - 0.75) / (2.0 * y),
        (y + 0.75) / (2.0 * y),
    ];
    let opening = [
        (x - 1.0) / (2.0 * x),
        (x + 1.0) / (2.0 * x),
        NICHE_Z.0 / h,
        NICHE_Z.1 / h,
    ];
    let corner = Vec3::new(-x, -y, 0.0);
    s.push(rect(corner, dx, dy, vec![], color::FLOOR, 2));
    s.push(rect(
        corner + Vec3::Z * h,
        dx,
        dy,
        vec![sky],
        color::CEILING,
        6,
    ));
    s.push(rect(
        Vec3::new(-x, y, 0.0),
        dx,
        Vec3::Z * h,
        vec![opening],
        color::WALL,
        6,
    ));
    s.push(rect(corner, dx, Vec3::Z * h, vec![], color::WALL, 6));
    s.push(rect(corner, dy, Vec3::Z * h, vec![], color::WALL, 6));
    s.push(rect(
        Vec3::new(x, -y, 0.0),
        dy,
        Vec3::Z * h,
        vec![],
        color::WALL,
        6,
    ));
}

/// The niche behind the back wall: 2 m wide, 2 m high, 0.8 m deep.
fn niche(s: &mut Vec<Surface>) {
    let (y, (n0, n1), d) = (HALL.1, NICHE_Z, NICHE_DEPTH);
    let (w, up, deep) = (Vec3::X * 2.0, Vec3::Z * (n1 - n0), Vec3::Y * d);
    for (o, u, v) in [
        (Vec3::new(-1.0, y + d, n0), w, up),
        (Vec3::new(-1.0, y, n0), deep, up),
        (Vec3::new(1.0, y, n0), deep, up),
        (Vec3::new(-1.0, y, n0), w, deep),
        (Vec3::new(-1.0, y, n1), w, deep),
    ] {
        s.push(rect(o, u, v, vec![], color::NICHE, 6));
    }
}

/// Four columns of radius 0.3 m, floor to ceiling.
fn columns(s: &mut Vec<Surface>) {
    for (cx, cy) in [(-2.5, -1.8), (2.5, -1.8), (-2.5, 1.8), (2.5, 1.8)] {
        let prim = Prim::Cylinder {
            c: Vec2::new(cx, cy),
            r: 0.3,
            z0: 0.0,
            z1: HALL.2,
        };
        s.push(Surface {
            prim,
            color: color::COLUMN,
            class: 6,
        });
    }
}

/// The figure in the niche: a pedestal (top and three sides), a body, a head.
fn figure(s: &mut Vec<Surface>) {
    let (y, n0) = (HALL.1, NICHE_Z.0);
    let (px, py0, py1, pz) = (0.4f32, y + 0.1, y + 0.65, n0 + 0.6);
    let (wide, deep, high) = (
        Vec3::X * 2.0 * px,
        Vec3::Y * (py1 - py0),
        Vec3::Z * (pz - n0),
    );
    for (o, u, v) in [
        (Vec3::new(-px, py0, pz), wide, deep),
        (Vec3::new(-px, py0, n0), wide, high),
        (Vec3::new(-px, py0, n0), deep, high),
        (Vec3::new(px, py0, n0), deep, high),
    ] {
        s.push(rect(o, u, v, vec![], color::PEDESTAL, 1));
    }
    let cy = (py0 + py1) / 2.0;
    let body = Prim::Cylinder {
        c: Vec2::new(0.0, cy),
        r: 0.2,
        z0: pz,
        z1: pz + 0.75,
    };
    let head = Prim::Sphere {
        c: Vec3::new(0.0, cy, pz + 0.95),
        r: 0.18,
    };
    for prim in [body, head] {
        s.push(Surface {
            prim,
            color: color::FIGURE,
            class: 1,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rays_hit_the_nearest_surface_and_leave_through_the_skylight() {
        let room = Room::hall();
        let p = Vec3::new(0.0, -2.0, 1.5);
        // Straight down: the floor, 1.5 m away, normal up.
        let h = room.trace(p, -Vec3::Z).unwrap();
        assert!((h.t - 1.5).abs() < 1e-5 && h.normal.z > 0.99);
        // Toward a column's axis: its surface, 0.3 m before the axis.
        let c = Vec3::new(-2.5, -1.8, 1.5);
        let h = room.trace(p, (c - p).normalize()).unwrap();
        assert!((h.t - ((c - p).length() - 0.3)).abs() < 1e-4, "{}", h.t);
        // Up through the skylight's centre: nothing.
        let sky = Vec3::new(1.5, 0.0, 4.0);
        assert!(room.trace(p, (sky - p).normalize()).is_none());
        // Into the niche: its back wall at y = 4.8, past the head.
        let h = room.trace(Vec3::new(0.8, 0.0, 2.3), Vec3::Y).unwrap();
        assert!((h.t - 4.8).abs() < 1e-4, "{}", h.t);
    }
}
