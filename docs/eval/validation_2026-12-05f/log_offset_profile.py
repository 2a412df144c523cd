#!/usr/bin/python3
"""The contrast estimate's fit (physics_numpy, as host/unroll/contrast_estimate.cpp) at each log-offset
candidate and at 0.1: per sequence, "eps:c:residual / smallest residual". A flat row means the data do
not pin the offset. Arguments: sequence folders or folders of sequences."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "tools"))
import physics_numpy as pn  # noqa: E402
from sequence_data import Sequence, list_sequences  # noqa: E402

for p in list_sequences(sys.argv[1:]):
    seq = Sequence(p)
    la, lb, n = pn.signal_samples(seq, None, pn.meta_gamma(seq))
    name = "/".join(p.rstrip("/").split("/")[-2:])
    if len(n) < pn._MIN_PIXELS:
        print(name, "too few signal pixels: no estimate")
        continue
    fits = [(eps, *pn.offset_fit(la, lb, n, eps)) for eps in pn._OFFSETS + (0.1,)]
    best = min(r for _, _, r in fits)
    print(name, " ".join(f"{e:g}:{c:.3f}:{r / best:.3f}" for e, c, r in fits), flush=True)
