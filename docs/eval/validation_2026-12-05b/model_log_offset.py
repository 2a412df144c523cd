#!/usr/bin/python3
"""Post hoc, validation only: the shipped model with its physics input at the log offset the
contrast estimate fitted (as `--mode physics` applies it) instead of 0, as the CLI feeds it now.
Patches the mirror's apply_log_ratio_torch and takes each sequence's offset from the CLI's
physics summary; every other step is tools/natural_eval.py's. Arguments: natural_eval.py's."""
import os
import sys

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


apply_log_ratio_torch = pn.apply_log_ratio_torch


def apply_log_ratio_offset(img, log_ratio, gamma, max_value=pn.MAX_VALUE):
    """The mirror's physics input at the sequence's fitted offset instead of 0."""
    return apply_log_ratio_torch(img, log_ratio, gamma, max_value, log_offset=EPS["value"])


natural_eval.cli_metrics = cli_metrics_noting_offset
pn.apply_log_ratio_torch = apply_log_ratio_offset
if __name__ == "__main__":
    sys.exit(natural_eval.main())
