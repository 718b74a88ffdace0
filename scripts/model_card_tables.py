"""MODEL_CARD's held-out tables from ``hyperbones eval`` reports: the per-garment means of every
method, then the ratios against #28's bars (the runtime and Module A alone against the teacher,
inertia against LBS's).

Usage: ``python scripts/model_card_tables.py EVAL_DIR [EVAL_DIR ...]`` (each holding a
``report.json``; together they must have lbs, teacher, hyperbones and hyperbones-raw rows).
"""
import json, sys
from collections import defaultdict
G = ["tshirt", "tshirt-open", "pants", "long-skirt", "dress", "tight-dress"]
M = ["lbs", "teacher", "hyperbones-raw", "hyperbones"]
C = ["edge_error_pct", "area_error_pct", "collision_pct", "collision_1mm_pct", "detached_pct", "hem_area_cm2",
     "strain", "bending", "inertia", "gravity", "ms_median"]
runs = [r for d in sys.argv[1:] for r in json.load(open(f"{d}/report.json"))]
groups = defaultdict(list)
for r in runs:
    groups[(r["garment"], r["method"])].append(r)
mean = {k: {c: sum(r[c] for r in v) / len(v) for c in C} for k, v in groups.items()}
counts = {len(v) for v in groups.values()}
print(f"runs per row: {counts}; dtypes: {sorted({str(r.get('conv_mlp_dtype')) for r in runs})}; "
      f"uv: {sorted({str((r.get('runtime') or {}).get('uv_resolution')) for r in runs})}\n")
print("| garment | method | ε_e % | ε_a % | ε_c % (d<0) | ε_c % (d<1mm) | detached % | hem cm² | strain J | bending J | inertia J | gravity J | ms/frame |")
print("|---|---|" + "---:|" * len(C))
for g in G:
    for m in M:
        print(f"| {g} | {m} | " + " | ".join(f"{mean[(g, m)][c]:.4g}" for c in C) + " |")
t = lambda g, c: mean[(g, "teacher")][c]
def row(name, f, bar=None, digits=2):
    cells = []
    for g in G:
        v = f(g)
        ok = "" if bar is None else (" ✓" if bar(v) else " ✗")
        cells.append(f"{v:.{digits}f}{ok}")
    print(f"| {name} | " + " | ".join(cells) + " |")
print("\n| bar | " + " | ".join(G) + " |\n|---|" + "---:|" * len(G))
row("`hyperbones` ε_e ÷ teacher's (#28: ≤ 1.1)", lambda g: mean[(g, "hyperbones")]["edge_error_pct"] / t(g, "edge_error_pct"), lambda v: v <= 1.1)
row("`hyperbones` ε_a ÷ teacher's (#28: ≤ 1.1)", lambda g: mean[(g, "hyperbones")]["area_error_pct"] / t(g, "area_error_pct"), lambda v: v <= 1.1)
row("`hyperbones` ε_c (d<0) ÷ teacher's", lambda g: mean[(g, "hyperbones")]["collision_pct"] / t(g, "collision_pct"))
row("`hyperbones` inertia ÷ LBS's (< 1)", lambda g: mean[(g, "hyperbones")]["inertia"] / mean[(g, "lbs")]["inertia"], lambda v: v < 1, 4)
row("(the teacher's inertia ÷ LBS's)", lambda g: t(g, "inertia") / mean[(g, "lbs")]["inertia"], None, 3)
row("`hyperbones-raw` ε_e ÷ teacher's (#28: ≤ 1.5)", lambda g: mean[(g, "hyperbones-raw")]["edge_error_pct"] / t(g, "edge_error_pct"), lambda v: v <= 1.5)
row("`hyperbones-raw` ε_a ÷ teacher's (#28: ≤ 1.5)", lambda g: mean[(g, "hyperbones-raw")]["area_error_pct"] / t(g, "area_error_pct"), lambda v: v <= 1.5)
row("`hyperbones` ε_c (d<0) % (#28: < 0.1)", lambda g: mean[(g, "hyperbones")]["collision_pct"], lambda v: v < 0.1, 3)
print("| `hyperbones` detached % (teacher's) (#28: ≤) | " + " | ".join(
    f"{mean[(g, 'hyperbones')]['detached_pct']:.2f} ({t(g, 'detached_pct'):.2f}) "
    + ("✓" if mean[(g, 'hyperbones')]['detached_pct'] <= t(g, 'detached_pct') else "✗") for g in G) + " |")
row("hem ÷ teacher's", lambda g: mean[(g, "hyperbones")]["hem_area_cm2"] / t(g, "hem_area_cm2"))
