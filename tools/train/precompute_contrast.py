"""Estimates each sequence's contrast threshold as `vkunroll unroll --mode physics` does
(physics_numpy.estimate_contrast) and stores it in the contrast cache tools/train/train.py reads
(OUT/contrast_cache.json), so a training run does not spend its time budget on it.

  precompute_contrast.py --out runs/v1 --data data/natural/train data/natural/val [--data-gamma 1]
"""
import argparse
import os
import sys
import time

from tools.data.sequence_data import Sequence, list_sequences
from tools.train.train_data import SeqInfo


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="the training run's folder (its contrast_cache.json)")
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--data-gamma", type=float, default=1.0)
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    cache = os.path.join(a.out, "contrast_cache.json")
    for p in list_sequences(a.data):
        t0 = time.time()
        info = SeqInfo(Sequence(p), a.data_gamma, cache)
        print(f"{p}: c = {info.contrast():.3f} (gamma {info.gamma:g}, {time.time() - t0:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
