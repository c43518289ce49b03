#!/usr/bin/env python3
"""Reference image means of the published scenes with Mitsuba 3 (run once; output committed).

Each scene is rendered as it is published, with only the `$name` parameters below changed
(`integrator=path`: the files default to a research integrator Mitsuba 3 does not ship; the
resolution and sample count: to keep the test quick; the image mean does not depend on them).
`host-demo/tests/published_scenes.rs` renders the unchanged files at the same size and
compares. Mitsuba 3 cannot load `veach-mis-v05/scene.xml` (it refuses the 0.5 file's
`strictNormals`); it is the same scene as `veach-mis-v3`, whose reference it shares.

Usage: python3 measure.py   (needs `pip install mitsuba numpy`; uses the scalar_rgb variant)
Writes mitsuba3.csv: scene,width,height,mean_r,mean_g,mean_b,se_r,se_g,se_b.
"""
import os
import sys

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")
HERE = os.path.dirname(os.path.abspath(__file__))
SEEDS = 8
SPP = 1024
SCENES = {
    "cornell-box-v3": (96, 96),
    "veach-bidir-v3": (96, 96),
    "veach-mis-v3": (128, 72),
}


def main():
    rows = []
    for name, (w, h) in SCENES.items():
        sc = mi.load_file(os.path.join(HERE, name, "scene.xml"), integrator="path",
                          resx=str(w), resy=str(h), spp=str(SPP))
        means = []
        for seed in range(SEEDS):
            img = np.array(mi.render(sc, seed=seed), dtype=np.float64)
            means.append(img[:, :, :3].reshape(-1, 3).mean(axis=0))
        means = np.array(means)
        m = means.mean(axis=0)
        se = means.std(axis=0, ddof=1) / np.sqrt(SEEDS)
        rows.append((name, w, h, m, se))
        print(name, m, se, file=sys.stderr)
    with open(os.path.join(HERE, "mitsuba3.csv"), "w") as f:
        f.write(f"# Mitsuba {mi.__version__} scalar_rgb, {SEEDS} seeds x {SPP} spp, -D integrator=path: "
                "scene,width,height,mean_r,mean_g,mean_b,se_r,se_g,se_b (written by measure.py)\n")
        for name, w, h, m, se in rows:
            f.write(",".join([name, str(w), str(h)] + [f"{v:.7g}" for v in list(m) + list(se)]) + "\n")


if __name__ == "__main__":
    main()
