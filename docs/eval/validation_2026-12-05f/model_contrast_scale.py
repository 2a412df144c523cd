#!/usr/bin/python3
"""Post hoc, validation only: the shipped model with its physics input at s x the contrast that
`--mode physics` estimates, for several s in one run. Each --model NAME=FILE whose NAME is
"x<s>" (x1, x1.15, ...) runs at that s; the physics unroller's score is the CLI's, unchanged.
Patches natural_eval's unroll_pair; every other step is tools/natural_eval.py's.
Arguments: natural_eval.py's."""
import copy
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import natural_eval  # noqa: E402

unroll_pair = natural_eval.unroll_pair


def unroll_pair_scaled(net, seq, k, t, texp, bins, crop, info):
    s = float(net.eval_name.lstrip("x"))  # natural_eval names each net by its --model NAME
    scaled = copy.copy(info)
    c = info.contrast() * s
    scaled.contrast = lambda: c
    return unroll_pair(net, seq, k, t, texp, bins, crop, scaled)


natural_eval.unroll_pair = unroll_pair_scaled
if __name__ == "__main__":
    sys.exit(natural_eval.main())
