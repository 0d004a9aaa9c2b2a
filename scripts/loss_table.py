#!/usr/bin/env python3
"""Training curve of a run as a Markdown table: mean and median loss per block of steps.

Usage: python3 scripts/loss_table.py runs/<name>/metrics.jsonl [BLOCK]   (BLOCK: steps per row, default 100)
"""
import json
import statistics
import sys


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    path = sys.argv[1]
    block = int(sys.argv[2]) if len(sys.argv) > 2 else 100
    rows = []
    with open(path) as f:
        for n, line in enumerate(f, 1):
            line = line.strip()
            if not line:
                continue
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError as e:
                sys.exit(f"{path}:{n}: not JSON ({e})")
    # A resumed run may repeat steps after its last checkpoint: keep the last record of each step.
    by_step = {r["step"]: r for r in rows if not r.get("skipped")}
    steps = sorted(by_step)
    if not steps:
        sys.exit(f"{path}: no steps")
    print("| steps | mean loss | median loss | wall time (s) |")
    print("|---|---|---|---|")
    for start in range(steps[0] - (steps[0] - 1) % block, steps[-1] + 1, block):
        chunk = [by_step[s] for s in steps if start <= s < start + block]
        if not chunk:
            continue
        losses = [r["loss"] for r in chunk]
        print(
            f"| {chunk[0]['step']}-{chunk[-1]['step']} | {statistics.mean(losses):.0f} | "
            f"{statistics.median(losses):.0f} | {chunk[-1]['wall_time_s']:.0f} |"
        )


if __name__ == "__main__":
    main()
