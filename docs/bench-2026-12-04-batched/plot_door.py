#!/usr/bin/env python3
"""The door's relMSE against time over both budgets of this run (door-20s and
door-60s were separate `host-demo bench` runs, so each report plots one
budget). Python standard library only; writes door-relmse-time.svg next to
this file: `python3 docs/bench-2026-12-04-batched/plot_door.py`."""
import csv
import math
import os
import statistics

HERE = os.path.dirname(os.path.abspath(__file__))
METHODS = [
    ("pt", "#d62728"),
    ("pt-nee", "#2ca02c"),
    ("npm-radiance", "#e6b800"),
    ("npm-radiance-nonee", "#1f77b4"),
]
W, H, L, R, T, B = 640, 420, 70, 190, 40, 50


def load():
    """(method, budget) -> (mean wall s, mean relMSE, sd relMSE)."""
    runs = {}
    for d in ("door-20s", "door-60s"):
        with open(os.path.join(HERE, d, "runs.csv")) as f:
            for r in csv.DictReader(f):
                key = (r["method"], float(r["budget"]))
                runs.setdefault(key, []).append((float(r["wall_s"]), float(r["relmse"])))
    out = {}
    for key, rs in runs.items():
        rel = [v for _, v in rs]
        out[key] = (statistics.mean(t for t, _ in rs), statistics.mean(rel), statistics.stdev(rel))
    return out


def main():
    data = load()
    xs = [t for t, _, _ in data.values()]
    ys = [m for _, m, _ in data.values()]
    x0, x1 = math.log10(min(xs) / 1.5), math.log10(max(xs) * 1.5)
    y0, y1 = math.floor(math.log10(min(ys))), math.ceil(math.log10(max(ys)))

    def px(t):
        return L + (math.log10(t) - x0) / (x1 - x0) * (W - L - R)

    def py(v):
        return T + (y1 - math.log10(v)) / (y1 - y0) * (H - T - B)

    s = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="DejaVu Sans, sans-serif" font-size="12">',
         f'<rect width="{W}" height="{H}" fill="white"/>',
         f'<text x="{W / 2}" y="22" font-size="15" text-anchor="middle">builtin:door: relMSE against time (3 seeds, 320 px)</text>']
    for e in range(y0, y1 + 1):
        y = py(10.0 ** e)
        s.append(f'<line x1="{L}" x2="{W - R}" y1="{y:.1f}" y2="{y:.1f}" stroke="#ccc"/>')
        s.append(f'<text x="{L - 8}" y="{y + 4:.1f}" text-anchor="end">1e{e}</text>')
    for t in (20, 30, 40, 60):
        x = px(t)
        s.append(f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{T}" y2="{H - B}" stroke="#eee"/>')
        s.append(f'<text x="{x:.1f}" y="{H - B + 16}" text-anchor="middle">{t}</text>')
    s.append(f'<text x="{(L + W - R) / 2:.1f}" y="{H - 12}" text-anchor="middle">wall time [s]</text>')
    s.append(f'<text x="16" y="{(T + H - B) / 2:.1f}" transform="rotate(-90 16 {(T + H - B) / 2:.1f})" text-anchor="middle">relMSE (trimmed 0.1 %)</text>')
    for i, (m, colour) in enumerate(METHODS):
        pts = sorted((t, v, sd) for (mm, _), (t, v, sd) in data.items() if mm == m)
        path = " ".join(f"{px(t):.1f},{py(v):.1f}" for t, v, _ in pts)
        s.append(f'<polyline points="{path}" fill="none" stroke="{colour}" stroke-width="2"/>')
        for t, v, sd in pts:
            lo, hi = max(v - sd, v * 0.5), v + sd
            s.append(f'<line x1="{px(t):.1f}" x2="{px(t):.1f}" y1="{py(lo):.1f}" y2="{py(hi):.1f}" stroke="{colour}"/>')
            s.append(f'<circle cx="{px(t):.1f}" cy="{py(v):.1f}" r="3.5" fill="{colour}"/>')
        ly = T + 10 + 20 * i
        s.append(f'<line x1="{W - R + 15}" x2="{W - R + 35}" y1="{ly}" y2="{ly}" stroke="{colour}" stroke-width="3"/>')
        s.append(f'<text x="{W - R + 40}" y="{ly + 4}">{m}</text>')
    s.append("</svg>")
    with open(os.path.join(HERE, "door-relmse-time.svg"), "w") as f:
        f.write("\n".join(s) + "\n")


if __name__ == "__main__":
    main()
