#!/usr/bin/python3
"""Post hoc, validation only (decision_rule.txt): where the physics estimates from frames k and k+1
toward t* agree within half a contrast step over each pixel's 3x3 neighbourhood, the output is their
mean; elsewhere the model's M. --model NAME=FILE whose NAME starts with "agree" runs so (its S
results are left as they are); other names run as tools/natural_eval.py does. Arguments: natural_eval.py's."""
import os
import sys

import numpy as np
import torch

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import natural_eval  # noqa: E402
import physics_numpy as pn  # noqa: E402

STEP_FRACTION, FLOOR = 0.5, 0.01
SHARE = {"pixels": 0, "agree": 0}
unroll_pair = natural_eval.unroll_pair
evaluate = natural_eval.evaluate


def agreement(p1: np.ndarray, p2: np.ndarray, gamma: float, c: float) -> np.ndarray:
    """[h, w] bool: |log change between the two estimates| < STEP_FRACTION * c over the 3x3 around."""
    lin = lambda p: np.power(np.clip(p, 0, None), gamma).mean(axis=0)  # noqa: E731
    d = torch.from_numpy(np.abs(np.log(lin(p1) + FLOOR) - np.log(lin(p2) + FLOOR)))[None, None]
    worst = torch.nn.functional.max_pool2d(d, 3, stride=1, padding=1)[0, 0].numpy()
    return worst < STEP_FRACTION * c


def blended_pair(net, seq, k, t_star, texp, bins, crop, info):
    res = unroll_pair(net, seq, k, t_star, texp, bins, crop, info)
    if not net.eval_name.startswith("agree") or "m" not in res:  # natural_eval names each net by its --model NAME
        return res
    c, gamma = info.contrast(), info.gamma
    p1 = pn.unroll_physics(seq, k, t_star, c, gamma, crop)
    p2 = pn.unroll_physics(seq, k + 1, t_star, c, gamma, crop)
    ok = agreement(p1, p2, gamma, c)
    SHARE["pixels"] += ok.size
    SHARE["agree"] += int(ok.sum())
    mean = torch.from_numpy(np.clip(0.5 * (p1 + p2), 0, 1).astype(np.float32))[None]
    res["m"] = torch.where(torch.from_numpy(ok)[None, None], mean, res["m"])
    return res


def evaluate_counting(data, models, *args, **kwargs):
    out = evaluate(data, models, *args, **kwargs)
    print(f"agreeing pixels: {SHARE['agree'] / max(SHARE['pixels'], 1):.3f} of {SHARE['pixels']}", file=sys.stderr)
    return out


natural_eval.unroll_pair = blended_pair
natural_eval.evaluate = evaluate_counting
if __name__ == "__main__":
    sys.exit(natural_eval.main())
