#!/usr/bin/python3
"""Sparse execution against dense, warm: one UnrollSession (the Python bindings) runs the same job
with `--sparse off`, `fast --halo 0` and `exact --halo 0` for several rounds, so that from the second
round on every device buffer is already faulted in. A cold CLI run pays for touching fresh memory
inside its frames (about 11 us per 4 KiB page on this project's 2-core VMs, docs/measurements.md);
a long recording pays it once.

  PYTHONPATH=build/python /usr/bin/python3 -m tools.experiments.sparse_rounds data/natural/draw/nat_03008 [--rounds 3] [--frames 0,1] [--model M.safetensors]

Prints per round and policy the compute ms per GS frame (summary's total less read, write, pipeline
builds, the contrast estimate and setup, as docs/tiling.md counts it), the ratio to `off` in the same
round, and the mean PSNR. Needs the Python module (build/python, or installed).
"""
import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

# The summary's host stages that are not the frames' compute (tools/experiments/sparse_cold.sh reads it too).
NOT_COMPUTE = ("read", "write", "pipeline_builds", "contrast_estimate", "setup")
POLICIES = (("off", -1), ("fast", 0), ("exact", 0))


def compute_ms(stats: dict) -> float:
    ms = stats["ms_per_gs_frame"]
    return stats["ms_per_gs_frame_total"] - sum(ms.get(k, 0.0) for k in NOT_COMPUTE)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequence")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", default="0,1", help="comma list of frames (their ground-truth instants are the targets)")
    ap.add_argument("--model", default=os.path.join(HERE, "..", "..", "models", "selfunroll_small_physics.safetensors"))
    a = ap.parse_args(argv)
    if a.rounds < 1:
        ap.error("--rounds must be at least 1")
    frames = [int(f) for f in a.frames.split(",")]
    import vkunroll as vk  # here, not at the top: sparse_cold.sh imports compute_ms without the module
    session = vk.UnrollSession(model=a.model)
    for rnd in range(a.rounds):
        off = None
        for sparse, halo in POLICIES:
            r = vk.unroll(a.sequence, times="gt", mode="s", frames=frames, sparse=sparse, halo=halo, session=session)
            c = compute_ms(r.stats)
            off = c if sparse == "off" else off
            print(f"round {rnd}  {sparse:5s} halo {halo:2d}  compute {c:7.1f} ms per GS frame  x{off / c:5.2f}  "
                  f"PSNR {r.metrics['mean_psnr']:.4f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
