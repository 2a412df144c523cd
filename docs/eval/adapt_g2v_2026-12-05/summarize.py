#!/usr/bin/python3
"""Scratch: the adaptation runs of tools/adapt_heldout.sh on the second generator's validation suite,
one row per sequence (M, PSNR dB inside / between frames: physics, the input model, 4 and 8 minutes),
the guard's export (tools/train.py's "[adapt] exported" line), and the means over the rows' instants.
Arguments: the runs' folders (each with eval.json and adapt.log)."""
import json
import os
import re
import sys

tags = ("physics", "base-M", "adapt4-M", "adapt8-M")
tot = {p: {t: [0.0, 0] for t in tags} for p in ("intra", "inter")}
print("| sequence | physics | input model | adapted 4 min | adapted 8 min | 8 min - input | guard's export |")
print("| --- | --- | --- | --- | --- | --- | --- |")
for run in sys.argv[1:]:
    s = json.load(open(os.path.join(run, "eval.json")))["summary"]["all"]
    m = re.findall(r"\[adapt\] exported (step \d+: held-out loss [0-9.]+ \(input model [0-9.]+\))",
                   open(os.path.join(run, "adapt.log")).read())
    cells = []
    for t in tags:
        cells.append(" / ".join(f"{s[p][t]['psnr']:.2f}" for p in ("intra", "inter")))
        for p in ("intra", "inter"):
            tot[p][t][0] += s[p][t]["psnr"] * s[p][t]["n"]
            tot[p][t][1] += s[p][t]["n"]
    gain = " / ".join(f"{s[p]['adapt8-M']['psnr'] - s[p]['base-M']['psnr']:+.2f}" for p in ("intra", "inter"))
    print(f"| {os.path.basename(run.rstrip('/')).replace('adapt_g2v_', '')} | " + " | ".join(cells)
          + f" | {gain} | {m[-1] if m else '?'} |")
mean = {p: {t: v[0] / v[1] for t, v in d.items()} for p, d in tot.items()}
print("| all (mean over instants) | " + " | ".join(" / ".join(f"{mean[p][t]:.2f}" for p in ("intra", "inter")) for t in tags)
      + " | " + " / ".join(f"{mean[p]['adapt8-M'] - mean[p]['base-M']:+.2f}" for p in ("intra", "inter")) + " | |")
