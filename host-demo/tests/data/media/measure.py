#!/usr/bin/env python3
"""Reference image means of the media scenes with Mitsuba 3's `volpath` (run once; output committed).

Each Mitsuba 3 scene of this folder is rendered as written (its `volpath` integrator, Mitsuba's
Russian roulette from depth 5: unbiased, so the mean is the same as host-demo's without it) at
the size host-demo/tests/media.rs renders it. `fog-box-v06.xml` (`smoke-v06.xml`) is `fog-box.xml` (`smoke.xml`) in Mitsuba 0.6's
spelling, which Mitsuba 3 does not load; it shares its twin's reference.

Usage: python3 measure.py   (needs `pip install mitsuba numpy`, and libLLVM for llvm_ad_rgb)
Writes mitsuba3.csv: scene,width,height,mean_r,mean_g,mean_b,se_r,se_g,se_b.
"""
import os
import sys

import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")
HERE = os.path.dirname(os.path.abspath(__file__))
SEEDS = 8
SPP = 2048
SCENES = {"fog-box": 48, "fog-room": 48, "smoke": 48}


def main():
    rows = []
    for name, res in SCENES.items():
        sc = mi.load_file(os.path.join(HERE, name + ".xml"), res=str(res), spp=str(SPP))
        means = []
        for seed in range(SEEDS):
            img = np.array(mi.render(sc, seed=seed), dtype=np.float64)
            means.append(img[:, :, :3].reshape(-1, 3).mean(axis=0))
        means = np.array(means)
        m = means.mean(axis=0)
        se = means.std(axis=0, ddof=1) / np.sqrt(SEEDS)
        rows.append((name, res, res, m, se))
        print(name, m, se, file=sys.stderr)
    with open(os.path.join(HERE, "mitsuba3.csv"), "w") as f:
        f.write(f"# Mitsuba {mi.__version__} llvm_ad_rgb volpath, {SEEDS} seeds x {SPP} spp: "
                "scene,width,height,mean_r,mean_g,mean_b,se_r,se_g,se_b (written by measure.py)\n")
        for name, w, h, m, se in rows:
            f.write(",".join([name, str(w), str(h)] + [f"{v:.7g}" for v in list(m) + list(se)]) + "\n")


if __name__ == "__main__":
    main()
