#!/usr/bin/env python3
"""Summarize `evaluate --json` lines (one file per workload) as a markdown table: per scene, the selection, the
oracle's best per workload, and the selection's regret. Usage: oracle_table.py primary.jsonl [shadow.jsonl ...]"""
import json
import os
import sys

if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
    print(__doc__)
    sys.exit(0 if len(sys.argv) >= 2 else 2)

runs = []
for path in sys.argv[1:]:
    rows = {}
    wl = None
    for line in open(path):
        d = json.loads(line)
        wl = d.get("workload", os.path.basename(path))
        rows[d["mesh"]] = d
    runs.append((wl, rows))

scenes = list(runs[0][1].keys())
head = "| scene | triangles | selected (thesis) |" + "".join(f" {w}: best, regret |" for w, _ in runs)
print(head)
print("|---|---:|---|" + "---|" * len(runs))
regrets = {w: [] for w, _ in runs}
hits = {w: 0 for w, _ in runs}
for m in scenes:
    d0 = runs[0][1][m]
    name = os.path.basename(m.rstrip("/"))
    cells = []
    for w, rows in runs:
        d = rows.get(m)
        if d is None:
            cells.append(" - |")
            continue
        noise = " (within noise)" if d.get("regret_within_noise") else ""
        cells.append(f" {d['oracle_best']}, {d['regret']:.2f}{noise} |")
        regrets[w].append(d["regret"])
        hits[w] += d["selected"] == d["oracle_best"] or bool(d.get("regret_within_noise"))
    print(f"| {name} | {d0['triangles']:,} | {d0['selected']} |" + "".join(cells))
print()
for w, r in regrets.items():
    if r:
        print(f"- {w}: selection right (or within noise) on {hits[w]} of {len(r)} scenes; mean regret "
              f"{sum(r) / len(r):.2f}, worst {max(r):.2f}")
