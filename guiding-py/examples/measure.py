"""Mitsuba's ``path`` against ``guided_path`` on one scene, at equal spp and at equal time.

    python guiding-py/examples/measure.py host-demo/tests/data/door-mitsuba3/scene.xml \
        --spp 64 --seeds 3 --reference-spp 4096 --out docs/bench-…/door

Per seed: ``guided_path`` at ``--spp``, ``path`` at ``--spp`` (equal spp), ``path`` with
the spp that fills the guided render's wall time (equal time, from ``path``'s measured seconds
per spp), and ``guided_path`` with ``guiding`` off at ``--spp`` (what the Python wavefront loop
costs by itself). With ``--timeout T`` the guided render is given ``T`` seconds (its
``timeout``) instead of ``--spp`` passes, and equal spp means its pass count. The reference is
``path`` at ``--reference-spp`` (cached in the output directory). relMSE is host-demo's
(``host-demo compare``): the channel mean of ``(I − R)² / (R² + 0.01)`` per pixel, the highest
0.1 % of pixels dropped. Writes ``results.json`` and prints a table.
"""

import argparse
import json
import os
import re
import time

import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")
import guiding.mitsuba  # noqa: E402,F401  (registers guided_path)


def relmse(img, ref):
    """host-demo's trimmed relMSE (``host-demo/src/render/compare.rs``)."""
    err = ((img[..., :3] - ref[..., :3]) ** 2 / (ref[..., :3] ** 2 + 0.01)).mean(axis=-1)
    err = np.sort(err.ravel().astype(np.float64))
    trimmed = int(np.floor(0.001 * err.size))
    return float(err[: err.size - trimmed].mean())


def render(scene, integrator, spp, seed):
    t = time.perf_counter()
    img = np.asarray(mi.render(scene, integrator=integrator, spp=spp, seed=seed))
    return img, time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--reference-spp", type=int, default=4096)
    ap.add_argument("--guide", default="npm")
    ap.add_argument("--selection-probability", type=float, default=-1.0)
    ap.add_argument("--reference", help="a reference EXR instead of rendering one")
    ap.add_argument(
        "--rr-depth",
        type=int,
        default=0,
        help="Russian roulette from this depth in both integrators (0: the scene's)",
    )
    ap.add_argument(
        "--define",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a scene parameter (<default name=…>), e.g. integrator=path",
    )
    ap.add_argument(
        "--timeout",
        type=float,
        default=0.0,
        help="guided_path renders for this many seconds (its timeout) instead of --spp passes;"
        " equal spp then means its pass count",
    )
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    scene = mi.load_file(a.scene, **dict(d.split("=", 1) for d in a.define))
    max_depth, rr_depth = path_depths(scene)
    if a.rr_depth > 0:
        rr_depth = a.rr_depth
    depths = {"max_depth": max_depth, "rr_depth": rr_depth}
    path = mi.load_dict({"type": "path", **depths})
    ref_file = a.reference or os.path.join(a.out, f"reference-{a.reference_spp}spp.exr")
    if os.path.exists(ref_file):
        ref = np.asarray(mi.Bitmap(ref_file))
    else:
        chunk = 256
        parts = []
        for k in range(max(1, a.reference_spp // chunk)):
            img, _ = render(scene, path, min(chunk, a.reference_spp), 10_000 + k)
            parts.append(img)
        ref = np.mean(parts, axis=0)
        mi.Bitmap(ref).write(ref_file)
    # Warm-up: Dr.Jit compiles each kernel once (then caches it); neither integrator's first
    # timed render should pay for it.
    for warm in (
        {"type": "guided_path", **depths},
        {"type": "guided_path", "guiding": False, **depths},
    ):
        render(scene, mi.load_dict(warm), 8, 9999)
    render(scene, path, 1, 9999)
    rows = []
    for seed in range(a.seeds):
        guided = mi.load_dict(
            {
                "type": "guided_path",
                "guide": a.guide,
                "selection_probability": a.selection_probability,
                "timeout": a.timeout if a.timeout > 0 else -1.0,
                **depths,
            }
        )
        g_img, g_s = render(scene, guided, 1_000_000 if a.timeout > 0 else a.spp, seed)
        spp = guided.stats["spp"]
        p_img, p_s = render(scene, path, spp, seed)
        loop = mi.load_dict(
            {"type": "guided_path", "guiding": False, **depths}
        )
        l_img, l_s = render(scene, loop, spp, 2000 + seed)
        spp_eq = max(1, int(round(g_s / (p_s / spp))))
        t_img, t_s = render(scene, path, spp_eq, 1000 + seed)
        rows.append(
            {
                "seed": seed,
                "guided": {"spp": spp, "seconds": g_s, "relmse": relmse(g_img, ref)},
                "path_equal_spp": {"spp": spp, "seconds": p_s, "relmse": relmse(p_img, ref)},
                "path_equal_time": {"spp": spp_eq, "seconds": t_s, "relmse": relmse(t_img, ref)},
                "loop_without_guide": {"spp": spp, "seconds": l_s, "relmse": relmse(l_img, ref)},
                "guided_stats": {
                    k: (v if isinstance(v, (int, float, dict, type(None))) else repr(v))
                    for k, v in guided.stats.items()
                },
            }
        )
        r = rows[-1]
        print(
            f"seed {seed}: guided {r['guided']['relmse']:.4g} ({g_s:.1f} s), "
            f"path same spp {r['path_equal_spp']['relmse']:.4g} ({p_s:.1f} s), "
            f"path same time {r['path_equal_time']['relmse']:.4g} ({spp_eq} spp, {t_s:.1f} s), "
            f"the loop without a guide {r['loop_without_guide']['relmse']:.4g} ({l_s:.1f} s)"
        )
    mean = lambda key: float(np.mean([r[key]["relmse"] for r in rows]))  # noqa: E731
    summary = {
        "scene": a.scene,
        "spp": a.spp,
        "timeout": a.timeout,
        "seeds": a.seeds,
        "reference_spp": a.reference_spp,
        "max_depth": max_depth,
        "rr_depth": rr_depth,
        "guided_relmse": mean("guided"),
        "path_equal_spp_relmse": mean("path_equal_spp"),
        "path_equal_time_relmse": mean("path_equal_time"),
        "ratio_equal_spp": mean("guided") / mean("path_equal_spp"),
        "ratio_equal_time": mean("guided") / mean("path_equal_time"),
        "runs": rows,
    }
    with open(os.path.join(a.out, "results.json"), "w") as fh:
        json.dump(summary, fh, indent=2)
    print(
        f"guided / path relMSE: equal spp {summary['ratio_equal_spp']:.3f}x, "
        f"equal time {summary['ratio_equal_time']:.3f}x"
    )


def path_depths(scene):
    """The scene's integrator's ``max_depth`` and ``rr_depth`` (from its description;
    Mitsuba's defaults -1 and 5 where it does not say)."""
    text = str(scene.integrator())
    m = re.search(r"max_depth\s*=\s*(-?\d+)", text)
    r = re.search(r"rr_depth\s*=\s*(\d+)", text)
    return (int(m.group(1)) if m else -1), (int(r.group(1)) if r else 5)


if __name__ == "__main__":
    main()
