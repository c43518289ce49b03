//! The concrete model types behind [`crate::GuidingField`], one enum variant
//! per (representation family, target, size), dispatched with a `match`
//! (no `dyn`), and the per-family decode into a [`Decoded`] distribution.

use crate::config::{compact_grid, GuidingConfig, ModelSize, Representation, Target};
use crate::error::GuidingError;
use glam::{Vec2, Vec3};
use guiding_core::field::{Field, FieldState};
use guiding_core::lobe::DirectionSample;
use guiding_core::mixture::nasg::NasgMixture;
use guiding_core::mixture::vmf::VmfMixture;
use guiding_core::model::batched::{DfTable, DfTableSums};
use guiding_core::model::df::Df;
use guiding_core::model::df::DfVertex;
use guiding_core::model::nasg::{Nasg, NASG_LOBES};
use guiding_core::model::npm::{Npm, NPM_LOBES};
use guiding_core::model::{Family, GuidingModel, QueryPoint};
use guiding_core::pdf1d::Interpolation;

pub use guiding_core::model::df::{DfCompactProduct, DfCompactRadiance};
pub use guiding_core::model::nasg::{NasgCompactProduct, NasgCompactRadiance};
pub use guiding_core::model::npm::{NpmCompactProduct, NpmCompactRadiance};

const B0: [f32; 3] = [0.0; 3];
const B1: [f32; 3] = [1.0; 3];
const _: () =
    assert!(NpmCompactRadiance::new(compact_grid(B0, B1), Target::Radiance).is_consistent());
const _: () =
    assert!(NpmCompactProduct::new(compact_grid(B0, B1), Target::Product).is_consistent());
const _: () =
    assert!(NasgCompactRadiance::new(compact_grid(B0, B1), Target::Radiance).is_consistent());
const _: () =
    assert!(NasgCompactProduct::new(compact_grid(B0, B1), Target::Product).is_consistent());
const _: () = assert!(DfCompactRadiance::new(
    compact_grid(B0, B1),
    Target::Radiance,
    Interpolation::Linear
)
.is_consistent());
const _: () =
    assert!(
        DfCompactProduct::new(compact_grid(B0, B1), Target::Product, Interpolation::Linear)
            .is_consistent()
    );

/// A distribution decoded at one query point: the mixtures are kept whole
/// (sampling and evaluating them again costs no network pass); DF keeps the
/// query, because its conditional network depends on the direction.
///
/// Kept by value (a few hundred bytes) in the renderer's per-lane storage;
/// boxing the larger NASG variant would allocate once per query.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug)]
pub(crate) enum Decoded {
    Vmf {
        mixture: VmfMixture<NPM_LOBES>,
        selection: f32,
    },
    Nasg(NasgMixture<NASG_LOBES>),
    /// DF keeps its base input and marginal: sampling and pdfs run only the
    /// conditional network.
    Df {
        vertex: DfVertex,
        selection: f32,
    },
}

/// The per-family buffers of a [`crate::batch::DistributionBatch`]; only
/// the model's family is filled.
#[derive(Clone, Debug, Default)]
pub(crate) struct BatchItems {
    pub(crate) vmf: Vec<VmfMixture<NPM_LOBES>>,
    pub(crate) nasg: Vec<NasgMixture<NASG_LOBES>>,
    pub(crate) df: Vec<DfVertex>,
    /// Tabulated DF lanes of a [`crate::GuideCache`] ([`DfTable`]).
    pub(crate) df_table: Vec<DfTable>,
    /// The running sums of `df_table` (one per table).
    pub(crate) df_sums: Vec<DfTableSums>,
    /// The constant selection probability (NPM, DF).
    pub(crate) selection: f32,
    /// Per-lane selection probabilities overriding `selection` (NPM, DF lanes of a
    /// [`crate::GuideCache`] with fitted probabilities); empty otherwise.
    pub(crate) lane_selection: Vec<f32>,
}

impl BatchItems {
    pub(crate) fn clear(&mut self) {
        self.vmf.clear();
        self.nasg.clear();
        self.df.clear();
        self.df_table.clear();
        self.df_sums.clear();
        self.lane_selection.clear();
    }

    pub(crate) fn len(&self) -> usize {
        self.vmf
            .len()
            .max(self.nasg.len())
            .max(self.df.len())
            .max(self.df_table.len())
    }

    /// Appends `other`'s lanes (same family; the selection constant is
    /// `other`'s).
    pub(crate) fn append(&mut self, other: &BatchItems) {
        self.vmf.extend_from_slice(&other.vmf);
        self.nasg.extend_from_slice(&other.nasg);
        self.df.extend_from_slice(&other.df);
        self.df_table.extend_from_slice(&other.df_table);
        self.df_sums.extend_from_slice(&other.df_sums);
        self.selection = other.selection;
    }

    /// Replaces the lanes by `source[i]`'s lane of `cells`, or of `network`
    /// where `source[i]` has the bit `flag` (then the low bits index
    /// `network`). Both come from the same field, so they share the family
    /// and the selection constant. A non-empty `cell_selection` (one per
    /// lane of `cells`) becomes the per-lane selection probability; lanes
    /// from `network` keep the constant.
    pub(crate) fn gather(
        &mut self,
        cells: &BatchItems,
        cell_selection: &[f32],
        network: &BatchItems,
        source: &[u32],
        flag: u32,
    ) {
        fn pick<T: Copy>(cells: &[T], network: &[T], source: &[u32], flag: u32, out: &mut Vec<T>) {
            out.clear();
            if cells.is_empty() && network.is_empty() {
                return;
            }
            out.extend(source.iter().map(|&s| {
                if s & flag != 0 {
                    network[(s & !flag) as usize]
                } else {
                    cells[s as usize]
                }
            }));
        }
        pick(&cells.vmf, &network.vmf, source, flag, &mut self.vmf);
        pick(&cells.nasg, &network.nasg, source, flag, &mut self.nasg);
        pick(&cells.df, &network.df, source, flag, &mut self.df);
        pick(
            &cells.df_table,
            &network.df_table,
            source,
            flag,
            &mut self.df_table,
        );
        pick(
            &cells.df_sums,
            &network.df_sums,
            source,
            flag,
            &mut self.df_sums,
        );
        self.selection = if cells.len() > 0 {
            cells.selection
        } else {
            network.selection
        };
        self.lane_selection.clear();
        if !cell_selection.is_empty() {
            let constant = self.selection;
            self.lane_selection.extend(source.iter().map(|&s| {
                if s & flag != 0 {
                    constant
                } else {
                    cell_selection.get(s as usize).copied().unwrap_or(constant)
                }
            }));
        }
    }

    /// Lane `i` as a [`Decoded`] value (`None` out of range, and for a
    /// tabulated DF lane, which has no plain-value form).
    pub(crate) fn get(&self, i: usize) -> Option<Decoded> {
        let selection = self
            .lane_selection
            .get(i)
            .copied()
            .unwrap_or(self.selection);
        if let Some(m) = self.vmf.get(i) {
            return Some(Decoded::Vmf {
                mixture: *m,
                selection,
            });
        }
        if let Some(m) = self.nasg.get(i) {
            return Some(Decoded::Nasg(*m));
        }
        self.df.get(i).map(|v| Decoded::Df {
            vertex: *v,
            selection,
        })
    }

    /// The guide-selection probability of lane `i` (0 out of range).
    pub(crate) fn selection_probability(&self, i: usize) -> f32 {
        if let Some(m) = self.nasg.get(i) {
            return m.selection_probability;
        }
        if let Some(&c) = self.lane_selection.get(i) {
            return c;
        }
        if i < self.len() {
            self.selection
        } else {
            0.0
        }
    }
}

/// Decoding of one family of models, per query and per batch. The DF
/// methods have a default for the mixture families (which never store DF
/// vertices, so it never runs): the uniform density.
pub(crate) trait Decode: GuidingModel {
    fn decode_at(&self, params: &[f32], query: &QueryPoint) -> Decoded;

    /// Decodes every query into `out` (cleared first), one batched network
    /// pass per chunk.
    fn decode_batch_into(&self, params: &[f32], queries: &[QueryPoint], out: &mut BatchItems);

    /// DF samples of many lanes, the conditional network batched.
    fn sample_vertices_any(
        &self,
        params: &[f32],
        vertices: &[DfVertex],
        lanes: &[u32],
        u: &[Vec2],
        out: &mut [DirectionSample],
    ) {
        let _ = (params, vertices, lanes);
        for (o, &ub) in out.iter_mut().zip(u) {
            *o = DirectionSample {
                direction: guiding_core::factorised::direction_from_square(ub),
                pdf: guiding_core::math::INV_FOUR_PI,
            };
        }
    }

    /// DF tables of vertices ([`Df::tabulate_vertices`]).
    fn tabulate_vertices_any(&self, params: &[f32], vertices: &[DfVertex], out: &mut [DfTable]) {
        let _ = (params, vertices, out);
    }

    /// DF densities of many lanes, the conditional network batched.
    fn pdf_vertices_any(
        &self,
        params: &[f32],
        vertices: &[DfVertex],
        lanes: &[u32],
        directions: &[Vec3],
        out: &mut [f32],
    ) {
        let _ = (params, vertices, lanes, directions);
        out.fill(guiding_core::math::INV_FOUR_PI);
    }
}

impl<const IN: usize, const W: usize, const H: usize> Decode for Npm<IN, W, H> {
    /// A batch of one: the same kernels (and bits) as every lane of a
    /// batched decode.
    fn decode_at(&self, params: &[f32], query: &QueryPoint) -> Decoded {
        let mut m = [VmfMixture::ZERO];
        self.decode_batch(params, std::slice::from_ref(query), &mut m);
        Decoded::Vmf {
            mixture: m[0],
            selection: self.selection_probability(params, query),
        }
    }

    fn decode_batch_into(&self, params: &[f32], queries: &[QueryPoint], out: &mut BatchItems) {
        out.clear();
        out.selection = self.constant_selection_probability().unwrap_or(0.0);
        out.vmf.resize(queries.len(), VmfMixture::ZERO);
        self.decode_batch(params, queries, &mut out.vmf);
    }
}

impl<const IN: usize, const W: usize, const H: usize> Decode for Nasg<IN, W, H> {
    /// A batch of one (see the NPM implementation).
    fn decode_at(&self, params: &[f32], query: &QueryPoint) -> Decoded {
        let mut m = [NasgMixture::ZERO];
        self.decode_batch(params, std::slice::from_ref(query), &mut m);
        Decoded::Nasg(m[0])
    }

    fn decode_batch_into(&self, params: &[f32], queries: &[QueryPoint], out: &mut BatchItems) {
        out.clear();
        out.selection = 0.0;
        out.nasg.resize(queries.len(), NasgMixture::ZERO);
        self.decode_batch(params, queries, &mut out.nasg);
    }
}

impl<
        const IN_M: usize,
        const IN_C: usize,
        const IN_R: usize,
        const W: usize,
        const H: usize,
        const WR: usize,
        const HR: usize,
    > Decode for Df<IN_M, IN_C, IN_R, W, H, WR, HR>
{
    fn decode_at(&self, params: &[f32], query: &QueryPoint) -> Decoded {
        let mut v = [DfVertex::ZERO];
        self.decode_batch(params, std::slice::from_ref(query), &mut v);
        Decoded::Df {
            vertex: v[0],
            selection: self.selection_probability(params, query),
        }
    }

    fn decode_batch_into(&self, params: &[f32], queries: &[QueryPoint], out: &mut BatchItems) {
        out.clear();
        out.selection = self.constant_selection_probability().unwrap_or(0.0);
        out.df.resize(queries.len(), DfVertex::ZERO);
        self.decode_batch(params, queries, &mut out.df);
    }

    fn sample_vertices_any(
        &self,
        params: &[f32],
        vertices: &[DfVertex],
        lanes: &[u32],
        u: &[Vec2],
        out: &mut [DirectionSample],
    ) {
        self.sample_vertices(params, vertices, lanes, u, out);
    }

    fn pdf_vertices_any(
        &self,
        params: &[f32],
        vertices: &[DfVertex],
        lanes: &[u32],
        directions: &[Vec3],
        out: &mut [f32],
    ) {
        self.pdf_vertices(params, vertices, lanes, directions, out);
    }

    fn tabulate_vertices_any(&self, params: &[f32], vertices: &[DfVertex], out: &mut [DfTable]) {
        self.tabulate_vertices(params, vertices, out);
    }
}

/// The field enum, its dispatch macro, constructors, prefixes and output
/// counts, generated from the model table ([`guiding_core::for_each_model`]):
/// one variant per row, named by the row's prefix.
macro_rules! any_field {
    ($($model:path => $prefix:ident, $family:ident, $size:ident, $target:ident,
       [$($entry:ident),*];)*) => {
        /// One [`Field`] of any supported model type (a variant per row of
        /// the model table, named by its prefix).
        #[allow(non_camel_case_types)]
        pub(crate) enum AnyField {
            $($prefix(Field<$model>),)*
        }

        /// Runs `$body` with `$f` bound to the inner `Field<M>` (by
        /// reference or mutable reference, as `$value` is).
        macro_rules! with_field {
            ($value:expr, $f:ident => $body:expr) => {
                match $value {
                    $(crate::models::AnyField::$prefix($f) => $body,)*
                }
            };
        }
        pub(crate) use with_field;

        /// Builds the field of `config` over `[lo, hi]`, from `state` if
        /// given (a loaded file) or from the model's deterministic
        /// initialisation.
        pub(crate) fn build(
            config: &GuidingConfig,
            lo: [f32; 3],
            hi: [f32; 3],
            state: Option<FieldState>,
        ) -> Result<AnyField, GuidingError> {
            fn make<M: GuidingModel + Send + Sync>(
                model: M,
                config: &GuidingConfig,
                state: Option<FieldState>,
            ) -> Result<Field<M>, GuidingError> {
                Ok(match state {
                    Some(state) => Field::from_state(model, config.training, state)?,
                    None => Field::new(model, config.training)?,
                })
            }
            let c = config.selection_probability;
            let interp = if config.representation == Representation::DfLinear {
                Interpolation::Linear
            } else {
                Interpolation::Nearest
            };
            let _ = (c, interp);
            $(
                if family_matches!($family, config.representation)
                    && config.size == ModelSize::$size
                    && config.target == Target::$target
                {
                    let model = construct!($family, $size, $target, $model, lo, hi, c, interp);
                    return Ok(AnyField::$prefix(make(model, config, state)?));
                }
            )*
            Err(GuidingError::InvalidConfig(format!(
                "no model of {:?} size {:?} target {:?}",
                config.representation, config.size, config.target
            )))
        }

        /// The model's name in the table: its SPIR-V entry-point prefix
        /// (crate `guiding-shaders`: `{prefix}_sample`, `_pdf`,
        /// `_gradient`, `_infer`).
        pub(crate) fn kernel_prefix(field: &AnyField) -> &'static str {
            match field {
                $(AnyField::$prefix(_) => stringify!($prefix),)*
            }
        }

    };
}

/// Whether a row's family is the configuration's representation.
macro_rules! family_matches {
    (npm, $rep:expr) => {
        $rep == Representation::Npm
    };
    (nasg, $rep:expr) => {
        $rep == Representation::Nasg
    };
    (df, $rep:expr) => {
        matches!($rep, Representation::DfNearest | Representation::DfLinear)
    };
}

/// The preset value of a row's type: the size's constructor (the compact
/// grid for `Compact`), NPM's and DF's constant selection probability
/// `$c`, DF's interpolation `$interp`.
macro_rules! construct {
    (npm, Small, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::small($lo, $hi).with_selection_probability($c)
    };
    (npm, Compact, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::new(compact_grid($lo, $hi), Target::$t).with_selection_probability($c)
    };
    (npm, Paper, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::paper($lo, $hi).with_selection_probability($c)
    };
    (nasg, Small, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::small($lo, $hi)
    };
    (nasg, Compact, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::new(compact_grid($lo, $hi), Target::$t)
    };
    (nasg, Paper, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::paper($lo, $hi)
    };
    (df, Small, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::small($lo, $hi, $i).with_selection_probability($c)
    };
    (df, Compact, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::new(compact_grid($lo, $hi), Target::$t, $i).with_selection_probability($c)
    };
    (df, Paper, $t:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        <$m>::paper($lo, $hi, $i).with_selection_probability($c)
    };
}

guiding_core::for_each_model!(any_field);

/// The distribution decoded from raw outputs computed elsewhere (a GPU
/// running [`guiding_core::model::RawOutputs::write_raw`]); `None` for DF.
pub(crate) fn decode_raw(field: &AnyField, raw: &[f32]) -> Option<Decoded> {
    use guiding_core::batch::{nasg_mixture_from_raw, vmf_mixture_from_raw};
    match family(field) {
        Family::Df => None,
        Family::Npm => Some(Decoded::Vmf {
            mixture: vmf_mixture_from_raw(raw, 0),
            selection: constant_selection(field),
        }),
        Family::Nasg => Some(Decoded::Nasg(nasg_mixture_from_raw(raw, 0))),
    }
}

/// The family of the field's model type.
pub(crate) fn family(field: &AnyField) -> Family {
    fn of<M: GuidingModel>(_: &M) -> Family {
        M::FAMILY
    }
    with_field!(field, f => of(f.model()))
}

/// Raw network outputs per query of the model (0 for DF, whose
/// conditional network depends on the direction).
pub(crate) fn raw_outputs(field: &AnyField) -> usize {
    family(field).raw_outputs()
}

/// The model's constant selection probability (NPM, DF); 0 where it is
/// learned per query (NASG: each lane carries its own).
pub(crate) fn constant_selection(field: &AnyField) -> f32 {
    with_field!(field, f => f.model().constant_selection_probability()).unwrap_or(0.0)
}

/// The model's bytes (`repr(C)` Pod): its grid box, layer offsets and
/// constants, stored in save files to detect a file written for another
/// model layout.
pub(crate) fn model_bytes(field: &AnyField) -> Vec<u8> {
    with_field!(field, f => bytemuck::bytes_of(f.model()).to_vec())
}
