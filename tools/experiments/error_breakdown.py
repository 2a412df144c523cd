#!/usr/bin/python3
"""Where a method's error is: squared error against the ground truth split by pixels with and
without events in the frame -> t* window (the physics unroller changes only pixels with events),
for the RS input, physics and models (mirror), per held-out sequence. A diagnostic for the
physics-informed variant (does it lose where physics is already exact, or where events are?).

  error_breakdown.py --data data/natural/heldout/h02* --model V=runs/v/model.safetensors [--limit 4]

Prints, per sequence and method, PSNR over all pixels and the share of the total squared error
(sum over targets) in pixels without events, plus the PSNR restricted to each part.
"""
from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np
import torch

from tools.model import physics_numpy as pn
from tools.model.selfunroll_torch import load_model
from tools.data.sequence_data import Sequence, eic_tensors, list_sequences
from tools.train.train import unroll_pair
from tools.train.train_data import SeqInfo


def event_mask(seq: Sequence, k: int, t: float) -> np.ndarray:
    """Pixels [H, W] with at least one event between their row's exposure of frame k and t*."""
    s, e = seq.row_times(k)
    full = (0, 0, seq.width, seq.height)
    ev = seq.events_in(min(s.min(), t) - 1, max(e.max(), t) + 1, full)
    ev1, ev2, _ = eic_tensors(ev, s, e, np.full(seq.height, t), seq.exposure, 2, full)
    return (np.abs(ev1).sum(0) + np.abs(ev2).sum(0)) > 0


def dilate(mask: np.ndarray, r: int) -> np.ndarray:
    """True where a pixel of `mask` lies within the (2r+1)^2 square around (a box sum > 0)."""
    if r <= 0:
        return mask
    p = np.pad(mask.astype(np.int32), r)
    cs = p.cumsum(0).cumsum(1)
    cs = np.pad(cs, ((1, 0), (1, 0)))
    h, w = mask.shape
    k = 2 * r + 1
    return (cs[k:k + h, k:k + w] - cs[:h, k:k + w] - cs[k:k + h, :w] + cs[:h, :w]) > 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--model", action="append", default=[], metavar="NAME=FILE")
    ap.add_argument("--limit", type=int, default=0, help="at most this many GT instants per sequence")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--gates", default="", help="comma list of radii r: also score each model gated to physics "
                    "outside the (2r+1)^2 neighbourhood of pixels with events (post hoc)")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    nets = {n: load_model(p) for n, p in (m.split("=", 1) for m in a.model)}
    for folder in list_sequences(a.data):
        seq = Sequence(folder)
        gamma = pn.meta_gamma(seq)
        c, eps = pn.estimate_physics(seq, None, gamma)  # the variant's physics input: offset 0
        info = SeqInfo(seq)
        info.gamma = gamma
        info.contrast = lambda c=c: c
        acc = {}
        gts = list(enumerate(seq.meta["ground_truth"]))[: a.limit or None]
        for i, g in gts:
            t = float(g["t_us"])
            k = pn.frame_for_time(seq, list(range(seq.num_frames)), t)
            kk = min(k, seq.num_frames - 2)
            gt = seq.gt_image(i).astype(np.float64)
            mask = event_mask(seq, k, t)
            phys = pn.unroll_physics(seq, k, t, c, gamma, log_offset=eps)
            imgs = {"RS": seq.frame(k), "physics": phys}
            for n, net in nets.items():
                r = unroll_pair(net, seq, kk, t, seq.exposure, net.cfg.N, (0, 0, seq.width, seq.height), info)
                imgs[n] = (r["s1"] if kk == k else r["s2"])[0].numpy()
                if "m" in r and kk == k:
                    imgs[n + "-M"] = r["m"][0].numpy()
                for rad in [int(x) for x in a.gates.split(",") if x]:
                    near = dilate(mask, rad)
                    imgs[f"{n}-gate{rad}"] = np.where(near[None], imgs[n], np.clip(phys, 0, 1))
            for n, img in imgs.items():
                se = ((np.clip(img, 0, 1) - np.clip(gt, 0, 1)) ** 2).sum(0)
                d = acc.setdefault(n, [0.0, 0.0, 0, 0])
                d[0] += float(se[mask].sum())
                d[1] += float(se[~mask].sum())
                d[2] += int(mask.sum())
                d[3] += int((~mask).sum())
        print(f"{os.path.basename(folder)}: c {c:.3f}, {len(gts)} targets, "
              f"{100 * acc['RS'][2] / (acc['RS'][2] + acc['RS'][3]):.1f}% pixels with events")
        for n, (sev, sno, nev, nno) in acc.items():
            ps = lambda s, n: 10 * math.log10(3 * n / max(s, 1e-12)) if n else float("nan")  # noqa: E731
            print(f"  {n:>14}: all {ps(sev + sno, nev + nno):6.2f} dB | with events {ps(sev, nev):6.2f} dB | "
                  f"without {ps(sno, nno):6.2f} dB | share of SE without events {100 * sno / max(sev + sno, 1e-12):5.1f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
