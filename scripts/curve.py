#!/usr/bin/env python3
"""Training curves as an SVG chart: the validation set's mean SSIM per step (`train --validate-every`'s
runs/NAME/validation.jsonl), one panel per protocol (4 nearest inputs, 3 spread inputs), one line per run,
and dashed reference levels (e.g. the shipped weights or `psv-mean` scored on the same validation set).

Usage:
  python3 scripts/curve.py --out docs/training_curve.svg \
      --run gen45=runs/gen45/validation.jsonl --run gen48=runs/gen48/validation.jsonl \
      --level "shipped=0.8755,0.7388" --level "psv-mean=0.70,0.55"

A run's steps are shifted with `NAME@OFFSET=PATH` (e.g. a run resumed from another's checkpoint). Only
steps where every scene of the run's first validation was scored count (a validation cut short by a stop
is left out). Needs only the Python standard library.
"""

import argparse
import collections
import json
import sys

PROTOCOLS = [("nearest:4", "4 nearest inputs"), ("spread:3", "3 spread inputs")]
COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf"]


def load(path):
    """Mean SSIM per (step, protocol) over the scenes, for complete validations only."""
    by = collections.defaultdict(dict)
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            r = json.loads(line)
            by[(r["step"], r["protocol"])][r["scene"]] = r["ssim"]
    if not by:
        sys.exit(f"{path}: no validation rows")
    first = min(s for s, _ in by)
    scenes = {p: set(by[(first, p)]) for p, _ in PROTOCOLS if (first, p) in by}
    out = {p: [] for p, _ in PROTOCOLS}
    for (step, p), v in sorted(by.items()):
        if p in scenes and set(v) == scenes[p]:
            out[p].append((step, sum(v.values()) / len(v)))
    return out


def ticks_for(lo, hi, n=5):
    """Round tick values covering [lo, hi]."""
    span = hi - lo if hi > lo else 1.0
    step = 10 ** int(f"{span / n:e}".split("e")[1])
    for m in (1, 2, 5, 10):
        if span / (m * step) <= n:
            step *= m
            break
    first = step * int(lo / step)
    if first < lo - 1e-12:
        first += step
    ticks = []
    t = first
    while t <= hi + 1e-9 * step:
        ticks.append(t)
        t += step
    return ticks, step


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", action="append", default=[], help="NAME[@OFFSET]=validation.jsonl")
    ap.add_argument("--level", action="append", default=[], help="NAME=SSIM_4NEAREST,SSIM_3SPREAD")
    ap.add_argument("--title", default="Validation SSIM (held-out views of the training scenes)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    runs = []
    for spec in a.run:
        name, _, path = spec.partition("=")
        name, _, off = name.partition("@")
        data = load(path)
        off = int(off or 0)
        runs.append((name, {p: [(s + off, v) for s, v in pts] for p, pts in data.items()}))
    levels = []
    for spec in a.level:
        name, _, vals = spec.partition("=")
        v = [float(x) for x in vals.split(",")]
        if len(v) != 2:
            sys.exit(f"--level {spec}: give two values (4 nearest, 3 spread)")
        levels.append((name, v))
    if not runs:
        sys.exit("give at least one --run")

    pw, ph, ml, mr, mt, mb, gap = 430, 300, 62, 16, 46, 48, 40
    width = ml + 2 * pw + gap + mr + 60
    height = mt + ph + mb + 22 * ((len(runs) + len(levels) + 2) // 3) + 10
    svg = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'font-family="sans-serif" font-size="12">',
        f'<rect width="{width}" height="{height}" fill="white"/>',
        f'<text x="{width / 2}" y="18" text-anchor="middle" font-size="14">{a.title}</text>',
    ]
    xmax = max(s for _, d in runs for pts in d.values() for s, _ in pts) or 1
    for k, (proto, label) in enumerate(PROTOCOLS):
        x0 = ml + k * (pw + gap)
        vals = [v for _, d in runs for _, v in d[proto]] + [lv[k] for _, lv in levels]
        lo, hi = min(vals), max(vals)
        pad = max((hi - lo) * 0.08, 0.001)
        lo, hi = lo - pad, hi + pad
        X = lambda s: x0 + pw * s / xmax  # noqa: E731
        Y = lambda v: mt + ph * (1 - (v - lo) / (hi - lo))  # noqa: E731
        svg.append(f'<text x="{x0 + pw / 2}" y="{mt - 10}" text-anchor="middle">{label}</text>')
        svg.append(f'<rect x="{x0}" y="{mt}" width="{pw}" height="{ph}" fill="none" stroke="#444"/>')
        yt, ys = ticks_for(lo, hi)
        digits = max(0, -int(f"{ys:e}".split("e")[1]))
        for t in yt:
            svg.append(f'<line x1="{x0}" x2="{x0 + pw}" y1="{Y(t):.1f}" y2="{Y(t):.1f}" stroke="#ddd"/>')
            svg.append(f'<text x="{x0 - 4}" y="{Y(t) + 4:.1f}" text-anchor="end">{t:.{digits}f}</text>')
        xt, _ = ticks_for(0, xmax)
        for t in xt:
            svg.append(f'<text x="{X(t):.1f}" y="{mt + ph + 16}" text-anchor="middle">{int(t)}</text>')
        svg.append(f'<text x="{x0 + pw / 2}" y="{mt + ph + 34}" text-anchor="middle">training step</text>')
        if k == 0:
            svg.append(
                f'<text x="14" y="{mt + ph / 2}" text-anchor="middle" '
                f'transform="rotate(-90 14 {mt + ph / 2})">mean SSIM</text>'
            )
        for j, (name, lv) in enumerate(levels):
            c = "#555" if j == 0 else "#999"
            dash = "6,4" if j % 2 == 0 else "2,3"
            svg.append(
                f'<line x1="{x0}" x2="{x0 + pw}" y1="{Y(lv[k]):.1f}" y2="{Y(lv[k]):.1f}" '
                f'stroke="{c}" stroke-dasharray="{dash}"/>'
            )
        for i, (name, d) in enumerate(runs):
            pts = d[proto]
            if not pts:
                continue
            c = COLOURS[i % len(COLOURS)]
            path = " ".join(f"{X(s):.1f},{Y(v):.1f}" for s, v in pts)
            svg.append(f'<polyline points="{path}" fill="none" stroke="{c}" stroke-width="1.8"/>')
            for s, v in pts:
                svg.append(f'<circle cx="{X(s):.1f}" cy="{Y(v):.1f}" r="2.2" fill="{c}"/>')
    # Legend
    items = [(n, COLOURS[i % len(COLOURS)], None) for i, (n, _) in enumerate(runs)]
    items += [(n, "#555" if j == 0 else "#999", "6,4" if j % 2 == 0 else "2,3") for j, (n, _) in enumerate(levels)]
    ly = mt + ph + mb + 8
    for i, (n, c, dash) in enumerate(items):
        x = ml + (i % 3) * 300
        y = ly + 22 * (i // 3)
        d = f' stroke-dasharray="{dash}"' if dash else ""
        svg.append(f'<line x1="{x}" x2="{x + 28}" y1="{y}" y2="{y}" stroke="{c}" stroke-width="2"{d}/>')
        svg.append(f'<text x="{x + 34}" y="{y + 4}">{n}</text>')
    svg.append("</svg>")
    with open(a.out, "w") as f:
        f.write("\n".join(svg) + "\n")
    print(f"wrote {a.out}: {len(runs)} run(s), {len(levels)} level(s)")


if __name__ == "__main__":
    main()
