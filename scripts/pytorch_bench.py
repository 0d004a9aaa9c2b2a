#!/usr/bin/env python3
"""PyTorch CPU reference for `deepview bench net` / `bench train`: the same core nets (the `cpu`
preset: 2 nets, 8 features, 1 max-pool stage, 8 state channels; or the paper's 64/16 nets, with the
one-level U-Net of `paper-spaces-4view`'s first two nets) alone, on the same shapes, 2 threads. Prints one JSON line per measurement.

    /usr/bin/python3 scripts/pytorch_bench.py --preset cpu --views 4 --planes 32 --size 575x412
    /usr/bin/python3 scripts/pytorch_bench.py --preset cpu --views 4 --planes 32 --train-crop 16
    /usr/bin/python3 scripts/pytorch_bench.py --preset paper-spaces-4view --views 4 --planes 8 --size 575x412

(Debian's `python3-torch`, a CPU build: `apt-get install python3-torch`.)
"""
import argparse
import json
import time

import torch
import torch.nn as nn
import torch.nn.functional as F


class CoreNet(nn.Module):
    """network.rs's CoreNet: 2 per-view convs, stages x (max over views, concat, 2 convs), max,
    head conv ELU, linear out conv. `unet`: network.rs's one-level U-Net (2x2 average pool with the
    odd row/column padded, the core at half resolution, bilinear upsampling back, cropped)."""

    def __init__(self, cin, f, out, stages, unet=False):
        super().__init__()
        self.unet = unet
        conv = lambda i, o: nn.Conv2d(i, o, 3, padding=1)
        self.inp = nn.ModuleList([conv(cin, f), conv(f, f)])
        self.stages = nn.ModuleList([conv(2 * f if i % 2 == 0 else f, f) for i in range(2 * stages)])
        self.head = conv(f, f)
        self.out = conv(f, out)

    def forward(self, x, views):
        if not self.unet:
            return self.core(x, views)
        h, w = x.shape[2:]
        x = F.avg_pool2d(F.pad(x, (0, w % 2, 0, h % 2)), 2)
        o = self.core(x, views)
        o = F.interpolate(o, size=(2 * o.shape[2], 2 * o.shape[3]), mode="bilinear", align_corners=False)
        return o[:, :, :h, :w]

    def core(self, x, views):
        kd, _, h, w = x.shape
        d = kd // views
        f = x
        for c in self.inp:
            f = F.elu(c(f))
        for i in range(0, len(self.stages), 2):
            fc = f.shape[1]
            m = f.reshape(views, d, fc, h, w).amax(0)
            f = torch.cat([f, m.unsqueeze(0).expand(views, d, fc, h, w).reshape(kd, fc, h, w)], 1)
            f = F.elu(self.stages[i](f))
            f = F.elu(self.stages[i + 1](f))
        m = f.reshape(views, d, f.shape[1], h, w).amax(0)
        return self.out(F.elu(self.head(m)))


def nets(preset):
    # (input channels, features, stages, U-Net) per net; state channels 8; update nets see 11 + 8
    # channels (config.rs's presets).
    if preset == "cpu":
        return [(4, 8, 1, False), (19, 8, 1, False)]
    if preset == "cpu-large":
        return [(4, 12, 1, False), (19, 12, 1, False), (19, 12, 1, False)]
    if preset == "paper-kalantari":
        return [(4, 64, 3, False), (19, 64, 3, False), (19, 16, 3, False), (19, 16, 3, False)]
    if preset in ("paper-spaces-4view", "paper-spaces-12view"):
        return [(4, 64, 3, True), (19, 64, 3, True), (19, 16, 3, False), (19, 16, 3, False)]
    raise SystemExit(f"unknown preset {preset}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="cpu")
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--planes", type=int, default=32)
    ap.add_argument("--size", default="575x412")
    ap.add_argument("--train-crop", type=int, default=0, help="forward+backward on training windows")
    ap.add_argument("--channels-last", action="store_true")
    ap.add_argument("--repeats", type=int, default=1)
    a = ap.parse_args()
    torch.set_num_threads(2)
    torch.manual_seed(0)
    k, d = a.views, a.planes
    specs = nets(a.preset)
    models = [CoreNet(cin, f, 8, s, u) for cin, f, s, u in specs]
    fmt = torch.channels_last if a.channels_last else torch.contiguous_format
    models = [m.to(memory_format=fmt) for m in models]
    if a.train_crop:
        # The training windows: the crop grown by each later net's margin (6 px a side per cpu net).
        # network.rs's margin: r = 2 + 2 * stages + 2 per net (2 * r + 4 with the U-Net), even.
        margins = [(2 * r + 4 if u else r) for r, u in ((2 + 2 * s + 2, u) for _, _, s, u in specs)]
        margins = [m + (m % 2) for m in margins]
        sides = [a.train_crop + 2 * sum(margins[n:]) for n in range(len(specs))]
        xs = [torch.rand(k * d, cin, s, s).to(memory_format=fmt).requires_grad_(n > 0)
              for n, ((cin, _, _, _), s) in enumerate(zip(specs, sides))]
        times = []
        for r in range(a.repeats + 2):
            t = time.perf_counter()
            loss = sum(m(x, k).square().mean() for m, x in zip(models, xs))
            loss.backward()
            if r >= 2:
                times.append(time.perf_counter() - t)
        times.sort()
        print(json.dumps({"torch": torch.__version__, "threads": torch.get_num_threads(),
                          "preset": a.preset, "views": k, "planes": d, "windows": sides,
                          "channels_last": a.channels_last,
                          "nets_forward_backward_s": round(times[len(times) // 2], 4)}))
        return
    w, h = (int(v) for v in a.size.split("x"))
    times = []
    with torch.no_grad():
        for r in range(a.repeats):
            total = 0.0
            for m, (cin, _, _, _) in zip(models, specs):
                x = torch.rand(k * d, cin, h, w).to(memory_format=fmt)
                t = time.perf_counter()
                m(x, k)
                total += time.perf_counter() - t
                del x
            times.append(total)
    times.sort()
    print(json.dumps({"torch": torch.__version__, "threads": torch.get_num_threads(),
                      "preset": a.preset, "views": k, "planes": d, "width": w, "height": h,
                      "channels_last": a.channels_last,
                      "nets_forward_s": round(times[len(times) // 2], 3)}))


if __name__ == "__main__":
    main()
