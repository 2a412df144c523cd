"""Each sequence's event gate radius as `vkunroll unroll --gate-radius auto` picks it (from the noise
its `--mode physics` contrast estimate measures), for `tools/train/train.py --gate-radii FILE`: a gated
variant then trains each recording at the radius it will run at.

  gate_radii.py --cli build/vkunroll --out runs/r/gate_radii.json --model-radius 1 data/natural/train/nat_*

The file maps each absolute sequence folder to {"radius", "frame_noise", "isolated_event_fraction",
"contrast"}; folders already in it are kept (a second call adds the rest).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

from tools.eval.natural_eval import auto_gate_radius  # the CLI's rule, its constants in one place


def measure(cli: str, folder: str, work: str, model_radius: int) -> dict:
    out = os.path.join(work, "physics")
    cmd = [cli, "unroll", folder, "--out", out, "--mode", "physics", "--no-video", "--quiet", "--overwrite"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {r.returncode}: {r.stderr.strip()[-400:]}")
    ph = json.load(open(os.path.join(out, "summary.json")))["physics"]
    return {"radius": auto_gate_radius(ph, model_radius), "frame_noise": ph.get("frame_noise"),
            "isolated_event_fraction": ph.get("isolated_event_fraction"), "contrast": ph.get("contrast")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cli", required=True, help="the vkunroll binary")
    ap.add_argument("--out", required=True, help="the JSON file (kept and extended if it exists)")
    ap.add_argument("--model-radius", type=int, default=1, help="the gated model's own radius (metadata physics_gate)")
    ap.add_argument("folders", nargs="+")
    a = ap.parse_args()
    if a.model_radius < 0:
        ap.error(f"--model-radius {a.model_radius}: expected a radius >= 0")
    res = json.load(open(a.out)) if os.path.isfile(a.out) else {}
    with tempfile.TemporaryDirectory() as work:
        for f in a.folders:
            key = os.path.abspath(f)
            if key in res:
                continue
            try:
                res[key] = measure(a.cli, f, work, a.model_radius)
            except (RuntimeError, OSError, KeyError, ValueError) as e:
                print(f"gate_radii.py: error: {f}: {e}", file=sys.stderr)
                return 1
            print(f"{f}: radius {res[key]['radius']}", flush=True)
            tmp = a.out + ".tmp"
            json.dump(res, open(tmp, "w"), indent=0)
            os.replace(tmp, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
