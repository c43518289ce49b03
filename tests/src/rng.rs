//! The deterministic generator of the statistical tests (PCG32, O'Neill
//! 2014), so that every test is reproducible from its seed: the workspace's
//! one copy, [`guiding_core::rng::Pcg32`].

pub use guiding_core::rng::Pcg32;

/// Signed zero, NaN and the infinities: the IEEE special values, which
/// tables of extreme inputs start with.
pub const IEEE_SPECIALS: [f32; 5] = [0.0, -0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY];

/// `n` rows of `N` values, entry `j` of a row `ordinary(rng, j)`, except in
/// the rows `i` with `i % period == phase`: there each entry is, with
/// probability 0.3, one of `specials` (uniformly) instead — batches of
/// ordinary inputs with rows of extreme ones mixed in.
pub fn rows_with_specials<const N: usize>(
    n: usize,
    rng: &mut Pcg32,
    (period, phase): (usize, usize),
    specials: &[f32],
    mut ordinary: impl FnMut(&mut Pcg32, usize) -> f32,
) -> Vec<[f32; N]> {
    (0..n)
        .map(|i| {
            core::array::from_fn(|j| {
                if i % period == phase && rng.next_f32() < 0.3 {
                    specials[rng.next_u32() as usize % specials.len()]
                } else {
                    ordinary(rng, j)
                }
            })
        })
        .collect()
}
