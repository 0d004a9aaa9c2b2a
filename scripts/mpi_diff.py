#!/usr/bin/env python3
"""Largest difference between two MPI folders' layers (8-bit units) and the share of texels that differ:
of the stored (straight-alpha) values, of alpha, and of the premultiplied colour (what renders see; the
straight colour of a nearly transparent texel is ill-conditioned).

    /usr/bin/python3 scripts/mpi_diff.py mpi_a mpi_b
"""
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

a, b = Path(sys.argv[1]), Path(sys.argv[2])
ma, mb = json.loads((a / "mpi.json").read_text()), json.loads((b / "mpi.json").read_text())
layers = sorted(p.name for p in a.glob("layer_*.png"))
assert layers == sorted(p.name for p in b.glob("layer_*.png")), "different layer files"
worst, differ, total, alpha, premult = 0, 0, 0, 0, 0.0
for name in layers:
    x = np.asarray(Image.open(a / name).convert("RGBA"), dtype=np.float64)
    y = np.asarray(Image.open(b / name).convert("RGBA"), dtype=np.float64)
    d = np.abs(x - y)
    worst = max(worst, int(round(d.max())))
    differ += int((d > 0).sum())
    total += d.size
    alpha = max(alpha, int(d[..., 3].max()))
    px = x[..., :3] * x[..., 3:4] / 255.0
    py = y[..., :3] * y[..., 3:4] / 255.0
    premult = max(premult, float(np.abs(px - py).max()))
print(json.dumps({"layers": len(layers), "max_abs_diff_8bit": worst, "differing_share": differ / total,
                  "max_alpha_diff_8bit": alpha, "max_premultiplied_diff_8bit": round(premult, 3),
                  "same_depths": ma.get("depths") == mb.get("depths")}))
