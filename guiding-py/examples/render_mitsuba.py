"""Renders a Mitsuba 3 scene with the guided integrator and writes an EXR.

    python guiding-py/examples/render_mitsuba.py ../shared/scenes/cornell-box/scene.xml \
        --spp 64 --out cornell-guided.exr [--guide npm --target radiance] [--compare]

``--compare`` also renders Mitsuba's own ``path`` with the same spp and prints both times.
"""

import argparse
import json
import time

import numpy as np
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import guiding.mitsuba  # noqa: E402,F401  (registers guided_path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--out", default="guided.exr")
    ap.add_argument("--guide", default="npm")
    ap.add_argument("--target", default="radiance")
    ap.add_argument("--max-depth", type=int, default=-1)
    ap.add_argument("--compare", action="store_true")
    a = ap.parse_args()
    scene = mi.load_file(a.scene)
    integrator = mi.load_dict(
        {"type": "guided_path", "guide": a.guide, "target": a.target, "max_depth": a.max_depth}
    )
    t = time.perf_counter()
    img = mi.render(scene, integrator=integrator, spp=a.spp)
    img = np.asarray(img)
    seconds = time.perf_counter() - t
    mi.util.write_bitmap(a.out, mi.TensorXf(img))
    stats = integrator.stats
    print(f"guided_path: {a.spp} spp in {seconds:.2f} s -> {a.out}")
    print(json.dumps(stats["time_split"], indent=2))
    print(stats["schedule"])
    if a.compare:
        path = mi.load_dict({"type": "path", "max_depth": a.max_depth})
        t = time.perf_counter()
        np.asarray(mi.render(scene, integrator=path, spp=a.spp))  # read back: renders are lazy
        print(f"path: {a.spp} spp in {time.perf_counter() - t:.2f} s")


if __name__ == "__main__":
    main()
