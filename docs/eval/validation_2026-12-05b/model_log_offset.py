#!/usr/bin/python3
"""Post hoc, validation only: the shipped model with its physics input at the log offset the
contrast estimate fitted (as `--mode physics` applies it) instead of 0, as the CLI feeds it now.
Patches the mirror's apply_log_ratio_torch and takes each sequence's offset from the CLI's
physics summary; every other step is tools/natural_eval.py's. Arguments: natural_eval.py's."""
import os
import sys

import numpy as np
import torch

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import natural_eval  # noqa: E402
import physics_numpy as pn  # noqa: E402

EPS = {"value": 0.0}
cli_metrics = natural_eval.cli_metrics


def cli_metrics_noting_offset(cli, seq, work, mode, model=None, gate="model"):
    res = cli_metrics(cli, seq, work, mode, model, gate)
    if mode == "physics":
        EPS["value"] = float(res["_summary"]["physics"].get("log_offset", 0.0))
        print(f"{seq.folder}: model physics input at log offset {EPS['value']:.4f}", flush=True)
    return res


def apply_log_ratio_offset(img, log_ratio, gamma, max_value=pn.MAX_VALUE):
    """apply_log_ratio (the C++ formula, offset eps) in torch."""
    g, eps = float(np.float32(gamma)), float(np.float32(EPS["value"]))
    lin = torch.where(img > 0, img.clamp(min=0) ** g, torch.zeros_like(img)) + eps
    o = torch.clamp(torch.exp(torch.clamp(torch.log(lin.clamp(min=1e-30)) + log_ratio, max=float(np.log(max_value)))),
                    max=max_value) - eps
    return torch.where(o > 0, o.clamp(min=0) ** (1.0 / g), torch.zeros_like(o))


natural_eval.cli_metrics = cli_metrics_noting_offset
pn.apply_log_ratio_torch = apply_log_ratio_offset
if __name__ == "__main__":
    sys.exit(natural_eval.main())
