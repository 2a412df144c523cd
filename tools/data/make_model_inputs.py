"""Model inputs from a sequence, for `vkunroll infer` and `vkunroll-bench-model --inputs`:
rs [2, 3, H, W] (RS frames k and k+1, in the model's channel order as stored: RGB planes) and
ev1, ev2, ev3 [2, 2N, H, W] (the E-IC passes of both frames toward GS(t*)), float32 safetensors.

usage: make_model_inputs.py SEQUENCE OUT.safetensors [--frame K] [--tau 0.5] [--bins 16]
                            [--crop x,y,w,h]
t* = the start of frame K's first row + tau x (frame K's readout span)."""
import argparse
import sys

import numpy as np
import torch

from tools.model import safetensors_io
from tools.data.sequence_data import Sequence
from tools.train.train_data import make_sample


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence")
    ap.add_argument("out")
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--tau", type=float, default=0.5)
    ap.add_argument("--bins", type=int, default=16)
    ap.add_argument("--crop", default=None, help="x,y,w,h (default: the whole sensor)")
    a = ap.parse_args()
    seq = Sequence(a.sequence)
    if not 0 <= a.frame < seq.num_frames - 1:
        print(f"--frame {a.frame}: expected 0..{seq.num_frames - 2} (frame K and K+1 are used)", file=sys.stderr)
        return 2
    crop = tuple(int(v) for v in a.crop.split(",")) if a.crop else (0, 0, seq.width, seq.height)
    s0, e0 = seq.row_times(a.frame)
    t_star = float(s0.min() + a.tau * (e0.max() - s0.min()))
    smp = make_sample(seq, a.frame, crop, t_star, seq.exposure, a.bins)
    t = {"rs": np.stack([smp.rs1, smp.rs2])}
    for i, name in enumerate(["ev1", "ev2", "ev3"]):
        t[name] = np.stack([smp.ev["g1"][i], smp.ev["g2"][i]])
    safetensors_io.save(a.out, {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) for k, v in t.items()},
                        {"sequence": a.sequence, "frame": str(a.frame), "t_star_us": repr(t_star)})
    print(f"wrote {a.out}: rs {t['rs'].shape}, ev1/ev2/ev3 {t['ev1'].shape}, t* {t_star:.1f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
