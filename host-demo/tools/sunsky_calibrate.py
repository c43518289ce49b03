"""Calibration of host-demo's `sunsky` approximation against Mitsuba 3's `sunsky` emitter.

Prints the Rust tables of host-demo/src/sunsky.rs (`SUN_EXTRATERRESTRIAL` and
`SKY_CORRECTION`): run `python3 host-demo/tools/sunsky_calibrate.py` with Mitsuba 3 installed
(`pip install mitsuba`, tested with 3.9.1), and paste its output over the tables.

* Sun: the Preetham transmittance model (as in sunsky.rs) is scaled per channel so that the
  sun's irradiance (radiance x solid angle) at turbidity 3 in the zenith equals Mitsuba 3's.
* Sky: the Preetham sky (as in sunsky.rs) is scaled per channel by
  E_mitsuba3 / E_preetham, the ratio of the horizontal sky irradiances (midpoint quadrature,
  90 x 120 cells over the upper hemisphere), tabulated at the turbidity and sun elevation
  nodes below for ground albedo 0 and 1.
"""
import math

import mitsuba as mi

mi.set_variant("scalar_rgb")

T_NODES = [1, 1.5, 2, 3, 4, 5, 6, 7, 8, 9, 10]
EL_NODES = [0.5, 1, 2, 3, 5, 7, 10, 15, 20, 30, 45, 60, 75, 90]
M3_APERTURE = 0.5338  # degrees, Mitsuba 3's default sun diameter
OUR_RADIUS = 0.5358 / 2  # degrees, Mitsuba 0.6's sun radius
WAVELENGTHS = (0.65, 0.57, 0.475)  # um
OZONE = (0.067, 0.12, 0.012)  # k_o per cm (Preetham et al. 1999, table 3)
T_SKY_MIN = 1.7


def perez(cos_t, g, a, b, c, d, e):
    return (1 + a * math.exp(b / max(cos_t, 1e-4))) * (1 + c * math.exp(d * g) + e * math.cos(g) ** 2)


def preetham_sky(T, ts, cos_t, g):
    T = max(T, T_SKY_MIN)
    cy = (0.1787 * T - 1.4630, -0.3554 * T + 0.4275, -0.0227 * T + 5.3251, 0.1206 * T - 2.5771, -0.0670 * T + 0.3703)
    cx = (-0.0193 * T - 0.2592, -0.0665 * T + 0.0008, -0.0004 * T + 0.2125, -0.0641 * T - 0.8989, -0.0033 * T + 0.0452)
    cyy = (-0.0167 * T - 0.2608, -0.0950 * T + 0.0092, -0.0079 * T + 0.2102, -0.0441 * T - 1.6537, -0.0109 * T + 0.0529)
    chi = (4 / 9 - T / 120) * (math.pi - 2 * ts)
    yz_lum = (4.0453 * T - 4.9710) * math.tan(chi) - 0.2155 * T + 2.4192
    p = (ts ** 3, ts ** 2, ts, 1)
    xz = sum(a * b for a, b in zip((0.00166 * T * T - 0.02903 * T + 0.11693, -0.00375 * T * T + 0.06377 * T - 0.21196,
                                    0.00209 * T * T - 0.03202 * T + 0.06052, 0.00394 * T + 0.25886), p))
    yz = sum(a * b for a, b in zip((0.00275 * T * T - 0.04214 * T + 0.15346, -0.00610 * T * T + 0.08970 * T - 0.26756,
                                    0.00317 * T * T - 0.04153 * T + 0.06670, 0.00516 * T + 0.26688), p))
    lum = yz_lum * perez(cos_t, g, *cy) / perez(1.0, ts, *cy)
    x = xz * perez(cos_t, g, *cx) / perez(1.0, ts, *cx)
    y = yz * perez(cos_t, g, *cyy) / perez(1.0, ts, *cyy)
    X, Z = x * lum / y, (1 - x - y) * lum / y
    rgb = (3.2404542 * X - 1.5371385 * lum - 0.4985314 * Z,
           -0.9692660 * X + 1.8760108 * lum + 0.0415560 * Z,
           0.0556434 * X - 0.2040259 * lum + 1.0572252 * Z)
    return [max(0.0, v) for v in rgb]


def air_mass(ts):
    ts = min(ts, math.pi / 2)
    return 1.0 / (math.cos(ts) + 0.15 * (93.885 - math.degrees(ts)) ** -1.253)


def transmittance(T, ts, c):
    lam = WAVELENGTHS[c]
    beta = 0.04608 * T - 0.04586
    m = air_mass(ts)
    return math.exp(-m * (0.008735 * lam ** -4.08 + beta * lam ** -1.3 + 0.35 * OZONE[c]))


def m3_eval(e, d):
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(-d[0], -d[1], -d[2])
    return list(e.eval(si))


def cone(r_deg):
    return 2 * math.pi * (1 - math.cos(math.radians(r_deg)))


def main():
    e = mi.load_dict({"type": "sunsky", "sun_direction": [0, 0, 1], "turbidity": 3})
    l_m3 = m3_eval(e, (0, 0, 1))
    ratio = cone(M3_APERTURE / 2) / cone(OUR_RADIUS)
    l0 = [l_m3[c] * ratio / transmittance(3, 0.0, c) for c in range(3)]
    print("const SUN_EXTRATERRESTRIAL: [f32; 3] = [%.1f, %.1f, %.1f];" % tuple(l0))
    nt, nphi = 90, 120
    rows = []
    for albedo in (0.0, 1.0):
        for T in T_NODES:
            row = []
            for el in EL_NODES:
                ts = math.radians(90 - el)
                s = (math.sin(ts), 0, math.cos(ts))
                em = mi.load_dict({"type": "sunsky", "sun_direction": list(s), "turbidity": T,
                                   "sun_scale": 0, "albedo": albedo})
                e_m3, e_ours = [0.0] * 3, [0.0] * 3
                for i in range(nt):
                    a = (i + 0.5) / nt * math.pi / 2
                    w = math.sin(a) * math.cos(a) * (math.pi / 2 / nt) * (2 * math.pi / nphi)
                    for j in range(nphi):
                        b = (j + 0.5) / nphi * 2 * math.pi
                        d = (math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a))
                        lm = m3_eval(em, d)
                        g = math.acos(max(-1.0, min(1.0, d[0] * s[0] + d[2] * s[2])))
                        lo = preetham_sky(T, ts, math.cos(a), g)
                        for c in range(3):
                            e_m3[c] += w * lm[c]
                            e_ours[c] += w * lo[c]
                row.append([e_m3[c] / e_ours[c] for c in range(3)])
            rows.append(row)
    print("#[rustfmt::skip]")
    print("const SKY_CORRECTION: [[[[f32; 3]; %d]; %d]; 2] = [" % (len(EL_NODES), len(T_NODES)))
    for k, albedo in enumerate((0.0, 1.0)):
        print("    // albedo %g" % albedo)
        print("    [")
        for ti, T in enumerate(T_NODES):
            cells = ", ".join("[%.5f, %.5f, %.5f]" % tuple(v) for v in rows[k * len(T_NODES) + ti])
            print("        [%s], // T = %g" % (cells, T))
        print("    ],")
    print("];")


if __name__ == "__main__":
    main()
