//! `guiding-core`: the `no_std` kernels of the path-guiding library.
//!
//! Every formula lives here once, as plain functions over `f32` that work on a
//! single query, so the CPU runtime loops over a batch and a SPIR-V shader runs
//! one invocation per element. GPU-visible values are `#[repr(C)]` +
//! [`bytemuck::Pod`]; transcendental math goes through [`math`] only.
//!
//! Directional distributions:
//! - [`lobe::vmf::VmfLobe`] and [`mixture::vmf::VmfMixture`] — von Mises–Fisher
//!   (Neural Parametric Mixtures, Dong et al. 2023);
//! - [`lobe::nasg::NasgLobe`] and [`mixture::nasg::NasgMixture`] — normalised
//!   anisotropic spherical Gaussians (Huang et al. 2024);
//! - [`pdf1d::Pdf1d`] and [`factorised`] — factorised piecewise PDFs
//!   (Figueiredo et al. 2025).
//!
//! ```
//! use guiding_core::glam::Vec2;
//! use guiding_core::mixture::vmf::VmfMixture;
//!
//! // Raw network outputs, 4 per lobe: [weight logit, ln κ, θ, φ] (NPM's activations).
//! let raw = [[0.0, 3.0, 0.5, -1.0], [1.0, 1.0, 2.0, 0.5]];
//! let guide = VmfMixture::<2>::decode(&raw);
//! let s = guide.sample(Vec2::new(0.3, 0.7));
//! assert!((guide.pdf(s.direction) / s.pdf - 1.0).abs() < 1e-4);
//! ```
//!
//! A neural field that learns these distributions online is
//! `field::Field` (feature `std`); renderers embed it through the
//! `guiding` crate (or its C ABI, `guiding-capi`).
//!
//! # Conventions
//!
//! - **`pdf` vs `eval`.** `pdf` is always a normalised density: in solid
//!   angle on the sphere (integrating to 1 over it), or per unit length on
//!   `[0, 1]` for [`pdf1d::Pdf1d`]. `eval` is always an *unnormalised* value,
//!   and only single lobes have one: [`lobe::vmf::VmfLobe::eval`]
//!   (`e^{κ(μ·ω − 1)}`) and [`lobe::nasg::NasgLobe::eval`] (`G(ω)`), both in
//!   `[0, 1]` and 1 at the lobe's mode, with `pdf = eval / normaliser` (and
//!   `log_eval` / `log_pdf` their logarithms). The normalised distributions —
//!   mixtures, [`pdf1d::Pdf1d`], [`factorised::FactorisedTable`] — have `pdf`
//!   only: they are built normalised, and a mixture's `Σ_k w_k eval_k` (the
//!   weights times the lobes' unnormalised values) would not be proportional
//!   to its density.
//! - **Directions** (`wo`, `wi`, and the directions a distribution samples
//!   and takes the `pdf` of) follow pbrt's convention, stated once for the
//!   whole library in the `guiding` crate's *Conventions* section.
#![no_std]
#![deny(missing_docs)]

#[cfg(feature = "std")]
extern crate std;

/// Declares a two-mode setting stored as a `u32` code in GPU-visible
/// structs: the `repr(u32)` enum (`$first = 0`, `$second = 1`), `code()`,
/// and `from_code()`, which reads `0` as `$first` and every other value as
/// `$second` (so a corrupt code still names a valid mode).
macro_rules! two_mode_enum {
    (
        $(#[$doc:meta])*
        pub enum $name:ident {
            $(#[$first_doc:meta])*
            $first:ident = 0,
            $(#[$second_doc:meta])*
            $second:ident = 1,
        }
    ) => {
        $(#[$doc])*
        #[repr(u32)]
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        pub enum $name {
            $(#[$first_doc])*
            $first = 0,
            $(#[$second_doc])*
            $second = 1,
        }

        impl $name {
            /// The `u32` code stored in GPU-visible structs.
            #[inline]
            #[must_use]
            pub const fn code(self) -> u32 {
                self as u32
            }

            #[doc = concat!(
                "Reads a code: `0` is [`", stringify!($name), "::", stringify!($first),
                "`], every other value [`", stringify!($name), "::", stringify!($second),
                "`] (so a corrupt code still names a valid mode)."
            )]
            #[inline]
            #[must_use]
            pub const fn from_code(code: u32) -> Self {
                if code == 0 {
                    Self::$first
                } else {
                    Self::$second
                }
            }
        }
    };
}

/// `const` builder methods that return `self` with some fields replaced:
/// `$method($field: $ty, …)` is `pub const fn $method(self, $field: $ty, …)
/// -> Self { Self { $field, …, ..self } }`. Exported (hidden) for the `guiding` crate's
/// configuration builders.
#[doc(hidden)]
#[macro_export]
macro_rules! with_fields {
    ($($(#[$doc:meta])* $method:ident($($field:ident: $ty:ty),+);)+) => {
        $(
            $(#[$doc])*
            #[must_use]
            pub const fn $method(self, $($field: $ty),+) -> Self {
                Self {
                    $($field,)+
                    ..self
                }
            }
        )+
    };
}

pub mod batch;
pub mod encoding;
pub mod factorised;
#[cfg(feature = "std")]
pub mod field;
pub mod frame;
pub mod gradient;
pub mod lobe;
pub mod loss;
pub mod math;
pub mod mixture;
pub mod mlp;
pub mod model;
pub mod optim;
pub mod pdf1d;
pub mod rng;
pub mod sample;
pub mod sphere;

pub use glam;
#[doc(hidden)]
pub use pastey as __pastey;
