#!/usr/bin/python3
"""Times the PyTorch mirror on given weights and inputs (used by vkunroll-bench-model): the peer
of the race, on the CPU or on a CUDA GPU (the same card as the Vulkan run), in fp32 or fp16.

usage: /usr/bin/python3 tools/bench_mirror.py WEIGHTS.safetensors INPUTS.safetensors OUT.safetensors
                    [--mode s|m] [--threads N] [--device cpu|cuda] [--precision fp32|fp16] [--runs N]
Writes the intermediates (float32) to OUT with the forward time in its metadata under 'seconds':
the best of --runs full-size runs after a warm-up at full size on CUDA (cuDNN autotuning, kernels
loaded) or on a 32x32 crop on the CPU; CUDA runs are timed between torch.cuda.synchronize() calls.
fp16 is the whole network in half (model.half(), inputs half), PyTorch's usual fp16 inference.
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
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--precision", default="fp32", choices=("fp32", "fp16"))
    ap.add_argument("--runs", type=int, default=1)
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    if a.device == "cuda" and not torch.cuda.is_available():
        sys.exit("bench_mirror: --device cuda, but this PyTorch has no CUDA device")
    dev = torch.device(a.device)
    dt = torch.float16 if a.precision == "fp16" else torch.float32
    if a.device == "cuda":
        torch.backends.cudnn.benchmark = True
    tensors, meta = safetensors_io.load(a.weights)
    net = SelfUnroll(SelfUnrollConfig.from_metadata(meta)).eval()
    net.load_state_dict({k: v.float() for k, v in tensors.items()}, strict=True)
    net = net.to(dev, dt)
    inputs = {k: v.to(dev, dt) for k, v in safetensors_io.load(a.inputs)[0].items()}
    sync = torch.cuda.synchronize if a.device == "cuda" else (lambda: None)
    warm = inputs if a.device == "cuda" else {k: v[:, :, :32, :32].contiguous() for k, v in inputs.items()}
    with torch.no_grad():
        run_named(net, warm, a.mode)
        sync()
        seconds = float("inf")
        for _ in range(max(1, a.runs)):
            t0 = time.perf_counter()
            outs = run_named(net, inputs, a.mode)
            sync()
            seconds = min(seconds, time.perf_counter() - t0)
    outs = {k: v.float().cpu() for k, v in outs.items()}
    where = torch.cuda.get_device_name(0) if a.device == "cuda" else f"{torch.get_num_threads()} threads"
    safetensors_io.save(a.out, outs, {"seconds": repr(seconds), "threads": str(torch.get_num_threads()), "device": where,
                                      "precision": a.precision})
    print(f"mirror: {seconds:.4f} s ({a.device}, {a.precision}, {where})")


if __name__ == "__main__":
    main()
