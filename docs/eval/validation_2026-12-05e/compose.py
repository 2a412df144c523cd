#!/usr/bin/python3
"""The candidate of decision_rule.txt, composed from one tools/natural_eval.py --gate auto run with two
models, `base` (the shipped file) and `r0` (the same weights, metadata physics_gate 0): per row, r0's M
where the target lies inside the frame's exposure span and --gate-radius auto read the recording clean
(r0 then ran at 0, base at 1), base's M elsewhere. Prints M intra / inter per motion kind and over all.
Usage: compose.py EVAL.json..."""
import json
import sys
from collections import defaultdict


def main(paths):
    acc = defaultdict(lambda: defaultdict(list))  # group -> (part, method) -> psnr
    for p in paths:
        for r in json.load(open(p))["rows"]:
            part = "intra" if r["intra"] else "inter"
            clean = r["gate_radius"].get("r0") == 0
            cand = r["psnr"]["r0-M"] if (r["intra"] and clean) else r["psnr"]["base-M"]
            for g in ("all", "kind:" + r["kind"], "seq:" + r["sequence"]):
                acc[g][(part, "physics")].append(r["psnr"]["physics"])
                acc[g][(part, "shipped")].append(r["psnr"]["base-M"])
                acc[g][(part, "candidate")].append(cand)
                acc[g][(part, "read clean")].append(1.0 if clean else 0.0)
    print("| group | instants | physics | shipped M | candidate M | candidate - shipped | read clean |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for g in sorted(acc, key=lambda g: (g != "all", g)):
        d = acc[g]
        mean = {k: sum(v) / len(v) for k, v in d.items()}
        n = [len(d.get((p, "shipped"), [])) for p in ("intra", "inter")]
        cell = lambda m: " / ".join(f"{mean[(p, m)]:.2f}" if (p, m) in mean else "-" for p in ("intra", "inter"))
        diff = " / ".join(f"{mean[(p, 'candidate')] - mean[(p, 'shipped')]:+.2f}" if (p, "shipped") in mean else "-"
                          for p in ("intra", "inter"))
        print(f"| {g} | {n[0]} / {n[1]} | {cell('physics')} | {cell('shipped')} | {cell('candidate')} | {diff} | "
              f"{cell('read clean')} |")


if __name__ == "__main__":
    main(sys.argv[1:])
