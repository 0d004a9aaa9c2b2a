#!/usr/bin/env python3
"""Print the markdown quality table from the JSON reports written by scripts/quality.sh."""
import glob
import json
import os
import sys

folder = sys.argv[1] if len(sys.argv) > 1 else "results"
rows = {}
methods = ["nearest", "psv-mean", "optimize", "deepview"]
for path in sorted(glob.glob(os.path.join(folder, "*.json"))):
    name = os.path.basename(path)[:-5]
    parts = name.rsplit("_", 1)
    if len(parts) != 2 or parts[1] not in methods:
        continue
    with open(path) as f:
        r = json.load(f)
    key = parts[0]
    rows.setdefault(key, {})[parts[1]] = r["results"]
    planes = [v["planes"] for v in r.get("views", []) if v.get("planes")]
    if planes:
        rows[key]["planes"] = planes

print("| scene / protocol | views | planes | " + " | ".join(f"{m} SSIM / PSNR" for m in methods) + " |")
print("|---|---|---|" + "---|" * len(methods))
for key in sorted(rows):
    cells = []
    n = ""
    for m in methods:
        res = rows[key].get(m)
        if res is None:
            cells.append("-")
            continue
        n = res.get("num_views", n)
        psnr = res.get("psnr")
        cells.append(f"{res['ssim']:.4f} / {psnr:.2f}" if psnr is not None else f"{res['ssim']:.4f} / inf")
    planes = ", ".join(str(p) for p in rows[key].get("planes", [])) or "-"
    print(f"| {key.replace('_', ' ')} | {n} | {planes} | " + " | ".join(cells) + " |")
