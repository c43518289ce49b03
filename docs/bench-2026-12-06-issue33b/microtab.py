import csv, sys, statistics
def load(paths):
    rows = {}
    order = []
    for p in paths:
        for r in csv.DictReader(open(p)):
            k = (r['group'], r['name'], r['unit'])
            if k not in rows:
                rows[k] = []; order.append(k)
            rows[k].append(float(r['value']))
    return rows, order
b, order = load(sys.argv[1].split(','))
a, _ = load(sys.argv[2].split(','))
fmt = lambda x: f"{x:.4g}"
print("| micro-benchmark | unit | before (min–max) | after (min–max) | median after/before |")
print("|---|---|---|---|---|")
for k in order:
    if k not in a: continue
    vb, va = b[k], a[k]
    print(f"| {k[0]}: {k[1]} | {k[2]} | {fmt(min(vb))}–{fmt(max(vb))} | {fmt(min(va))}–{fmt(max(va))} | {statistics.median(va)/statistics.median(vb):.3f} |")
