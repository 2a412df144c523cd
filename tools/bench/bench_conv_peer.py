#!/usr/bin/python3
"""The same-run peer of vkunroll-bench-kernels: PyTorch's conv2d / conv_transpose2d (CPU or CUDA) on
each conv shape of the model, with the fused LeakyReLU(0.1) our kernels apply.

usage: /usr/bin/python3 -m tools.bench.bench_conv_peer SHAPES.json OUT.json [--threads N] [--reps N] [--device cpu|cuda]
SHAPES.json: a list of {"key", "transposed", "k", "s", "cin", "cout", "h", "w"}. OUT.json gets
{"torch": version, "threads": N, "device": name, "ms": {key: best of --reps after one warm-up}}; on CUDA
also "ms_fp16" (the same in half), with cudnn.benchmark on and TF32 off (fp32 is fp32 arithmetic, as
ours), each time between torch.cuda.synchronize() calls.
A transposed conv uses padding 1 (the UNet's 4x4 stride-2 up-sampling); a conv pads k // 2.
"""
import argparse
import json
import sys
import time

import torch
import torch.nn.functional as F


def time_shape(s, reps, device="cpu", dtype=torch.float32):
    g = torch.Generator().manual_seed(1)
    x = torch.rand(1, s["cin"], s["h"], s["w"], generator=g) * 2 - 1
    scale = 1.0 / (s["cin"] * s["k"] * s["k"]) ** 0.5
    if s["transposed"]:
        w = (torch.rand(s["cin"], s["cout"], s["k"], s["k"], generator=g) * 2 - 1) * scale
        b = None
    else:
        w = (torch.rand(s["cout"], s["cin"], s["k"], s["k"], generator=g) * 2 - 1) * scale
        b = torch.zeros(s["cout"])
    x, w = x.to(device, dtype), w.to(device, dtype)
    b = None if b is None else b.to(device, dtype)
    if s["transposed"]:
        run = lambda: F.leaky_relu(F.conv_transpose2d(x, w, None, stride=s["s"], padding=1), 0.1)  # noqa: E731
    else:
        run = lambda: F.leaky_relu(F.conv2d(x, w, b, stride=s["s"], padding=s["k"] // 2), 0.1)  # noqa: E731
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    best = float("inf")
    with torch.no_grad():
        run()  # warm-up: oneDNN / cuDNN picks and caches its kernel
        sync()
        for _ in range(max(1, reps)):
            t0 = time.perf_counter()
            run()
            sync()
            best = min(best, time.perf_counter() - t0)
    return best * 1e3


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("shapes")
    ap.add_argument("out")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    a = ap.parse_args()
    if a.threads < 1:
        sys.exit("bench_conv_peer: --threads must be >= 1")
    torch.set_num_threads(a.threads)
    with open(a.shapes) as f:
        shapes = json.load(f)
    result = {"torch": torch.__version__, "threads": a.threads, "device": "cpu"}
    if a.device == "cuda":
        if not torch.cuda.is_available():
            sys.exit("bench_conv_peer: --device cuda, but this PyTorch has no CUDA device")
        torch.backends.cudnn.benchmark = True
        torch.backends.cudnn.allow_tf32 = False
        torch.backends.cuda.matmul.allow_tf32 = False
        result["device"] = torch.cuda.get_device_name(0)
        result["ms_fp16"] = {s["key"]: time_shape(s, a.reps, "cuda", torch.float16) for s in shapes}
    result["ms"] = {s["key"]: time_shape(s, a.reps, a.device) for s in shapes}
    with open(a.out, "w") as f:
        json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
