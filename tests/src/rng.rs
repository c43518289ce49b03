//! The deterministic generator of the statistical tests (PCG32, O'Neill
//! 2014), so that every test is reproducible from its seed: the workspace's
//! one copy, [`guiding_core::rng::Pcg32`].

pub use guiding_core::rng::Pcg32;
