//! The grids, model types and constructors of every size, generated from
//! the one size table ([`for_each_size!`](crate::for_each_size)).
//!
//! For each size `S` (`name` `s`): the grid `s_grid(bbox_min, bbox_max)`, and
//! per family and target a type alias (`NpmSRadiance`, `NasgSProduct`,
//! `DfSRadiance`, …, re-exported by [`npm`](super::npm),
//! [`nasg`](super::nasg) and [`df`](super::df)) with its constructor
//! `s(bbox_min, bbox_max)` (DF: `s(bbox_min, bbox_max, interpolation)`).
//! Input widths follow from the grid: `IN = levels · features` (radiance) or
//! that plus [`PRODUCT_INPUT_DIMS`] (product); DF's conditional adds the
//! [`DF_EPS1_FREQUENCIES`] triangle-wave inputs, its cache reads the grid
//! features and the [`DF_CACHE_SH_DIMS`] spherical harmonics of the direction.

use crate::encoding::GridConfig;
use crate::model::df::{DF_CACHE_SH_DIMS, DF_EPS1_FREQUENCIES};
use crate::model::npm::PRODUCT_INPUT_DIMS;

/// Generates the items of the [module docs](self) from the size table.
macro_rules! size_items {
    ([$($Size:ident = $code:literal, $size:ident, $doc:literal, {
        grid(levels: $levels:literal, base_resolution: $base:literal,
             per_level_scale: $scale:literal, features: $features:literal),
        npm(n_hidden_layers: $npm_layers:literal, n_neurons: $npm_neurons:literal),
        nasg(n_hidden_layers: $nasg_layers:literal, n_neurons: $nasg_neurons:literal),
        df(n_hidden_layers: $df_layers:literal, n_neurons: $df_neurons:literal,
           cache_hidden_layers: $cache_layers:literal, cache_neurons: $cache_neurons:literal)
    };)*]) => { pastey::paste! {
        $(
            #[doc = concat!("The grid of the `", stringify!($size), "` size: ", stringify!($levels),
                " levels from ", stringify!($base), " cells per axis (×", stringify!($scale),
                " per level), ", stringify!($features), " features per vertex, over the box.")]
            #[must_use]
            pub const fn [<$size _grid>](bbox_min: [f32; 3], bbox_max: [f32; 3]) -> GridConfig {
                GridConfig::new(bbox_min, bbox_max, $levels, $base, $scale, $features)
            }
        )*

        /// NPM at every size ([`super::npm`] re-exports them).
        pub mod npm {
            use super::*;
            use crate::loss::Target;
            use crate::model::npm::Npm;
            $(
                size_items!(@mixture Npm, $Size, $size, Radiance, { $levels * $features },
                    $npm_neurons, $npm_layers);
                size_items!(@mixture Npm, $Size, $size, Product,
                    { $levels * $features + PRODUCT_INPUT_DIMS }, $npm_neurons, $npm_layers);
            )*
        }

        /// NASG at every size ([`super::nasg`] re-exports them).
        pub mod nasg {
            use super::*;
            use crate::loss::Target;
            use crate::model::nasg::Nasg;
            $(
                size_items!(@mixture Nasg, $Size, $size, Radiance, { $levels * $features },
                    $nasg_neurons, $nasg_layers);
                size_items!(@mixture Nasg, $Size, $size, Product,
                    { $levels * $features + PRODUCT_INPUT_DIMS }, $nasg_neurons, $nasg_layers);
            )*
        }

        /// DF at every size ([`super::df`] re-exports them).
        pub mod df {
            use super::*;
            use crate::loss::Target;
            use crate::model::df::Df;
            use crate::pdf1d::Interpolation;
            $(
                size_items!(@df $Size, $size, Radiance, { $levels * $features },
                    { $levels * $features }, $df_neurons, $df_layers, $cache_neurons, $cache_layers);
                size_items!(@df $Size, $size, Product, { $levels * $features + PRODUCT_INPUT_DIMS },
                    { $levels * $features }, $df_neurons, $df_layers, $cache_neurons, $cache_layers);
            )*
        }
    } };

    (@mixture $Family:ident, $Size:ident, $size:ident, $Target:ident, $inputs:tt,
     $neurons:literal, $layers:literal) => { pastey::paste! {
        #[doc = concat!("`", stringify!($Family), "` of the `", stringify!($size), "` size, ",
            stringify!($Target), " target: ", stringify!($layers), " hidden layers × ",
            stringify!($neurons), " neurons.")]
        pub type [<$Family $Size $Target>] = $Family<$inputs, $neurons, $layers>;

        impl [<$Family $Size $Target>] {
            #[doc = concat!("The model over the scene box on [`", stringify!($size), "_grid`](super::",
                stringify!($size), "_grid).")]
            #[must_use]
            pub const fn $size(bbox_min: [f32; 3], bbox_max: [f32; 3]) -> Self {
                Self::new([<$size _grid>](bbox_min, bbox_max), Target::$Target)
            }
        }

        const _: () = assert!([<$Family $Size $Target>]::$size([0.0; 3], [1.0; 3]).is_consistent());
    } };

    (@df $Size:ident, $size:ident, $Target:ident, $inputs:tt, $grid_features:tt,
     $neurons:literal, $layers:literal, $cache_neurons:literal, $cache_layers:literal) => {
        pastey::paste! {
        #[doc = concat!("`Df` of the `", stringify!($size), "` size, ", stringify!($Target),
            " target: density networks ", stringify!($layers), " hidden layers × ",
            stringify!($neurons), " neurons, radiance cache ", stringify!($cache_layers), " × ",
            stringify!($cache_neurons), ".")]
        pub type [<Df $Size $Target>] = Df<
            $inputs,
            { ($inputs) + DF_EPS1_FREQUENCIES as usize },
            { ($grid_features) + DF_CACHE_SH_DIMS },
            $neurons,
            $layers,
            $cache_neurons,
            $cache_layers,
        >;

        impl [<Df $Size $Target>] {
            #[doc = concat!("The model over the scene box on [`", stringify!($size), "_grid`](super::",
                stringify!($size), "_grid); `Nearest` gives DF-N, `Linear` DF-L.")]
            #[must_use]
            pub const fn $size(bbox_min: [f32; 3], bbox_max: [f32; 3], interp: Interpolation) -> Self {
                Self::new([<$size _grid>](bbox_min, bbox_max), Target::$Target, interp)
            }
        }

        const _: () = assert!(
            [<Df $Size $Target>]::$size([0.0; 3], [1.0; 3], Interpolation::Linear).is_consistent()
        );
    } };
}

crate::for_each_size!(size_items);

// The paper size's grid is NPM's (Dong et al. 2023, §5).
const _: () = {
    let (a, b) = (
        paper_grid([0.0; 3], [1.0; 3]),
        GridConfig::npm([0.0; 3], [1.0; 3]),
    );
    assert!(a.levels == b.levels && a.base_resolution == b.base_resolution);
    assert!(a.per_level_scale == b.per_level_scale && a.features == b.features);
};
