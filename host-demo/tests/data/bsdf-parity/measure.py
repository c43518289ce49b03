#!/usr/bin/env python3
"""Measures the BSDF parity figures with Mitsuba 3 (run once; the output is committed).

Each case is a large rectangle (normal +z) with one BSDF under a white constant environment,
seen at 32 x 32 pixels by a perspective camera looking down at 45 degrees, so that every pixel
sees the plane and the pixels cover a range of incidence angles. The image mean, per channel,
is the BSDF's albedo averaged over those view directions (including transmission, which sees
the environment below the plane). `host-demo/tests/bsdf_parity.rs` renders the same XML (this
script writes it into `scenes/`) and compares.

Usage: python3 measure.py   (needs `pip install mitsuba numpy`; uses the scalar_rgb variant)
Writes: scenes/<case>.xml and mitsuba3.csv (case, mean r g b, standard error r g b).
"""
import os
import sys

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")

HERE = os.path.dirname(os.path.abspath(__file__))
SEEDS = 8
SPP = 512

CASES = {
    "diffuse": '<bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>',
    "diffuse-rgb": '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.8"/></bsdf>',
    "plastic": '<bsdf type="plastic"/>',
    "plastic-nonlinear": '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.7, 0.4, 0.1"/><boolean name="nonlinear" value="true"/></bsdf>',
    "roughplastic-a0.1": '<bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.1"/></bsdf>',
    "roughplastic-a0.3": '<bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf>',
    "roughplastic-a0.3-ior1.9": '<bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/><float name="int_ior" value="1.9"/><rgb name="diffuse_reflectance" value="0.8, 0.5, 0.2"/></bsdf>',
    "roughplastic-a0.6-nonlinear": '<bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.6"/><boolean name="nonlinear" value="true"/><rgb name="diffuse_reflectance" value="0.9"/></bsdf>',
    "conductor-none": '<bsdf type="conductor"/>',
    "conductor-Au": '<bsdf type="conductor"><string name="material" value="Au"/></bsdf>',
    "conductor-rgb": '<bsdf type="conductor"><rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 2.1"/><rgb name="specular_reflectance" value="0.9, 0.7, 0.5"/></bsdf>',
    "roughconductor-Cu-a0.1": '<bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.1"/><string name="material" value="Cu"/></bsdf>',
    "roughconductor-Al-a0.3": '<bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/><string name="material" value="Al"/></bsdf>',
    "roughconductor-Au-a0.2-spec": '<bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/><string name="material" value="Au"/><rgb name="specular_reflectance" value="0.8, 0.5, 0.2"/></bsdf>',
    "dielectric-1.5": '<bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>',
    "dielectric-1.33": '<bsdf type="dielectric"><float name="int_ior" value="1.33"/></bsdf>',
    "thindielectric-1.5": '<bsdf type="thindielectric"><float name="int_ior" value="1.5"/></bsdf>',
    "roughdielectric-a0.1": '<bsdf type="roughdielectric"><string name="distribution" value="ggx"/><float name="alpha" value="0.1"/><float name="int_ior" value="1.5"/></bsdf>',
    "roughdielectric-a0.3": '<bsdf type="roughdielectric"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/><float name="int_ior" value="1.5"/></bsdf>',
    # Beckmann, Mitsuba's default distribution (left implicit in some cases to test the default).
    "roughconductor-beckmann-Cu-a0.1": '<bsdf type="roughconductor"><float name="alpha" value="0.1"/><string name="material" value="Cu"/></bsdf>',
    "roughconductor-beckmann-Al-a0.3": '<bsdf type="roughconductor"><string name="distribution" value="beckmann"/><float name="alpha" value="0.3"/><string name="material" value="Al"/></bsdf>',
    "roughdielectric-beckmann-a0.1": '<bsdf type="roughdielectric"><float name="alpha" value="0.1"/><float name="int_ior" value="1.5"/></bsdf>',
    "roughdielectric-beckmann-a0.3": '<bsdf type="roughdielectric"><string name="distribution" value="beckmann"/><float name="alpha" value="0.3"/><float name="int_ior" value="1.5"/></bsdf>',
    "roughplastic-beckmann-a0.1": '<bsdf type="roughplastic"><float name="alpha" value="0.1"/></bsdf>',
    "roughplastic-beckmann-a0.3": '<bsdf type="roughplastic"><string name="distribution" value="beckmann"/><float name="alpha" value="0.3"/></bsdf>',
    "roughplastic-beckmann-a0.3-ior1.9": '<bsdf type="roughplastic"><string name="distribution" value="beckmann"/><float name="alpha" value="0.3"/><float name="int_ior" value="1.9"/><rgb name="diffuse_reflectance" value="0.8, 0.5, 0.2"/></bsdf>',
    "twosided-diffuse": '<bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.6, 0.9"/></bsdf></bsdf>',
    "blendbsdf": '<bsdf type="blendbsdf"><float name="weight" value="0.3"/><bsdf type="diffuse"/><bsdf type="roughconductor"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/></bsdf></bsdf>',
}


def scene(bsdf):
    return f"""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="8"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, -3, 3" target="0, 0, 0" up="0, 0, 1"/></transform>
    <sampler type="independent"><integer name="sample_count" value="{SPP}"/></sampler>
    <film type="hdrfilm">
      <integer name="width" value="32"/><integer name="height" value="32"/>
      <rfilter type="box"/>
    </film>
  </sensor>
  <shape type="rectangle">
    <transform name="to_world"><scale value="100"/></transform>
    {bsdf}
  </shape>
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
</scene>
"""


def main():
    os.makedirs(os.path.join(HERE, "scenes"), exist_ok=True)
    rows = []
    for name, bsdf in CASES.items():
        path = os.path.join(HERE, "scenes", f"{name}.xml")
        with open(path, "w") as f:
            f.write(scene(bsdf))
        sc = mi.load_file(path)
        means = []
        for seed in range(SEEDS):
            img = np.array(mi.render(sc, seed=seed), dtype=np.float64)
            means.append([float(img[:, :, c].mean()) for c in range(3)])
        m = [sum(s[c] for s in means) / SEEDS for c in range(3)]
        var = [sum((s[c] - m[c]) ** 2 for s in means) / (SEEDS - 1) for c in range(3)]
        se = [(v / SEEDS) ** 0.5 for v in var]
        rows.append((name, m, se))
        print(name, m, se, file=sys.stderr)
    with open(os.path.join(HERE, "mitsuba3.csv"), "w") as f:
        f.write(f"# Mitsuba {mi.__version__} scalar_rgb, {SEEDS} seeds x {SPP} spp at 32x32: "
                "case,mean_r,mean_g,mean_b,se_r,se_g,se_b (written by measure.py)\n")
        for name, m, se in rows:
            f.write(",".join([name] + [f"{v:.7g}" for v in m + se]) + "\n")


if __name__ == "__main__":
    main()
