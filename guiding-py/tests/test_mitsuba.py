"""``guided_path`` inside Mitsuba 3: unbiased against Mitsuba's own ``path``, per pixel block.

Run: ``python -m unittest discover -s guiding-py/tests`` (needs ``mitsuba`` and ``scipy``; the
LLVM variant needs ``libLLVM``, which ``.ci/test`` installs). Skipped without Mitsuba unless
``GUIDING_REQUIRE_MITSUBA=1`` (as CI sets it), which turns a missing Mitsuba into a failure.

The method is host-demo's ``tests/unbiased.rs``: each scene is rendered small (``RES`` pixels
wide, box filter) with ``SEEDS`` independent seeds by ``path`` and by ``guided_path`` (which
trains its own guide per seed, so the seeds are the independent replications). Per block of
``BLOCK`` × ``BLOCK`` pixels and channel the seed means give each integrator's mean and standard
error; ``t = (m_a − m_b) / √(s_a²/n + s_b²/n)`` is compared with Student's t at the
Welch–Satterthwaite degrees of freedom, two-sided, at the Šidák-corrected level for a
family-wise false-alarm rate of 1 % over the scene's blocks × channels.

Negative control (committed): the guide's density scaled by 1.5 in the MIS weights
(``GuidedPath._guide_pdf_scale``, a test hook, applied in-kernel after training) must be
rejected on the Cornell box.
"""

import os
import re
import unittest

import numpy as np

try:
    import mitsuba as mi
    from scipy import stats

    mi.set_variant("llvm_ad_rgb")
    import guiding.mitsuba  # noqa: F401  (registers guided_path)

    HAVE_MITSUBA = True
except ImportError as e:  # pragma: no cover
    if os.environ.get("GUIDING_REQUIRE_MITSUBA") == "1":
        raise
    HAVE_MITSUBA = False
    MISSING = str(e)

SCENES = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "scenes")
SEEDS = 16
SPP = 16
BLOCK = 8
ALPHA = 0.01


def load_small(name, width):
    """The shared scene ``name`` with its film cut to ``width`` pixels (aspect kept) and a box
    filter, and its integrator's ``max_depth``."""
    path = os.path.abspath(os.path.join(SCENES, name, "scene.xml"))
    with open(path) as fh:
        xml = fh.read()
    w = int(re.search(r'name="width" value="(\d+)"', xml).group(1))
    h = int(re.search(r'name="height" value="(\d+)"', xml).group(1))
    height = max(BLOCK, round(h * width / w / BLOCK) * BLOCK)
    xml = re.sub(r'name="width" value="\d+"', f'name="width" value="{width}"', xml)
    xml = re.sub(r'name="height" value="\d+"', f'name="height" value="{height}"', xml)
    max_depth = int(re.search(r'name="max_depth" value="(\d+)"', xml).group(1))
    mi.file_resolver().prepend(os.path.dirname(path))
    return mi.load_string(xml), max_depth


def block_means(img):
    h, w, _ = img.shape
    return img[:, :, :3].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, 3).mean(axis=(1, 3))


def seed_blocks(scene, integrator):
    return np.stack(
        [block_means(np.array(mi.render(scene, integrator=integrator, spp=SPP, seed=s)))
         for s in range(SEEDS)]
    )


def welch_p_values(a, b):
    """Two-sided Welch p-values per block and channel of seed-block arrays ``a``, ``b``."""
    n = a.shape[0]
    va, vb = a.var(axis=0, ddof=1) / n, b.var(axis=0, ddof=1) / n
    t = (a.mean(axis=0) - b.mean(axis=0)) / np.sqrt(va + vb)
    df = (va + vb) ** 2 / (va**2 / (n - 1) + vb**2 / (n - 1))
    return 2.0 * stats.t.sf(np.abs(t), df), t


def sidak(tests):
    return 1.0 - (1.0 - ALPHA) ** (1.0 / tests)


@unittest.skipUnless(HAVE_MITSUBA, "mitsuba / scipy not installed")
class Unbiased(unittest.TestCase):
    cache = {}

    def path_blocks(self, name, width):
        if (name, width) not in self.cache:
            scene, max_depth = load_small(name, width)
            path = mi.load_dict({"type": "path", "max_depth": max_depth})
            self.cache[(name, width)] = (scene, max_depth, seed_blocks(scene, path))
        return self.cache[(name, width)]

    def check(self, name, width, scale=1.0, native=True, fit=False):
        scene, max_depth, ref = self.path_blocks(name, width)
        guided = mi.load_dict(
            {"type": "guided_path", "max_depth": max_depth, "threads": 1, "native_guide": native,
             "fit_selection": fit}
        )
        guided._guide_pdf_scale = scale
        got = seed_blocks(scene, guided)
        p, t = welch_p_values(got, ref)
        level = sidak(p.size)
        self.assertGreater(guided.stats["field"].steps, 0, "the guide never trained")
        return p, t, level

    def assert_agrees(self, name, width, native=True, fit=False):
        p, t, level = self.check(name, width, native=native, fit=fit)
        print(f"\n{name}: smallest p {p.min():.2e} of {p.size} tests (level {level:.2e}), "
              f"worst |t| {np.abs(t).max():.2f}")
        self.assertGreater(p.min(), level, f"worst |t| {np.abs(t).max():.2f}")

    def test_cornell_box(self):
        self.assert_agrees("cornell-box", 32)

    def test_cornell_box_through_numpy(self):
        """The guide after training through the library's cache on numpy arrays (the
        ``native_guide`` off) instead of inside Mitsuba's kernels."""
        self.assert_agrees("cornell-box", 32, native=False)

    def test_veach_mis(self):
        self.assert_agrees("veach-mis", 48)

    def test_cornell_box_with_a_fitted_selection(self):
        """The selection probability fitted per cell (``fit_selection``)."""
        self.assert_agrees("cornell-box", 32, fit=True)

    def test_a_scaled_guide_pdf_is_caught(self):
        # With the preset selection probability (the default): on the Cornell box the fit
        # turns the guide down where it does not pay, and with it the scaled pdf's effect (0 of
        # 48 rejected, worst t -3.3, with the fit).
        p, t, level = self.check("cornell-box", 32, scale=1.5)
        rejected = int((p < level).sum())
        print(f"\nscaled guide pdf: {rejected} of {p.size} block-channel tests rejected, "
              f"worst t {t.flat[np.argmax(np.abs(t))]:.2f}")
        self.assertGreater(rejected, 0)


@unittest.skipUnless(HAVE_MITSUBA, "mitsuba / scipy not installed")
class Combined(unittest.TestCase):
    def test_the_film_gets_the_combiners_image(self):
        """With a box filter the developed image is the combiner's weighted mean, and the
        cache's selection was fitted to the last training pass."""
        scene, max_depth = load_small("cornell-box", 32)
        guided = mi.load_dict({"type": "guided_path", "max_depth": max_depth, "threads": 1,
                               "fit_selection": True})
        img = np.array(mi.render(scene, integrator=guided, spp=SPP, seed=3))
        c = guided.combination
        self.assertIsNotNone(c)
        self.assertFalse(c.fell_back)
        self.assertEqual(sum(g.passes for g in c.groups), SPP)
        self.assertGreater(len(c.groups), 2)  # training passes, then one group
        np.testing.assert_allclose(img[:, :, :3].reshape(-1, 3), c.pixels, rtol=1e-4,
                                   atol=1e-6)
        fit = guided.stats["guide_cache"]["selection_fit"]
        self.assertGreater(fit["samples_used"], 0)
        off = mi.load_dict({"type": "guided_path", "max_depth": max_depth, "threads": 1,
                            "combine_passes": False})
        mi.render(scene, integrator=off, spp=SPP, seed=3)
        self.assertIsNone(off.combination)
        self.assertIsNone(off.stats["guide_cache"]["selection_fit"])


@unittest.skipUnless(HAVE_MITSUBA, "mitsuba / scipy not installed")
class Timeout(unittest.TestCase):
    def test_a_timeout_ends_the_render_and_the_training_by_time(self):
        """``timeout``: far fewer passes than the spp asked for, at least one after training,
        and the schedule's training phase a share of the time, not of the passes."""
        scene, max_depth = load_small("cornell-box", 32)
        guided = mi.load_dict({"type": "guided_path", "max_depth": max_depth, "threads": 1,
                               "timeout": 1.5})
        img = np.array(mi.render(scene, integrator=guided, spp=100_000, seed=1))
        st = guided.stats
        self.assertLess(st["spp"], 100_000)
        self.assertGreater(st["spp"], st["training_passes"])
        self.assertGreater(st["training_passes"], 0)
        self.assertGreater(st["field"].steps, 0)
        self.assertTrue(np.all(np.isfinite(img)))
        self.assertEqual(sum(g.passes for g in guided.combination.groups), st["spp"])


if __name__ == "__main__":
    unittest.main()
