//! [`GuideCache`]: the decoded guide stored per cell of a fine spatial grid,
//! so a query costs a table lookup instead of a network pass (issue #14's
//! "frozen guide"; the role of Open PGL's per-region mixtures).
//!
//! A radiance-target guide depends on the position alone: the network maps
//! `x` to a directional distribution. Once the parameters stop changing
//! (after training, or between two updates) the same distribution is
//! decoded again and again at nearby points. The cache decodes it once per
//! occupied cell and hands out copies:
//!
//! - **Cells.** Cubes of side `h = max extent / resolution` over the field's
//!   box (plus one cell of margin). A cell exists only where the renderer has shown positions
//!   ([`GuidingField::build_cache`], [`GuideCache::extend`]); it is decoded
//!   at the centroid of the positions that created it, so the decode point
//!   lies on (or next to) the surfaces that fall in the cell rather than at
//!   a cell centre inside a wall.
//! - **Stochastic trilinear lookup.** A query at `x` with three uniform
//!   numbers `ξ` looks up the cell containing `x + (ξ − ½)·h`. Averaged over
//!   `ξ` this box-jitter is the tent filter of width `2h`, i.e. trilinear
//!   interpolation between the neighbouring cells' distributions, so the
//!   spatial interpolation survives in expectation (the stochastic filtering
//!   of Pharr et al. 2024 and Open PGL's spatial jitter). Where the jittered
//!   cell is empty the query's own cell is used; where that is empty too the
//!   query is decoded by the network (a *miss*, reported so the renderer can
//!   [`extend`](GuideCache::extend) the cache).
//! - **Unbiased by construction.** Each lane is one valid distribution
//!   (the network's, at a point near the query), and the renderer samples it
//!   and evaluates its density from the same lane: the estimator is
//!   unbiased whatever cell was picked; only its variance depends on the
//!   cache's resolution.
//!
//! - **Cosine product per normal bin.** With [`CacheOptions::cosine_product`]
//!   (vMF guides) a cell keeps one lane per octahedral bin (8 × 8) of the
//!   shading normals that fell in it, holding the guide times the clamped
//!   cosine of the bin's mean normal
//!   ([`DistributionBatch::apply_cosine_product`], Open PGL's
//!   `ApplyCosineProduct`): a query takes the lane of its own normal's bin,
//!   so the per-vertex product is gone too. On a plane the mean normal is
//!   the normal; on a curved surface it is off by at most the normal's
//!   spread within the cell and bin (a valid distribution all the same).
//!   Queries without a surface (a zero normal: scattering points inside a
//!   medium) have a lane of their own per cell, the guide without the
//!   product, so surfaces and media share one cache.
//!
//! Product-target guides also depend on `ωo`, the normal and the roughness,
//! so [`GuidingField::build_cache`] refuses them.
//!
//! A cache is valid for the field generation it was built at; after an
//! update that changed the parameters, [`GuideCache::refresh`] decodes its
//! cells again (one batched decode of every cell, a few ms).

use crate::batch::{DistributionBatch, LaneLocation, CACHE_MISS as MISS};
use crate::config::Target;
use crate::error::{same_lengths, GuidingError};
use crate::field::GuidingField;
use crate::models::{with_df_field, with_field, BatchItems, Decode, Lanes};
use glam::Vec3;
use guiding_core::mixture::vmf::VmfMixture;
use guiding_core::model::npm::NPM_LOBES;
use guiding_core::model::QueryPoint;
use std::sync::Arc;

/// Marks an empty cell (and the end of a cell's lane chain).
const EMPTY: u32 = u32::MAX;
/// How many queries ahead [`GuideCache::decode_batch`] fetches index entries
/// (enough lookups in flight to cover a memory access).
const LOOKAHEAD: usize = 16;
/// Octahedral normal bins per axis with [`CacheOptions::cosine_product`].
const NORMAL_BINS: u32 = 8;
/// Most cells along one axis (the index is `resolution³` `u32`s at most).
pub const MAX_CACHE_RESOLUTION: u32 = 256;

/// Options of a [`GuideCache`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheOptions {
    /// Cells along the longest axis of the field's box, in `[1,`
    /// [`MAX_CACHE_RESOLUTION`]`]`.
    pub resolution: u32,
    /// vMF guides: store the product with the clamped cosine per normal bin
    /// (see the [module docs](self)); lanes handed out are then already
    /// multiplied, network-decoded misses included. Ignored for NASG and DF.
    pub cosine_product: bool,
    /// DF guides: store each cell's frozen distribution as a table
    /// ([`guiding_core::model::batched::DfTable`]: the marginal, and the
    /// conditional at the 32 marginal bins' centres, ~2.4 kB a cell), so a
    /// query runs no network at all; otherwise a cell keeps the marginal and
    /// every sample and pdf runs the conditional network. A deviation from
    /// DF's conditional, continuous in `ε₁`, that keeps the estimator
    /// unbiased (a table samples and evaluates the same density). Ignored
    /// for NPM and NASG. On by default.
    pub df_table: bool,
}

impl Default for CacheOptions {
    fn default() -> Self {
        Self {
            resolution: 64,
            cosine_product: false,
            df_table: true,
        }
    }
}

/// The lane of a cell that serves queries without a surface (a zero normal,
/// [`guiding_core::frame::is_no_surface`]: scattering points in a medium): the
/// guide without a cosine product.
const NO_SURFACE_BIN: u8 = (NORMAL_BINS * NORMAL_BINS) as u8;

/// The octahedral bin (`NORMAL_BINS²` of them) of a normal; a zero one is
/// [`NO_SURFACE_BIN`], a non-finite one counts as `+z` (the normal its lane's
/// product falls back to).
fn normal_bin(n: Vec3) -> u8 {
    if guiding_core::frame::is_no_surface(n) {
        return NO_SURFACE_BIN;
    }
    let l1 = n.x.abs() + n.y.abs() + n.z.abs();
    let p = if l1 > 0.0 && l1.is_finite() {
        n / l1
    } else {
        Vec3::Z
    };
    let (x, y) = if p.z >= 0.0 {
        (p.x, p.y)
    } else {
        (
            (1.0 - p.y.abs()).copysign(p.x),
            (1.0 - p.x.abs()).copysign(p.y),
        )
    };
    let b = |t: f32| (((t + 1.0) * 0.5 * NORMAL_BINS as f32) as u32).min(NORMAL_BINS - 1);
    (b(x) + NORMAL_BINS * b(y)) as u8
}

/// What one [`GuideCache::decode_batch`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheLookup {
    /// Lanes copied from a cell.
    pub hits: u64,
    /// Lanes decoded by the network (no occupied cell near the query).
    pub misses: u64,
}

/// The decoded guide per occupied cell of a spatial grid (see the [module
/// docs](self)).
#[derive(Clone, Debug)]
pub struct GuideCache {
    field_id: u64,
    generation: u64,
    lo: Vec3,
    /// Cell side `h` and `1 / h`.
    cell: f32,
    inv_cell: f32,
    res: [u32; 3],
    /// Cosine product per normal bin (vMF guides with the option on).
    product: bool,
    /// Tabulated DF cells (DF guides with [`CacheOptions::df_table`]).
    tabulate: bool,
    /// Per cell: its first lane in `items`, or [`EMPTY`].
    index: Vec<u32>,
    /// Per lane: the next lane of the same cell (another normal bin), or [`EMPTY`].
    next: Vec<u32>,
    /// Per lane: its normal bin (0 without the product).
    bin: Vec<u8>,
    /// Per lane: the decode point (centroid of the positions that made it).
    points: Vec<Vec3>,
    /// Per lane: the unit mean normal of the cosine product (product only).
    normals: Vec<Vec3>,
    /// The decoded lanes, shared with the batches [`GuideCache::decode_batch`]
    /// fills (no copy per query); their `lane_selection` holds the fitted
    /// guide-selection probabilities ([`GuideCache::fit_selection`]), empty
    /// before a fit.
    items: Arc<BatchItems>,
    /// The fit's value for cells with too few samples (and cells added later).
    global_selection: f32,
}

impl GuidingField {
    /// A cache of this field's decoded guide over the cells that contain
    /// the positions of `points` (typically the vertices of the latest
    /// training pass; their normals pick the bins of the cosine product).
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] for a product-target field (its guide
    /// depends on more than the position) or a resolution outside `[1,`
    /// [`MAX_CACHE_RESOLUTION`]`]`.
    pub fn build_cache(
        &self,
        points: &[QueryPoint],
        options: &CacheOptions,
    ) -> Result<GuideCache, GuidingError> {
        if self.config().target != Target::Radiance {
            return Err(GuidingError::InvalidConfig(
                "a guide cache needs a radiance-target field (a product guide also depends \
                 on the outgoing direction, the normal and the roughness)"
                    .into(),
            ));
        }
        if !(1..=MAX_CACHE_RESOLUTION).contains(&options.resolution) {
            return Err(GuidingError::InvalidConfig(format!(
                "cache resolution {} outside [1, {MAX_CACHE_RESOLUTION}]",
                options.resolution
            )));
        }
        let (lo, hi) = self.bounds();
        let (lo, hi) = (Vec3::from_array(lo), Vec3::from_array(hi));
        let extent = hi - lo;
        let cell = extent.max_element() / options.resolution as f32;
        // One cell of margin on every side: surface points on the scene box (and rounding
        // just past it) still fall in a cell.
        let lo = lo - Vec3::splat(cell);
        let res = (extent / cell)
            .ceil()
            .to_array()
            .map(|r| (r as u32).clamp(1, options.resolution) + 2);
        let mut cache = GuideCache {
            field_id: self.id,
            generation: self.generation,
            lo,
            cell,
            inv_cell: 1.0 / cell,
            res,
            product: options.cosine_product
                && self.config().representation == crate::config::Representation::Npm,
            tabulate: options.df_table
                && matches!(
                    self.config().representation,
                    crate::config::Representation::DfNearest
                        | crate::config::Representation::DfLinear
                ),
            index: vec![EMPTY; res[0] as usize * res[1] as usize * res[2] as usize],
            next: Vec::new(),
            bin: Vec::new(),
            points: Vec::new(),
            normals: Vec::new(),
            items: Arc::default(),
            global_selection: 0.0,
        };
        cache.extend(self, points)?;
        Ok(cache)
    }
}

/// A vMF guide cache as plain tables ([`GuideCache::vmf_table`]), for a renderer that
/// evaluates the guide inside its own kernels (a shader, a Dr.Jit loop): the lookup of the
/// [module docs](self) is `lane = index[cell(x + (ξ − ½) h)]`, falling back to the cell of `x`
/// itself, with `cell(p) = (z·res_y + y)·res_x + x` for `(x, y, z) = ⌊(p − lo) / h⌋` inside
/// `res`; where both are empty the renderer samples the BSDF alone (`c = 0`), which keeps its
/// estimator unbiased.
#[derive(Clone, Copy, Debug)]
pub struct VmfTable<'a> {
    /// The grid's lower corner.
    pub lo: [f32; 3],
    /// Cell side `h`.
    pub cell: f32,
    /// Cells along x, y, z.
    pub res: [u32; 3],
    /// Per cell: its lane, or `u32::MAX` where the cell is empty.
    pub index: &'a [u32],
    /// Per lane: the decoded mixture.
    pub lanes: &'a [VmfMixture<NPM_LOBES>],
    /// Per lane: the fitted selection probability ([`GuideCache::fit_selection`]); empty
    /// before a fit, when every lane has [`Self::selection`].
    pub lane_selection: &'a [f32],
    /// The constant selection probability.
    pub selection: f32,
}

impl GuideCache {
    /// The cache as plain tables ([`VmfTable`]); `None` unless the guide is NPM's vMF mixtures
    /// without the cosine product (one lane per cell).
    #[must_use]
    pub fn vmf_table(&self) -> Option<VmfTable<'_>> {
        match (&self.items.lanes, self.product) {
            (Lanes::Vmf(lanes), false) => Some(VmfTable {
                lo: self.lo.to_array(),
                cell: self.cell,
                res: self.res,
                index: &self.index,
                lanes,
                lane_selection: &self.items.lane_selection,
                selection: self.items.selection,
            }),
            _ => None,
        }
    }

    /// Stored distributions: occupied cells, times their normal bins with
    /// the cosine product.
    #[must_use]
    pub fn cells(&self) -> usize {
        self.points.len()
    }

    /// Whether the lanes hold the cosine product (see [`CacheOptions`]).
    #[must_use]
    pub fn has_cosine_product(&self) -> bool {
        self.product
    }

    /// The bin of normal `n` (always 0 without the product).
    fn bin_of(&self, n: Vec3) -> u8 {
        if self.product {
            normal_bin(n)
        } else {
            0
        }
    }

    /// The lane of `(cell, bin)`, or [`EMPTY`].
    fn lane_of(&self, cell: usize, bin: u8) -> u32 {
        let mut l = self.index[cell];
        while l != EMPTY && self.bin[l as usize] != bin {
            l = self.next[l as usize];
        }
        l
    }

    /// Cells along x, y and z.
    #[must_use]
    pub fn resolution(&self) -> [u32; 3] {
        self.res
    }

    /// Cell side in world units.
    #[must_use]
    pub fn cell_size(&self) -> f32 {
        self.cell
    }

    /// The field generation the cells were decoded at.
    #[must_use]
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// The cell containing `p`, or `None` outside the grid (or non-finite).
    fn cell_of(&self, p: Vec3) -> Option<usize> {
        let c = (p - self.lo) * self.inv_cell;
        if !(c.cmpge(Vec3::ZERO).all() && c.is_finite()) {
            return None;
        }
        let (x, y, z) = (c.x as u32, c.y as u32, c.z as u32);
        if x >= self.res[0] || y >= self.res[1] || z >= self.res[2] {
            return None;
        }
        let (nx, ny) = (self.res[0] as usize, self.res[1] as usize);
        Some((z as usize * ny + y as usize) * nx + x as usize)
    }

    /// The error for using the cache with `field` when it was built for
    /// another field or generation.
    fn stale(&self, field: &GuidingField) -> GuidingError {
        GuidingError::StaleDistribution {
            field_id: self.field_id,
            generation: self.generation,
            used_id: field.id,
            used_generation: field.generation,
        }
    }

    fn check(&self, field: &GuidingField) -> Result<(), GuidingError> {
        if field.id != self.field_id || field.generation != self.generation {
            return Err(self.stale(field));
        }
        Ok(())
    }

    /// Adds the cells (and normal bins) of `points` that are not in the
    /// cache yet, each decoded at the centroid of its positions (and, with
    /// the cosine product, multiplied by the clamped cosine of their mean
    /// normal). Points with a non-finite position or outside the grid (the
    /// field's box plus one cell of margin) are ignored. The result does not
    /// depend on the order of `points`. Returns the number of lanes added.
    ///
    /// # Errors
    /// [`GuidingError::StaleDistribution`] if the field was updated since the
    /// cache was built or refreshed (call [`Self::refresh`] first), or is
    /// another field.
    pub fn extend(
        &mut self,
        field: &GuidingField,
        points: &[QueryPoint],
    ) -> Result<usize, GuidingError> {
        self.check(field)?;
        // New points keyed by (cell, bin), sorted with their bits so the
        // centroid sums run in an order independent of the input's.
        let mut fresh: Vec<(usize, u8, [u32; 6])> = points
            .iter()
            .filter_map(|q| {
                let p = Vec3::from_array(q.position);
                let c = self.cell_of(p)?;
                let n = Vec3::from_array(q.normal);
                let b = self.bin_of(n);
                let n = if self.product && n.is_finite() {
                    n
                } else {
                    Vec3::ZERO
                };
                let bits = [p.x, p.y, p.z, n.x, n.y, n.z].map(f32::to_bits);
                (self.lane_of(c, b) == EMPTY).then_some((c, b, bits))
            })
            .collect();
        fresh.sort_unstable();
        let mut queries = Vec::new();
        let mut normals = Vec::new();
        let mut k = 0;
        while k < fresh.len() {
            let (c, b) = (fresh[k].0, fresh[k].1);
            let (mut sum, mut n) = ([0.0f64; 6], 0u32);
            while k < fresh.len() && fresh[k].0 == c && fresh[k].1 == b {
                for (s, bits) in sum.iter_mut().zip(fresh[k].2) {
                    *s += f64::from(f32::from_bits(bits));
                }
                n += 1;
                k += 1;
            }
            let mean = sum.map(|s| (s / f64::from(n)) as f32);
            let lane = (self.points.len() + queries.len()) as u32;
            self.next.push(self.index[c]);
            self.bin.push(b);
            self.index[c] = lane;
            let centroid = Vec3::new(mean[0], mean[1], mean[2]);
            queries.push(QueryPoint::from_vec3(centroid, Vec3::Z, Vec3::Z, 1.0));
            // The raw mean: the product normalises it (a zero mean reads as +z).
            normals.push(Vec3::new(mean[3], mean[4], mean[5]));
        }
        let added = queries.len();
        if added > 0 {
            let mut decoded = BatchItems::default();
            decode_cells(field, &queries, self.tabulate, &mut decoded);
            if self.product {
                guiding_core::model::batched::cosine_product_batch(
                    decoded.lanes.vmf_mut(),
                    &normals,
                );
                self.normals.extend_from_slice(&normals);
            }
            let items = Arc::make_mut(&mut self.items);
            items.append(&decoded);
            self.points
                .extend(queries.iter().map(|q| Vec3::from_array(q.position)));
            if !items.lane_selection.is_empty() {
                items
                    .lane_selection
                    .resize(self.points.len(), self.global_selection);
            }
        }
        Ok(added)
    }

    /// Decodes every cell again with `field`'s current parameters (after an
    /// update); the cells and their decode points stay.
    ///
    /// # Errors
    /// [`GuidingError::StaleDistribution`] if `field` is not the field the
    /// cache was built for.
    pub fn refresh(&mut self, field: &GuidingField) -> Result<(), GuidingError> {
        if field.id != self.field_id {
            return Err(self.stale(field));
        }
        if field.generation == self.generation {
            return Ok(());
        }
        let queries: Vec<QueryPoint> = self
            .points
            .iter()
            .map(|&p| QueryPoint::from_vec3(p, Vec3::Z, Vec3::Z, 1.0))
            .collect();
        self.generation = field.generation;
        let items = Arc::make_mut(&mut self.items);
        // The fitted probabilities stay with their cells.
        let selection = std::mem::take(&mut items.lane_selection);
        decode_cells(field, &queries, self.tabulate, items);
        items.lane_selection = selection;
        if self.product {
            guiding_core::model::batched::cosine_product_batch(
                items.lanes.vmf_mut(),
                &self.normals,
            );
        }
        Ok(())
    }

    /// Fills `out` with one distribution per query from the cache: lane `i`
    /// is the cell found by the stochastic trilinear lookup of
    /// `queries[i].position` with the three uniform numbers `jitter[i]`
    /// (see the [module docs](self)), or the network's decode at the query
    /// where no cell is near (its index is pushed to `missed`, after
    /// `missed` is cleared). With the cosine product the lanes (misses too)
    /// are already multiplied: do not apply it again. `out` then serves
    /// [`GuidingField::sample_decoded`] / [`GuidingField::pdf_decoded`] as
    /// after [`GuidingField::decode_batch`].
    ///
    /// # Errors
    /// [`GuidingError::StaleDistribution`] if the field was updated since the
    /// cache was built or refreshed; [`GuidingError::LengthMismatch`] if
    /// `jitter` and `queries` differ in length. `out` is left empty then.
    pub fn decode_batch(
        &self,
        field: &GuidingField,
        queries: &[QueryPoint],
        jitter: &[Vec3],
        out: &mut DistributionBatch,
        missed: &mut Vec<u32>,
    ) -> Result<CacheLookup, GuidingError> {
        out.reset(field);
        missed.clear();
        self.check(field)?;
        same_lengths(&[(queries.len(), "queries"), (jitter.len(), "jitters")])?;
        // Source lane per query: a cell's lane, or MISS | index into `missed`
        // (in `out`'s reused scratch: no allocation per call in steady state).
        let mut source = std::mem::take(&mut out.scratch);
        source.clear();
        // First the jittered cell of every query (`EMPTY` outside the grid),
        // then the lookups, each fetching the index entry of the query
        // `LOOKAHEAD` places on: the index spans a megabyte or more and a
        // lone lookup waits on memory (perf on the Cornell box: most of
        // this function's time was that wait).
        source.extend(queries.iter().zip(jitter).map(|(q, &xi)| {
            let p = Vec3::from_array(q.position);
            let jittered = p + (xi - Vec3::splat(0.5)) * self.cell;
            self.cell_of(jittered).map_or(EMPTY, |c| c as u32)
        }));
        for i in 0..queries.len() {
            if let Some(&ahead) = source.get(i + LOOKAHEAD) {
                if let Some(entry) = self.index.get(ahead as usize) {
                    guiding_core::model::mixture_batch::prefetch(entry);
                }
            }
            let q = &queries[i];
            let bin = self.bin_of(Vec3::from_array(q.normal));
            let jittered_cell = source[i];
            let mut lane = if jittered_cell == EMPTY {
                EMPTY
            } else {
                self.lane_of(jittered_cell as usize, bin)
            };
            if lane == EMPTY {
                lane = self
                    .cell_of(Vec3::from_array(q.position))
                    .map_or(EMPTY, |c| self.lane_of(c, bin));
            }
            source[i] = if lane == EMPTY {
                missed.push(i as u32);
                MISS | (missed.len() as u32 - 1)
            } else {
                lane
            };
        }
        // The misses in `out`'s own lanes; the cells shared.
        if !missed.is_empty() {
            let mq: Vec<QueryPoint> = missed.iter().map(|&i| queries[i as usize]).collect();
            // Tabulated like the cells, so every lane of the batch is of one
            // kind (a batch that mixes DF tables and DF vertices cannot be
            // gathered into one buffer).
            decode_cells(field, &mq, self.tabulate, &mut out.items);
            if self.product {
                let normals: Vec<Vec3> = mq.iter().map(|q| Vec3::from_array(q.normal)).collect();
                guiding_core::model::batched::cosine_product_batch(
                    out.items.lanes.vmf_mut(),
                    &normals,
                );
            }
        }
        out.items.selection = self.items.selection;
        out.field_id = field.id;
        out.generation = field.generation;
        out.location = LaneLocation::Cache {
            cells: Arc::clone(&self.items),
            source,
        };
        Ok(CacheLookup {
            hits: (queries.len() - missed.len()) as u64,
            misses: missed.len() as u64,
        })
    }
}

/// The field's batched decode of `queries` into `out`.
fn decode_into(field: &GuidingField, queries: &[QueryPoint], out: &mut BatchItems) {
    with_field!(&field.inner, f => f
        .model()
        .decode_batch_into(f.ema_params(), queries, out));
}

/// [`decode_into`] for a cache's cells: DF vertices replaced by their tables
/// with `tabulate`.
fn decode_cells(
    field: &GuidingField,
    queries: &[QueryPoint],
    tabulate: bool,
    out: &mut BatchItems,
) {
    decode_into(field, queries, out);
    if !tabulate {
        return;
    }
    if let Lanes::Df(vertices) = &out.lanes {
        let mut tables = vec![guiding_core::model::batched::DfTable::ZERO; vertices.len()];
        with_df_field!(&field.inner, f => f
            .model()
            .tabulate_vertices(f.ema_params(), vertices, &mut tables), ());
        let sums = tables.iter().map(|t| t.running_sums()).collect();
        out.lanes = Lanes::DfTable { tables, sums };
    }
}

/// A vMF lobe `e^{κ (a·ω − 1)}` a renderer multiplied a vertex's guide by
/// before sampling ([`DistributionBatch::apply_lobe_product`]; e.g. the vMF
/// fit [`guiding_core::lobe::vmf::hg_vmf_kappa`] of a Henyey–Greenstein
/// phase function around the forward direction), one per training sample
/// for [`GuideCache::fit_selection`]. `κ = 0` (the [`Default`]): no product.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProductLobe {
    /// The lobe's axis (normalised; a non-finite one means no product, see
    /// [`guiding_core::lobe::vmf::product_lobe`]).
    pub axis: [f32; 3],
    /// Its concentration `κ ≥ 0`.
    pub kappa: f32,
}

/// Options of [`GuideCache::fit_selection`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SelectionFit {
    /// Smallest and largest selection probability tried (the candidates are
    /// `CANDIDATES` values evenly spaced from `min` to `max`); `max < 1`
    /// keeps a defensive share of BSDF sampling, `min = 0` lets the fit turn
    /// the guide off where the BSDF and NEE do better (the renderer then
    /// skips the guide's sample and pdfs there).
    pub min: f32,
    /// See `min`.
    pub max: f32,
    /// Shrinkage towards the fit over all samples: each cell's estimate gets
    /// this many pseudo-samples of the global mean estimate (a cell without
    /// samples takes the global value; one with many keeps its own).
    pub prior_samples: u32,
    /// The extra cost of a vertex that queries the guide (`c > 0`: the
    /// guide's pdfs for MIS, and its sample) relative to one that does not
    /// (`c = 0`), `κ ≥ 0`. An estimator's efficiency is `1 / (variance ·
    /// time)`; to first order a cell then takes the candidate of least
    /// `s V(c) / V_ref + κ [c > 0] n / N`: its variance `V(c) = M̂(c) − mean`
    /// as a share of `V_ref` (the variance of all samples at their best
    /// constant `c`) scaled by [`Self::variance_share`] `s`, plus its share
    /// `n / N` of the samples (the vertices) times `κ` where it queries the
    /// guide. `0` (the default): the variance alone. A renderer measures `κ`
    /// as the guide queries' share of its tracing time, `Q / (T − Q)`, over
    /// passes traced with the cache.
    pub guide_cost: f32,
    /// `s ∈ [0, 1]`: the share of the image's variance that the fitted
    /// vertices' sampling makes (1, the default, counts all of it: the fit
    /// then trusts the vertex variances). A renderer that measured the image
    /// variance ratio `r_pix` of a fitted guide against none, where the fit
    /// predicted the vertex variance ratio `r_vert` ([`SelectionReport::variance_ratio`]),
    /// has `1 − r_pix = s (1 − r_vert)`. Only weighed with a `guide_cost`.
    pub variance_share: f32,
}

impl Default for SelectionFit {
    fn default() -> Self {
        Self {
            min: 0.0,
            max: 0.9,
            prior_samples: 32,
            guide_cost: 0.0,
            variance_share: 1.0,
        }
    }
}

impl SelectionFit {
    /// The `k`-th of the [`CANDIDATES`] probabilities, evenly spaced from `min` to `max`.
    fn candidate(&self, k: usize) -> f32 {
        self.min + (self.max - self.min) * k as f32 / (CANDIDATES - 1) as f32
    }

    /// The fit's settings in their ranges, or the error naming the one that is not.
    fn validate(&self) -> Result<(), GuidingError> {
        if !(self.min >= 0.0 && self.min <= self.max && self.max < 1.0) {
            return Err(GuidingError::InvalidConfig(format!(
                "selection fit range [{}, {}] must satisfy 0 <= min <= max < 1",
                self.min, self.max
            )));
        }
        if !(self.variance_share >= 0.0 && self.variance_share <= 1.0) {
            return Err(GuidingError::InvalidConfig(format!(
                "selection fit variance share {} must lie in [0, 1]",
                self.variance_share
            )));
        }
        if !(self.guide_cost >= 0.0 && self.guide_cost.is_finite()) {
            return Err(GuidingError::InvalidConfig(format!(
                "selection fit guide cost {} must be finite and >= 0",
                self.guide_cost
            )));
        }
        Ok(())
    }
}

/// Candidate selection probabilities of [`GuideCache::fit_selection`].
pub const CANDIDATES: usize = 10;

/// What [`GuideCache::fit_selection`] found.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SelectionReport {
    /// Samples that fell in a cell and had a finite, positive weight.
    pub samples_used: u64,
    /// Cells with samples of their own.
    pub cells_fitted: u64,
    /// Cells without samples (the global value).
    pub cells_global: u64,
    /// Cells fitted to `c = 0` (the guide off).
    pub cells_off: u64,
    /// The fit over all samples.
    pub global: f32,
    /// Mean fitted probability over the cells.
    pub mean: f32,
    /// Estimated variance of the renderer's one-sample estimator over the
    /// samples with the fitted probabilities, relative to BSDF sampling
    /// alone (`c = 0`): `Σ_cells V(c_cell) / Σ_cells V(0)` with
    /// `V(c) = M̂(c) − μ̂² / n` per cell (`μ̂ = Σ F/p_s`, the cell's `n`
    /// samples); below 1 the guide lowers the vertex variance (the estimate
    /// of a variance near 0, where the guide matches the integrand, may
    /// come out below 0). `NaN` when BSDF sampling alone has no finite
    /// estimate (or no samples). Measured at 20 s: 0.47 on the Cornell box
    /// and 0.49 on `builtin:door`, where the pixel variance per sample is
    /// 0.9× and 0.4× that of `pt-nee`: a vertex's variance does not tell how
    /// much of the pixel's it is.
    pub variance_ratio: f64,
}

impl GuideCache {
    /// Fits a guide-selection probability `c` per cell: the candidate that
    /// minimises the estimated second moment of the renderer's one-sample
    /// MIS estimator `F / p_c` with `p_c = c·q + (1 − c)·p_bsdf` (the
    /// variance-optimal sampling fraction of Müller et al. 2019, "Practical
    /// Path Guiding in Production", §4, found here by a search over
    /// candidates instead of their stochastic gradient descent).
    ///
    /// For any `c`, `∫ F² / p_c = E_s[F² / (p_c · p_s)]` whatever density
    /// `p_s` the samples were drawn with, so the samples of a training pass
    /// (drawn with an older guide and `c`, their `sample_pdf`) estimate the
    /// second moment under the cached guide `q` for every candidate at
    /// once: per cell, `M̂(c) = Σ F_i² / ((c·q(ω_i) + (1 − c)·p_bsdf,i) · p_s,i)`
    /// with `F_i = Y(L_i ⊙ f cos)` (luminance of the sample's integrand),
    /// `L_i` the sample's MIS-weighted incident radiance `mis_radiance[i]`
    /// when given ([`crate::BatchRecorder::mis_radiance`]: with NEE the
    /// emission found along `ω_i` counts with its MIS weight, as in the
    /// render), else its training radiance.
    /// `q` is the lane the sample's position and normal fall in (with the
    /// cache's cosine product, if it has one), times `lobes[i]` where given
    /// and `κ > 0` (vMF lanes: the renderer's
    /// [`DistributionBatch::apply_lobe_product`] at that vertex, e.g. the
    /// phase function's lobe at a scattering point in a medium; without it
    /// the fit would weigh a guide the renderer does not sample). Each cell's sums get
    /// `prior_samples` pseudo-samples of the global mean
    /// (`M̂(c) + n₀ · M̂_all(c) / N`), so sparse cells lean on the fit over
    /// all samples (a cell without samples takes it). The probabilities then
    /// replace the configuration's constant in [`Self::decode_batch`]'s
    /// lanes (NASG keeps its learned per-point value).
    ///
    /// Measured on `builtin:door` with NEE: with the training radiance
    /// (emission in full) the fit picks `c = 0.9` and triples the per-pixel
    /// variance, because it credits the guide with direct light that NEE
    /// already estimates; hence `mis_radiance`.
    ///
    /// # Errors
    /// [`GuidingError::StaleDistribution`] as [`Self::decode_batch`];
    /// [`GuidingError::InvalidConfig`] unless `0 ≤ min ≤ max < 1`, or for a
    /// NASG field (it learns its own selection probability);
    /// [`GuidingError::LengthMismatch`] if `mis_radiance` or `lobes` is
    /// given with another length than `samples`.
    pub fn fit_selection(
        &mut self,
        field: &GuidingField,
        samples: &[guiding_core::sample::TrainingSample],
        mis_radiance: Option<&[[f32; 3]]>,
        lobes: Option<&[ProductLobe]>,
        fit: &SelectionFit,
    ) -> Result<SelectionReport, GuidingError> {
        self.check(field)?;
        if matches!(self.items.lanes, Lanes::Nasg(_)) {
            return Err(GuidingError::InvalidConfig(
                "NASG learns its own selection probability".into(),
            ));
        }
        fit.validate()?;
        if let Some(m) = mis_radiance {
            if m.len() != samples.len() {
                return Err(GuidingError::LengthMismatch {
                    what: format!("{} samples, {} MIS radiances", samples.len(), m.len()),
                });
            }
        }
        if let Some(l) = lobes {
            if l.len() != samples.len() {
                return Err(GuidingError::LengthMismatch {
                    what: format!("{} samples, {} product lobes", samples.len(), l.len()),
                });
            }
        }
        let sums = self.selection_moments(field, samples, mis_radiance, lobes, fit)?;
        Ok(self.assign_selection(fit, &sums))
    }

    /// Per lane and candidate `c`, the sums of the second-moment estimate `M̂(c)` of the
    /// samples whose position and normal fall in the lane (see [`Self::fit_selection`]).
    fn selection_moments(
        &self,
        field: &GuidingField,
        samples: &[guiding_core::sample::TrainingSample],
        mis_radiance: Option<&[[f32; 3]]>,
        lobes: Option<&[ProductLobe]>,
        fit: &SelectionFit,
    ) -> Result<Moments, GuidingError> {
        let candidate = |k: usize| fit.candidate(k);
        // The samples' own cells (no jitter) and their guide densities.
        let mut lanes = Vec::new();
        let mut kept = Vec::new();
        for (i, s) in samples.iter().enumerate() {
            if let Some(c) = self.cell_of(Vec3::from_array(s.position)) {
                let lane = self.lane_of(c, self.bin_of(Vec3::from_array(s.normal)));
                if lane != EMPTY {
                    lanes.push(lane);
                    kept.push(i);
                }
            }
        }
        // The samples' lanes, shared with the cache.
        let mut batch = DistributionBatch::new();
        batch.field_id = field.id;
        batch.generation = field.generation;
        batch.items.selection = self.items.selection;
        batch.location = LaneLocation::Cache {
            cells: Arc::clone(&self.items),
            source: lanes.clone(),
        };
        let directions: Vec<Vec3> = kept
            .iter()
            .map(|&i| Vec3::from_array(samples[i].wi))
            .collect();
        let all: Vec<u32> = (0..kept.len() as u32).collect();
        let mut q = vec![0.0f32; kept.len()];
        field.pdf_decoded(&batch, &all, &directions, &mut q)?;
        // The lanes the renderer multiplied by a lobe (vMF only, as
        // `apply_lobe_product`, with the same kernel): their density is the product's.
        if let (Some(lobes), Lanes::Vmf(mixtures)) = (lobes, &self.items.lanes) {
            let (mut lobed, mut products, mut rows) = (Vec::new(), Vec::new(), Vec::new());
            for (k, &i) in kept.iter().enumerate() {
                let l = &lobes[i];
                let axis = Vec3::from_array(l.axis);
                if guiding_core::lobe::vmf::product_lobe(axis, l.kappa).is_some() {
                    lobed.push(k);
                    products.push(mixtures[lanes[k] as usize]);
                    rows.push([l.axis[0], l.axis[1], l.axis[2], l.kappa]);
                }
            }
            guiding_core::model::batched::lobe_product_batch(&mut products, &rows);
            for (&k, product) in lobed.iter().zip(&products) {
                q[k] = product.pdf(directions[k]);
            }
        }
        // Second-moment estimates per cell and candidate (f64 sums).
        let cells = self.points.len();
        let mut moment = vec![[0.0f64; CANDIDATES]; cells];
        let mut first = vec![0.0f64; cells];
        let mut count = vec![0u32; cells];
        let mut total = [0.0f64; CANDIDATES];
        let mut used = 0u64;
        for (k, &i) in kept.iter().enumerate() {
            let s = &samples[i];
            let l = mis_radiance.map_or(s.radiance, |m| m[i]);
            let f = 0.2126 * l[0] * s.bsdf_cos[0]
                + 0.7152 * l[1] * s.bsdf_cos[1]
                + 0.0722 * l[2] * s.bsdf_cos[2];
            let (qk, pb, ps) = (q[k], s.bsdf_pdf, s.sample_pdf);
            let w = f64::from(f) * f64::from(f) / f64::from(ps);
            if !(w.is_finite() && w >= 0.0 && qk.is_finite() && qk >= 0.0 && pb >= 0.0) {
                continue;
            }
            // An infinite term (a candidate density 0 where F ≠ 0, e.g. c = 0 with
            // p_bsdf = 0) rules that candidate out for the cell; NaN drops the sample.
            let mut terms = [0.0f64; CANDIDATES];
            let mut ok = true;
            for (j, t) in terms.iter_mut().enumerate() {
                let c = f64::from(candidate(j));
                let p = c * f64::from(qk) + (1.0 - c) * f64::from(pb);
                *t = if w == 0.0 { 0.0 } else { w / p };
                ok &= !t.is_nan();
            }
            if !ok {
                continue;
            }
            let lane = lanes[k] as usize;
            for j in 0..CANDIDATES {
                moment[lane][j] += terms[j];
                total[j] += terms[j];
            }
            first[lane] += f64::from(f) / f64::from(ps);
            count[lane] += 1;
            used += 1;
        }
        Ok(Moments {
            moment,
            first,
            count,
            total,
            used,
        })
    }

    /// Takes each lane's candidate of least (cost-weighted) variance from the sums of
    /// [`Self::selection_moments`], stores the probabilities in the lanes and reports them.
    fn assign_selection(&mut self, fit: &SelectionFit, sums: &Moments) -> SelectionReport {
        let Moments {
            moment,
            first,
            count,
            total,
            used,
        } = sums;
        let used = *used;
        let candidate = |k: usize| fit.candidate(k);
        let cells = moment.len();
        // The candidate of least variance times cost, to first order the least
        // `s V(c) / V_ref + κ [c > 0] n / N` (`V(c) = M̂(c) − mean` of the cell's
        // sums, `n` its samples, `V_ref` the variance of the whole set at its
        // best constant `c`; see `SelectionFit::guide_cost`); exactly the least
        // `M̂(c)` without a cost. Every candidate infinite (a sample with both
        // densities 0): the largest.
        let first_total: f64 = first.iter().sum();
        let mean_total = first_total * first_total / (used.max(1) as f64);
        let v_ref = total
            .iter()
            .map(|&m| m - mean_total)
            .filter(|v| v.is_finite())
            .fold(f64::INFINITY, f64::min);
        let kappa = if v_ref > 0.0 && v_ref.is_finite() {
            f64::from(fit.guide_cost)
        } else {
            0.0
        };
        let share = f64::from(fit.variance_share);
        let argmin_index = |m: &[f64; CANDIDATES], mean: f64, vertices: f64| {
            let cost = kappa * vertices / (used.max(1) as f64);
            let score = |j: usize| {
                if kappa > 0.0 {
                    share * (m[j] - mean) / v_ref + if candidate(j) > 0.0 { cost } else { 0.0 }
                } else {
                    m[j]
                }
            };
            let mut best = 0;
            for j in 1..CANDIDATES {
                if score(j) < score(best) {
                    best = j;
                }
            }
            m[best].is_finite().then_some(best)
        };
        let global = argmin_index(total, mean_total, used as f64).map_or(fit.max, candidate);
        let mut report = SelectionReport {
            samples_used: used,
            global,
            ..SelectionReport::default()
        };
        self.global_selection = global;
        let mut fitted = Vec::with_capacity(cells);
        let mut sum = 0.0f64;
        let (mut var_fit, mut var_bsdf) = (0.0f64, 0.0f64);
        let prior = f64::from(fit.prior_samples) / (used.max(1) as f64);
        for lane in 0..cells {
            let c = if count[lane] > 0 {
                report.cells_fitted += 1;
                let mut m = moment[lane];
                if prior > 0.0 {
                    for (mj, tj) in m.iter_mut().zip(total) {
                        *mj += prior * tj;
                    }
                }
                // The shrunk sums' mean term: `prior · used` pseudo-samples of the
                // global sums.
                let (n, f) = (
                    f64::from(count[lane]) + prior * used as f64,
                    first[lane] + prior * first_total,
                );
                // V(c) = M̂(c) − μ̂²/n per cell (its own samples, unshrunk); a cell
                // with every candidate infinite makes the ratio NaN.
                let j = argmin_index(&m, f * f / n, n);
                let mean_term = first[lane] * first[lane] / f64::from(count[lane]);
                var_fit += j.map_or(f64::INFINITY, |j| moment[lane][j]) - mean_term;
                var_bsdf += moment[lane][0] - mean_term;
                j.map_or(fit.max, candidate)
            } else {
                report.cells_global += 1;
                global
            };
            report.cells_off += u64::from(c == 0.0);
            sum += f64::from(c);
            fitted.push(c);
        }
        Arc::make_mut(&mut self.items).lane_selection = fitted;
        report.variance_ratio = if var_bsdf > 0.0 && var_bsdf.is_finite() {
            var_fit / var_bsdf
        } else {
            f64::NAN
        };
        report.mean = if cells > 0 {
            (sum / cells as f64) as f32
        } else {
            global
        };
        report
    }
}

/// The per-lane sums of [`GuideCache::selection_moments`].
struct Moments {
    /// `Σ w / p_c` per lane and candidate (`w = F² / p_sample`).
    moment: Vec<[f64; CANDIDATES]>,
    /// `Σ F / p_sample` per lane (the mean term).
    first: Vec<f64>,
    /// Samples per lane.
    count: Vec<u32>,
    /// `moment` summed over the lanes.
    total: [f64; CANDIDATES],
    /// Samples used in all.
    used: u64,
}
