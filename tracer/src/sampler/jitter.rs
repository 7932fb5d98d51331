//! Where samples go: positions hashed from the pixel, the sample's index and a seed (never
//! a running random generator, so a pixel's rays do not depend on the tile), and the
//! stratified grid of the fixed-count samplers and the reference.

use crate::math::Color;

use super::Sample;

pub(super) const SEED_JITTER: u64 = 0x9e37_79b9_7f4a_7c15;
pub(super) const SEED_FIRST: u64 = 0xc2b2_ae3d_27d4_eb4f;
#[cfg(feature = "bench")]
pub(super) const SEED_REFERENCE: u64 = 0x27d4_eb2f_1656_67c5;

/// A high-rate stratified estimate of one pixel's exact value (`n × n` jittered samples with a
/// seed of its own, so it is statistically independent of every user-facing sampler). This
/// is the yardstick the samplers are measured against (see `tessera-bench`).
#[cfg(feature = "bench")]
pub fn reference_pixel<F: Fn(f64, f64) -> Sample>(x: u32, y: u32, n: u32, trace: &F) -> Color {
    stratified(x, y, n, Some(SEED_REFERENCE), trace)
}

/// `n × n` samples, one per cell of a regular grid: at the cell centre (`seed = None`) or at
/// a hashed position inside the cell.
pub(super) fn stratified<F: Fn(f64, f64) -> Sample>(
    x: u32,
    y: u32,
    n: u32,
    seed: Option<u64>,
    trace: &F,
) -> Color {
    let mut sum = Color::ZERO;
    let inv = 1.0 / f64::from(n);
    let hash = seed.map(|s| PixelHash::new(x, y, s));
    for j in 0..n {
        for i in 0..n {
            let (ox, oy) = match hash {
                None => (0.5, 0.5),
                Some(h) => h.pair(j * n + i),
            };
            let sx = f64::from(x) + (f64::from(i) + ox) * inv;
            let sy = f64::from(y) + (f64::from(j) + oy) * inv;
            sum += trace(sx, sy).color;
        }
    }
    sum / f64::from(n * n)
}

/// Two numbers in `[0, 1)` from the pixel, the sample index and a seed.
#[cfg(test)]
#[inline]
pub fn unit_pair(x: u32, y: u32, index: u32, seed: u64) -> (f64, f64) {
    PixelHash::new(x, y, seed).pair(index)
}

/// [`unit_pair`] for one pixel and seed, with the pixel's part of the hash mixed once rather
/// than once per sample (the values are the same).
#[derive(Clone, Copy)]
pub(super) struct PixelHash(pub(super) u64);

impl PixelHash {
    #[inline]
    pub(super) fn new(x: u32, y: u32, seed: u64) -> PixelHash {
        PixelHash(mix(seed ^ (u64::from(x) << 32 | u64::from(y))))
    }

    #[inline]
    pub(super) fn pair(self, index: u32) -> (f64, f64) {
        let h = mix(self.0 ^ u64::from(index));
        let a = (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        let h2 = mix(h);
        let b = (h2 >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        (a, b)
    }
}

/// SplitMix64's finaliser: a bijective 64-bit mix with full avalanche.
#[inline]
pub(super) fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}
