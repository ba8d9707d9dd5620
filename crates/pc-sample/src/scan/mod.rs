//! A virtual terrestrial laser scanner: several stations in [`room::Room::hall`], each casting
//! rays on an even grid of azimuth and elevation, and recording what a scanner records where a
//! ray hits: the point (with range noise), the surface's color (with a little texture), an
//! intensity, a LAS class, and which station saw it. Points exist only where a ray hit, their
//! density falls with distance (fixed angular steps), and what a station cannot see is missing
//! (occlusion shadows behind the columns and the figure).
//!
//! Any count (1 to 1e9 points): each station's grid is sized from a pilot pass so that it holds
//! at least its share of hits, the hits are counted row by row, and exactly the share is kept
//! by thinning evenly. Rows are traced in parallel; each draws its noise from its own PCG
//! stream (seed, station, row), so the output does not depend on the threads. Points are
//! generated in batches of rows and handed to the writer in order ([`write`](mod@write): LAS, LAZ, E57):
//! memory stays small whatever the count. docs/scan.md.

pub mod room;
pub mod write;

pub use write::{write_scan, ScanFormat};

use glam::{DQuat, DVec3, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;
use rayon::prelude::*;

use room::Room;

/// Lowest elevation a station scans (its tripod hides the rest), radians.
const MIN_ELEVATION: f64 = -55.0 * std::f64::consts::PI / 180.0;
/// Highest elevation (straight up).
const MAX_ELEVATION: f64 = std::f64::consts::FRAC_PI_2;
/// Rows traced per batch.
const BATCH_ROWS: usize = 64;

/// One scanner position: where it stands (scene frame) and how it is turned about z.
#[derive(Clone, Copy, Debug)]
pub struct Station {
    pub position: Vec3,
    /// Rotation about z of the scanner's own frame, radians (its azimuth zero).
    pub yaw: f64,
}

impl Station {
    /// The scanner's own frame to the scene frame (E57 stores points in it, with this pose).
    pub fn rotation(&self) -> DQuat {
        DQuat::from_rotation_z(self.yaw)
    }
}

/// What the virtual scanner does.
#[derive(Clone, Debug)]
pub struct ScanParams {
    /// Points in all, split evenly between the stations.
    pub points: u64,
    pub stations: Vec<Station>,
    pub seed: u64,
    /// Range noise: standard deviation at zero range (m) and growth per metre of range.
    pub noise: f64,
    pub noise_per_metre: f64,
    /// Where the scene frame's origin lies in the (georeferenced) frame written to the files.
    pub georef: DVec3,
}

impl ScanParams {
    /// Three stations around the hall, 1.5 m up, turned differently, millimetre noise, a
    /// georeference in UTM-like metres.
    pub fn hall(points: u64, seed: u64) -> ScanParams {
        let station = |x, y, yaw: f64| Station {
            position: Vec3::new(x, y, 1.5),
            yaw: yaw.to_radians(),
        };
        ScanParams {
            points,
            stations: vec![
                station(-3.4, -2.6, 20.0),
                station(3.6, -0.2, -75.0),
                station(-0.6, 2.4, 140.0),
            ],
            seed,
            noise: 0.002,
            noise_per_metre: 0.0002,
            georef: DVec3::new(512_000.0, 5_403_000.0, 212.0),
        }
    }

    /// The share of the points that station `s` keeps.
    fn share(&self, s: usize) -> u64 {
        let n = self.stations.len() as u64;
        self.points / n + u64::from((s as u64) < self.points % n)
    }
}

/// One recorded point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanPoint {
    /// Scene frame (add `georef` for the files' frame).
    pub position: Vec3,
    /// In the station's own frame: range (m), azimuth and elevation (radians).
    pub range: f64,
    pub azimuth: f64,
    pub elevation: f64,
    /// sRGB, 8-bit.
    pub color: [u8; 3],
    /// Return intensity, 16-bit.
    pub intensity: u16,
    pub class: u8,
    pub station: u16,
}

/// The angular grid of one station.
#[derive(Clone, Copy, Debug)]
struct Grid {
    azimuths: usize,
    rows: usize,
}

impl Grid {
    /// An even grid of about `rays` rays.
    fn with_rays(rays: f64) -> Grid {
        let span = MAX_ELEVATION - MIN_ELEVATION;
        let step = (2.0 * std::f64::consts::PI * span / rays.max(1.0)).sqrt();
        Grid {
            azimuths: ((2.0 * std::f64::consts::PI / step).round() as usize).max(4),
            rows: ((span / step).round() as usize).max(2),
        }
    }

    fn rays(&self) -> f64 {
        (self.azimuths * self.rows) as f64
    }

    /// Azimuth and elevation of ray `(row, col)`, at the cell centres.
    fn angles(&self, row: usize, col: usize) -> (f64, f64) {
        let az = (col as f64 + 0.5) / self.azimuths as f64 * 2.0 * std::f64::consts::PI;
        let el =
            MIN_ELEVATION + (row as f64 + 0.5) / self.rows as f64 * (MAX_ELEVATION - MIN_ELEVATION);
        (az, el)
    }
}

/// The unit direction of (azimuth, elevation) in the station's frame.
fn direction(az: f64, el: f64) -> DVec3 {
    DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin())
}

/// Scans `room` from station `s` of `p`, handing its points to `sink` in order, a batch of
/// rows at a time. Returns the number of points (the station's share of `p.points`).
pub fn scan_station(
    room: &Room,
    p: &ScanParams,
    s: usize,
    sink: &mut dyn FnMut(&[ScanPoint]) -> std::io::Result<()>,
) -> std::io::Result<u64> {
    let station = &p.stations[s];
    let share = p.share(s);
    let grid = grid_for(room, station, share);
    let counts: Vec<u64> = (0..grid.rows)
        .into_par_iter()
        .map(|row| row_hits(room, station, &grid, row))
        .collect();
    let hits: u64 = counts.iter().sum();
    let mut total = 0;
    let mut first = 0u64; // the index among the station's hits of each row's first
    let mut rows = 0..grid.rows;
    while rows.start < grid.rows {
        let batch: Vec<usize> = rows.by_ref().take(BATCH_ROWS).collect();
        let starts: Vec<u64> = batch
            .iter()
            .map(|&r| {
                let f = first;
                first += counts[r];
                f
            })
            .collect();
        let points: Vec<Vec<ScanPoint>> = batch
            .par_iter()
            .zip(starts.par_iter())
            .map(|(&row, &start)| row_points(room, p, s, &grid, row, start, hits, share))
            .collect();
        for row in &points {
            sink(row)?;
            total += row.len() as u64;
        }
    }
    Ok(total)
}

/// A grid that holds at least `share` hits from `station`: sized from a pilot grid's hit
/// fraction, grown until the count is reached.
fn grid_for(room: &Room, station: &Station, share: u64) -> Grid {
    let pilot = Grid::with_rays(20_000.0);
    let pilot_hits: u64 = (0..pilot.rows)
        .map(|r| row_hits(room, station, &pilot, r))
        .sum();
    let fraction = (pilot_hits as f64 / pilot.rays()).max(0.05);
    let mut rays = share as f64 / fraction * 1.02 + 64.0;
    loop {
        let grid = Grid::with_rays(rays);
        let hits: u64 = (0..grid.rows)
            .into_par_iter()
            .map(|r| row_hits(room, station, &grid, r))
            .sum();
        if hits >= share {
            return grid;
        }
        rays *= 1.05 * share as f64 / hits.max(1) as f64;
    }
}

/// The ray of `(row, col)` in the scene frame.
fn ray(station: &Station, grid: &Grid, row: usize, col: usize) -> (f64, f64, Vec3) {
    let (az, el) = grid.angles(row, col);
    let d = station.rotation() * direction(az, el);
    (az, el, d.as_vec3())
}

/// How many rays of `row` hit something.
fn row_hits(room: &Room, station: &Station, grid: &Grid, row: usize) -> u64 {
    (0..grid.azimuths)
        .filter(|&col| {
            room.trace(station.position, ray(station, grid, row, col).2)
                .is_some()
        })
        .count() as u64
}

/// The points of one row that the even thinning keeps: the station's hit `j` (of `hits`) is
/// kept when `floor((j + 1) share / hits)` steps past `floor(j share / hits)`.
#[allow(clippy::too_many_arguments)]
fn row_points(
    room: &Room,
    p: &ScanParams,
    s: usize,
    grid: &Grid,
    row: usize,
    first: u64,
    hits: u64,
    share: u64,
) -> Vec<ScanPoint> {
    let station = &p.stations[s];
    let mut rng =
        Pcg32::seed_from_u64(p.seed ^ ((s as u64) << 40) ^ (row as u64).wrapping_mul(0x9E37_79B9));
    let keeps = |j: u64| {
        let a = u128::from(j) * u128::from(share) / u128::from(hits);
        let b = u128::from(j + 1) * u128::from(share) / u128::from(hits);
        b > a
    };
    let mut out = Vec::new();
    let mut j = first;
    for col in 0..grid.azimuths {
        let (az, el, d) = ray(station, grid, row, col);
        let Some(hit) = room.trace(station.position, d) else {
            continue;
        };
        // Noise is drawn for every hit, kept or not, so that thinning does not shift it.
        let gauss = standard_normal(&mut rng);
        let texture: f32 = rng.random_range(0.94..1.06);
        let keep = keeps(j);
        j += 1;
        if !keep {
            continue;
        }
        let surface = &room.surfaces[hit.surface];
        let range = f64::from(hit.t) + gauss * (p.noise + p.noise_per_metre * f64::from(hit.t));
        let position = station.position + d * range as f32;
        let color = surface
            .color
            .map(|c| (f32::from(c) * texture).round().clamp(0.0, 255.0) as u8);
        let cos = hit.normal.dot(-d).clamp(0.0, 1.0);
        let lum = color.iter().map(|&c| f32::from(c)).sum::<f32>() / (3.0 * 255.0);
        let falloff = 1.0 / (1.0 + 0.02 * hit.t * hit.t);
        let intensity = (65535.0 * (0.15 + 0.85 * lum * cos) * falloff).round() as u16;
        out.push(ScanPoint {
            position,
            range,
            azimuth: az,
            elevation: el,
            color,
            intensity,
            class: surface.class,
            station: s as u16,
        });
    }
    out
}

/// A standard normal deviate (Box–Muller).
fn standard_normal(rng: &mut Pcg32) -> f64 {
    let u: f64 = rng.random_range(f64::EPSILON..1.0);
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every point of every station, in order.
    fn collect(room: &Room, p: &ScanParams) -> Vec<ScanPoint> {
        let mut all = Vec::new();
        for s in 0..p.stations.len() {
            let n = scan_station(room, p, s, &mut |pts| {
                all.extend_from_slice(pts);
                Ok(())
            })
            .unwrap();
            assert_eq!(n, p.share(s));
        }
        all
    }

    #[test]
    fn exactly_the_requested_points_on_the_surfaces_seen() {
        let room = Room::hall();
        for n in [1u64, 1000, 30_001] {
            let p = ScanParams::hall(n, 3);
            let points = collect(&room, &p);
            assert_eq!(points.len() as u64, n);
            for q in &points {
                let st = &p.stations[q.station as usize];
                // On the ray of its angles, at its range.
                let d = (st.rotation() * direction(q.azimuth, q.elevation)).as_vec3();
                let at = st.position + d * q.range as f32;
                assert!((at - q.position).length() < 1e-4);
                // Near the surface the noiseless ray hits (range noise: mm).
                let hit = room.trace(st.position, d).unwrap();
                assert!(
                    (hit.t as f64 - q.range).abs() < 0.03,
                    "{} {}",
                    hit.t,
                    q.range
                );
            }
        }
    }

    #[test]
    fn the_scan_does_not_depend_on_the_threads() {
        let room = Room::hall();
        let p = ScanParams::hall(20_000, 9);
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| collect(&room, &p))
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn density_falls_with_distance_and_columns_cast_shadows() {
        let room = Room::hall();
        let p = ScanParams::hall(60_000, 1);
        let points = collect(&room, &p);
        // Station 0's floor points: more per square metre near it than far away.
        let st = p.stations[0].position;
        let floor: Vec<Vec3> = points
            .iter()
            .filter(|q| q.station == 0 && q.class == 2)
            .map(|q| q.position)
            .collect();
        let near = floor
            .iter()
            .filter(|q| (q.truncate() - st.truncate()).length() < 2.0)
            .count() as f32
            / (std::f32::consts::PI * 4.0);
        let ring = floor
            .iter()
            .filter(|q| (4.0..5.0).contains(&(q.truncate() - st.truncate()).length()))
            .count() as f32
            / (std::f32::consts::PI * (25.0 - 16.0));
        assert!(near > 3.0 * ring, "near {near} far {ring}");
        // Behind the column nearest to station 0, seen from it: a shadow on the floor.
        let col = glam::Vec2::new(-2.5, -1.8);
        let away = (col - st.truncate()).normalize();
        let behind = col + away * 0.8;
        let in_shadow = floor
            .iter()
            .filter(|q| (q.truncate() - behind).length() < 0.15)
            .count();
        assert_eq!(in_shadow, 0);
    }
}
