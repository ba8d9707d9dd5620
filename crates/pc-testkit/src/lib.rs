//! Test scenes shared by the stage crates' tests: splats in structure-of-arrays form, sampled as
//! jittered grids on rectangles and boxes or as Fibonacci spheres. Deterministic for a given RNG.
//! It depends on nothing of pcgi, so even pc-octree's own tests can use it.

pub mod material;

use glam::Vec3;
use rand::Rng;
use rand_pcg::Pcg64;

/// Splats: positions, unit normals, radii, material indices.
#[derive(Default, Clone, Debug)]
pub struct Soa {
    pub p: Vec<Vec3>,
    pub n: Vec<Vec3>,
    pub r: Vec<f32>,
    pub m: Vec<u32>,
}

impl Soa {
    pub fn len(&self) -> usize {
        self.p.len()
    }

    pub fn is_empty(&self) -> bool {
        self.p.is_empty()
    }

    pub fn push(&mut self, p: Vec3, n: Vec3, r: f32, m: u32) {
        self.p.push(p);
        self.n.push(n);
        self.r.push(r);
        self.m.push(m);
    }

    /// Per-splat color factors of one (what the build wants when the material decides).
    pub fn ones(&self) -> Vec<Vec3> {
        vec![Vec3::ONE; self.p.len()]
    }

    /// Jittered grid on the rectangle c + a·u + b·v, a, b ∈ [-1, 1]: spacing ≈ h, radius h,
    /// normal u × v, jitter ±0.2 of a cell.
    pub fn rect(&mut self, c: Vec3, u: Vec3, v: Vec3, h: f32, m: u32, rng: &mut Pcg64) {
        let nu = (2.0 * u.length() / h).round().max(1.0) as i32;
        let nv = (2.0 * v.length() / h).round().max(1.0) as i32;
        let n = u.cross(v).normalize();
        for i in 0..nu {
            for j in 0..nv {
                let a = -1.0 + (i as f32 + 0.5 + rng.random_range(-0.2..0.2)) * 2.0 / nu as f32;
                let b = -1.0 + (j as f32 + 0.5 + rng.random_range(-0.2..0.2)) * 2.0 / nv as f32;
                self.push(c + u * a + v * b, n, h, m);
            }
        }
    }

    /// Axis-aligned box with outward faces.
    pub fn cube(&mut self, c: Vec3, half: Vec3, h: f32, m: u32, rng: &mut Pcg64) {
        let (x, y, z) = (Vec3::X * half.x, Vec3::Y * half.y, Vec3::Z * half.z);
        self.rect(c + x, y, z, h, m, rng);
        self.rect(c - x, z, y, h, m, rng);
        self.rect(c + y, z, x, h, m, rng);
        self.rect(c - y, x, z, h, m, rng);
        self.rect(c + z, x, y, h, m, rng);
        self.rect(c - z, y, x, h, m, rng);
    }

    /// Fibonacci sphere of `count` splats, outward normals, radius chosen so disks overlap.
    pub fn sphere(&mut self, c: Vec3, radius: f32, count: usize, m: u32) {
        let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
        let h = (4.0 * std::f32::consts::PI * radius * radius / count as f32).sqrt();
        for k in 0..count {
            let z = 1.0 - 2.0 * (k as f32 + 0.5) / count as f32;
            let rho = (1.0 - z * z).sqrt();
            let a = k as f32 * golden;
            let n = Vec3::new(rho * a.cos(), rho * a.sin(), z);
            self.push(c + n * radius, n, h, m);
        }
    }
}
