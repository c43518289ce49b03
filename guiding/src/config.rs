//! What kind of field to build: representation, training target, model size
//! and training hyper-parameters, as one `Copy` value with `const fn` presets.

use crate::error::GuidingError;
use guiding_core::field::FieldConfig;
pub use guiding_core::loss::Target;

/// The directional representation the network decodes.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Representation {
    /// Neural Parametric Mixtures (Dong et al. 2023): 8 von Mises–Fisher
    /// lobes, constant guide-selection probability.
    Npm = 0,
    /// Normalised anisotropic spherical Gaussians (Huang et al. 2024): 8 NASG
    /// lobes plus a learned guide-selection probability.
    Nasg = 1,
    /// Distribution factorisation (Figueiredo et al. 2025), piecewise-constant
    /// marginal × conditional.
    DfNearest = 2,
    /// Distribution factorisation, piecewise-linear reconstruction.
    DfLinear = 3,
}

impl Representation {
    /// Every representation, in code order.
    pub const ALL: [Self; 4] = [Self::Npm, Self::Nasg, Self::DfNearest, Self::DfLinear];

    /// The representation with this stable code (the `repr(u32)` value).
    #[must_use]
    pub const fn from_code(code: u32) -> Option<Self> {
        match code {
            0 => Some(Self::Npm),
            1 => Some(Self::Nasg),
            2 => Some(Self::DfNearest),
            3 => Some(Self::DfLinear),
            _ => None,
        }
    }

    /// The representation's name (`npm`, `nasg`, `df-n`, `df-l`), as
    /// [`str::parse`] reads it and as the bench's method names spell it.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Npm => "npm",
            Self::Nasg => "nasg",
            Self::DfNearest => "df-n",
            Self::DfLinear => "df-l",
        }
    }

    /// Whether the guide-selection probability is learned (NASG) rather than
    /// [`GuidingConfig::selection_probability`].
    #[must_use]
    pub const fn learns_selection(self) -> bool {
        matches!(self, Self::Nasg)
    }
}

/// Generates [`ModelSize`] from the size table.
macro_rules! model_size {
    ([$($size:ident = $code:literal, $name:ident, $doc:literal, $shape:tt;)*]) => {
        /// Network and grid size, one variant per row of the size table
        /// ([`guiding_core::for_each_size`]), which gives each its grid and
        /// networks (`n_hidden_layers` × `n_neurons`).
        #[repr(u32)]
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum ModelSize {
            $(
                #[doc = $doc]
                #[doc = ""]
                #[doc = concat!("`", stringify!($shape), "`")]
                $size = $code,
            )*
        }

        impl ModelSize {
            /// Every size, in code order.
            pub const ALL: [Self; [$($code),*].len()] = [$(Self::$size),*];

            /// The size's name, as [`str::parse`] reads it.
            #[must_use]
            pub const fn name(self) -> &'static str {
                match self {
                    $(Self::$size => stringify!($name),)*
                }
            }

            /// The size's one-line description (the size table's).
            #[must_use]
            pub const fn description(self) -> &'static str {
                match self {
                    $(Self::$size => $doc,)*
                }
            }

            /// The size with this stable code (the `repr(u32)` value).
            #[must_use]
            pub const fn from_code(code: u32) -> Option<Self> {
                match code {
                    $($code => Some(Self::$size),)*
                    _ => None,
                }
            }
        }
    };
}

guiding_core::for_each_size!(model_size);

/// The [`ModelSize::Compact`] grid over `[bbox_min, bbox_max]`.
pub use guiding_core::model::sizes::compact_grid;

/// Training defaults of the presets, the settings `host-demo`'s guided integrator takes its
/// defaults from (and `host-demo bench` measures): Adam with learning rate `3·10⁻²` (NPM:
/// [`NPM_LEARNING_RATE`]), batches of 8192 samples, at most 64 steps per
/// [`crate::GuidingField::update`] (a [`crate::TrainingSchedule`] decides the steps of a render
/// itself), the other values of [`FieldConfig::DEFAULT`].
///
/// 64 steps: a 320-px pass of `builtin:door` records ~480 k samples, of which 32 steps of 8192
/// used 262 k; with 64 the door at 20 s gave relMSE 0.222 against 0.241 (3 seeds each, lower
/// on every seed), the Cornell box 0.00174 against 0.00178.
pub const PRESET_TRAINING: FieldConfig = FieldConfig::DEFAULT
    .with_learning_rate(3e-2)
    .with_batch_size(8192)
    .with_steps_per_update(64);

/// NPM's learning rate in the presets: on `builtin:door` (64 spp, 32 steps per pass) learning
/// rates 3e-2 / 1e-2 / 5e-3 / 2e-3 gave relMSE 0.234 / 0.209 / 0.198 / 0.242; NASG and DF keep
/// 3e-2.
pub const NPM_LEARNING_RATE: f32 = 5e-3;

/// The presets' constant guide-selection probability (NPM, DF): on `builtin:door` (64 spp)
/// c = 0.25 / 0.35 / 0.5 / 0.75 gave relMSE 0.246 / 0.254 / 0.282 / 0.479, and a
/// per-cell fit ([`crate::GuideCache::fit_selection`]) replaces it where a cache exists.
pub const PRESET_SELECTION_PROBABILITY: f32 = 0.3;

/// Everything needed to build a [`crate::GuidingField`] except the scene
/// bounds. Build one from a preset and adjust it with the `with_*` methods:
///
/// ```
/// use guiding::{GuidingConfig, ModelSize};
/// const CONFIG: GuidingConfig = GuidingConfig::npm_product().with_size(ModelSize::Small);
/// assert!(CONFIG.validate().is_ok());
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuidingConfig {
    /// Directional representation.
    pub representation: Representation,
    /// What the guide learns to be proportional to.
    pub target: Target,
    /// Grid and network size.
    pub size: ModelSize,
    /// Probability of sampling the guide rather than the BSDF, in `[0, 1]`
    /// (NPM and DF; NASG learns its own and ignores this).
    pub selection_probability: f32,
    /// Online training: optimiser, batch size, steps per update, EMA,
    /// threads, convergence.
    pub training: FieldConfig,
}

impl GuidingConfig {
    const fn preset(representation: Representation, target: Target) -> Self {
        let training = match representation {
            Representation::Npm => PRESET_TRAINING.with_learning_rate(NPM_LEARNING_RATE),
            _ => PRESET_TRAINING,
        };
        Self {
            representation,
            target,
            size: ModelSize::Compact,
            selection_probability: PRESET_SELECTION_PROBABILITY,
            training,
        }
    }

    /// The preset of `representation` and `target` (the named presets below are this).
    #[must_use]
    pub const fn for_representation(representation: Representation, target: Target) -> Self {
        Self::preset(representation, target)
    }

    /// NPM learning incident radiance (the guide is multiplied by the BSDF
    /// by the renderer's MIS, not by the network).
    #[must_use]
    pub const fn npm_radiance() -> Self {
        Self::preset(Representation::Npm, Target::Radiance)
    }

    /// NPM learning the full product `f · L_i · |cos|` (needs normal, ωo and
    /// roughness in every query).
    #[must_use]
    pub const fn npm_product() -> Self {
        Self::preset(Representation::Npm, Target::Product)
    }

    /// NASG learning incident radiance, with a learned selection probability.
    #[must_use]
    pub const fn nasg() -> Self {
        Self::preset(Representation::Nasg, Target::Radiance)
    }

    /// NASG learning the product.
    #[must_use]
    pub const fn nasg_product() -> Self {
        Self::preset(Representation::Nasg, Target::Product)
    }

    /// Factorised piecewise-constant PDFs (DF-N), radiance target.
    #[must_use]
    pub const fn df_nearest() -> Self {
        Self::preset(Representation::DfNearest, Target::Radiance)
    }

    /// Factorised piecewise-linear PDFs (DF-L), radiance target.
    #[must_use]
    pub const fn df_linear() -> Self {
        Self::preset(Representation::DfLinear, Target::Radiance)
    }

    guiding_core::with_fields! {
        /// `self` with another training target.
        with_target(target: Target);
        /// `self` with another model size.
        with_size(size: ModelSize);
        /// `self` with another constant selection probability (NPM, DF).
        with_selection_probability(selection_probability: f32);
        /// `self` with other training settings.
        with_training(training: FieldConfig);
    }

    /// Checks every value against its documented range.
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] for a selection probability outside
    /// `[0, 1]`, [`GuidingError::Field`] for invalid training settings.
    pub fn validate(&self) -> Result<(), GuidingError> {
        if !(0.0..=1.0).contains(&self.selection_probability) {
            return Err(GuidingError::InvalidConfig(format!(
                "selection_probability {} is not in [0, 1]",
                self.selection_probability
            )));
        }
        self.training.validate()?;
        Ok(())
    }
}

impl Default for GuidingConfig {
    /// [`GuidingConfig::npm_product`].
    fn default() -> Self {
        Self::npm_product()
    }
}

/// The error of parsing a [`Representation`] or [`ModelSize`] name: the name
/// and the names that exist.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnknownName {
    /// The name that was given.
    pub given: String,
    /// The names that exist.
    pub expected: Vec<&'static str>,
}

impl std::fmt::Display for UnknownName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "unknown name {:?} (expected one of: {})",
            self.given,
            self.expected.join(", ")
        )
    }
}

impl std::error::Error for UnknownName {}

/// Parses `s` as the value of `all` whose `name` it is.
fn parse_name<T: Copy>(s: &str, all: &[T], name: fn(T) -> &'static str) -> Result<T, UnknownName> {
    all.iter()
        .copied()
        .find(|&v| name(v) == s)
        .ok_or_else(|| UnknownName {
            given: s.to_string(),
            expected: all.iter().map(|&v| name(v)).collect(),
        })
}

impl std::str::FromStr for Representation {
    type Err = UnknownName;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        parse_name(s, &Self::ALL, Self::name)
    }
}

impl std::str::FromStr for ModelSize {
    type Err = UnknownName;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        parse_name(s, &Self::ALL, Self::name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name parses back to its value, the error lists exactly the names of `ALL`, and
    /// the stable codes run in `ALL`'s order: a value added to one list and not the others
    /// fails here.
    #[test]
    fn names_codes_and_lists_are_in_step() {
        let e = "?".parse::<Representation>().unwrap_err();
        assert_eq!(e.expected, Representation::ALL.map(Representation::name));
        for (i, r) in Representation::ALL.into_iter().enumerate() {
            assert_eq!(r.name().parse::<Representation>(), Ok(r));
            assert_eq!(Representation::from_code(i as u32), Some(r));
            assert_eq!(r as u32, i as u32);
        }
        let e = "?".parse::<ModelSize>().unwrap_err();
        assert_eq!(e.expected, ModelSize::ALL.map(ModelSize::name));
        for (i, s) in ModelSize::ALL.into_iter().enumerate() {
            assert_eq!(s.name().parse::<ModelSize>(), Ok(s));
            assert_eq!(ModelSize::from_code(i as u32), Some(s));
            assert_eq!(s as u32, i as u32);
        }
        assert_eq!(
            Representation::from_code(Representation::ALL.len() as u32),
            None
        );
        assert_eq!(ModelSize::from_code(ModelSize::ALL.len() as u32), None);
        assert!(
            "Npm".parse::<Representation>().is_err(),
            "names are case-sensitive"
        );
    }
}
