//! The concrete model types behind [`crate::GuidingField`], one enum variant
//! per (representation family, target, size), dispatched with a `match`
//! (no `dyn`), and the per-family decode into a [`Decoded`] distribution.

use crate::config::{GuidingConfig, ModelSize, Representation, Target};
use crate::error::GuidingError;

use guiding_core::field::{Field, FieldState};
use guiding_core::mixture::nasg::NasgMixture;
use guiding_core::mixture::vmf::VmfMixture;
use guiding_core::model::batched::{DfTable, DfTableSums};
use guiding_core::model::df::Df;
use guiding_core::model::df::DfVertex;
use guiding_core::model::nasg::{Nasg, NASG_LOBES};
use guiding_core::model::npm::{Npm, NPM_LOBES};
use guiding_core::model::{Family, GuidingModel, QueryPoint};
use guiding_core::pdf1d::Interpolation;

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

/// The decoded lanes of one family, as a [`crate::batch::DistributionBatch`]
/// or a [`crate::GuideCache`] keeps them.
#[derive(Clone, Debug)]
pub(crate) enum Lanes {
    /// NPM's vMF mixtures.
    Vmf(Vec<VmfMixture<NPM_LOBES>>),
    /// NASG's mixtures (each with its learned selection probability).
    Nasg(Vec<NasgMixture<NASG_LOBES>>),
    /// DF's vertices: sampling and pdfs run the conditional network.
    Df(Vec<DfVertex>),
    /// DF vertices tabulated by a [`crate::GuideCache`] ([`DfTable`]), with
    /// each table's running sums.
    DfTable {
        tables: Vec<DfTable>,
        sums: Vec<DfTableSums>,
    },
}

impl Default for Lanes {
    fn default() -> Self {
        Self::Vmf(Vec::new())
    }
}

/// `Lanes::$variant`'s buffer: read (empty for another family) and written
/// (the lanes switched to `$variant`, emptied, if they were another family).
macro_rules! lane_buffer {
    ($read:ident, $write:ident, $variant:ident, $t:ty) => {
        pub(crate) fn $read(&self) -> &[$t] {
            match self {
                Self::$variant(v) => v,
                _ => &[],
            }
        }

        pub(crate) fn $write(&mut self) -> &mut Vec<$t> {
            if !matches!(self, Self::$variant(_)) {
                *self = Self::$variant(Vec::new());
            }
            match self {
                Self::$variant(v) => v,
                _ => unreachable!("switched to {} above", stringify!($variant)),
            }
        }
    };
}

impl Lanes {
    lane_buffer!(vmf, vmf_mut, Vmf, VmfMixture<NPM_LOBES>);
    lane_buffer!(nasg, nasg_mut, Nasg, NasgMixture<NASG_LOBES>);
    lane_buffer!(df, df_mut, Df, DfVertex);

    /// The tables and their sums (empty for another family).
    pub(crate) fn tables(&self) -> (&[DfTable], &[DfTableSums]) {
        match self {
            Self::DfTable { tables, sums } => (tables, sums),
            _ => (&[], &[]),
        }
    }

    /// The table buffers (the lanes switched to tables, emptied, if they
    /// were another kind).
    pub(crate) fn tables_mut(&mut self) -> (&mut Vec<DfTable>, &mut Vec<DfTableSums>) {
        if !matches!(self, Self::DfTable { .. }) {
            *self = Self::DfTable {
                tables: Vec::new(),
                sums: Vec::new(),
            };
        }
        match self {
            Self::DfTable { tables, sums } => (tables, sums),
            _ => unreachable!("switched to DfTable above"),
        }
    }

    pub(crate) fn len(&self) -> usize {
        match self {
            Self::Vmf(v) => v.len(),
            Self::Nasg(v) => v.len(),
            Self::Df(v) => v.len(),
            Self::DfTable { tables, .. } => tables.len(),
        }
    }

    /// Empties the lanes, keeping the family and the allocations.
    fn clear(&mut self) {
        match self {
            Self::Vmf(v) => v.clear(),
            Self::Nasg(v) => v.clear(),
            Self::Df(v) => v.clear(),
            Self::DfTable { tables, sums } => {
                tables.clear();
                sums.clear();
            }
        }
    }
}

/// The lanes of a [`crate::batch::DistributionBatch`] or a guide cache, with
/// their selection probabilities.
#[derive(Clone, Debug, Default)]
pub(crate) struct BatchItems {
    pub(crate) lanes: Lanes,
    /// The constant selection probability (NPM, DF).
    pub(crate) selection: f32,
    /// Per-lane selection probabilities overriding `selection` (NPM, DF lanes of a
    /// [`crate::GuideCache`] with fitted probabilities); empty otherwise.
    pub(crate) lane_selection: Vec<f32>,
}

impl BatchItems {
    pub(crate) fn clear(&mut self) {
        self.lanes.clear();
        self.lane_selection.clear();
    }

    pub(crate) fn len(&self) -> usize {
        self.lanes.len()
    }

    /// Appends `other`'s lanes (same family; the selection constant is
    /// `other`'s).
    pub(crate) fn append(&mut self, other: &BatchItems) {
        match &other.lanes {
            Lanes::Vmf(v) => self.lanes.vmf_mut().extend_from_slice(v),
            Lanes::Nasg(v) => self.lanes.nasg_mut().extend_from_slice(v),
            Lanes::Df(v) => self.lanes.df_mut().extend_from_slice(v),
            Lanes::DfTable { tables, sums } => {
                let (t, s) = self.lanes.tables_mut();
                t.extend_from_slice(tables);
                s.extend_from_slice(sums);
            }
        }
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
        let (c, n) = (&cells.lanes, &network.lanes);
        // The family of whichever holds lanes (an empty one may be a default).
        match if cells.len() > 0 { c } else { n } {
            Lanes::Vmf(_) => pick(c.vmf(), n.vmf(), source, flag, self.lanes.vmf_mut()),
            Lanes::Nasg(_) => pick(c.nasg(), n.nasg(), source, flag, self.lanes.nasg_mut()),
            Lanes::Df(_) => pick(c.df(), n.df(), source, flag, self.lanes.df_mut()),
            Lanes::DfTable { .. } => {
                let ((ct, cs), (nt, ns)) = (c.tables(), n.tables());
                let (tables, sums) = self.lanes.tables_mut();
                pick(ct, nt, source, flag, tables);
                pick(cs, ns, source, flag, sums);
            }
        }
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
        match &self.lanes {
            Lanes::Vmf(v) => v.get(i).map(|&mixture| Decoded::Vmf { mixture, selection }),
            Lanes::Nasg(v) => v.get(i).map(|&m| Decoded::Nasg(m)),
            Lanes::Df(v) => v.get(i).map(|&vertex| Decoded::Df { vertex, selection }),
            Lanes::DfTable { .. } => None,
        }
    }

    /// The guide-selection probability of lane `i` (0 out of range).
    pub(crate) fn selection_probability(&self, i: usize) -> f32 {
        match &self.lanes {
            Lanes::Nasg(v) => v.get(i).map_or(0.0, |m| m.selection_probability),
            _ if i < self.len() => self
                .lane_selection
                .get(i)
                .copied()
                .unwrap_or(self.selection),
            _ => 0.0,
        }
    }
}

/// Decoding of one family of models, per query and per batch.
pub(crate) trait Decode: GuidingModel {
    /// The family's decoded query.
    type Lane: DecodedLane;

    /// The model's batched decode of `queries` into `out` (one lane per query).
    fn decode_lanes(&self, params: &[f32], queries: &[QueryPoint], out: &mut [Self::Lane]);

    /// One decoded lane with its selection probability at `query`.
    fn decoded(&self, lane: Self::Lane, params: &[f32], query: &QueryPoint) -> Decoded;

    /// Decodes one query, as a batch of one: the same kernels (and bits) as every lane of
    /// a batched decode.
    fn decode_at(&self, params: &[f32], query: &QueryPoint) -> Decoded {
        let mut lane = [Self::Lane::ZERO];
        self.decode_lanes(params, std::slice::from_ref(query), &mut lane);
        self.decoded(lane[0], params, query)
    }

    /// Decodes every query into `out` (cleared first), one batched network pass per chunk,
    /// with the model's constant selection probability (0 where it is learned per lane).
    fn decode_batch_into(&self, params: &[f32], queries: &[QueryPoint], out: &mut BatchItems) {
        out.clear();
        out.selection = self.constant_selection_probability().unwrap_or(0.0);
        let lanes = Self::Lane::buffer(&mut out.lanes);
        lanes.resize(queries.len(), Self::Lane::ZERO);
        self.decode_lanes(params, queries, lanes);
    }
}

/// A lane type that a model decodes into [`Lanes`].
pub(crate) trait DecodedLane: Copy {
    /// The lane before decoding.
    const ZERO: Self;
    /// Its buffer in `lanes` (switched to this family, emptied, if they were another).
    fn buffer(lanes: &mut Lanes) -> &mut Vec<Self>;
}

impl DecodedLane for VmfMixture<NPM_LOBES> {
    const ZERO: Self = VmfMixture::ZERO;
    fn buffer(lanes: &mut Lanes) -> &mut Vec<Self> {
        lanes.vmf_mut()
    }
}

impl DecodedLane for NasgMixture<NASG_LOBES> {
    const ZERO: Self = NasgMixture::ZERO;
    fn buffer(lanes: &mut Lanes) -> &mut Vec<Self> {
        lanes.nasg_mut()
    }
}

impl DecodedLane for DfVertex {
    const ZERO: Self = DfVertex::ZERO;
    fn buffer(lanes: &mut Lanes) -> &mut Vec<Self> {
        lanes.df_mut()
    }
}

impl<const IN: usize, const W: usize, const H: usize> Decode for Npm<IN, W, H> {
    type Lane = VmfMixture<NPM_LOBES>;

    fn decode_lanes(&self, params: &[f32], queries: &[QueryPoint], out: &mut [Self::Lane]) {
        self.decode_batch(params, queries, out);
    }

    fn decoded(&self, mixture: Self::Lane, params: &[f32], query: &QueryPoint) -> Decoded {
        let selection = self.selection_probability(params, query);
        Decoded::Vmf { mixture, selection }
    }
}

impl<const IN: usize, const W: usize, const H: usize> Decode for Nasg<IN, W, H> {
    type Lane = NasgMixture<NASG_LOBES>;

    fn decode_lanes(&self, params: &[f32], queries: &[QueryPoint], out: &mut [Self::Lane]) {
        self.decode_batch(params, queries, out);
    }

    /// The selection probability is the mixture's own (learned).
    fn decoded(&self, mixture: Self::Lane, _params: &[f32], _query: &QueryPoint) -> Decoded {
        Decoded::Nasg(mixture)
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
    type Lane = DfVertex;

    fn decode_lanes(&self, params: &[f32], queries: &[QueryPoint], out: &mut [Self::Lane]) {
        self.decode_batch(params, queries, out);
    }

    fn decoded(&self, vertex: Self::Lane, params: &[f32], query: &QueryPoint) -> Decoded {
        let selection = self.selection_probability(params, query);
        Decoded::Df { vertex, selection }
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

        /// Runs `$body` with `$f` bound to the inner `Field<M>` of a DF
        /// field (its DF-only kernels), `$otherwise` for the mixtures.
        macro_rules! with_df_field {
            ($value:expr, $f:ident => $body:expr, $otherwise:expr) => {
                match $value {
                    $(
                        #[allow(unused_variables)]
                        crate::models::AnyField::$prefix($f) => {
                            crate::models::df_only!($family, $body, $otherwise)
                        }
                    )*
                }
            };
        }
        pub(crate) use with_df_field;

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
                    let model = construct!($family, $size, $model, lo, hi, c, interp);
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

/// `$body` for a DF row, `$otherwise` for a mixture row (whose model has no
/// DF kernels: `$body` is not compiled for it).
macro_rules! df_only {
    (df, $body:expr, $otherwise:expr) => {
        $body
    };
    ($family:ident, $body:expr, $otherwise:expr) => {
        $otherwise
    };
}
pub(crate) use df_only;

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

/// The preset value of a row's type: the size's constructor (named after the
/// size, [`guiding_core::model::sizes`]), NPM's and DF's constant selection
/// probability `$c`, DF's interpolation `$interp`.
macro_rules! construct {
    (npm, $size:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        guiding_core::__pastey::paste!(<$m>::[<$size:lower>]($lo, $hi)).with_selection_probability($c)
    };
    (nasg, $size:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        guiding_core::__pastey::paste!(<$m>::[<$size:lower>]($lo, $hi))
    };
    (df, $size:ident, $m:path, $lo:ident, $hi:ident, $c:ident, $i:ident) => {
        guiding_core::__pastey::paste!(<$m>::[<$size:lower>]($lo, $hi, $i))
            .with_selection_probability($c)
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

/// How many queries' raw outputs `raw_len` values hold (`exactly_one`: it
/// must be one query's).
///
/// # Errors
/// [`GuidingError::InvalidConfig`] for DF (no raw outputs), and
/// [`GuidingError::LengthMismatch`] if `raw_len` is not a whole number of
/// the model's rows (or not one row).
pub(crate) fn raw_queries(
    field: &AnyField,
    raw_len: usize,
    exactly_one: bool,
) -> Result<usize, GuidingError> {
    let r = raw_outputs(field);
    if r == 0 {
        return Err(GuidingError::InvalidConfig(
            "DF models have no raw outputs (the conditional network depends on the \
             direction)"
                .into(),
        ));
    }
    if raw_len % r != 0 || (exactly_one && raw_len != r) {
        return Err(GuidingError::LengthMismatch {
            what: format!("{raw_len} raw outputs for a {r}-output model"),
        });
    }
    Ok(raw_len / r)
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
