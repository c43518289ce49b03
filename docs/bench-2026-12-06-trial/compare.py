#!/usr/bin/env python3
"""Before/after table of `host-demo bench --suite` runs: per scene the `guided` / `pt-nee`
relMSE ratio (means over seeds first, as suite.md forms it), the per-seed ratios, guided spp
over pt-nee's, and what each guided run's efficiency trial did (from its --stats JSON).

usage: compare.py LABEL=DIR [LABEL=DIR ...]   (DIR holds runs.csv and runs/)
"""
import csv, json, math, os, sys
from collections import defaultdict


def load(d):
    rows = list(csv.DictReader(open(os.path.join(d, "runs.csv"))))
    by = defaultdict(dict)
    for r in rows:
        name = os.path.basename(os.path.dirname(r["scene"])) if r["scene"].endswith(".xml") else r["scene"].split(":")[-1]
        by[name].setdefault(r["method"], {})[int(r["seed"])] = r
    return by


def trial(d, scene, seed):
    f = os.path.join(d, "runs", f"{scene}-guided-time_s30-s{seed}.json")
    try:
        t = json.load(open(f))["stages"]["efficiency_trial"]
    except (OSError, KeyError):
        return "?"
    if not t.get("ran"):
        return "off"
    if t.get("finished"):
        lo, hi = t["cost_ratio_interval"]
        at = f"{t['guided_passes']}+{t['unguided_passes']}" if "guided_passes" in t else f"{t['passes']} passes"
        return f"{t['evidence']} at {at} {t['cost_ratio']:.2f} [{lo:.2f}, {hi:.2f}]"
    l = t.get("latest") or {}
    if l:
        lo, hi = l["cost_ratio_interval"]
        return f"open at {l['guided_passes']}+{l['unguided_passes']} {l['cost_ratio']:.2f} [{lo:.2f}, {hi:.2f}]"
    return f"open ({t['passes']} passes)"


runs = [(a.split("=", 1)[0], a.split("=", 1)[1]) for a in sys.argv[1:]]
data = [(label, d, load(d)) for label, d in runs]
scenes = list(data[0][2].keys())
print("| scene | " + " | ".join(f"`guided` {l} (per seed; spp)" for l, _, _ in data) + " |")
print("|---|" + "---|" * len(data))
geo = defaultdict(list)
for s in scenes:
    cells = []
    for label, d, by in data:
        g, p = by[s].get("guided", {}), by[s].get("pt-nee", {})
        seeds = sorted(set(g) & set(p))
        mean = lambda m, k: sum(float(m[i][k]) for i in seeds) / len(seeds)
        ratio = mean(g, "relmse") / mean(p, "relmse")
        spp = mean(g, "spp") / mean(p, "spp")
        geo[label].append(ratio)
        per = ", ".join(f"{float(g[i]['relmse']) / float(p[i]['relmse']):.2f}" for i in seeds)
        cells.append(f"{ratio:.3f}× ({per}; {spp:.2f}×)")
    print(f"| {s} | " + " | ".join(cells) + " |")
print("| **geometric mean** | " + " | ".join(
    f"**{math.exp(sum(map(math.log, geo[l])) / len(geo[l])):.3f}×**" for l, _, _ in data) + " |")
print()
for label, d, by in data:
    print(f"Trials, {label}:")
    for s in scenes:
        print(f"- {s}: " + "; ".join(trial(d, s, i) for i in sorted(by[s].get("guided", {}))))
    print()
