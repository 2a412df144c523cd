#!/usr/bin/python3
"""Times the PyTorch mirror on the CPU on given weights and inputs (used by vkunroll-bench-model).

usage: /usr/bin/python3 tools/bench_mirror.py WEIGHTS.safetensors INPUTS.safetensors OUT.safetensors
                                              [--mode s|m] [--threads N]
Writes the intermediates to OUT with the forward time (seconds, one run after a small warm-up) in
its metadata under 'seconds'.
"""
import argparse
import os
import sys
import time

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import safetensors_io  # noqa: E402
from selfunroll_torch import SelfUnroll, SelfUnrollConfig, run_named  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("weights")
    ap.add_argument("inputs")
    ap.add_argument("out")
    ap.add_argument("--mode", default="m", choices=("s", "m"))
    ap.add_argument("--threads", type=int, default=0)
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    tensors, meta = safetensors_io.load(a.weights)
    net = SelfUnroll(SelfUnrollConfig.from_metadata(meta)).eval()
    net.load_state_dict({k: v.float() for k, v in tensors.items()}, strict=True)
    inputs = {k: v.float() for k, v in safetensors_io.load(a.inputs)[0].items()}
    warm = {k: v[:, :, :32, :32].contiguous() for k, v in inputs.items()}
    run_named(net, warm, a.mode)
    t0 = time.perf_counter()
    outs = run_named(net, inputs, a.mode)
    seconds = time.perf_counter() - t0
    safetensors_io.save(a.out, outs, {"seconds": repr(seconds), "threads": str(torch.get_num_threads())})
    print(f"mirror: {seconds:.3f} s on {torch.get_num_threads()} threads")


if __name__ == "__main__":
    main()
