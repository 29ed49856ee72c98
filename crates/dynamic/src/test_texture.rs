//! Test images: a blocky random texture, lightly blurred so that LK has gradients everywhere.

/// Grey value at (x, y) of a texture of `block`-pixel squares whose values come from a hash of the
/// square (30..230), averaged over 3x3 pixels; `seed` picks the pattern.
pub(crate) fn blocky(seed: u32, block: isize, x: isize, y: isize) -> u8 {
    let square = |bx: isize, by: isize| -> f32 {
        let mut v = (bx as u32).wrapping_mul(73_856_093)
            ^ (by as u32).wrapping_mul(19_349_663)
            ^ seed.wrapping_mul(83_492_791);
        v ^= v >> 13;
        v = v.wrapping_mul(0x5bd1_e995);
        v ^= v >> 15;
        30.0 + (v % 200) as f32
    };
    let mut sum = 0.0;
    for dy in -1..=1 {
        for dx in -1..=1 {
            sum += square((x + dx).div_euclid(block), (y + dy).div_euclid(block));
        }
    }
    (sum / 9.0) as u8
}
