//! The one table of model sizes ([`for_each_size!`](crate::for_each_size))
//! and the model table generated from it
//! ([`for_each_model!`](crate::for_each_model)).
//!
//! Every place that enumerates sizes or model types is generated from
//! [`for_each_size!`](crate::for_each_size): the grids, type aliases and constructors of
//! [`sizes`](super::sizes), the `guiding` facade's `ModelSize` and field
//! enum, its save-file / entry-point prefixes and constructors, and the SPIR-V
//! entry points of `guiding-shaders`. Adding a model size is one row there;
//! the C ABI's `PG_SIZE_*` constants are literal for cbindgen, and a test of
//! `guiding-capi` fails until they list the same sizes.

/// Calls `$callback!` with every model size, one row each, in code order,
/// inside one bracket (after `$extra`, if given):
///
/// ```text
/// Variant = code, name, "description", { grid(…), npm(…), nasg(…), df(…) };
/// ```
///
/// - `Variant` is the facade's `ModelSize` variant, `code` its stable `u32`
///   (save files, C ABI), `name` its lower-case name (`ModelSize::name`, the
///   constructors `Npm…::name(bbox_min, bbox_max)`, `{name}_grid`);
/// - `grid` is the multiresolution grid (`GridConfig::new`'s arguments): the
///   network input is `levels · features` wide for radiance, plus
///   [`PRODUCT_INPUT_DIMS`](crate::model::npm::PRODUCT_INPUT_DIMS) for product;
/// - the networks are named as tiny-cuda-nn names them: `n_hidden_layers` of
///   `n_neurons` each; DF has its density networks' and its radiance cache's.
///
/// The codes are `0, 1, …` in row order (save files and the C ABI store them):
///
/// ```
/// macro_rules! codes {
///     ([$($size:ident = $code:literal, $name:ident, $doc:literal, $shape:tt;)*]) => {
///         [$($code),*]
///     };
/// }
/// let codes = guiding_core::for_each_size!(codes);
/// assert!((0..codes.len()).all(|i| codes[i] == i as u32));
/// ```
#[macro_export]
macro_rules! for_each_size {
    ($($callback:ident)::+ $(, $extra:tt)?) => {
        $($callback)::+! { $($extra)? [
            Small = 0, small, "Tiny, a few thousand parameters: tests and toy scenes.", { grid(levels: 2, base_resolution: 2, per_level_scale: 2.0, features: 4), npm(n_hidden_layers: 2, n_neurons: 16), nasg(n_hidden_layers: 2, n_neurons: 16), df(n_hidden_layers: 2, n_neurons: 16, cache_hidden_layers: 2, cache_neurons: 16) };
            Compact = 1, compact, "About 25x fewer parameters than the papers' (a 166 816-parameter grid): the default, sized for CPU rendering.", { grid(levels: 4, base_resolution: 4, per_level_scale: 2.0, features: 4), npm(n_hidden_layers: 2, n_neurons: 32), nasg(n_hidden_layers: 2, n_neurons: 32), df(n_hidden_layers: 2, n_neurons: 32, cache_hidden_layers: 2, cache_neurons: 32) };
            Paper = 2, paper, "The papers' sizes (NPM's grid of 4.1 M parameters).", { grid(levels: 8, base_resolution: 8, per_level_scale: 1.405, features: 4), npm(n_hidden_layers: 3, n_neurons: 64), nasg(n_hidden_layers: 4, n_neurons: 128), df(n_hidden_layers: 3, n_neurons: 64, cache_hidden_layers: 3, cache_neurons: 64) };
        ] }
    };
}

/// Calls the macro `$callback` once with every model type, one row each:
///
/// ```text
/// path::to::Type => prefix, family, Size, Target, [sample, pdf, gradient, infer];       (npm, nasg)
/// path::to::Type => prefix, family, Size, Target, [sample, pdf, gradient, vertex,
///                                                  vertex_sample, vertex_pdf];           (df)
/// ```
///
/// - `prefix` names the type everywhere else (`npm_compact_radiance`): the
///   facade's enum variant and save-file / entry-point prefix;
/// - `family` is `npm`, `nasg` or `df` (the decoded distribution);
/// - `Size` (a [`for_each_size!`](crate::for_each_size) variant) and `Target`
///   (`Radiance`, `Product`) are the facade's `ModelSize` / `Target` variants;
/// - the bracket lists the type's SPIR-V entry points (rust-gpu names an
///   entry point after its function): whole-model sample, pdf and per-sample
///   gradient; then for the mixtures the raw-output inference, for DF the
///   per-vertex kernel and the vertex lanes' sample and pdf.
///
/// The rows are generated: every size × the three families × both targets.
///
/// ```
/// macro_rules! count_rows {
///     ($($ty:path => $prefix:ident, $family:ident, $size:ident, $target:ident,
///        [$($entry:ident),*];)*) => { [$(stringify!($prefix)),*].len() };
/// }
/// macro_rules! count_sizes {
///     ([$($size:ident = $code:literal, $name:ident, $doc:literal, $shape:tt;)*]) => {
///         [$($code),*].len()
///     };
/// }
/// let sizes = guiding_core::for_each_size!(count_sizes);
/// assert_eq!(guiding_core::for_each_model!(count_rows), 3 * 2 * sizes);
/// ```
#[macro_export]
macro_rules! for_each_model {
    ($callback:ident) => {
        $crate::for_each_size!($crate::__model_rows, $callback);
    };
}

/// [`for_each_model!`]'s rows from the size table.
#[doc(hidden)]
#[macro_export]
macro_rules! __model_rows {
    ($callback:ident [$($Size:ident = $code:literal, $size:ident, $doc:literal, $shape:tt;)*]) => {
        $crate::__pastey::paste! { $callback! {
            $(
                $crate::model::npm::[<Npm $Size Radiance>] => [<npm_ $size _radiance>], npm, $Size, Radiance, [[<npm_ $size _radiance_sample>], [<npm_ $size _radiance_pdf>], [<npm_ $size _radiance_gradient>], [<npm_ $size _radiance_infer>]];
                $crate::model::npm::[<Npm $Size Product>] => [<npm_ $size _product>], npm, $Size, Product, [[<npm_ $size _product_sample>], [<npm_ $size _product_pdf>], [<npm_ $size _product_gradient>], [<npm_ $size _product_infer>]];
            )*
            $(
                $crate::model::nasg::[<Nasg $Size Radiance>] => [<nasg_ $size _radiance>], nasg, $Size, Radiance, [[<nasg_ $size _radiance_sample>], [<nasg_ $size _radiance_pdf>], [<nasg_ $size _radiance_gradient>], [<nasg_ $size _radiance_infer>]];
                $crate::model::nasg::[<Nasg $Size Product>] => [<nasg_ $size _product>], nasg, $Size, Product, [[<nasg_ $size _product_sample>], [<nasg_ $size _product_pdf>], [<nasg_ $size _product_gradient>], [<nasg_ $size _product_infer>]];
            )*
            $(
                $crate::model::df::[<Df $Size Radiance>] => [<df_ $size _radiance>], df, $Size, Radiance, [[<df_ $size _radiance_sample>], [<df_ $size _radiance_pdf>], [<df_ $size _radiance_gradient>], [<df_ $size _radiance_vertex>], [<df_ $size _radiance_vertex_sample>], [<df_ $size _radiance_vertex_pdf>]];
                $crate::model::df::[<Df $Size Product>] => [<df_ $size _product>], df, $Size, Product, [[<df_ $size _product_sample>], [<df_ $size _product_pdf>], [<df_ $size _product_gradient>], [<df_ $size _product_vertex>], [<df_ $size _product_vertex_sample>], [<df_ $size _product_vertex_pdf>]];
            )*
        } }
    };
}
