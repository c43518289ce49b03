"""Mitsuba 3 integrator ``guided_path``: Mitsuba's ``path`` with a learned guide.

``import guiding.mitsuba`` registers it, so that a scene names it
(``<integrator type="guided_path"/>``, or ``{"type": "guided_path"}`` in ``mi.load_dict``).
It runs on the JIT variants with RGB colour (``llvm_ad_rgb``, ``cuda_ad_rgb``).

What it computes is Mitsuba's ``path`` estimator (next-event estimation, MIS with the power
heuristic, Russian roulette from ``rr_depth``) with one change at every vertex whose BSDF has no
delta lobe: the continuation is sampled by one-sample MIS between the BSDF and the guide, with
the guide's selection probability ``c`` (the library's preset, or NASG's learned one), so its
density is ``p = c·p_guide + (1 − c)·p_bsdf``; that ``p`` also weighs next-event estimation
against the continuation. Each of the ``spp`` passes traces one sample per pixel as a wavefront
(one evaluated kernel per bounce, the guide called between them on numpy arrays); the passes
of the training phase (the library's ``Schedule``: its default fraction of the passes) record
their paths and train the guide between passes. Every pass is an unbiased estimate given the
guide of the passes before it. The passes are combined as host-demo combines them
(``guiding.PassCombiner``): each training pass is a group of its own, the passes after
training one group, each group weighted by the inverse of its estimated variance, with the
weights of a pixel estimated on the other half of a checkerboard, so that the image stays
unbiased. When training stops, the guide cache is built from the last training pass's vertices.

Properties: ``max_depth`` (default -1, unbounded), ``rr_depth`` (5), as ``path``; ``guide``
(``npm``, ``nasg``, ``df-n``, ``df-l``; default ``npm``), ``target`` (``radiance``, ``product``),
``size`` (``small``, ``compact``, ``paper``), ``train_fraction`` (the library's default when
absent), ``selection_probability`` (the library's preset when absent), ``guide_cache``
(default ``true``: after training, radiance guides are looked up in the library's
``GuideCache`` instead of decoded by the network per vertex), ``native_guide`` (default
``true``: an NPM guide's cache is read inside Mitsuba's kernels, its vMF mixtures sampled and
evaluated in Dr.Jit, with no transfer to numpy; a vertex whose cells are empty is sampled by
its BSDF alone and its position extends the cache after the pass), ``combine_passes`` (default
``true``; ``false``: all passes splatted into one block, as ``path`` splats its samples),
``timeout`` (seconds, as Mitsuba's integrators: no pass starts after it, and ``spp`` passes at
most; the library's schedule then trains for its share of the time, not of the passes),
``fit_selection`` (default ``false``; ``true``: the selection probability fitted per cell to the
last training pass's paths, ``GuideCache.fit_selection``, as host-demo does; off by default
because with Mitsuba's roulette the fit is dominated by a few survivors' ``1/q`` weights: on the
door at 64 spp its global value came out 0.8, 0.0 and 0.7 on three seeds, and relMSE 0.89x
``path``'s instead of 0.66x), ``guiding`` (``false``: the same wavefront loop without a guide,
to measure what the loop itself costs), ``threads`` (the library's threads, 0: all cores).

After a render, ``integrator.field`` is the trained ``guiding.Field`` (save it with
``field.save``), ``integrator.combination`` the passes' ``guiding.Combination`` (None when
not combined), and ``integrator.stats`` says what the render did and where its time went.
"""

import time
from typing import NamedTuple

import drjit as dr
import mitsuba as mi
import numpy as np

from . import BatchRecorder, Field, PassCombiner, Schedule


def _rows(v):
    """A Dr.Jit 3-vector (or colour) as an ``(n, 3)`` float32 array (a transposed view of one
    copy; the bindings take any strides)."""
    return np.asarray(v, dtype=np.float32).T


def _path_start(ray):
    """A wavefront's loop state at the camera: throughput, radiance, relative IOR, active,
    previous interaction, its density and whether it was a delta sample, the ray."""
    return (mi.Spectrum(1.0), mi.Spectrum(0.0), mi.Float(1.0), mi.Bool(True),
            dr.zeros(mi.Interaction3f), mi.Float(1.0), mi.Bool(True), mi.Ray3f(ray))


class _Nee(NamedTuple):
    """What ``GuidedPath._nee_and_bsdf`` draws at a bounce's vertices."""

    active_em: object  # mi.Bool: vertices with an emitter sample
    ds_em: object  # mi.DirectionSample3f: the emitter sample
    em_weight: object  # mi.Spectrum: its radiance over its density
    bsdf_val_em: object  # mi.Spectrum: the BSDF (× cos) towards it
    bsdf_pdf_em: object  # mi.Float: the BSDF's density of it
    bs: object  # mi.BSDFSample3f: the BSDF's own sample
    bsdf_weight: object  # mi.Spectrum: that sample's weight
    u_select: object  # mi.Float: the guide-or-BSDF choice
    u_guide: object  # mi.Point2f: the guide's sample


def _vec3(rows):
    """An ``(n, 3)`` array as a ``mi.Vector3f``."""
    return mi.Vector3f(np.ascontiguousarray(rows.T))


def _mis_weight(pdf_a, pdf_b):
    """The power heuristic, as Mitsuba's ``path`` (0 where it is not finite)."""
    a2 = dr.square(pdf_a)
    w = a2 / (a2 + dr.square(pdf_b))
    return dr.select(dr.isfinite(w), w, 0.0)


class _Times:
    """Seconds spent per part of a render: Mitsuba's kernels, the library's guide calls
    (decode, sample, pdf, cache upkeep), its recorder calls, training, and the transfers
    between Dr.Jit and numpy arrays around them."""

    def __init__(self):
        self.mitsuba = 0.0
        self.guide = 0.0
        self.recording = 0.0
        self.training = 0.0
        self.transfers = 0.0

    def library(self):
        return self.guide + self.recording

    def as_dict(self):
        return dict(self.__dict__)


class _Timed:
    """Forwards method calls to ``target``, adding their seconds to ``times.<bucket>``."""

    def __init__(self, target, times, bucket):
        self._target, self._times, self._bucket = target, times, bucket

    def __getattr__(self, name):
        attr = getattr(self._target, name)
        if not callable(attr):
            return attr

        def call(*args, **kwargs):
            t = time.perf_counter()
            try:
                return attr(*args, **kwargs)
            finally:
                setattr(self._times, self._bucket,
                        getattr(self._times, self._bucket) + time.perf_counter() - t)

        return call


class _NativeVmf:
    """The guide cache's vMF table (``GuideCache.vmf_table``) as Dr.Jit arrays: the cell
    lookup, the mixture's sample and its pdf run inside Mitsuba's kernels, with no transfer to
    numpy. A vertex whose cells are empty gets ``c = 0`` (the BSDF alone: unbiased)."""

    EMPTY = 0xFFFFFFFF

    def __init__(self, table):
        self.lo = [float(x) for x in table["lo"]]
        self.h = float(table["cell"])
        self.res = [int(x) for x in table["res"]]
        self.index = mi.UInt32(np.ascontiguousarray(table["index"]))
        lanes = table["lanes"]  # (L, 7, K): weight, mean x/y/z, kappa, norm, 1 - e^-2k
        self.k = lanes.shape[2]
        self.rows = [
            [mi.Float(np.ascontiguousarray(lanes[:, r, k])) for k in range(self.k)]
            for r in range(7)
        ]
        fitted = table["lane_selection"]
        self.lane_selection = mi.Float(np.ascontiguousarray(fitted)) if fitted.size else None
        self.selection = float(table["selection"])

    def _cell(self, p):
        c = (p - mi.Point3f(*self.lo)) / self.h
        inside = (
            (c.x >= 0) & (c.y >= 0) & (c.z >= 0)
            & (c.x < self.res[0]) & (c.y < self.res[1]) & (c.z < self.res[2])
        )
        i = mi.UInt32(dr.select(inside, c.x, 0))
        j = mi.UInt32(dr.select(inside, c.y, 0))
        k = mi.UInt32(dr.select(inside, c.z, 0))
        idx = (k * self.res[1] + j) * self.res[0] + i
        lane = dr.gather(mi.UInt32, self.index, idx, inside)
        return dr.select(inside, lane, self.EMPTY)

    def lookup(self, p, jitter, active):
        """The lane of the cell of ``p + (ξ − ½) h``, else of ``p``'s own; and whether found."""
        lane = self._cell(p + (jitter - 0.5) * self.h)
        lane = dr.select(lane == self.EMPTY, self._cell(p), lane)
        found = active & (lane != self.EMPTY)
        return dr.select(found, lane, 0), found

    def selection_probability(self, lane, found):
        if self.lane_selection is None:
            return dr.select(found, self.selection, 0.0)
        return dr.select(found, dr.gather(mi.Float, self.lane_selection, lane, found), 0.0)

    def lobes(self, lane, active):
        """The mixture of ``lane``: per lobe its weight, mean x / y / z, κ, normaliser and
        ``1 − e^{−2κ}``, gathered once (the pdfs and the sample of a vertex share them)."""
        return [[dr.gather(mi.Float, self.rows[r][k], lane, active) for r in range(7)]
                for k in range(self.k)]

    @staticmethod
    def pdf(lobes, active, d):
        """``Σ_k w_k · norm_k · exp(κ_k (μ_k·d − 1))`` (0 where not ``active``)."""
        total = mi.Float(0.0)
        for w, mx, my, mz, kappa, norm, _ in lobes:
            cos = mx * d.x + my * d.y + mz * d.z
            total += w * norm * dr.exp(kappa * (cos - 1.0))
        return dr.select(active, total, 0.0)

    @staticmethod
    def sample(lobes, u):
        """A direction of the mixture: ``u.x`` picks the lobe and, rescaled, its ``cos θ``;
        ``u.y`` the azimuth."""
        cdf = mi.Float(0.0)
        chosen = mi.Bool(False)
        mean = mi.Vector3f(0.0, 0.0, 1.0)
        kappa = mi.Float(0.0)
        ome = mi.Float(0.0)
        v = mi.Float(u.x)
        for k, (w, mx, my, mz, kap, _, om) in enumerate(lobes):
            last = k == len(lobes) - 1
            take = ~chosen & (((u.x < cdf + w) & (w > 0.0)) | last)
            mean = dr.select(take, mi.Vector3f(mx, my, mz), mean)
            kappa = dr.select(take, kap, kappa)
            ome = dr.select(take, om, ome)
            v = dr.select(take, dr.clip((u.x - cdf) / dr.maximum(w, 1e-30), 0.0, 0.99999994), v)
            chosen |= take
            cdf += w
        # cos θ = 1 + ln(1 − v (1 − e^{−2κ})) / κ, the uniform sphere's 1 − 2v as κ → 0.
        cos_t = dr.select(kappa > 1e-4, 1.0 + dr.log(1.0 - v * ome) / dr.maximum(kappa, 1e-4),
                          1.0 - 2.0 * v)
        cos_t = dr.clip(cos_t, -1.0, 1.0)
        sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
        phi = 2.0 * dr.pi * u.y
        local = mi.Vector3f(sin_t * dr.cos(phi), sin_t * dr.sin(phi), cos_t)
        return mi.Frame3f(dr.normalize(mean)).to_world(local)


class _Guide:
    """The field and, once training has stopped, its cache: decodes a bounce's guidable
    vertices. The cache is built from the guidable vertices of the last training pass and
    extended after each pass with the positions it missed (host-demo's policy)."""

    def __init__(self, field, use_cache, seed, times, native=True, recorder=None):
        self.allow_native = native
        # Fits the selection probability per cell to this recorder's kept samples (the last
        # training pass's) when the cache is built, as host-demo does; None: the preset.
        self.fit_recorder = recorder if field.representation != "nasg" else None
        self.selection_fit = None
        self.native = None
        self.raw_field = field
        self.field = _Timed(field, times, "guide")
        self.times = times
        self.cache = None
        self.use_cache = use_cache
        self.rng = np.random.default_rng(seed)
        self.positions = []
        self.missed = []
        self.training = True
        self.hits = 0
        self.misses = 0

    def begin_pass(self, training):
        if not training and self.training:
            self.field.stop_training()
            if self.use_cache and self.positions:
                self.cache = _Timed(
                    self.field.build_cache(np.concatenate(self.positions)), self.times, "guide"
                )
                if self.fit_recorder is not None and self.fit_recorder.kept_samples:
                    self.selection_fit = self.cache.fit_selection(self.raw_field,
                                                                  self.fit_recorder)
                table = self.cache.vmf_table() if self.allow_native else None
                if table is not None:
                    self.native = _NativeVmf(table)
        self.training = training
        self.positions = []

    def decode(self, pos, nrm, wo):
        if self.cache is None:
            if self.training and self.use_cache:
                self.positions.append(pos)
            return self.field.decode(pos, nrm, wo, np.ones(len(pos), dtype=np.float32))
        jitter = self.rng.random((len(pos), 3), dtype=np.float32)
        batch = self.cache.decode(self.raw_field, pos, jitter)
        missed = self.cache.misses
        self.hits += len(pos) - missed.size
        self.misses += missed.size
        if missed.size:
            self.missed.append(pos[missed])
        return batch

    def end_pass(self):
        if self.cache is not None and self.missed:
            added = self.cache.extend(self.raw_field, np.concatenate(self.missed))
            if added and self.native is not None:
                self.native = _NativeVmf(self.cache.vmf_table())
        self.missed = []

    def stats(self):
        return {
            "cells": self.cache.cells if self.cache is not None else 0,
            "in_kernel": self.native is not None,
            "hits": self.hits,
            "misses": self.misses,
            "selection_fit": _report(self.selection_fit),
        }


def _report(r):
    """A library report (frozen object with one attribute per value) as a dict, or None."""
    if r is None:
        return None
    return {k: getattr(r, k) for k in dir(r) if not k.startswith("_")}


class _PassImages:
    """The render's passes, combined as host-demo combines them (``guiding.PassCombiner``):
    each training pass is a group of its own (its guide is new), the passes after training one
    group. Each pass is splatted into its own image block; the block's pixel values (its colour
    over its filter weight, the border cropped) go to the combiner, and its tensor is summed
    per group. The film gets ``Σ_g N·a_g(h)·S_g`` in the colour (and alpha) channels and
    ``Σ_g W_g`` in the weight channel: with Mitsuba's box filter (one weight per sample per
    pixel) that develops to the combiner's ``Σ_g a_g S_g`` exactly; with other filters the
    weight sums differ between passes only by the filter's jitter. ``a_g(h)`` is the group's
    per-pass weight for a pixel of checkerboard half ``h`` (estimated on the other half, which
    keeps the weighted image unbiased; ``guiding::combine``'s documentation)."""

    AFTER_TRAINING = 1 << 30

    def __init__(self, film):
        self.film = film
        size = film.crop_size()
        self.width, self.height = int(size[0]), int(size[1])
        self.combiner = PassCombiner(self.width, self.height)
        self.sums = {}
        self.block = None
        self.stats = None
        self.combination = None

    def begin(self):
        self.block = self.film.create_block()
        return self.block

    def end(self, group):
        t = self.block.tensor().numpy()
        b = self.block.border_size() if self.block.has_border() else 0
        inner = t[b : b + self.height, b : b + self.width]
        w = inner[..., -1:]
        rgb = np.where(w > 0.0, inner[..., :3] / np.where(w > 0.0, w, 1.0), 0.0)
        self.combiner.add_pass(group, rgb.reshape(-1, 3).astype(np.float32))
        if group in self.sums:
            self.sums[group] += t
        else:
            self.sums[group] = t.astype(np.float64)
        self.block = None

    def develop_into(self, film):
        """Puts the combined passes into ``film``; returns the combination's report."""
        c = self.combination = self.combiner.combine()
        n = self.combiner.passes
        total = sum(self.sums.values())
        block = self.film.create_block()
        if not c.fell_back:
            b = block.border_size() if block.has_border() else 0
            rows, cols = total.shape[0], total.shape[1]
            y, x = np.mgrid[0:rows, 0:cols]
            half = (x - b + y - b) % 2
            colour = np.zeros_like(total[..., :-1])
            for g in c.groups:
                # Pixels of half h take the weight estimated on half 1 - h.
                scale = np.where(half == 0, g.pass_weight[1], g.pass_weight[0]) * n
                colour += scale[..., None] * self.sums[g.group][..., :-1]
            total = np.concatenate([colour, total[..., -1:]], axis=-1)
        combined = mi.ImageBlock(
            mi.TensorXf(total.astype(np.float32)),
            block.offset(),
            block.rfilter(),
            block.has_border(),
        )
        film.put_block(combined)
        self.stats = {
            "fell_back": c.fell_back,
            "predicted_gain": c.predicted_gain,
            "groups": [
                {"group": g.group, "passes": g.passes, "share": g.share} for g in c.groups
            ],
        }
        return self.stats


class GuidedPath(mi.SamplingIntegrator):
    """``guided_path``: see the module documentation."""

    def __init__(self, props=mi.Properties()):
        super().__init__(props)
        self.max_depth = props.get("max_depth", -1)
        self.rr_depth = props.get("rr_depth", 5)
        if self.rr_depth <= 0:
            raise ValueError('guided_path: "rr_depth" must be greater than zero')
        self.guide = props.get("guide", "npm")
        self.target = props.get("target", "radiance")
        self.size = props.get("size", "compact")
        fraction = props.get("train_fraction", -1.0)
        self.train_fraction = None if fraction < 0 else float(fraction)
        self.guiding = props.get("guiding", True)
        self.threads = props.get("threads", 0)
        # Mitsuba's integrators' time limit (seconds; <= 0: none).
        self.timeout = float(props.get("timeout", -1.0))
        self.guide_cache = props.get("guide_cache", True)
        self.native_guide = props.get("native_guide", True)
        self.combine_passes = props.get("combine_passes", True)
        self.fit_selection = props.get("fit_selection", False)
        c = props.get("selection_probability", -1.0)
        self.selection_probability = None if c < 0 else float(c)
        self.field = None
        self.combination = None
        self.stats = {}
        # Test hook: multiplies the guide's density in the MIS weights (a wrong estimator,
        # for the unbiasedness test's negative control).
        self._guide_pdf_scale = 1.0

    def to_string(self):
        return (
            f"GuidedPath[guide = {self.guide} {self.target} {self.size}, "
            f"max_depth = {self.max_depth}, rr_depth = {self.rr_depth}]"
        )

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if not mi.is_rgb or mi.is_polarized or not dr.is_jit_v(mi.Float):
            raise RuntimeError(
                "guided_path runs on the JIT RGB variants (llvm_ad_rgb, cuda_ad_rgb), "
                f"not {mi.variant()}"
            )
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        film = sensor.film()
        spp = spp if spp > 0 else sensor.sampler().sample_count()
        times = _Times()
        field, schedule, recorder, guide = None, None, None, None
        if self.guiding:
            bbox = scene.bbox()
            field = Field(
                [float(x) for x in bbox.min],
                [float(x) for x in bbox.max],
                representation=self.guide,
                target=self.target,
                size=self.size,
                threads=self.threads,
                selection_probability=self.selection_probability,
            )
            budget = {"seconds": self.timeout} if self.timeout > 0 else {"spp": spp}
            schedule = Schedule(train_fraction=self.train_fraction, **budget)
            recorder = BatchRecorder()
            use_cache = self.guide_cache and self.target == "radiance"
            fit = recorder if use_cache and self.fit_selection else None
            guide = _Guide(field, use_cache, int(seed), times, self.native_guide, fit)
            recorder = _Timed(recorder, times, "recording")
        self.field = field
        self.combination = None
        with dr.suspend_grad():
            film.prepare([])
            passes = _PassImages(film) if guide is not None and self.combine_passes else None
            block = film.create_block() if passes is None else None
            start = time.perf_counter()
            training_passes = 0
            passes_done = 0
            for p in range(spp):
                elapsed = time.perf_counter() - start
                if self.timeout > 0 and p > 0 and elapsed >= self.timeout:
                    break
                train = schedule is not None and schedule.in_training_phase(elapsed, p)
                if schedule is not None and not train and not schedule.training_over:
                    schedule.end_training()
                if guide is not None:
                    guide.begin_pass(train)
                t0 = time.perf_counter()
                sampler, n = self._pass_sampler(sensor, (int(seed) * spp + p) & 0xFFFFFFFF)
                ray, weight, pos = self._sample_rays(sensor, sampler)
                if guide is not None and not train and guide.native is not None:
                    L = self._trace_native_timed(scene, sampler, ray, n, guide, times)
                else:
                    L = self._trace(scene, sampler, ray, n, guide, recorder if train else None,
                                    times)
                target = block if passes is None else passes.begin()
                self._splat(target, film, pos, L * weight)
                dr.eval(target.tensor())
                traced = time.perf_counter() - t0
                if passes is not None:
                    passes.end(p if train else _PassImages.AFTER_TRAINING)
                passes_done += 1
                if guide is not None:
                    guide.end_pass()
                if train:
                    training_passes += 1
                    recorder.end()
                    recorder.flush_into(field, keep=guide.fit_recorder is not None)
                    schedule.record_traced(traced, n)
                    t2 = time.perf_counter()
                    field.train_scheduled(schedule)
                    times.training += time.perf_counter() - t2
            if passes is None:
                film.put_block(block)
            else:
                passes.develop_into(film)
                self.combination = passes.combination
            self.stats = {
                "spp": passes_done,
                "training_passes": training_passes,
                "seconds": time.perf_counter() - start,
                "time_split": times.as_dict(),
                "schedule": schedule.report() if schedule is not None else None,
                "field": field.stats() if field is not None else None,
                "guide_cache": guide.stats() if guide is not None else None,
                "combination": passes.stats if passes is not None else None,
            }
            return film.develop() if develop else None

    def _pass_sampler(self, sensor, seed):
        """The sensor's sampler for one sample per pixel, seeded for this pass."""
        film = sensor.film()
        sampler = sensor.sampler().clone()
        sampler.set_sample_count(1)
        sampler.set_samples_per_wavefront(1)
        size = film.crop_size()
        if film.sample_border():
            size += 2 * film.rfilter().border_size()
        n = int(dr.prod(size))
        sampler.seed(seed, n)
        return sampler, n

    def _sample_rays(self, sensor, sampler):
        """One camera ray per pixel (Mitsuba's sample positions and ray weights)."""
        film = sensor.film()
        size = film.crop_size()
        border = film.rfilter().border_size()
        if film.sample_border():
            size += 2 * border
        idx = dr.arange(mi.UInt32, dr.prod(size))
        pos = mi.Vector2i()
        pos.y = mi.Int32(idx // size[0])
        pos.x = mi.Int32(idx - mi.UInt32(pos.y) * size[0])
        if film.sample_border():
            pos -= border
        pos += mi.Vector2i(film.crop_offset())
        pos_f = mi.Vector2f(pos) + sampler.next_2d()
        scale = dr.rcp(mi.ScalarVector2f(film.crop_size()))
        offset = -mi.ScalarVector2f(film.crop_offset()) * scale
        aperture = sampler.next_2d() if sensor.needs_aperture_sample() else mi.Vector2f(0.0)
        t = sensor.shutter_open()
        if sensor.shutter_open_time() > 0:
            t += sampler.next_1d() * sensor.shutter_open_time()
        ray, weight = sensor.sample_ray_differential(
            time=t, sample1=0.0, sample2=dr.fma(pos_f, scale, offset), sample3=aperture
        )
        splat = mi.Vector2f(pos) if film.rfilter().is_box_filter() else pos_f
        return ray, weight, splat

    @staticmethod
    def _splat(block, film, pos, rgb):
        if mi.has_flag(film.flags(), mi.FilmFlags.Alpha):
            values = [rgb.x, rgb.y, rgb.z, mi.Float(1.0), mi.Float(1.0)]
        else:
            values = [rgb.x, rgb.y, rgb.z, mi.Float(1.0)]
        block.put(pos, values)

    def _hit(self, scene, si, ray, prev_si, prev_pdf, prev_delta, active, depth):
        """A bounce's hit: the emission found by the continuation (or the camera) and its MIS
        weight against NEE, whether the path goes on, and whether the guide may sample it
        (no delta lobe, a smooth one)."""
        ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
        em_pdf = scene.pdf_emitter_direction(prev_si, ds, ~prev_delta)
        mis_bsdf = _mis_weight(prev_pdf, em_pdf)
        emitted = ds.emitter.eval(si, active)
        valid = active & si.is_valid()
        limit = self.max_depth if self.max_depth >= 0 else 0xFFFFFFFF
        active_next = valid & (depth + 1 < limit)
        bsdf = si.bsdf(ray)
        flags = bsdf.flags()
        guidable = (
            active_next
            & ~mi.has_flag(flags, mi.BSDFFlags.Delta)
            & mi.has_flag(flags, mi.BSDFFlags.Smooth)
        )
        return emitted, mis_bsdf, valid, active_next, bsdf, guidable

    @staticmethod
    def _nee_and_bsdf(scene, sampler, ctx, si, bsdf, active_next):
        """Next-event estimation's emitter sample, the BSDF at it, the BSDF's own sample, and
        the random numbers of the guide's selection and sample."""
        active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        ds_em, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(), True, active_em)
        active_em &= ds_em.pdf != 0.0
        s1, s2 = sampler.next_1d(), sampler.next_2d()
        bsdf_val_em, bsdf_pdf_em, bs, bsdf_weight = bsdf.eval_pdf_sample(
            ctx, si, si.to_local(ds_em.d), s1, s2, active_next
        )
        u_select, u_guide = sampler.next_1d(), sampler.next_2d()
        return _Nee(active_em, ds_em, em_weight, bsdf_val_em, bsdf_pdf_em, bs, bsdf_weight,
                    u_select, u_guide)

    @staticmethod
    def _mixture(ctx, si, bsdf, guidable, c, nee, g_em, wi_world, g_pdf):
        """Direct light weighed against the mixture ``p = c·p_guide + (1 − c)·p_bsdf``, and the
        continuation ``wi_world`` with its weight and density (the BSDF's own sample where the
        vertex is not guidable)."""
        pdf_em = dr.select(guidable, c * g_em + (1.0 - c) * nee.bsdf_pdf_em, nee.bsdf_pdf_em)
        mis_em = dr.select(nee.ds_em.delta, 1.0, _mis_weight(nee.ds_em.pdf, pdf_em))
        direct = dr.select(nee.active_em, nee.bsdf_val_em * nee.em_weight * mis_em, 0.0)
        bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, si.to_local(wi_world), guidable)
        pdf_mix = c * g_pdf + (1.0 - c) * bsdf_pdf
        ok = guidable & (pdf_mix > 0.0) & dr.isfinite(pdf_mix)
        weight = dr.select(guidable, dr.select(ok, bsdf_val / pdf_mix, 0.0), nee.bsdf_weight)
        pdf = dr.select(guidable, pdf_mix, nee.bs.pdf)
        return direct, bsdf_val, bsdf_pdf, pdf_mix, weight, pdf

    def _roulette(self, sampler, beta, eta, depth, active_next):
        """Mitsuba's path's Russian roulette (it counts this vertex before its roulette):
        survival ``min(max(β)·η², 0.95)`` from ``rr_depth``."""
        beta_max = dr.max(beta)
        rr_active = depth + 1 >= self.rr_depth
        rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
        rr_continue = sampler.next_1d() < rr_prob
        beta = dr.select(rr_active, beta * dr.rcp(rr_prob), beta)
        active = active_next & (~rr_active | rr_continue) & (beta_max != 0.0)
        return beta, active, rr_prob, rr_active

    def _trace_native_timed(self, scene, sampler, ray, n, guide, times):
        """``_trace_native``, its seconds in ``times.mitsuba``; the positions it missed go to
        the guide, to extend the cache after the pass."""
        t0 = time.perf_counter()
        missed_at = dr.full(mi.Point3f, dr.nan, n)
        L = self._trace_native(scene, sampler, ray, n, guide.native, missed_at)
        dr.eval(L, missed_at)
        dr.sync_thread()  # the kernel runs asynchronously: its time is Mitsuba's
        times.mitsuba += time.perf_counter() - t0
        t1 = time.perf_counter()
        p = _rows(missed_at)
        p = p[np.isfinite(p[:, 0])]
        guide.misses += len(p)
        if p.size:
            guide.missed.append(np.ascontiguousarray(p))
        times.transfers += time.perf_counter() - t1
        return L

    @dr.syntax
    def _trace_native(self, scene, sampler, ray, n, native, missed_at):
        """One wavefront of ``n`` paths after training, the guide read in-kernel from the
        cache's vMF table: one symbolic loop (one kernel per pass). Where a guidable vertex
        finds no cell, its position is written to ``missed_at`` (the path's last such vertex;
        ``NaN`` elsewhere) to extend the cache after the pass."""
        ctx = mi.BSDFContext()
        slot = dr.arange(mi.UInt32, n)
        beta, L, eta, active, prev_si, prev_pdf, prev_delta, ray = _path_start(ray)
        depth = mi.UInt32(0)
        scale = self._guide_pdf_scale
        while dr.hint(active, label="guided_path"):
            si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=depth == 0,
                                     active=active)
            emitted, mis_bsdf, _, active_next, bsdf, guidable = self._hit(
                scene, si, ray, prev_si, prev_pdf, prev_delta, active, depth)
            L += dr.select(active, beta * mis_bsdf * emitted, 0.0)
            nee = self._nee_and_bsdf(scene, sampler, ctx, si, bsdf, active_next)
            bs = nee.bs
            jitter = mi.Vector3f(sampler.next_1d(), sampler.next_1d(), sampler.next_1d())
            lane, found = native.lookup(si.p, jitter, guidable)
            dr.scatter(missed_at, si.p, slot, guidable & ~found)
            c = native.selection_probability(lane, found)
            guided = found & (c > 0.0)
            lobes = native.lobes(lane, guided)
            g_em = native.pdf(lobes, guided & nee.active_em, nee.ds_em.d) * scale
            use_guide = guided & (nee.u_select < c)
            wi_world = dr.select(use_guide, native.sample(lobes, nee.u_guide), si.to_world(bs.wo))
            g_pdf = native.pdf(lobes, guided, wi_world) * scale
            direct, _, _, _, weight, pdf = self._mixture(ctx, si, bsdf, guidable, c, nee, g_em,
                                                         wi_world, g_pdf)
            L += beta * direct
            ray = si.spawn_ray(wi_world)
            beta *= weight
            eta *= dr.select(guidable, 1.0, bs.eta)
            prev_si = dr.detach(mi.Interaction3f(si))
            prev_pdf = pdf
            prev_delta = ~guidable & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            beta, active, _, _ = self._roulette(sampler, beta, eta, depth, active_next)
            depth += 1
        return L

    def _trace(self, scene, sampler, ray, n, guide, recorder, times):
        """One wavefront of ``n`` paths as an evaluated loop (the guide through the library on
        numpy arrays between Mitsuba's kernels, the recorder's calls in the training passes);
        returns their radiance."""
        field = guide.field if guide is not None else None
        slots = np.arange(n, dtype=np.uint32)
        ctx = mi.BSDFContext()
        beta, L, eta, active, prev_si, prev_pdf, prev_delta, ray = _path_start(ray)
        if recorder is not None:
            recorder.start(n)
        depth = 0
        while True:
            t0 = time.perf_counter()
            si = scene.ray_intersect(
                ray, ray_flags=mi.RayFlags.All, coherent=depth == 0, active=active
            )
            emitted, mis_bsdf, valid, active_next, bsdf, guidable = self._hit(
                scene, si, ray, prev_si, prev_pdf, prev_delta, active, depth)
            L[active] += beta * mis_bsdf * emitted
            escaped = active & ~si.is_valid() & (depth > 0)
            wo_world = -ray.d
            dr.eval(si, wo_world, emitted, mis_bsdf, guidable, active_next, valid, escaped)
            times.mitsuba += time.perf_counter() - t0
            if recorder is not None:
                t1, lib = time.perf_counter(), times.library()
                self._record_hits(recorder, slots, si, wo_world, emitted, mis_bsdf, valid,
                                  escaped, depth, guidable)
                times.transfers += time.perf_counter() - t1 - (times.library() - lib)
            if not dr.any(active_next):
                break

            # The guide at the guidable vertices, through the library on numpy arrays.
            t2, lib = time.perf_counter(), times.library()
            gmask = np.asarray(guidable, dtype=bool)
            gidx = np.nonzero(gmask)[0].astype(np.uint32)
            lane = np.full(n, 0, dtype=np.uint32)
            lane[gidx] = np.arange(gidx.size, dtype=np.uint32)
            c_full = np.zeros(n, dtype=np.float32)
            batch = None
            if field is not None and gidx.size > 0:
                batch = guide.decode(
                    _rows(si.p)[gidx], _rows(si.sh_frame.n)[gidx], _rows(wo_world)[gidx]
                )
                c_full[gidx] = batch.selection_probability()
            times.transfers += time.perf_counter() - t2 - (times.library() - lib)

            # Next-event estimation and the BSDF's sample.
            t3 = time.perf_counter()
            nee = self._nee_and_bsdf(scene, sampler, ctx, si, bsdf, active_next)
            active_em, ds_em, bs, bsdf_weight = nee.active_em, nee.ds_em, nee.bs, nee.bsdf_weight
            bsdf_wo_world = si.to_world(bs.wo)
            dr.eval(*nee, bsdf_wo_world)
            times.mitsuba += time.perf_counter() - t3

            # Guide densities at the NEE directions, guide samples, guide densities of the
            # BSDF's samples (through the library).
            c, g_em_dr, wi_world, g_pdf_dr, final_dir, em_np = self._guide_numpy(
                field, batch, lane, gmask, c_full, nee.u_select, nee.u_guide, active_em, ds_em,
                bsdf_wo_world, n, times)

            # Direct light with the combined density; the continuation.
            t5 = time.perf_counter()
            direct, bsdf_val, bsdf_pdf, pdf_mix, weight, pdf = self._mixture(
                ctx, si, bsdf, guidable, c, nee, g_em_dr, wi_world, g_pdf_dr)
            L[active_em] += beta * direct
            sampled_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            # The recorder's f·|cos| and density (a delta sample: the weight over a pdf of 1).
            rec_f = dr.select(guidable, bsdf_val, dr.select(sampled_delta, bsdf_weight,
                                                            bsdf_weight * bs.pdf))
            rec_pdf = dr.select(guidable, pdf_mix, dr.select(sampled_delta, 1.0, bs.pdf))
            rec_pdf = dr.select(active_next & (dr.max(weight) > 0.0), rec_pdf, 0.0)
            bsdf_pdf_rec = dr.select(guidable, bsdf_pdf, bs.pdf)

            ray = si.spawn_ray(wi_world)
            beta *= weight
            eta *= dr.select(guidable, 1.0, bs.eta)
            prev_si = si
            prev_pdf = pdf
            prev_delta = ~guidable & sampled_delta
            beta, active, rr_prob, rr_active = self._roulette(
                sampler, beta, eta, mi.UInt32(depth), active_next)
            if recorder is None:
                dr.eval(ray, beta, eta, prev_si, prev_pdf, prev_delta, active, L)
            else:
                dr.eval(ray, beta, eta, prev_si, prev_pdf, prev_delta, active, L, direct, rec_f,
                        rec_pdf, bsdf_pdf_rec, rr_prob, rr_active)
            times.mitsuba += time.perf_counter() - t5

            if recorder is not None:
                t6, lib = time.perf_counter(), times.library()
                q = np.nonzero(em_np)[0].astype(np.uint32)
                if q.size:
                    recorder.add_direct(q, _rows(direct)[q])
                # Paths that go on (not those the roulette ended: they record nothing).
                going_on = np.asarray(active, dtype=bool)
                q = np.nonzero(going_on)[0].astype(np.uint32)
                if q.size:
                    recorder.set_continuations(
                        q,
                        final_dir[q],
                        np.asarray(rec_pdf, dtype=np.float32)[q],
                        np.asarray(bsdf_pdf_rec, dtype=np.float32)[q],
                        _rows(rec_f)[q],
                    )
                if depth + 1 >= self.rr_depth and q.size:
                    factor = 1.0 / np.asarray(rr_prob, dtype=np.float32)[q]
                    recorder.scale_continuations(q, factor.astype(np.float32))
                times.transfers += time.perf_counter() - t6 - (times.library() - lib)
            depth += 1
        return L

    def _guide_numpy(self, field, batch, lane, gmask, c_full, u_select, u_guide, active_em,
                     ds_em, bsdf_wo_world, n, times):
        """The guide's densities at the NEE directions, its samples and its densities at the
        continuations through the library on numpy arrays; returns them as Dr.Jit arrays
        (and the continuation directions and NEE mask as numpy, for the recorder)."""
        t4, lib = time.perf_counter(), times.library()
        c_np = c_full
        use_guide_np = gmask & (np.asarray(u_select) < c_np)
        em_np = np.asarray(active_em, dtype=bool)
        g_em = np.zeros(n, dtype=np.float32)
        g_pdf = np.zeros(n, dtype=np.float32)
        bsdf_dir = _rows(bsdf_wo_world)
        final_dir = bsdf_dir.copy()
        if batch is not None:
            q = np.nonzero(gmask & em_np & (c_np > 0))[0]
            if q.size:
                g_em[q] = field.pdf(batch, lane[q], _rows(ds_em.d)[q])
            q = np.nonzero(use_guide_np)[0]
            if q.size:
                u = np.stack([np.asarray(u_guide.x), np.asarray(u_guide.y)], axis=1)[q]
                d, pdf = field.sample(batch, lane[q], np.ascontiguousarray(u, np.float32))
                final_dir[q] = d
            q = np.nonzero(gmask & (c_np > 0))[0]
            if q.size:
                g_pdf[q] = field.pdf(batch, lane[q], final_dir[q])
        g_pdf *= self._guide_pdf_scale
        g_em *= self._guide_pdf_scale
        times.transfers += time.perf_counter() - t4 - (times.library() - lib)
        return (mi.Float(c_np), mi.Float(g_em), _vec3(final_dir), mi.Float(g_pdf), final_dir,
                em_np)

    @staticmethod
    def _record_hits(recorder, slots, si, wo_world, emitted, mis_bsdf, valid, escaped, depth,
                     guidable):
        """The recorder's calls for the hits and escapes of one bounce (a vertex that the
        guide does not sample trains nothing: it is recorded as delta)."""
        valid_np = np.asarray(valid, dtype=bool)
        q = slots[valid_np]
        emitted_rows = _rows(emitted)
        mis = np.asarray(mis_bsdf, dtype=np.float32)
        if depth == 0:
            mis = np.ones_like(mis)
        if q.size:
            delta = ~np.asarray(guidable, dtype=bool)[valid_np]
            recorder.add_vertices(
                q,
                _rows(si.p)[valid_np],
                _rows(si.sh_frame.n)[valid_np],
                _rows(wo_world)[valid_np],
                np.ones(q.size, dtype=np.float32),
                emitted_rows[valid_np],
                mis[valid_np],
                delta,
            )
        esc = np.asarray(escaped, dtype=bool)
        if esc.any():
            recorder.add_escaped_radiance(slots[esc], emitted_rows[esc], mis[esc])


def register():
    """Registers ``guided_path`` with Mitsuba (done on import of this module)."""
    mi.register_integrator("guided_path", lambda props: GuidedPath(props))


register()
