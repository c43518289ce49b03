//! [`DistributionBatch`]: the decoded distributions of a whole wavefront,
//! from one [`GuidingField::decode_batch`] call.
//!
//! A wavefront renderer has a few thousand shading points per bounce. One
//! call decodes them all (grid features gathered per point, the network run
//! over blocks of points by the batched SIMD kernel, the decoder per point);
//! the guide samples and the densities of the BSDF-sampled and NEE
//! directions then take lanes of the batch:
//!
//! ```text
//! field.decode_batch(&queries, &mut batch);              // one network pass per point
//! c_i = batch.selection_probability(i);                  // NPM / DF: constant; NASG: learned
//! field.sample_decoded(&batch, &lanes, &u, &mut samples); // NPM / NASG: no network
//! field.pdf_decoded(&batch, &lanes, &dirs, &mut pdfs);    // DF: the conditional network, batched
//! ```
//!
//! NPM and NASG keep the decoded mixture per lane, so sampling and pdfs run
//! no network at all. DF keeps the network input and the marginal density
//! ([`guiding_core::model::df::DfVertex`]); each sample or pdf then
//! runs only the conditional network, batched over the lanes of the call.
//!
//! A batch remembers the field and generation it was decoded with; using it
//! after an [`GuidingField::update`] that changed the parameters is
//! [`GuidingError::StaleDistribution`].

use crate::device::{DeviceLanes, LanesOut};
use crate::error::{same_lengths, GuidingError};
use crate::field::{DecodedDistribution, GuidingField};
use crate::models::{self, with_df_field, with_field, BatchItems, Decode, Lanes};
use glam::{Vec2, Vec3};
use guiding_core::lobe::DirectionSample;
use guiding_core::model::mixture_batch;
use guiding_core::model::{Family, QueryPoint};
use std::sync::{Arc, Mutex, PoisonError};

/// Decoded distributions of a batch of shading points (see the [module
/// docs](self)). Reusable: decoding into it again keeps its allocations.
/// The directions its lanes sample and take densities of are `wi`s of the
/// [crate conventions](crate#conventions) (unit, world space, pointing away
/// from the surface).
#[derive(Clone, Debug, Default)]
pub struct DistributionBatch {
    pub(crate) field_id: u64,
    pub(crate) generation: u64,
    /// The lanes ([`LaneLocation::Owned`]), a guide cache's misses
    /// ([`LaneLocation::Cache`]) or the device lanes' selection
    /// probabilities ([`LaneLocation::Device`]).
    pub(crate) items: BatchItems,
    /// Where the lanes live.
    pub(crate) location: LaneLocation,
    /// A guide cache's lane sources of an earlier decode, kept for the next
    /// (no allocation per call in steady state).
    pub(crate) scratch: Vec<u32>,
}

/// Where the lanes of a [`DistributionBatch`] live.
#[derive(Clone, Debug, Default)]
pub(crate) enum LaneLocation {
    /// In the batch's `items`.
    #[default]
    Owned,
    /// A [`crate::GuideCache`]'s stored lanes, shared rather than copied:
    /// lane `i` is `cells[source[i]]`, or `items[source[i] & !CACHE_MISS]`
    /// where `source[i]` has the bit [`CACHE_MISS`].
    Cache {
        cells: Arc<BatchItems>,
        source: Vec<u32>,
    },
    /// Decoded on the field's device ([`crate::device`]): the raw outputs
    /// stay there; `items` holds only the selection probabilities.
    Device(DeviceBatch),
}

/// The lanes of a batch decoded on a device.
#[derive(Clone, Debug)]
pub(crate) struct DeviceBatch {
    pub(crate) lanes: Arc<Mutex<DeviceLanes>>,
    pub(crate) len: usize,
    /// The decoded family.
    pub(crate) family: Family,
    /// Per lane `[n, 1]` after [`DistributionBatch::apply_cosine_product`]
    /// (NPM), else empty.
    pub(crate) normals: Vec<[f32; 4]>,
}

/// Marks a lane of a [`DistributionBatch`] that the network decoded (a guide
/// cache's miss): the low bits index `items`.
pub(crate) const CACHE_MISS: u32 = 1 << 31;

/// Where the results of a device lane call go.
enum DeviceOut<'a> {
    Samples(&'a mut [DirectionSample]),
    Pdfs(&'a mut [f32]),
}

impl DistributionBatch {
    /// An empty batch.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Empty, stamped with `field`'s id and generation (the device
    /// buffers are dropped).
    pub(crate) fn reset(&mut self, field: &GuidingField) {
        self.field_id = field.id;
        self.generation = field.generation;
        if let LaneLocation::Cache { source, .. } = std::mem::take(&mut self.location) {
            self.scratch = source;
        }
        self.items.clear();
    }

    /// Number of decoded lanes (the length of the latest decode).
    #[must_use]
    pub fn len(&self) -> usize {
        match &self.location {
            LaneLocation::Owned => self.items.len(),
            LaneLocation::Cache { source, .. } => source.len(),
            LaneLocation::Device(d) => d.len,
        }
    }

    /// The buffer and index that hold lane `i` (`i` in range).
    fn resolve(&self, i: usize) -> (&BatchItems, usize) {
        match &self.location {
            LaneLocation::Cache { cells, source } => match source.get(i) {
                Some(&s) if s & CACHE_MISS != 0 => (&self.items, (s & !CACHE_MISS) as usize),
                Some(&s) => (cells, s as usize),
                None => (&self.items, usize::MAX),
            },
            _ => (&self.items, i),
        }
    }

    /// Copies the shared cache lanes in (before lanes are changed in place).
    fn materialize(&mut self) {
        if let LaneLocation::Cache { cells, source } = std::mem::take(&mut self.location) {
            let network = std::mem::take(&mut self.items);
            self.items
                .gather(&cells, &cells.lane_selection, &network, &source, CACHE_MISS);
            self.scratch = source;
        }
    }

    /// Evaluates `eval` (a family kernel over `(buffer, lanes, inputs,
    /// outputs)`) for `lanes` of this batch: on its own lanes, or, with
    /// shared cache lanes, on the cells with the lanes translated (and on the
    /// network's lanes for a cache's misses, if any).
    fn route<I: Copy, O: Copy>(
        &self,
        lanes: &[u32],
        inputs: &[I],
        out: &mut [O],
        eval: impl Fn(&BatchItems, &[u32], &[I], &mut [O]),
    ) {
        let LaneLocation::Cache { cells, source } = &self.location else {
            eval(&self.items, lanes, inputs, out);
            return;
        };
        let mapped: Vec<u32> = lanes.iter().map(|&l| source[l as usize]).collect();
        if mapped.iter().all(|&s| s & CACHE_MISS == 0) {
            eval(cells, &mapped, inputs, out);
            return;
        }
        for miss in [false, true] {
            let picked: Vec<usize> = (0..mapped.len())
                .filter(|&k| (mapped[k] & CACHE_MISS != 0) == miss)
                .collect();
            if picked.is_empty() {
                continue;
            }
            let sub: Vec<u32> = picked.iter().map(|&k| mapped[k] & !CACHE_MISS).collect();
            let inp: Vec<I> = picked.iter().map(|&k| inputs[k]).collect();
            let mut res: Vec<O> = picked.iter().map(|&k| out[k]).collect();
            eval(if miss { &self.items } else { cells }, &sub, &inp, &mut res);
            for (&k, r) in picked.iter().zip(res) {
                out[k] = r;
            }
        }
    }

    /// Whether it holds no lane.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Probability of sampling the guide rather than the BSDF at lane `i`
    /// (NASG: learned per point; NPM, DF: the configuration's constant); 0
    /// for a lane out of range.
    #[must_use]
    pub fn selection_probability(&self, i: usize) -> f32 {
        match &self.location {
            // Device lanes hold no host lanes, only their selection probabilities.
            LaneLocation::Device(d) if i < d.len => self
                .items
                .lane_selection
                .get(i)
                .copied()
                .unwrap_or(self.items.selection),
            LaneLocation::Device(_) => 0.0,
            // `resolve` maps a lane out of range to an index out of range, which reads 0.
            _ => {
                let (items, k) = self.resolve(i);
                items.selection_probability(k)
            }
        }
    }

    /// Multiplies every lane's vMF mixture by the clamped cosine
    /// `max(0, n·ω)` of its shading normal `normals[i]` (the vMF
    /// approximation of NPM §4.2; Open PGL's `ApplyCosineProduct`): a
    /// radiance-target guide then samples `∝ L_i · cos` instead of `∝ L_i`,
    /// which on diffuse surfaces is the product with the BSDF. Samples and
    /// pdfs of the batch use the product afterwards (still exact densities
    /// of what is sampled). A lane whose normal is zero (no surface: a
    /// scattering point in a medium) stays as it is. Returns `false` and changes nothing for NASG and
    /// DF (no closed-form product) or when the lengths differ.
    pub fn apply_cosine_product(&mut self, normals: &[Vec3]) -> bool {
        let has_vmf = match &mut self.location {
            LaneLocation::Device(d) => {
                // Device lanes: the lane kernels multiply (NPM only).
                if d.family != Family::Npm || d.len != normals.len() {
                    return false;
                }
                d.normals.clear();
                d.normals
                    .extend(normals.iter().map(|n| [n.x, n.y, n.z, 1.0]));
                return true;
            }
            // Checked before the shared cells are copied in: a NASG or DF
            // batch needs no copy.
            LaneLocation::Cache { cells, .. } => {
                !self.items.lanes.vmf().is_empty() || !cells.lanes.vmf().is_empty()
            }
            LaneLocation::Owned => !self.items.lanes.vmf().is_empty(),
        };
        if !has_vmf || self.len() != normals.len() {
            return false;
        }
        self.materialize();
        let vmf = self.items.lanes.vmf_mut();
        guiding_core::model::batched::cosine_product_batch(vmf, normals);
        true
    }

    /// Multiplies the vMF mixtures of the lanes `lanes[j]` by the vMF lobe
    /// `e^{κ_j (a_j·ω − 1)}` (`axes[j]`, normalised; `kappas[j] ≥ 0`), closed form
    /// ([`VmfMixture::product_with_lobe`](guiding_core::mixture::vmf::VmfMixture::product_with_lobe),
    /// batched: [`guiding_core::model::batched::lobe_product_batch`]):
    /// the product of a radiance guide with the vMF fit of a phase function
    /// ([`guiding_core::lobe::vmf::hg_vmf_kappa`], its axis the forward or
    /// backward direction) at scattering points inside media, as Open PGL
    /// guides in volumes. Samples and pdfs of those lanes use the product
    /// afterwards (exact densities of what is sampled); the other lanes, and
    /// lanes whose `κ` is 0 (or non-finite, or whose axis is), stay as they
    /// are. Lanes served by a [`crate::GuideCache`] are copied out of the
    /// shared cells first, only the multiplied ones. A lane listed twice gets
    /// the last of its lobes. Returns `false` and changes nothing for NASG and
    /// DF, for lanes on a device, when the lengths differ or a lane is out of
    /// range.
    pub fn apply_lobe_product(&mut self, lanes: &[u32], axes: &[Vec3], kappas: &[f32]) -> bool {
        let n = self.len();
        if lanes.len() != axes.len()
            || lanes.len() != kappas.len()
            || lanes.iter().any(|&i| i as usize >= n)
        {
            return false;
        }
        let has_vmf = match &self.location {
            LaneLocation::Device(_) => false,
            LaneLocation::Cache { cells, .. } => {
                !self.items.lanes.vmf().is_empty() || !cells.lanes.vmf().is_empty()
            }
            LaneLocation::Owned => !self.items.lanes.vmf().is_empty(),
        };
        if !has_vmf {
            return false;
        }
        // The lanes that get a product, their mixtures and lobes (one batched kernel).
        let mut picked = Vec::with_capacity(lanes.len());
        let mut lobes = Vec::with_capacity(lanes.len());
        for j in 0..lanes.len() {
            if guiding_core::lobe::vmf::product_lobe(axes[j], kappas[j]).is_some() {
                picked.push(lanes[j]);
                lobes.push([axes[j].x, axes[j].y, axes[j].z, kappas[j]]);
            }
        }
        if picked.is_empty() {
            return true;
        }
        let mut mixtures: Vec<_> = picked
            .iter()
            .map(|&l| {
                let (items, k) = self.resolve(l as usize);
                items.lanes.vmf()[k]
            })
            .collect();
        guiding_core::model::batched::lobe_product_batch(&mut mixtures, &lobes);
        // Written back: in place where the batch owns the lane, else as a lane of its own
        // (the cache's cells are shared), with the cell's fitted selection probability.
        let items = &mut self.items;
        if let LaneLocation::Cache { cells, source } = &mut self.location {
            let fitted = !cells.lane_selection.is_empty();
            if fitted {
                items.lane_selection.resize(items.len(), items.selection);
            }
            for (&l, m) in picked.iter().zip(&mixtures) {
                let s = &mut source[l as usize];
                if *s & CACHE_MISS != 0 {
                    items.lanes.vmf_mut()[(*s & !CACHE_MISS) as usize] = *m;
                } else {
                    if fitted {
                        items.lane_selection.push(cells.lane_selection[*s as usize]);
                    }
                    *s = CACHE_MISS | items.len() as u32;
                    items.lanes.vmf_mut().push(*m);
                }
            }
        } else {
            let vmf = items.lanes.vmf_mut();
            for (&l, m) in picked.iter().zip(&mixtures) {
                vmf[l as usize] = *m;
            }
        }
        true
    }

    /// Lane `i` as a plain value, to [attach](GuidingField::attach) to its
    /// field later (`None` out of range, and for lanes decoded on a device,
    /// which stay there).
    #[must_use]
    pub fn get(&self, i: usize) -> Option<DecodedDistribution> {
        if i >= self.len() || matches!(self.location, LaneLocation::Device(_)) {
            return None;
        }
        let (items, k) = self.resolve(i);
        items
            .get(k)
            .map(|d| DecodedDistribution::new(self.field_id, self.generation, d))
    }
}

impl GuidingField {
    /// Decodes the distribution at every query into `out`, on the calling
    /// thread: grid encoding, the network over blocks of queries with the
    /// batched SIMD kernel, and the decoder (see [`crate::batch`]). Lane `i`
    /// of `out` is the distribution at `queries[i]`.
    ///
    /// On a field that runs on a device ([`GuidingField::use_device`]) the
    /// network runs there and the lanes stay there (see [`crate::device`]);
    /// a device failure leaves `out` empty (or, falling back, decodes on
    /// the CPU) and [`Self::try_decode_batch`] returns it.
    pub fn decode_batch(&self, queries: &[QueryPoint], out: &mut DistributionBatch) {
        // The error stays with the field: `device_error` and every later call.
        let _ = self.try_decode_batch(queries, out);
    }

    /// [`Self::decode_batch`], returning a device failure.
    ///
    /// # Errors
    /// [`GuidingError::Device`] when the field runs on a device that failed
    /// (now or before) and does not fall back; `out` is empty then.
    pub fn try_decode_batch(
        &self,
        queries: &[QueryPoint],
        out: &mut DistributionBatch,
    ) -> Result<(), GuidingError> {
        if let Some(e) = self.device_refusal() {
            out.reset(self);
            return Err(e);
        }
        let Some(d) = self.active_device() else {
            self.decode_batch_cpu(queries, out);
            return Ok(());
        };
        // The previous decode's device buffer is reused when nobody shares it.
        let lanes = match std::mem::take(&mut out.location) {
            LaneLocation::Device(d) => Arc::try_unwrap(d.lanes)
                .ok()
                .map(|m| m.into_inner().unwrap_or_else(PoisonError::into_inner)),
            _ => None,
        };
        let mut lanes = lanes.unwrap_or(DeviceLanes {
            raw: None,
            queries: Vec::new(),
        });
        out.reset(self);
        let mut selection = std::mem::take(&mut out.items.lane_selection);
        match d.decode(queries, &mut lanes, &mut selection) {
            Ok(()) => {
                out.items.selection = models::constant_selection(&self.inner);
                out.items.lane_selection = selection;
                out.location = LaneLocation::Device(DeviceBatch {
                    lanes: Arc::new(Mutex::new(lanes)),
                    len: queries.len(),
                    family: d.family,
                    normals: Vec::new(),
                });
                Ok(())
            }
            Err(e) => {
                let e = d.fail(e);
                if d.on_failure == crate::DeviceFailure::Error {
                    return Err(e);
                }
                self.decode_batch_cpu(queries, out);
                Ok(())
            }
        }
    }

    /// [`Self::decode_batch`] on the CPU (the field's EMA weights: the
    /// device's, copied back after each update, when it runs on one).
    pub(crate) fn decode_batch_cpu(&self, queries: &[QueryPoint], out: &mut DistributionBatch) {
        out.reset(self);
        with_field!(&self.inner, f => f
            .model()
            .decode_batch_into(f.ema_params(), queries, &mut out.items));
    }

    /// The device lanes `lanes` of `batch` decoded again on the CPU (the
    /// fallback after a device failure), with the batch's cosine product.
    fn device_lanes_on_cpu(&self, batch: &DistributionBatch, lanes: &[u32]) -> DistributionBatch {
        let mut cpu = DistributionBatch::new();
        let LaneLocation::Device(device) = &batch.location else {
            return cpu;
        };
        let queries: Vec<QueryPoint> = {
            let d = device.lanes.lock().unwrap_or_else(PoisonError::into_inner);
            lanes
                .iter()
                .map(|&l| d.queries.get(l as usize).copied().unwrap_or_default())
                .collect()
        };
        self.decode_batch_cpu(&queries, &mut cpu);
        if !device.normals.is_empty() {
            let normals: Vec<Vec3> = lanes
                .iter()
                .map(|&l| {
                    let n = device.normals[l as usize];
                    Vec3::new(n[0], n[1], n[2])
                })
                .collect();
            cpu.apply_cosine_product(&normals);
        }
        cpu
    }

    /// Samples or evaluates device lanes (`sample` chooses which; `inputs`
    /// are the random pairs or directions as `[f32; 4]`), falling back to
    /// the CPU when the device fails and the field asks for it.
    fn device_lanes_call(
        &self,
        batch: &DistributionBatch,
        lanes: &[u32],
        inputs: &[[f32; 4]],
        mut out: DeviceOut<'_>,
    ) -> Result<(), GuidingError> {
        let LaneLocation::Device(device) = &batch.location else {
            return Ok(());
        };
        let normals: Vec<[f32; 4]> = lanes
            .iter()
            .filter_map(|&l| device.normals.get(l as usize).copied())
            .collect();
        let failed = |e: GuidingError| -> Result<bool, GuidingError> {
            match &self.device {
                Some(d) if d.on_failure == crate::DeviceFailure::FallbackToCpu => Ok(true),
                _ => Err(e),
            }
        };
        let fallback = match self.active_device() {
            None => failed(
                self.device_error()
                    .unwrap_or_else(|| GuidingError::Device("the device is gone".into())),
            )?,
            Some(d) => {
                let lanes_ref = device.lanes.lock().unwrap_or_else(PoisonError::into_inner);
                let r = match out {
                    DeviceOut::Samples(ref mut o) => {
                        let mut packed = vec![[0.0f32; 4]; lanes.len()];
                        let r = d.eval_lanes(
                            &lanes_ref,
                            lanes,
                            &normals,
                            inputs,
                            LanesOut::Samples(&mut packed),
                        );
                        for (s, p) in o.iter_mut().zip(&packed) {
                            *s = DirectionSample {
                                direction: Vec3::new(p[0], p[1], p[2]),
                                pdf: p[3],
                            };
                        }
                        r
                    }
                    DeviceOut::Pdfs(ref mut o) => {
                        d.eval_lanes(&lanes_ref, lanes, &normals, inputs, LanesOut::Pdfs(o))
                    }
                };
                match r {
                    Ok(()) => false,
                    Err(e) => failed(d.fail(e))?,
                }
            }
        };
        if fallback {
            let cpu = self.device_lanes_on_cpu(batch, lanes);
            let own: Vec<u32> = (0..lanes.len() as u32).collect();
            match out {
                DeviceOut::Samples(o) => {
                    let u: Vec<Vec2> = inputs.iter().map(|v| Vec2::new(v[0], v[1])).collect();
                    self.sample_decoded(&cpu, &own, &u, o)?;
                }
                DeviceOut::Pdfs(o) => {
                    let dirs: Vec<Vec3> =
                        inputs.iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect();
                    self.pdf_decoded(&cpu, &own, &dirs, o)?;
                }
            }
        }
        Ok(())
    }

    /// Decodes raw network outputs computed elsewhere (a GPU running the
    /// model's inference kernel, [`GuidingField::export_model`]) into `out`:
    /// `raw` holds `n · raw_outputs` values, lane `i` at `raw[i ·
    /// raw_outputs ..]`. The same decoders as [`Self::decode_batch`].
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] for DF (no fixed-size outputs),
    /// [`GuidingError::LengthMismatch`] if `raw.len()` is not a multiple of
    /// the model's output count; `out` is left empty then.
    pub fn decode_raw_batch(
        &self,
        raw: &[f32],
        out: &mut DistributionBatch,
    ) -> Result<(), GuidingError> {
        use guiding_core::model::batched::{decode_nasg_batch, decode_vmf_batch};
        use guiding_core::model::nasg::NASG_OUTPUTS;
        use guiding_core::model::npm::NPM_OUTPUTS;
        out.reset(self);
        let n = models::raw_queries(&self.inner, raw.len(), false)?;
        let r = models::raw_outputs(&self.inner);
        if models::family(&self.inner) == Family::Npm {
            out.items.selection = models::constant_selection(&self.inner);
            let rows: Vec<[f32; NPM_OUTPUTS]> = raw
                .chunks_exact(r)
                .map(|c| c.try_into().unwrap_or([0.0; NPM_OUTPUTS]))
                .collect();
            let lanes = out.items.lanes.vmf_mut();
            lanes.resize(n, guiding_core::mixture::vmf::VmfMixture::ZERO);
            decode_vmf_batch(&rows, lanes);
        } else {
            // The batched decoders, as decode_batch: rows of the model's outputs.
            let rows: Vec<[f32; NASG_OUTPUTS]> = raw
                .chunks_exact(r)
                .map(|c| c.try_into().unwrap_or([0.0; NASG_OUTPUTS]))
                .collect();
            let lanes = out.items.lanes.nasg_mut();
            lanes.resize(n, guiding_core::mixture::nasg::NasgMixture::ZERO);
            decode_nasg_batch(&rows, lanes);
        }
        Ok(())
    }

    /// Checks that `batch` was decoded by this field at its current
    /// generation and that every lane index is in range.
    fn check_batch(&self, batch: &DistributionBatch, lanes: &[u32]) -> Result<(), GuidingError> {
        if let Some(e) = self.device_refusal() {
            return Err(e);
        }
        self.check_current(batch.field_id, batch.generation)?;
        let n = batch.len();
        if let Some(&bad) = lanes.iter().find(|&&l| l as usize >= n) {
            return Err(GuidingError::LengthMismatch {
                what: format!("lane {bad} of a batch of {n} distributions"),
            });
        }
        Ok(())
    }

    /// Samples a direction `wi` from lane `lanes[k]` of `batch` with `u[k]`
    /// into `out[k]`, for every `k`. NPM / NASG sample their mixtures; DF runs its conditional
    /// network once per sample, batched over the call (and a second time
    /// for the rare direction whose `ε₁` rounds into another bin, as
    /// [`crate::Distribution::sample`]).
    ///
    /// An empty `lanes` asks nothing of `batch` and returns `Ok` at once,
    /// whatever the batch (a wavefront that guided no vertex need not have
    /// decoded one).
    ///
    /// # Errors
    /// [`GuidingError::LengthMismatch`] if the slices differ in length or a
    /// lane is out of range; [`GuidingError::StaleDistribution`] if `batch`
    /// is from another field or an older generation. Nothing is written then.
    pub fn sample_decoded(
        &self,
        batch: &DistributionBatch,
        lanes: &[u32],
        u: &[Vec2],
        out: &mut [DirectionSample],
    ) -> Result<(), GuidingError> {
        self.decoded_call(
            batch,
            lanes,
            u,
            "random pairs",
            out,
            |v| [v.x, v.y, 0.0, 0.0],
            |o| DeviceOut::Samples(o),
            |items, lanes, u, out| match &items.lanes {
                Lanes::Vmf(m) => mixture_batch::vmf_sample_batch(m, lanes, u, out),
                Lanes::Nasg(m) => mixture_batch::nasg_sample_batch(m, lanes, u, out),
                // DF lanes come from a DF field (`check_batch`: this field).
                Lanes::Df(v) => with_df_field!(&self.inner, f => f
                    .model()
                    .sample_vertices(f.ema_params(), v, lanes, u, out), ()),
                Lanes::DfTable { tables, sums } => {
                    mixture_batch::table_sample_batch(tables, sums, lanes, u, out);
                }
            },
        )
    }

    /// The density of `directions[k]` (unit `wi`s) under lane `lanes[k]`
    /// of `batch`, into `out[k]`. DF runs its conditional network once per
    /// direction, batched over the call.
    ///
    /// An empty `lanes` returns `Ok` at once, as in [`Self::sample_decoded`].
    ///
    /// # Errors
    /// As [`Self::sample_decoded`].
    pub fn pdf_decoded(
        &self,
        batch: &DistributionBatch,
        lanes: &[u32],
        directions: &[Vec3],
        out: &mut [f32],
    ) -> Result<(), GuidingError> {
        self.decoded_call(
            batch,
            lanes,
            directions,
            "directions",
            out,
            |d| [d.x, d.y, d.z, 0.0],
            |o| DeviceOut::Pdfs(o),
            |items, lanes, dirs, out| match &items.lanes {
                Lanes::Vmf(m) => mixture_batch::vmf_pdf_batch(m, lanes, dirs, out),
                Lanes::Nasg(m) => mixture_batch::nasg_pdf_batch(m, lanes, dirs, out),
                // DF lanes come from a DF field (`check_batch`: this field).
                Lanes::Df(v) => with_df_field!(&self.inner, f => f
                    .model()
                    .pdf_vertices(f.ema_params(), v, lanes, dirs, out), ()),
                Lanes::DfTable { tables, .. } => {
                    mixture_batch::table_pdf_batch(tables, lanes, dirs, out);
                }
            },
        )
    }

    /// The common body of [`Self::sample_decoded`] and [`Self::pdf_decoded`]:
    /// checks the lengths (`inputs` named `what`) and the batch, then
    /// answers `lanes` on the device (inputs packed by `pack`, results
    /// through `device_out`) or through `batch.route` with `eval`.
    #[allow(clippy::too_many_arguments)] // the two calls' inputs, outputs and kernels
    fn decoded_call<I: Copy, O: Copy>(
        &self,
        batch: &DistributionBatch,
        lanes: &[u32],
        inputs: &[I],
        what: &str,
        out: &mut [O],
        pack: impl Fn(&I) -> [f32; 4],
        device_out: impl FnOnce(&mut [O]) -> DeviceOut<'_>,
        eval: impl Fn(&BatchItems, &[u32], &[I], &mut [O]),
    ) -> Result<(), GuidingError> {
        same_lengths(&[
            (lanes.len(), "lanes"),
            (inputs.len(), what),
            (out.len(), "outputs"),
        ])?;
        if lanes.is_empty() {
            return Ok(());
        }
        self.check_batch(batch, lanes)?;
        if matches!(batch.location, LaneLocation::Device(_)) {
            let packed: Vec<[f32; 4]> = inputs.iter().map(pack).collect();
            return self.device_lanes_call(batch, lanes, &packed, device_out(out));
        }
        batch.route(lanes, inputs, out, eval);
        Ok(())
    }
}
