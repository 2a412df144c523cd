#!/usr/bin/python3
"""Evaluates a vkunroll weights file on held-out sequences with ground truth (generic layout) and
prints a Markdown table: mean PSNR (dB) of the RS input, the physics unroller
(`vkunroll unroll --mode physics`, when the CLI has it) and the model's S and M results, split
into intra-frame targets (inside the RS frame's exposure span) and inter-frame targets (between
two frames).

  evaluate.py --model models/small.safetensors --data data/test [--cli build/vkunroll] [--json OUT.json]

Targets: every GT instant t with RS frames k and k+1 around it (k = last frame starting at or
before t). RS input = frame k as is. S = SelfUnroll-S on frame k toward t* = t. M = SelfUnroll-M
on frames k and k+1 toward t. The GS target exposure (ev3 window) is the RS exposure unless
--target-exposure-us says otherwise. Images are clamped to [0,1]; PSNR on the full frame, all
three channels.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from typing import Dict, List

import numpy as np
import torch

from tools.model import safetensors_io
from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig
from tools.data.sequence_data import DataError, Sequence, list_sequences
from tools.train.train import gt_targets, psnr, unroll_pair


def load_model(path: str) -> SelfUnroll:
    tensors, md = safetensors_io.load(path)
    cfg = SelfUnrollConfig.from_metadata(md)
    net = SelfUnroll(cfg)
    missing, unexpected = net.load_state_dict({k: v.float() for k, v in tensors.items()}, strict=False)
    if missing or unexpected:
        raise DataError(f"{path}: missing keys {missing[:3]}, unexpected keys {unexpected[:3]}")
    net.eval()
    return net


def physics_psnr(cli: str, seq: Sequence, work: str) -> Dict[float, float]:
    """PSNR per GT time from `vkunroll unroll --mode physics` (its metrics.csv), or {} when the CLI
    has no unroll command."""
    out = os.path.join(work, os.path.basename(seq.folder.rstrip("/")))
    r = subprocess.run([cli, "unroll", seq.folder, "--out", out, "--mode", "physics", "--times", "gt", "--no-video",
                        "--quiet"], capture_output=True, text=True)
    if r.returncode != 0:
        raise DataError(f"vkunroll unroll --mode physics failed on {seq.folder}: {r.stderr.strip()[-400:]}")
    rows = list(csv.DictReader(open(os.path.join(out, "metrics.csv"))))
    res = {}
    for row in rows:
        t = float(row["t_us"])
        if row.get("psnr") not in (None, ""):
            res[t] = float(row["psnr"])
    return res


def physics_edi(seq: Sequence, k: int, t_star: float, contrast: float = 0.2, gamma: float = 2.2,
                max_value: float = 1e4) -> np.ndarray:
    """The weight-free EDI unroller of kernels/physics_unroll.cpp (physics_unroll_ref), vectorized:
    I(t*) = I_rs * T / integral over the row's exposure [S, E] of exp(c (F(s) - F(t*))) ds, F the
    pixel's cumulative polarity, on linear intensity (PNG value ^ gamma). Used when the CLI has no
    `unroll --mode physics` yet."""
    H, W = seq.height, seq.width
    S_abs, E_abs = seq.row_times(k)
    t, x, y, p = seq.events_in(min(S_abs.min(), t_star) - 1, max(E_abs.max(), t_star) + 1, (0, 0, W, H))
    S, E = S_abs[y] - t_star, E_abs[y] - t_star
    tau = t - t_star
    keep = (tau >= np.minimum(S, 0)) & (tau <= np.maximum(E, 0))
    tau, x, y, p, S, E = tau[keep], x[keep], y[keep], p[keep], S[keep], E[keep]
    pol = np.where(p > 0, 1.0, -1.0)
    pix = y * W + x
    npx = H * W
    f0 = np.bincount(pix, weights=pol * (tau <= 0), minlength=npx)
    fS = np.bincount(pix, weights=pol * (tau <= S), minlength=npx)
    rowS = np.repeat(S_abs - t_star, W)
    rowE = np.repeat(E_abs - t_star, W)
    inside = (tau > S) & (tau < E)
    ti, pi, poli = tau[inside], pix[inside], pol[inside]
    order = np.lexsort((ti, pi))  # by pixel, then time (stable: keeps stream order)
    ti, pi, poli = ti[order], pi[order], poli[order]
    # cumulative polarity within each pixel's run of events
    cs = np.cumsum(poli)
    first = np.r_[True, pi[1:] != pi[:-1]] if len(pi) else np.zeros(0, bool)
    base = np.maximum.accumulate(np.where(first, np.arange(len(pi)), 0)) if len(pi) else np.zeros(0, int)
    cp = cs - (cs[base] - poli[base])
    last = np.r_[pi[1:] != pi[:-1], True] if len(pi) else np.zeros(0, bool)
    t_next = np.where(last, rowE[pi], np.r_[ti[1:], 0.0] if len(ti) else ti)
    seg = np.bincount(pi, weights=(t_next - ti) * np.exp(contrast * (fS[pi] + cp - f0[pi])), minlength=npx)
    t_first = np.full(npx, np.nan)
    if len(pi):
        t_first[pi[first]] = ti[first]
    t_first = np.where(np.isnan(t_first), rowE, t_first)
    integral = (t_first - rowS) * np.exp(contrast * (fS - f0)) + seg
    log_ratio = np.log(rowE - rowS) - np.log(integral)
    rs = seq.frame(k).astype(np.float64)
    lin = np.power(rs, gamma)
    with np.errstate(divide="ignore"):
        o = np.where(lin > 0, np.minimum(np.exp(np.log(np.maximum(lin, 1e-300)) + log_ratio.reshape(H, W)), max_value), 0)
    return np.power(o, 1.0 / gamma).astype(np.float32)


def cli_has_unroll(cli: str) -> bool:
    if not cli:
        return False
    r = subprocess.run([cli, "unroll", "--help"], capture_output=True, text=True)
    return r.returncode == 0 and "physics" in r.stdout + r.stderr


def evaluate(model: str, data: List[str], cli: str = "", target_exposure=None, limit=0, contrast=0.2,
             gamma=2.2) -> dict:
    net = load_model(model)
    torch.set_num_threads(2)
    seqs = [Sequence(p, cache_images=False) for p in list_sequences(data)]
    use_phys = cli_has_unroll(cli)
    res = {"intra": {}, "inter": {}}
    t0 = time.time()
    with tempfile.TemporaryDirectory() as work:
        for seq in seqs:
            phys = physics_psnr(cli, seq, work) if use_phys else {}
            targets = gt_targets(seq)
            if limit:
                targets = targets[:limit]
            for i, k, intra in targets:
                t = seq.gt[i][1]
                crop = (0, 0, seq.width, seq.height)
                r = unroll_pair(net, seq, k, t, target_exposure or seq.exposure, net.cfg.N, crop)
                gt = torch.from_numpy(seq.gt_image(i))[None]
                d = res["intra" if intra else "inter"]
                d.setdefault("RS input", []).append(psnr(r["rs1"], gt))
                if use_phys:
                    m = [v for tt, v in phys.items() if abs(tt - t) < 0.5]
                    if m:
                        d.setdefault("physics", []).append(m[0])
                else:
                    edi = torch.from_numpy(physics_edi(seq, k, t, contrast, gamma))[None]
                    d.setdefault("physics", []).append(psnr(edi, gt))
                d.setdefault("SelfUnroll-S", []).append(psnr(r["s1"], gt))
                if "m" in r:
                    d.setdefault("SelfUnroll-M", []).append(psnr(r["m"], gt))
    out = {"model": model, "sequences": [s.folder for s in seqs], "physics_available": use_phys,
           "physics": ("vkunroll unroll --mode physics" if use_phys else
                       f"tools/eval/evaluate.py physics_edi (mirror of kernels/physics_unroll.cpp), c={contrast}, gamma={gamma}"),
           "seconds": round(time.time() - t0, 1)}
    for kind, d in res.items():
        out[kind] = {k: {"psnr": float(np.mean(v)), "n": len(v)} for k, v in d.items()}
    return out


def markdown(r: dict) -> str:
    methods = ["RS input", "physics", "SelfUnroll-S", "SelfUnroll-M"]
    lines = ["| method | intra-frame PSNR (dB) | inter-frame PSNR (dB) |", "| --- | --- | --- |"]
    for m in methods:
        cells = []
        for kind in ("intra", "inter"):
            v = r[kind].get(m)
            cells.append(f"{v['psnr']:.2f} (n={v['n']})" if v else "n/a")
        lines.append(f"| {m} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines) + f"\n\nphysics: {r['physics']}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True)
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--cli", default=os.environ.get("VKUNROLL_CLI", ""), help="vkunroll executable (physics baseline)")
    ap.add_argument("--target-exposure-us", type=float)
    ap.add_argument("--limit", type=int, default=0, help="at most this many targets per sequence (0 = all)")
    ap.add_argument("--json", help="also write the numbers here")
    ap.add_argument("--contrast", type=float, default=0.2, help="EDI contrast threshold (Python physics fallback)")
    ap.add_argument("--gamma", type=float, default=2.2, help="EDI decoding gamma (Python physics fallback)")
    a = ap.parse_args(argv)
    try:
        r = evaluate(a.model, a.data, a.cli, a.target_exposure_us, a.limit, a.contrast, a.gamma)
    except DataError as e:
        print(f"evaluate.py: error: {e}", file=sys.stderr)
        return 1
    print(markdown(r))
    if a.json:
        json.dump(r, open(a.json, "w"), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
