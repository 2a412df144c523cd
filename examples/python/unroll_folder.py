"""Unrolls a recording folder (the generic layout, docs/usage.md) with the default model, the same
job as `vkunroll unroll`, and saves the GS frames as one NumPy array.
    python3 examples/python/unroll_folder.py SEQUENCE_FOLDER [OUT.npy]
At the sequence's ground-truth instants when it has them (a simulated one does), else mid-frame."""
import sys

import numpy as np
import vkunroll


def main(folder, out="gs_frames.npy"):
    seq = vkunroll.Sequence.open(folder)
    times = "gt" if seq.ground_truth else 0.5
    frames, metrics, targets, stats = vkunroll.unroll(seq, times=times)  # model=None: the default
    print(f"vkunroll {vkunroll.__version__}: {len(frames)} GS frames of {seq.width}x{seq.height} "
          f"from {len(seq)} RS frames, mode {stats['mode']}, model {vkunroll.default_model()}")
    if metrics["count"]:
        print(f"PSNR {metrics['mean_psnr']:.2f} dB against the ground truth (the RS input: {metrics['rs_mean_psnr']:.2f} dB)")
    np.save(out, frames)  # [T, H, W, 3] float32 RGB in [0, 1]
    print(f"saved {out}")


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    main(*sys.argv[1:])
