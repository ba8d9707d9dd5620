//! The walk's per-chunk arithmetic: a ray against a chunk's four disks ([`lanes`], the hit
//! test), a point against them ([`cover_lanes`], the blend's cover test), each in SSE (x86-64's
//! baseline), in AVX2 two chunks at once where the CPU has it ([`lanes8`], [`cover_lanes8`];
//! [`has_avx2`]) and one lane at a time (the portable twins, `*_scalar`), all held to each
//! other bit for bit by `simd_lanes_match_scalar_lanes`; and the cache hint [`prefetch`].

use super::{Chunk, LANES};
pub(super) use crate::has_avx2;

/// Asks the cache for the line holding `x` (a hint: no effect on any result).
#[inline(always)]
pub(super) fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of the x86-64 baseline; a prefetch reads nothing the program sees
    // and cannot fault, and the pointer comes from a reference.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>((x as *const T).cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// One chunk's ray-disk tests: each lane's plane distance `t` and the mask of lanes hit inside
/// their radius within `[t_min, limit]` (the border clip is left to the caller). The
/// arithmetic is [`crate::ray::intersect_splat`]'s, operation for operation (no fused
/// multiply-add), so `t` is bit for bit the scalar one. SSE on x86-64 (part of its baseline);
/// [`lanes_scalar`] elsewhere and in the test that holds the two together.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn lanes(
    c: &Chunk,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    limit: f32,
) -> ([f32; LANES], u32) {
    use std::arch::x86_64::*;
    // SAFETY: SSE is part of the x86-64 baseline, so every intrinsic here is available; the
    // loads read `[f32; 4]` fields of a `#[repr(C, align(16))]` struct whose fields are all
    // 16 bytes, so each is 16-byte aligned, and the store writes a local `[f32; 4]`.
    unsafe {
        let (add, sub, mul) = (_mm_add_ps, _mm_sub_ps, _mm_mul_ps);
        let ld = |a: &[f32; LANES]| _mm_load_ps(a.as_ptr());
        let (nx, ny, nz) = (ld(&c.nx), ld(&c.ny), ld(&c.nz));
        let (px, py, pz) = (ld(&c.px), ld(&c.py), ld(&c.pz));
        let (ox, oy, oz) = (_mm_set1_ps(o[0]), _mm_set1_ps(o[1]), _mm_set1_ps(o[2]));
        let (dx, dy, dz) = (_mm_set1_ps(d[0]), _mm_set1_ps(d[1]), _mm_set1_ps(d[2]));
        let denom = add(add(mul(dx, nx), mul(dy, ny)), mul(dz, nz));
        let num = add(
            add(mul(sub(px, ox), nx), mul(sub(py, oy), ny)),
            mul(sub(pz, oz), nz),
        );
        let th = _mm_div_ps(num, denom);
        let ex = sub(add(ox, mul(dx, th)), px);
        let ey = sub(add(oy, mul(dy, th)), py);
        let ez = sub(add(oz, mul(dz, th)), pz);
        let d2 = add(add(mul(ex, ex), mul(ey, ey)), mul(ez, ez));
        let abs = _mm_andnot_ps(_mm_set1_ps(-0.0), denom);
        let ok = _mm_and_ps(
            _mm_and_ps(
                _mm_cmpge_ps(abs, _mm_set1_ps(1e-8)),
                _mm_cmpge_ps(th, _mm_set1_ps(t_min)),
            ),
            _mm_and_ps(
                _mm_cmple_ps(th, _mm_set1_ps(limit)),
                _mm_cmple_ps(d2, ld(&c.r2)),
            ),
        );
        let mut t = [0.0f32; LANES];
        _mm_storeu_ps(t.as_mut_ptr(), th);
        (t, _mm_movemask_ps(ok) as u32)
    }
}

/// [`lanes`] of two chunks at once (lanes 0-3 the first's, 4-7 the second's) with AVX2's
/// eight-lane registers: the same operations in the same order on each lane, so `t` and the
/// mask are bit for bit two [`lanes`] calls' (`lanes8_are_two_lanes_calls`).
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(super) unsafe fn lanes8(
    c0: &Chunk,
    c1: &Chunk,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    limit: f32,
) -> ([f32; 2 * LANES], u32) {
    use std::arch::x86_64::*;
    let (add, sub, mul) = (_mm256_add_ps, _mm256_sub_ps, _mm256_mul_ps);
    // SAFETY (the loads): each field is a 16-byte-aligned `[f32; 4]` of a `#[repr(C,
    // align(16))]` struct whose fields are all 16 bytes.
    let ld = |a: &[f32; LANES], b: &[f32; LANES]| {
        _mm256_insertf128_ps::<1>(
            _mm256_castps128_ps256(_mm_load_ps(a.as_ptr())),
            _mm_load_ps(b.as_ptr()),
        )
    };
    let (nx, ny, nz) = (ld(&c0.nx, &c1.nx), ld(&c0.ny, &c1.ny), ld(&c0.nz, &c1.nz));
    let (px, py, pz) = (ld(&c0.px, &c1.px), ld(&c0.py, &c1.py), ld(&c0.pz, &c1.pz));
    let [ox, oy, oz] = o.map(|x| _mm256_set1_ps(x));
    let [dx, dy, dz] = d.map(|x| _mm256_set1_ps(x));
    let denom = add(add(mul(dx, nx), mul(dy, ny)), mul(dz, nz));
    let num = add(
        add(mul(sub(px, ox), nx), mul(sub(py, oy), ny)),
        mul(sub(pz, oz), nz),
    );
    let th = _mm256_div_ps(num, denom);
    let ex = sub(add(ox, mul(dx, th)), px);
    let ey = sub(add(oy, mul(dy, th)), py);
    let ez = sub(add(oz, mul(dz, th)), pz);
    let d2 = add(add(mul(ex, ex), mul(ey, ey)), mul(ez, ez));
    let abs = _mm256_andnot_ps(_mm256_set1_ps(-0.0), denom);
    // Ordered comparisons (false on NaN), as SSE's cmpge/cmple.
    let ok = _mm256_and_ps(
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(abs, _mm256_set1_ps(1e-8)),
            _mm256_cmp_ps::<_CMP_GE_OQ>(th, _mm256_set1_ps(t_min)),
        ),
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_LE_OQ>(th, _mm256_set1_ps(limit)),
            _mm256_cmp_ps::<_CMP_LE_OQ>(d2, ld(&c0.r2, &c1.r2)),
        ),
    );
    let mut t = [0.0f32; 2 * LANES];
    _mm256_storeu_ps(t.as_mut_ptr(), th);
    (t, _mm256_movemask_ps(ok) as u32)
}

#[cfg(not(target_arch = "x86_64"))]
pub(super) unsafe fn lanes8(
    c0: &Chunk,
    c1: &Chunk,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    limit: f32,
) -> ([f32; 2 * LANES], u32) {
    let ((t0, m0), (t1, m1)) = (lanes(c0, o, d, t_min, limit), lanes(c1, o, d, t_min, limit));
    let mut t = [0.0f32; 2 * LANES];
    t[..LANES].copy_from_slice(&t0);
    t[LANES..].copy_from_slice(&t1);
    (t, m0 | m1 << LANES)
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
pub(super) fn lanes(
    c: &Chunk,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    limit: f32,
) -> ([f32; LANES], u32) {
    lanes_scalar(c, o, d, t_min, limit)
}

/// [`lanes`] one lane at a time.
#[allow(clippy::needless_range_loop)] // lane l of seven arrays
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn lanes_scalar(
    c: &Chunk,
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    limit: f32,
) -> ([f32; LANES], u32) {
    let ([ox, oy, oz], [dx, dy, dz]) = (o, d);
    let mut t = [0.0f32; LANES];
    let mut mask = 0u32;
    for l in 0..LANES {
        let denom = dx * c.nx[l] + dy * c.ny[l] + dz * c.nz[l];
        let th = ((c.px[l] - ox) * c.nx[l] + (c.py[l] - oy) * c.ny[l] + (c.pz[l] - oz) * c.nz[l])
            / denom;
        let (ex, ey, ez) = (
            ox + dx * th - c.px[l],
            oy + dy * th - c.py[l],
            oz + dz * th - c.pz[l],
        );
        let inside = ex * ex + ey * ey + ez * ez <= c.r2[l];
        let ok = denom.abs() >= 1e-8 && th >= t_min && th <= limit && inside;
        t[l] = th;
        mask |= (ok as u32) << l;
    }
    (t, mask)
}

/// One chunk's cover tests for [`Accel::covering`]: each lane's height `h` of the point `x`
/// over the disk's plane, its squared in-plane distance `ρ²`, and the mask of lanes that face
/// the normal `n` (`n_j · n > 0`) with `ρ² < r²` (padding lanes never: zero normal). The
/// arithmetic is [`crate::covering`]'s, operation for operation. SSE on x86-64;
/// [`cover_lanes_scalar`] elsewhere and in the test that holds the two together.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn cover_lanes(
    c: &Chunk,
    x: [f32; 3],
    n: [f32; 3],
) -> ([f32; LANES], [f32; LANES], u32) {
    use std::arch::x86_64::*;
    // SAFETY: as in `lanes`: SSE is baseline on x86-64, the loads read 16-byte aligned
    // `[f32; 4]` fields of a `#[repr(C, align(16))]` struct, the stores write local arrays.
    unsafe {
        let (add, sub, mul) = (_mm_add_ps, _mm_sub_ps, _mm_mul_ps);
        let ld = |a: &[f32; LANES]| _mm_load_ps(a.as_ptr());
        let (nx, ny, nz) = (ld(&c.nx), ld(&c.ny), ld(&c.nz));
        let facing = add(
            add(mul(nx, _mm_set1_ps(n[0])), mul(ny, _mm_set1_ps(n[1]))),
            mul(nz, _mm_set1_ps(n[2])),
        );
        let dx = sub(_mm_set1_ps(x[0]), ld(&c.px));
        let dy = sub(_mm_set1_ps(x[1]), ld(&c.py));
        let dz = sub(_mm_set1_ps(x[2]), ld(&c.pz));
        let h = add(add(mul(dx, nx), mul(dy, ny)), mul(dz, nz));
        let d2 = add(add(mul(dx, dx), mul(dy, dy)), mul(dz, dz));
        let rho2 = sub(d2, mul(h, h));
        let ok = _mm_and_ps(
            _mm_cmpgt_ps(facing, _mm_set1_ps(crate::ray::BLEND_MIN_COS)),
            _mm_cmplt_ps(rho2, ld(&c.r2)),
        );
        let (mut ho, mut ro) = ([0.0f32; LANES], [0.0f32; LANES]);
        _mm_storeu_ps(ho.as_mut_ptr(), h);
        _mm_storeu_ps(ro.as_mut_ptr(), rho2);
        (ho, ro, _mm_movemask_ps(ok) as u32)
    }
}

/// [`cover_lanes`] of two chunks at once with AVX2 (lanes 0-3 the first's, 4-7 the second's):
/// the same operations lane for lane, so bit for bit two [`cover_lanes`] calls.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(super) unsafe fn cover_lanes8(
    c0: &Chunk,
    c1: &Chunk,
    x: [f32; 3],
    n: [f32; 3],
) -> ([f32; 2 * LANES], [f32; 2 * LANES], u32) {
    use std::arch::x86_64::*;
    let (add, sub, mul) = (_mm256_add_ps, _mm256_sub_ps, _mm256_mul_ps);
    // SAFETY (the loads): as in `lanes8`.
    let ld = |a: &[f32; LANES], b: &[f32; LANES]| {
        _mm256_insertf128_ps::<1>(
            _mm256_castps128_ps256(_mm_load_ps(a.as_ptr())),
            _mm_load_ps(b.as_ptr()),
        )
    };
    let (nx, ny, nz) = (ld(&c0.nx, &c1.nx), ld(&c0.ny, &c1.ny), ld(&c0.nz, &c1.nz));
    let [sx, sy, sz] = n.map(|v| _mm256_set1_ps(v));
    let facing = add(add(mul(nx, sx), mul(ny, sy)), mul(nz, sz));
    let dx = sub(_mm256_set1_ps(x[0]), ld(&c0.px, &c1.px));
    let dy = sub(_mm256_set1_ps(x[1]), ld(&c0.py, &c1.py));
    let dz = sub(_mm256_set1_ps(x[2]), ld(&c0.pz, &c1.pz));
    let h = add(add(mul(dx, nx), mul(dy, ny)), mul(dz, nz));
    let d2 = add(add(mul(dx, dx), mul(dy, dy)), mul(dz, dz));
    let rho2 = sub(d2, mul(h, h));
    // Ordered comparisons (false on NaN), as SSE's cmpgt/cmplt.
    let ok = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_GT_OQ>(facing, _mm256_set1_ps(crate::ray::BLEND_MIN_COS)),
        _mm256_cmp_ps::<_CMP_LT_OQ>(rho2, ld(&c0.r2, &c1.r2)),
    );
    let (mut ho, mut ro) = ([0.0f32; 2 * LANES], [0.0f32; 2 * LANES]);
    _mm256_storeu_ps(ho.as_mut_ptr(), h);
    _mm256_storeu_ps(ro.as_mut_ptr(), rho2);
    (ho, ro, _mm256_movemask_ps(ok) as u32)
}

#[cfg(not(target_arch = "x86_64"))]
pub(super) unsafe fn cover_lanes8(
    c0: &Chunk,
    c1: &Chunk,
    x: [f32; 3],
    n: [f32; 3],
) -> ([f32; 2 * LANES], [f32; 2 * LANES], u32) {
    let ((h0, r0, m0), (h1, r1, m1)) = (cover_lanes(c0, x, n), cover_lanes(c1, x, n));
    let (mut h, mut rho2) = ([0.0f32; 2 * LANES], [0.0f32; 2 * LANES]);
    (
        h[..LANES].copy_from_slice(&h0),
        h[LANES..].copy_from_slice(&h1),
    );
    (
        rho2[..LANES].copy_from_slice(&r0),
        rho2[LANES..].copy_from_slice(&r1),
    );
    (h, rho2, m0 | m1 << LANES)
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
pub(super) fn cover_lanes(
    c: &Chunk,
    x: [f32; 3],
    n: [f32; 3],
) -> ([f32; LANES], [f32; LANES], u32) {
    cover_lanes_scalar(c, x, n)
}

/// [`cover_lanes`] one lane at a time, with glam as [`crate::covering`] computes it.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn cover_lanes_scalar(c: &Chunk, x: [f32; 3], n: [f32; 3]) -> ([f32; LANES], [f32; LANES], u32) {
    let (x, n) = (glam::Vec3::from(x), glam::Vec3::from(n));
    let (mut h, mut rho2, mut mask) = ([0.0f32; LANES], [0.0f32; LANES], 0u32);
    for l in 0..LANES {
        let sn = glam::Vec3::new(c.nx[l], c.ny[l], c.nz[l]);
        let d = x - glam::Vec3::new(c.px[l], c.py[l], c.pz[l]);
        h[l] = d.dot(sn);
        rho2[l] = d.length_squared() - h[l] * h[l];
        let ok = sn.dot(n) > crate::ray::BLEND_MIN_COS && rho2[l] < c.r2[l];
        mask |= (ok as u32) << l;
    }
    (h, rho2, mask)
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::PAD;
    use super::*;

    /// 20,000 random chunks (every other one with a padding lane) with a ray through each: its
    /// origin, direction (every seventh parallel to lane 0's plane), `t_min` and limit.
    pub(in crate::accel) fn cases(
    ) -> impl Iterator<Item = (usize, Chunk, [f32; 3], [f32; 3], f32, f32)> {
        let mut seed = 12345u32;
        let mut rnd = move || {
            seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
            (seed >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
        };
        (0..20_000).map(move |k| {
            let mut c = PAD;
            for l in 0..LANES - (k % 2) {
                [c.px[l], c.py[l], c.pz[l]] = [rnd(), rnd(), rnd()];
                let n = glam::Vec3::new(rnd(), rnd(), rnd()).normalize_or_zero();
                [c.nx[l], c.ny[l], c.nz[l]] = n.to_array();
                c.r2[l] = 0.5 * rnd().abs();
            }
            let o = [rnd(), rnd(), rnd()];
            let mut d = glam::Vec3::new(rnd(), rnd(), rnd())
                .normalize_or_zero()
                .to_array();
            if k % 7 == 0 {
                d = [c.nz[0], 0.0, -c.nx[0]]; // parallel to lane 0's plane
            }
            let (t_min, limit) = (0.1 * rnd().abs(), 2.0 * rnd().abs());
            (k, c, o, d, t_min, limit)
        })
    }

    /// The SSE lanes and the scalar ones agree bit for bit, and AVX2's eight lanes with two SSE
    /// calls where the CPU has AVX2, on random disks and rays including parallel rays, padding
    /// lanes and ties at the interval's ends (the cover lanes on the same disks, the ray's
    /// origin and direction standing for a point and a normal).
    #[test]
    fn simd_lanes_match_scalar_lanes() {
        for (k, c, o, d, t_min, limit) in cases() {
            let (ch, cr, cm) = cover_lanes(&c, o, d);
            let (sh, sr, sm) = cover_lanes_scalar(&c, o, d);
            assert_eq!(cm, sm, "case {k}");
            for l in 0..LANES {
                assert_eq!(ch[l].to_bits(), sh[l].to_bits(), "case {k} lane {l}");
                assert_eq!(cr[l].to_bits(), sr[l].to_bits(), "case {k} lane {l}");
            }
            let (a, ma) = lanes(&c, o, d, t_min, limit);
            let (b, mb) = lanes_scalar(&c, o, d, t_min, limit);
            assert_eq!(ma, mb, "case {k}");
            for l in 0..LANES {
                assert!(
                    a[l].to_bits() == b[l].to_bits() || (a[l].is_nan() && b[l].is_nan()),
                    "case {k} lane {l}"
                );
            }
            if has_avx2() {
                // Two chunks at once: this one and one with its lanes reversed.
                let mut e = c;
                for f in [
                    &mut e.px, &mut e.py, &mut e.pz, &mut e.nx, &mut e.ny, &mut e.nz,
                ] {
                    f.reverse();
                }
                e.r2.reverse();
                // SAFETY: the CPU has AVX2.
                let (wh, wr, wm) = unsafe { cover_lanes8(&c, &e, o, d) };
                let ((h0, r0, m0), (h1, r1, m1)) = (cover_lanes(&c, o, d), cover_lanes(&e, o, d));
                assert_eq!(wm, m0 | m1 << LANES, "case {k}");
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&wh), bits(&[h0, h1].concat()), "case {k}");
                assert_eq!(bits(&wr), bits(&[r0, r1].concat()), "case {k}");
                // The stretch as drawn, and one that ends and starts exactly on two lanes' t.
                for (t_min, limit) in [(t_min, limit), (a[1].min(a[0]), a[0].max(a[1]))] {
                    let (a, ma) = lanes(&c, o, d, t_min, limit);
                    let (b, mb) = lanes(&e, o, d, t_min, limit);
                    // SAFETY: the CPU has AVX2.
                    let (w, mw) = unsafe { lanes8(&c, &e, o, d, t_min, limit) };
                    assert_eq!(mw, ma | mb << LANES, "case {k}");
                    for (l, (x, y)) in w.iter().zip(a.iter().chain(&b)).enumerate() {
                        assert!(
                            x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()),
                            "case {k} lane {l}"
                        );
                    }
                }
            }
        }
    }
}
