#!/usr/bin/python3
"""Converts a SelfUnroll PyTorch checkpoint to vkunroll's weights file (safetensors).

usage: /usr/bin/python3 -m tools.model.convert_checkpoint IN.pth OUT.safetensors [--fp16] [--channel-order rgb|bgr]
                                                    [--description TEXT] [--gamma G]

Reads a bare state_dict or a dict holding one under 'state_dict' or 'model' (the authors'
checkpoints), removes a DataParallel 'module.' prefix, keeps the key names, infers the
configuration (D, C, G, G0, N, UNet bases/depths) from the shapes, compares the keys and
shapes with what that configuration needs, prints missing and unexpected keys, and writes
F32 (or F16 with --fp16) tensors with the configuration in the safetensors __metadata__.
A checkpoint without attfusion_net converts to a SelfUnroll-S-only file (metadata moa=false).
The physics-informed variant (SFENet1 with 4*(6+6N) inputs: rs, ev1-3 and the physics estimate;
docs/model.md) is recognised from the shapes and written with metadata physics_input=true.
--gamma G records the intensity encoding the model was trained in (metadata 'gamma'; the
variant defaults to 2.2, the published checkpoints state none).
Exit status: 0 written, 1 error (a missing key outside attfusion_net, a wrong shape, bad file).
"""
import argparse
import os
import pickle
import sys

import torch

from tools.model import safetensors_io
from tools.model.selfunroll_torch import SelfUnroll, infer_config


def extract_state_dict(obj, path):
    if isinstance(obj, dict):
        for key in ("state_dict", "model"):
            if key in obj and isinstance(obj[key], dict):
                return extract_state_dict(obj[key], path)
        tensors = {k: v for k, v in obj.items() if isinstance(v, torch.Tensor)}
        if tensors:
            skipped = [k for k in obj if k not in tensors]
            if skipped:
                print(f"note: ignoring {len(skipped)} non-tensor entries: {', '.join(map(str, skipped[:8]))}")
            return tensors
    raise ValueError(f"{path}: no state_dict found (expected a dict of tensors, or one under 'state_dict'/'model')")


def strip_prefix(sd):
    out = {}
    for k, v in sd.items():
        while k.startswith("module."):
            k = k[len("module."):]
        out[k] = v
    return out


def convert(src, dst, fp16=False, channel_order="rgb", description="", gamma=None, physics_contrast="estimate"):
    """Returns (config, missing, unexpected). Raises ValueError on errors."""
    obj = torch.load(src, map_location="cpu", weights_only=False)
    sd = strip_prefix(extract_state_dict(obj, src))
    cfg = infer_config({k: tuple(v.shape) for k, v in sd.items()})
    cfg.channel_order = channel_order
    cfg.gamma = gamma if gamma is not None else (2.2 if cfg.physics_input else None)
    if gamma is not None and not gamma > 0:
        raise ValueError(f"--gamma {gamma}: expected a positive number")
    cfg.physics_contrast = physics_contrast
    cfg.description = description or f"converted from {os.path.basename(src)}"
    expected = {k: tuple(v.shape) for k, v in SelfUnroll(cfg).state_dict().items()}
    missing = sorted(k for k in expected if k not in sd)
    unexpected = sorted(k for k in sd if k not in expected)
    wrong = [f"{k}: {tuple(sd[k].shape)} (expected {expected[k]})" for k in expected
             if k in sd and tuple(sd[k].shape) != expected[k]]
    print(f"configuration: D={cfg.D} C={cfg.C} G={cfg.G} G0={cfg.G0} N={cfg.N} upnet_width={cfg.upnet_width} "
          f"flownet={cfg.flownet.base}/{cfg.flownet.depth} fusion_net={cfg.fusion_net.base}/{cfg.fusion_net.depth} "
          + (f"attfusion_net={cfg.attfusion_net.base}/{cfg.attfusion_net.depth}" if cfg.moa else "attfusion_net=absent")
          + f" channel_order={cfg.channel_order}"
          + (f" physics-informed (contrast {cfg.physics_contrast})" if cfg.physics_input else "")
          + (f" gamma={cfg.gamma:g}" if cfg.gamma is not None else ""))
    if not cfg.moa:
        print("note: no attfusion_net (MOA) weights: the file runs SelfUnroll-S only")
    print(f"missing keys ({len(missing)}): " + (", ".join(missing) if missing else "none"))
    print(f"unexpected keys ({len(unexpected)}): " + (", ".join(unexpected) if unexpected else "none"))
    if wrong:
        raise ValueError("wrong shapes: " + "; ".join(wrong))
    if missing:
        raise ValueError(f"{len(missing)} keys the configuration needs are missing (first: {missing[0]})")
    dtype = torch.float16 if fp16 else torch.float32
    tensors = {k: sd[k].detach().to(dtype) for k in expected}
    if fp16:
        big = [k for k, v in tensors.items() if not torch.isfinite(v).all()]
        if big:
            raise ValueError(f"fp16 overflow in {big[0]} ({len(big)} tensors); convert without --fp16")
    safetensors_io.save(dst, tensors, cfg.to_metadata())
    n = sum(v.numel() for v in tensors.values())
    print(f"wrote {dst}: {len(tensors)} tensors, {n} parameters, {'F16' if fp16 else 'F32'}"
          + (f" (unexpected keys not written: {len(unexpected)})" if unexpected else ""))
    return cfg, missing, unexpected


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--fp16", action="store_true", help="store F16 tensors (half the size)")
    ap.add_argument("--channel-order", choices=("rgb", "bgr"), default="rgb",
                    help="image channel order the checkpoint expects (DRE-trained models: bgr)")
    ap.add_argument("--description", default="")
    ap.add_argument("--gamma", type=float, help="intensity encoding the model was trained in (metadata 'gamma')")
    a = ap.parse_args(argv)
    try:
        convert(a.input, a.output, a.fp16, a.channel_order, a.description, a.gamma)
    except (ValueError, KeyError, OSError, RuntimeError, pickle.UnpicklingError, EOFError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"convert_checkpoint: error: {a.input}: {msg}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
