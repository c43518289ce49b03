//! The one table of model types ([`for_each_model!`](crate::for_each_model)).
//!
//! Every place that enumerates the model types — the `guiding` facade's
//! field enum, its save-file / entry-point prefixes, output counts and
//! constructors, and the SPIR-V entry points of `guiding-shaders` — is
//! generated from this table by a callback macro, so adding a model size
//! is one row here (plus its type alias in [`npm`](super::npm),
//! [`nasg`](super::nasg) or [`df`](super::df), and its `ModelSize` in the
//! facade).

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
/// - `Size` (`Small`, `Compact`, `Paper`) and `Target` (`Radiance`,
///   `Product`) are the facade's `ModelSize` / `Target` variants;
/// - the bracket lists the type's SPIR-V entry points (rust-gpu names an
///   entry point after its function, and `macro_rules!` cannot paste
///   identifiers): whole-model sample, pdf and per-sample gradient; then
///   for the mixtures the raw-output inference, for DF the per-vertex
///   kernel and the vertex lanes' sample and pdf.
///
/// ```
/// macro_rules! count_rows {
///     ($($ty:path => $prefix:ident, $family:ident, $size:ident, $target:ident,
///        [$($entry:ident),*];)*) => { [$(stringify!($prefix)),*].len() };
/// }
/// assert_eq!(guiding_core::for_each_model!(count_rows), 18);
/// ```
#[macro_export]
macro_rules! for_each_model {
    ($callback:ident) => {
        $callback! {
            $crate::model::npm::NpmSmallRadiance => npm_small_radiance, npm, Small, Radiance, [npm_small_radiance_sample, npm_small_radiance_pdf, npm_small_radiance_gradient, npm_small_radiance_infer];
            $crate::model::npm::NpmSmallProduct => npm_small_product, npm, Small, Product, [npm_small_product_sample, npm_small_product_pdf, npm_small_product_gradient, npm_small_product_infer];
            $crate::model::npm::NpmCompactRadiance => npm_compact_radiance, npm, Compact, Radiance, [npm_compact_radiance_sample, npm_compact_radiance_pdf, npm_compact_radiance_gradient, npm_compact_radiance_infer];
            $crate::model::npm::NpmCompactProduct => npm_compact_product, npm, Compact, Product, [npm_compact_product_sample, npm_compact_product_pdf, npm_compact_product_gradient, npm_compact_product_infer];
            $crate::model::npm::NpmRadiance => npm_paper_radiance, npm, Paper, Radiance, [npm_paper_radiance_sample, npm_paper_radiance_pdf, npm_paper_radiance_gradient, npm_paper_radiance_infer];
            $crate::model::npm::NpmProduct => npm_paper_product, npm, Paper, Product, [npm_paper_product_sample, npm_paper_product_pdf, npm_paper_product_gradient, npm_paper_product_infer];
            $crate::model::nasg::NasgSmallRadiance => nasg_small_radiance, nasg, Small, Radiance, [nasg_small_radiance_sample, nasg_small_radiance_pdf, nasg_small_radiance_gradient, nasg_small_radiance_infer];
            $crate::model::nasg::NasgSmallProduct => nasg_small_product, nasg, Small, Product, [nasg_small_product_sample, nasg_small_product_pdf, nasg_small_product_gradient, nasg_small_product_infer];
            $crate::model::nasg::NasgCompactRadiance => nasg_compact_radiance, nasg, Compact, Radiance, [nasg_compact_radiance_sample, nasg_compact_radiance_pdf, nasg_compact_radiance_gradient, nasg_compact_radiance_infer];
            $crate::model::nasg::NasgCompactProduct => nasg_compact_product, nasg, Compact, Product, [nasg_compact_product_sample, nasg_compact_product_pdf, nasg_compact_product_gradient, nasg_compact_product_infer];
            $crate::model::nasg::NasgRadiance => nasg_paper_radiance, nasg, Paper, Radiance, [nasg_paper_radiance_sample, nasg_paper_radiance_pdf, nasg_paper_radiance_gradient, nasg_paper_radiance_infer];
            $crate::model::nasg::NasgProduct => nasg_paper_product, nasg, Paper, Product, [nasg_paper_product_sample, nasg_paper_product_pdf, nasg_paper_product_gradient, nasg_paper_product_infer];
            $crate::model::df::DfSmallRadiance => df_small_radiance, df, Small, Radiance, [df_small_radiance_sample, df_small_radiance_pdf, df_small_radiance_gradient, df_small_radiance_vertex, df_small_radiance_vertex_sample, df_small_radiance_vertex_pdf];
            $crate::model::df::DfSmallProduct => df_small_product, df, Small, Product, [df_small_product_sample, df_small_product_pdf, df_small_product_gradient, df_small_product_vertex, df_small_product_vertex_sample, df_small_product_vertex_pdf];
            $crate::model::df::DfCompactRadiance => df_compact_radiance, df, Compact, Radiance, [df_compact_radiance_sample, df_compact_radiance_pdf, df_compact_radiance_gradient, df_compact_radiance_vertex, df_compact_radiance_vertex_sample, df_compact_radiance_vertex_pdf];
            $crate::model::df::DfCompactProduct => df_compact_product, df, Compact, Product, [df_compact_product_sample, df_compact_product_pdf, df_compact_product_gradient, df_compact_product_vertex, df_compact_product_vertex_sample, df_compact_product_vertex_pdf];
            $crate::model::df::DfRadiance => df_paper_radiance, df, Paper, Radiance, [df_paper_radiance_sample, df_paper_radiance_pdf, df_paper_radiance_gradient, df_paper_radiance_vertex, df_paper_radiance_vertex_sample, df_paper_radiance_vertex_pdf];
            $crate::model::df::DfProduct => df_paper_product, df, Paper, Product, [df_paper_product_sample, df_paper_product_pdf, df_paper_product_gradient, df_paper_product_vertex, df_paper_product_vertex_sample, df_paper_product_vertex_pdf];
        }
    };
}
