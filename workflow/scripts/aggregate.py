#!/usr/bin/python3
"""One row per sequence from each unroll output's summary.json: vkunroll aggregate OUT.csv SUMMARY..."""
import csv
import json
import os
import sys


def row(path):
    s = json.load(open(path))
    m = s.get("metrics") or {}
    return {
        "sequence": os.path.basename(os.path.dirname(path)),
        "layout": s.get("sequence", {}).get("layout"),
        "mode": s.get("mode"),
        "frames": s.get("frames"),
        "gs_frames": s.get("targets"),
        "gt_frames": m.get("count", 0),
        "mean_psnr": m.get("mean_psnr"),
        "mean_ssim": m.get("mean_ssim"),
        "rs_mean_psnr": m.get("rs_mean_psnr"),
        "rs_mean_ssim": m.get("rs_mean_ssim"),
        "ms_per_gs_frame": s.get("ms_per_gs_frame_total"),
        "events_in_windows": s.get("events", {}).get("in_frame_windows"),
        "warnings": len(s.get("warnings", [])),
        "device": s.get("device"),
        "git_revision": s.get("provenance", {}).get("git_revision"),
    }


def main(argv):
    if len(argv) < 3:
        sys.exit("usage: aggregate.py OUT.csv SUMMARY.json...")
    rows = [row(p) for p in argv[2:]]
    tmp = argv[1] + ".tmp"
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    os.replace(tmp, argv[1])


if __name__ == "__main__":
    main(sys.argv)
