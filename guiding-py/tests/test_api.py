"""The Python API of ``guiding``: results, round trips and error paths.

Run: ``python -m unittest discover -s guiding-py/tests`` after ``pip install ./guiding-py``.
"""

import os
import tempfile
import unittest

import numpy as np

import guiding


def field(**kw):
    return guiding.Field([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], size="small", threads=1, **kw)


def points(n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-0.9, 0.9, size=(n, 3)).astype(np.float32)


def lanes(n):
    return np.arange(n, dtype=np.uint32)


def record_one_bounce(rec, n, radiance=2.0):
    """``n`` paths with one diffuse-like vertex each that escape to a light of ``radiance``."""
    rng = np.random.default_rng(1)
    wi = rng.normal(size=(n, 3)).astype(np.float32)
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    slots = lanes(n)
    rec.start(n)
    z = np.zeros((n, 3), np.float32)
    normal = np.tile(np.float32([0, 0, 1]), (n, 1))
    rec.add_vertices(slots, points(n), normal, normal, np.ones(n, np.float32), z,
                     np.ones(n, np.float32), np.zeros(n, bool))
    pdf = np.full(n, 1.0 / (2.0 * np.pi), np.float32)
    rec.set_continuations(slots, wi, pdf, pdf, np.tile(np.float32([0.25, 0.25, 0.25]), (n, 1)))
    rec.add_escaped_radiance(slots, np.full((n, 3), radiance, np.float32), np.ones(n, np.float32))
    return rec.end()


class Results(unittest.TestCase):
    def test_sample_and_pdf_agree(self):
        f = field()
        b = f.decode(points(64))
        self.assertEqual(len(b), 64)
        u = np.random.default_rng(2).uniform(size=(64, 2)).astype(np.float32)
        d, pdf = f.sample(b, lanes(64), u)
        self.assertEqual(d.shape, (64, 3))
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-5)
        np.testing.assert_allclose(f.pdf(b, lanes(64), d), pdf, rtol=1e-4)
        c = b.selection_probability()
        self.assertTrue(np.all((c >= 0) & (c <= 1)))

    def test_recorder_estimates_and_trains(self):
        f = field()
        rec = guiding.BatchRecorder()
        est = record_one_bounce(rec, 256)
        # L_o(0) = f·cos / pdf · L = 0.25 · 2π · 2 per path.
        np.testing.assert_allclose(est, 0.25 * 2.0 * np.pi * 2.0, rtol=1e-5)
        self.assertEqual(len(rec), 256)
        self.assertEqual(rec.flush_into(f), 256)
        self.assertEqual(f.stats().buffered_samples, 256)
        report = f.update()
        self.assertGreater(report.steps, 0)
        self.assertEqual(f.generation, 1)
        rec.add_direct(np.uint32([7]), np.ones((1, 3), np.float32))  # no block open
        self.assertEqual(rec.ignored_calls, 1)

    def test_schedule_trains_when_due(self):
        f = field()
        # 20 % of 10 passes: passes 0 and 1 train; an answer "no" ends the phase for good.
        late = guiding.Schedule(spp=10)
        self.assertFalse(late.in_training_phase(0.0, 2))
        self.assertTrue(late.training_over)
        s = guiding.Schedule(spp=10)
        self.assertTrue(s.in_training_phase(0.0, 1))
        rec = guiding.BatchRecorder()
        record_one_bounce(rec, 512)
        rec.flush_into(f)
        s.record_traced(0.5, 512)
        r = f.train_scheduled(s)
        self.assertGreater(r.steps, 0)
        self.assertEqual(s.report().steps, r.steps)

    def test_save_load_round_trip(self):
        f = field(representation="nasg")
        rec = guiding.BatchRecorder()
        record_one_bounce(rec, 256)
        rec.flush_into(f)
        f.update()
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "scene.guide")
            f.save(path)
            g = guiding.Field.load(path)
        self.assertEqual((g.representation, g.target, g.size), ("nasg", "radiance", "small"))
        p = points(32)
        dirs = np.tile(np.float32([0, 0, 1]), (32, 1))
        np.testing.assert_array_equal(
            f.pdf(f.decode(p), lanes(32), dirs), g.pdf(g.decode(p), lanes(32), dirs)
        )


    def test_guide_cache_serves_the_fields_distributions(self):
        f = field()
        rec = guiding.BatchRecorder()
        record_one_bounce(rec, 256)
        rec.flush_into(f)
        f.update()
        p = points(500, seed=3)
        cache = f.build_cache(p, resolution=16)
        self.assertGreater(cache.cells, 0)
        batch = cache.decode(f, p, np.full((500, 3), 0.5, np.float32))
        self.assertEqual(cache.misses.size, 0)  # every point made or shares a cell
        u = np.random.default_rng(4).uniform(size=(500, 2)).astype(np.float32)
        d, pdf = f.sample(batch, lanes(500), u)
        np.testing.assert_allclose(f.pdf(batch, lanes(500), d), pdf, rtol=1e-4)
        far = np.float32([[0.95, -0.95, 0.95]])  # outside every occupied cell
        cache.decode(f, far, np.full((1, 3), 0.5, np.float32))
        self.assertEqual(list(cache.misses), [0])
        self.assertEqual(cache.extend(f, far), 1)
        # After an update the cache is stale until refreshed.
        rec2 = guiding.BatchRecorder()
        record_one_bounce(rec2, 256)
        rec2.flush_into(f)
        f.update()
        with self.assertRaises(guiding.GuidingError):
            cache.decode(f, p, np.full((500, 3), 0.5, np.float32))
        cache.refresh(f)
        cache.decode(f, p, np.full((500, 3), 0.5, np.float32))

    def test_selection_fit_uses_the_kept_samples(self):
        f = field()
        rec = guiding.BatchRecorder()
        record_one_bounce(rec, 512)
        self.assertEqual(rec.flush_into(f, keep=True), 512)
        self.assertEqual(rec.kept_samples, 512)
        f.update()
        p = points(512)
        cache = f.build_cache(p, resolution=8)
        r = cache.fit_selection(f, rec)
        self.assertEqual(r.samples_used, 512)
        self.assertEqual(r.cells_fitted + r.cells_global, cache.cells)
        self.assertTrue(0.0 <= r.mean <= 0.9 and 0.0 <= r.global_selection <= 0.9)
        # The fitted probabilities are what the cache's batches (and its table) carry.
        c = cache.decode(f, p, np.full((512, 3), 0.5, np.float32)).selection_probability()
        self.assertTrue(np.all((c >= 0.0) & (c <= 0.9)))
        table = cache.vmf_table()
        self.assertEqual(table["lane_selection"].size, cache.cells)
        np.testing.assert_allclose(c.mean(), table["lane_selection"][
            table["index"][table["index"] != 0xFFFFFFFF]].mean(), rtol=0.5)

    def test_pass_combiner_weights_by_inverse_variance(self):
        w, h = 16, 8
        rng = np.random.default_rng(5)
        truth = rng.uniform(0.5, 1.0, size=(w * h, 3)).astype(np.float32)
        comb = guiding.PassCombiner(w, h)
        noisy = [truth + rng.normal(0, 0.5, size=truth.shape).astype(np.float32)]
        calm = [truth + rng.normal(0, 0.05, size=truth.shape).astype(np.float32)
                for _ in range(6)]
        comb.add_pass(0, noisy[0])
        for x in calm:
            comb.add_pass(1, x)
        self.assertEqual((comb.passes, comb.group_count), (7, 2))
        c = comb.combine()
        self.assertFalse(c.fell_back)
        self.assertLess(c.predicted_gain, 0.5)
        by_id = {g.group: g for g in c.groups}
        self.assertLess(by_id[0].share, 0.05)  # the noisy pass weighs little
        # A pixel of half (x + y) mod 2 = k takes the weights estimated on half 1 - k.
        x, y = np.arange(w * h) % w, np.arange(w * h) // w
        half = (x + y) % 2
        expect = np.zeros_like(truth, dtype=np.float64)
        for g, passes in ((by_id[0], noisy), (by_id[1], calm)):
            a = np.where(half == 0, g.pass_weight[1], g.pass_weight[0])
            expect += a[:, None] * np.sum(passes, axis=0)
        np.testing.assert_allclose(c.pixels, expect, rtol=1e-5, atol=1e-6)
        self.assertEqual(c.var_of_mean.shape, (w * h, 3))
        self.assertLess(np.abs(c.pixels - truth).mean(), np.abs(np.mean(noisy + calm, axis=0)
                                                                 - truth).mean())


class Errors(unittest.TestCase):
    def test_pass_combiner_errors(self):
        with self.assertRaises(guiding.GuidingError):
            guiding.PassCombiner(0, 4)
        with self.assertRaises(guiding.GuidingError):
            guiding.PassCombiner(4, 4, epsilon=0.0)
        comb = guiding.PassCombiner(4, 4)
        with self.assertRaises(guiding.GuidingError):
            comb.add_pass(0, np.zeros((15, 3), np.float32))
        with self.assertRaisesRegex(ValueError, "pixels: expected"):
            comb.add_pass(0, np.zeros((16, 4), np.float32))
        self.assertEqual(comb.passes, 0)

    def test_nasg_learns_its_own_selection(self):
        f = field(representation="nasg")
        rec = guiding.BatchRecorder()
        record_one_bounce(rec, 64)
        rec.flush_into(f, keep=True)
        cache = f.build_cache(points(64), resolution=8)
        with self.assertRaisesRegex(guiding.GuidingError, "NASG"):
            cache.fit_selection(f, rec)

    def test_bad_names(self):
        with self.assertRaisesRegex(ValueError, "representation"):
            field(representation="vmf")
        with self.assertRaisesRegex(ValueError, "target"):
            field(target="irradiance")
        with self.assertRaisesRegex(ValueError, "size"):
            guiding.Field([-1.0] * 3, [1.0] * 3, size="huge")

    def test_product_guides_have_no_cache(self):
        with self.assertRaisesRegex(guiding.GuidingError, "radiance-target"):
            field(target="product").build_cache(points(8))

    def test_bad_bounds(self):
        with self.assertRaises(guiding.GuidingError):
            guiding.Field([1.0, 1.0, 1.0], [-1.0, -1.0, -1.0])

    def test_bad_shapes_and_lengths(self):
        f = field()
        with self.assertRaisesRegex(ValueError, r"position: expected an array of shape \(n, 3\)"):
            f.decode(np.zeros((4, 2), np.float32))
        b = f.decode(points(4))
        with self.assertRaisesRegex(ValueError, "u: expected"):
            f.sample(b, lanes(4), np.zeros((4, 3), np.float32))
        with self.assertRaises(guiding.GuidingError):  # 3 lanes, 4 random pairs
            f.sample(b, lanes(3), np.zeros((4, 2), np.float32))
        with self.assertRaises(guiding.GuidingError):  # lane out of range
            f.pdf(b, np.uint32([9]), np.float32([[0, 0, 1]]))
        with self.assertRaisesRegex(ValueError, "normal has 3 rows where position has 4"):
            f.decode(points(4), normal=np.zeros((3, 3), np.float32))
        with self.assertRaises(TypeError):  # float64 is not converted silently
            f.decode(np.zeros((4, 3)))

    def test_non_finite_query_is_refused(self):
        p = points(4)
        p[2, 1] = np.nan
        with self.assertRaisesRegex(ValueError, "row 2 is not finite"):
            field().decode(p)

    def test_stale_batch_is_refused(self):
        f = field()
        b = f.decode(points(8))
        rec = guiding.BatchRecorder()
        record_one_bounce(rec, 256)
        rec.flush_into(f)
        f.update()
        with self.assertRaisesRegex(guiding.GuidingError, "stale|generation"):
            f.pdf(b, lanes(8), np.tile(np.float32([0, 0, 1]), (8, 1)))

    def test_schedule_needs_one_budget(self):
        with self.assertRaisesRegex(ValueError, "exactly one"):
            guiding.Schedule()
        with self.assertRaisesRegex(ValueError, "exactly one"):
            guiding.Schedule(spp=4, seconds=1.0)
        with self.assertRaises(guiding.GuidingError):
            guiding.Schedule(spp=4, train_fraction=1.5)

    def test_missing_and_corrupt_files(self):
        with tempfile.TemporaryDirectory() as d:
            with self.assertRaises(guiding.GuidingError):
                guiding.Field.load(os.path.join(d, "missing.guide"))
            bad = os.path.join(d, "bad.guide")
            with open(bad, "wb") as fh:
                fh.write(b"not a guide file at all")
            with self.assertRaises(guiding.GuidingError):
                guiding.Field.load(bad)


if __name__ == "__main__":
    unittest.main()
