//! Morton (Z-order) codes: 21 bits per axis interleaved into a u64, child index = x + 2y + 4z.
//!
//! The code of a point is taken from the same normalised f32 coordinate the point-location
//! descent uses (`(p − origin) · inv_size`), so that the level-d child of the code and the
//! child the descent picks are the same number (see pc-tree).

/// Bits per axis; the octree can be at most this deep.
pub const BITS: u32 = 21;
/// 2^21 as f32, exact.
pub const SCALE: f32 = (1u32 << BITS) as f32;

/// Spread the low 21 bits of `v` so that bit i lands at bit 3i.
#[inline]
pub fn spread(v: u32) -> u64 {
    let mut x = (v as u64) & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Interleave integer cell coordinates: x in bits 0, 3, 6…, y in 1, 4, 7…, z in 2, 5, 8….
#[inline]
pub fn encode(x: u32, y: u32, z: u32) -> u64 {
    spread(x) | (spread(y) << 1) | (spread(z) << 2)
}

/// Integer coordinate (0..2^21) of a normalised coordinate in [0, 1).
#[inline]
pub fn quantize(q: f32) -> u32 {
    ((q * SCALE) as u32).min((1 << BITS) - 1)
}

/// The child index (0..8) a code takes at `depth` (root = 0, its children are depth 1).
#[inline]
pub fn child_at(code: u64, depth: u32) -> u32 {
    ((code >> (3 * (BITS - 1 - depth))) & 7) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interleaves_bits() {
        assert_eq!(encode(1, 0, 0), 1);
        assert_eq!(encode(0, 1, 0), 2);
        assert_eq!(encode(0, 0, 1), 4);
        assert_eq!(encode(2, 0, 0), 8);
        let m = (1 << BITS) - 1;
        assert_eq!(encode(m, m, m), (1u64 << 63) - 1);
    }

    #[test]
    fn child_at_reads_levels_from_the_top() {
        // x = 0b1 << 20 (upper half in x at depth 0), y in upper half at depth 1.
        let code = encode(1 << 20, 1 << 19, 0);
        assert_eq!(child_at(code, 0), 1);
        assert_eq!(child_at(code, 1), 2);
        assert_eq!(child_at(code, 2), 0);
    }
}
