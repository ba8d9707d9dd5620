//! Wider neighbourhoods for noisy normals ([`widen`]): a fit is widened until its tilt error
//! meets the tolerance, and kept while it stays as flat as the noise around it.
//! docs/import.md, "Noise: wider neighbourhoods".

use glam::Vec3;
use rayon::prelude::*;

use super::Fit;
use crate::knn::Knn;

/// A widened neighbourhood's radius, in the `k`-th neighbour's distances: at least the first,
/// at most the second.
const WIDEN_RADIUS: (f32, f32) = (2.0, 4.0);
/// A wider fit is kept only while the variance across its plane stays within this factor of
/// the noise of the narrower fits around it: range noise does not grow with the radius, a
/// crease or a curve does. Not 1: the narrower fits underestimate the noise (the thinnest
/// direction of a few points), and on the 20M hall scan's flat faces the ratio runs from 1 to
/// 3, median 1.6 (docs/import.md, "Noise: wider neighbourhoods"); the crease test bounds it
/// from above.
const WIDEN_FLAT: f32 = 2.5;
/// A wider fit is also kept where it is at most this many times as thick (in variance) as the
/// same ball at half its radius: range noise does not grow with the radius. Where the noise is
/// deeper than the k nearest are wide (the 20M hall scan's zeniths: 2.5 mm of noise, the 16
/// nearest within 4.6 mm), the narrower fits are thinner than the noise by chance and the
/// test against their noise refused every wider fit (3.7 times their variance at 4 k-th
/// distances, 1.3 times the half ball's).
const WIDEN_GROWTH: f32 = 2.0;
/// Where a wider fit's half ball lay within the noise's depth, the fit is tried once more in a
/// ball whose half clears it: a half radius of at least `.0` standard deviations of the noise
/// (the wider fit's thinness), the whole ball at most `.1` times the `k`-th neighbour's
/// distance.
const WIDEN_DEEP: (f32, f32) = (3.0, 8.0);
/// Fits whose own tilt error is below this share of the tolerance are taken as they are.
const WIDEN_LOOK: f32 = 0.35;

/// Widens the neighbourhoods of noisy normals. A scanner's range noise is millimetres
/// whatever the point spacing, so at a dense spacing the `k` nearest points span a patch
/// hardly wider than the noise is deep, and their plane tilts by many degrees (the 20M-point
/// hall scan: a median of 8–16° from the true wall at `k` = 16).
///
/// A plane fitted to `m` points spread `s` wide with noise `σ` tilts by about `σ / (s √m)`
/// ([`Fit`]); on a surface `m` grows with `s²`, so the tilt falls with the square of the
/// radius. A fit whose tilt error is above `above` ([`NormalFit::widen_above`]) is fitted
/// again over every point within the radius that brings its error to `above`, at least
/// [`WIDEN_RADIUS`]`.0` and at most `.1` times its `k`-th neighbour's distance. The wider
/// fit is kept where it stays as flat as the noise ([`WIDEN_FLAT`]): near a crease or on a
/// tight curve it does not. Where the ball's half lay within the noise's depth (a scan merged
/// closer than its noise is deep, which leaves blobs: the 100M hall scan's zeniths), its fit is
/// tried once more in a ball whose half clears the noise ([`WIDEN_DEEP`]). A fit wider than
/// the least radius that still fails is tried once more at the least; failing that, the
/// `k`-nearest normal stays.
///
/// The noise is not the fit's own thinness, a sample of `k + 1` points (±40 % at 17), but the
/// median over the fits around it ([`pooled_thin`]): a fit that came out thin by chance is
/// widened too, and is not held to a tolerance it beat by chance. Fits far below the
/// tolerance (a smooth surface: [`WIDEN_LOOK`]) are taken as they are.
///
/// The neighbourhood thus follows the noise, as Mitra, Nguyen and Guibas (2004, "Estimating
/// surface normals in noisy point cloud data") ask, with the flatness test in place of their
/// curvature estimate. `fits[i]` is point `i`'s fit to its `k` nearest and the squared
/// distance of the `k`-th.
pub(super) fn widen(knn: &Knn, normals: &mut [Vec3], fits: &[(Fit, f32)], above: f32) {
    let (least, most) = (
        WIDEN_RADIUS.0 * WIDEN_RADIUS.0,
        WIDEN_RADIUS.1 * WIDEN_RADIUS.1,
    );
    let mut reach2: Vec<f32> = fits
        .par_iter()
        .map(|&(ref f, d2)| {
            let noisy = f.error > WIDEN_LOOK * above && f.count > 3;
            match above > 0.0 && noisy && d2 > 0.0 {
                // The error falls with the square of the radius.
                true => d2 * (f.error / above).clamp(least, most),
                false => 0.0,
            }
        })
        .collect();
    // Whether a point's ball was already widened past the noise's depth (once at most).
    let mut deepened = vec![false; fits.len()];
    let deepest = WIDEN_DEEP.1 * WIDEN_DEEP.1;
    // At most three balls a point: the first, one past the noise, the least.
    for _ in 0..3 {
        if !reach2.iter().any(|&r| r > 0.0) {
            break;
        }
        // Twice the points of the widest ball on a plane (every k-nearest fit holds the same
        // k + 1): a stray point's ball, sized by its far neighbours, is given up instead of
        // spanning the cloud.
        let cap = 2 * (deepest as usize) * (fits[0].0.count as usize).max(1);
        let wider = knn.map_within(&reach2, cap, |i, inside, offsets| {
            let noise = pooled_thin(fits, i, inside);
            // The k-nearest fit's error with its patch's noise: within the tolerance, no wider
            // fit is asked (an empty one stands for it).
            let fit = fits[i].0;
            let error = match fit.thin > 0.0 {
                true => fit.error * (noise / fit.thin).sqrt(),
                false => f32::INFINITY,
            };
            if error <= above {
                return (Fit::NONE, noise, false);
            }
            let all = offsets.iter().map(|&o| Vec3::from(o).as_dvec3());
            let wide = Fit::of_offsets(all.clone());
            if wide.thin <= WIDEN_FLAT * noise {
                return (wide, noise, false); // flat as the noise: kept, growth not asked
            }
            // The same ball at half the radius, for the growth test. Range noise does not
            // thicken a fit as its ball grows; a crease or a curve does (4 and 16 times the
            // variance for twice the radius).
            let quarter = reach2[i] / 4.0;
            let half = all
                .zip(inside)
                .filter(|&(_, &(_, d2))| d2 <= quarter)
                .map(|(o, _)| o);
            let half = Fit::of_offsets(half);
            let grows = half.count < 2 * fit.count || wide.thin > WIDEN_GROWTH * half.thin;
            (wide, noise, grows)
        });
        (&mut *normals, fits, &mut reach2, &mut deepened, &wider)
            .into_par_iter()
            .for_each(|(n, &(fit, d2), r2, deep, wider)| {
                let Some((f, noise, grows)) = *wider else {
                    *r2 = 0.0; // given up (or never asked): not asked again
                    return;
                };
                // An empty wide fit: the k-nearest one is within the tolerance.
                if f.count <= fit.count {
                    *r2 = 0.0;
                } else if f.thin <= WIDEN_FLAT * noise || !grows {
                    *n = f.normal;
                    *r2 = 0.0;
                } else {
                    // The half ball lay within the noise's depth (the wide fit's thinness
                    // measures it): its fit was a blob, and the test compared a blob with the
                    // noise. Once, wide enough that the half ball clears it.
                    let past = 4.0 * WIDEN_DEEP.0 * WIDEN_DEEP.0 * f.thin;
                    if !*deep && *r2 < past && *r2 < deepest * d2 {
                        *deep = true;
                        *r2 = past.min(deepest * d2);
                        return;
                    }
                    // Not flat: once more at the least radius, if this was wider.
                    *r2 = match *r2 > least * d2 * 1.001 {
                        true => least * d2,
                        false => 0.0,
                    };
                }
            });
    }
}

/// The median thinness of the `k`-nearest fits of point `i` and of up to [`POOLED`] points
/// `inside` its wider patch: the noise across the surface there, from many samples.
fn pooled_thin(fits: &[(Fit, f32)], i: usize, inside: &[(u32, f32)]) -> f32 {
    let mut t = [0f32; POOLED + 1];
    t[0] = fits[i].0.thin;
    let n = 1 + inside.len().min(POOLED);
    for (t, &(j, _)) in t[1..n].iter_mut().zip(inside) {
        *t = fits[j as usize].0.thin;
    }
    let t = &mut t[..n];
    *t.select_nth_unstable_by(n / 2, f32::total_cmp).1
}

/// Fits read for [`pooled_thin`] at most, besides the point's own.
const POOLED: usize = 32;
