#!/usr/bin/python3
"""Times the PyTorch mirror on given weights and inputs (used by vkunroll-bench-model): the peer
of the race, on the CPU or on a CUDA GPU (the same card as the Vulkan run), in fp32 or fp16.

usage: /usr/bin/python3 -m tools.bench.bench_mirror WEIGHTS.safetensors INPUTS.safetensors OUT.safetensors
                    [--mode s|m] [--threads N] [--device cpu|cuda] [--precision fp32|fp16] [--runs N]
Writes the intermediates (float32) to OUT with the forward time in its metadata under 'seconds':
the best of --runs full-size runs after a warm-up at full size on CUDA (cuDNN autotuning, kernels
loaded) or on a 32x32 crop on the CPU; CUDA runs are timed between torch.cuda.synchronize() calls.
fp16 is the whole network in half (model.half(), inputs half), PyTorch's usual fp16 inference.
On CUDA the peer gets PyTorch's best settings, each timed and the fastest reported (all of them in
the metadata and on stdout): cudnn.benchmark always; fp32 strict, with TF32 and with TF32 in
channels_last; fp16 as half(), as fp32 weights under autocast, and as half() in channels_last.
The intermediates written are those of the first (reference) setting of the precision.
"""
import argparse
import copy
import sys
import time

import torch

from tools.model import safetensors_io
from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig, run_named


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
    inputs32 = safetensors_io.load(a.inputs)[0]
    sync = torch.cuda.synchronize if a.device == "cuda" else (lambda: None)

    def settings():  # (name, tf32, autocast, channels_last): the first is the reference
        if a.device != "cuda":
            return [("plain", False, False, False)]
        if a.precision == "fp32":
            return [("strict", False, False, False), ("tf32", True, False, False), ("tf32+channels_last", True, False, True)]
        return [("half", False, False, False), ("autocast", False, True, False), ("half+channels_last", False, False, True)]

    timed, outs = {}, None
    for name, tf32, autocast, channels_last in settings():
        torch.backends.cuda.matmul.allow_tf32 = tf32
        torch.backends.cudnn.allow_tf32 = tf32
        wdt = torch.float32 if autocast else dt  # autocast keeps fp32 weights and casts per op
        fmt = torch.channels_last if channels_last else torch.contiguous_format
        m = copy.deepcopy(net).to(dev, wdt).to(memory_format=fmt)  # each setting from the fp32 weights
        ins = {k: v.to(dev, wdt).contiguous(memory_format=fmt) for k, v in inputs32.items()}
        warm = ins if a.device == "cuda" else {k: v[:, :, :32, :32].contiguous() for k, v in ins.items()}

        def forward(x):
            with torch.autocast("cuda", dtype=torch.float16, enabled=autocast):
                return run_named(m, x, a.mode)

        with torch.no_grad():
            forward(warm)
            sync()
            best = float("inf")
            for _ in range(max(1, a.runs)):
                t0 = time.perf_counter()
                o = forward(ins)
                sync()
                best = min(best, time.perf_counter() - t0)
        timed[name] = best
        print(f"mirror: {name}: {1000 * best:.2f} ms", flush=True)
        if outs is None:
            outs = o
    fastest = min(timed, key=timed.get)
    seconds = timed[fastest]
    outs = {k: v.float().cpu() for k, v in outs.items()}
    where = torch.cuda.get_device_name(0) if a.device == "cuda" else f"{torch.get_num_threads()} threads"
    meta = {"seconds": repr(seconds), "threads": str(torch.get_num_threads()), "device": where, "precision": a.precision,
            "setting": fastest, "settings": ", ".join(f"{k} {1000 * v:.2f} ms" for k, v in timed.items())}
    safetensors_io.save(a.out, outs, meta)
    print(f"mirror: {seconds:.4f} s ({a.device}, {a.precision}, {where}, fastest setting {fastest})")


if __name__ == "__main__":
    main()
