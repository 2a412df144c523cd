#!/usr/bin/python3
"""Scores unrolling methods on held-out sequences with ground truth (tools/data/natural_data.py
--heldout): intra-frame (t* inside its frame's exposure span) and inter-frame (between frames)
PSNR and SSIM, per sequence, per motion kind and overall.

  natural_eval.py --data data/natural/heldout --cli build/vkunroll \
      --model S=models/selfunroll_small_physics.safetensors --json docs/natural_eval_shipped.json
  natural_eval.py ... --model V=runs/v/model.safetensors --cli-modes s   # also vkunroll unroll --mode s

Methods:
  RS input          frame k as it is (k = the frame `vkunroll unroll` picks: the one whose
                    exposure span holds t*, else the nearest middle)
  physics           `vkunroll unroll --mode physics --times gt` (contrast estimated, gamma from
                    meta.json), read from its metrics.csv; without --cli: tools/model/physics_numpy.py
                    (the same numbers to 1e-5)
  NAME-S / NAME-M   each --model NAME=FILE through the PyTorch mirror (which `vkunroll infer`
                    reproduces within 1e-4): S on frame k, M on frames k and k+1 (S on the last
                    frame, as `unroll --mode m`). A model whose metadata states a gamma runs in
                    that encoding (frames re-encoded from the sequence's, results back), which is
                    what `unroll` is specified to do (docs/model.md); the variant gets the physics
                    estimate at the contrast `--mode physics` estimates.
  NAME-S(cli) ...   --cli-modes s,m: the same model through `vkunroll unroll --mode s|m` (only for
                    models the C++ side loads)
PSNR/SSIM as host/metrics.cpp: images clamped to [0,1], PSNR over all channels, SSIM Gaussian
11x11 (sigma 1.5), valid region, mean over channels.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from typing import Dict, List, Optional

import numpy as np
import torch

from tools.model import physics_numpy as pn
from tools.model.selfunroll_torch import load_model
from tools.data.sequence_data import DataError, Sequence, list_sequences
from tools.train.train import unroll_pair
from tools.train.train_data import SeqInfo


# ---- metrics as host/metrics.cpp --------------------------------------------------------------------
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    d = np.clip(a, 0, 1).astype(np.float64) - np.clip(b, 0, 1).astype(np.float64)
    mse = float((d * d).mean())
    return 100.0 if mse <= 0 else 10 * math.log10(1.0 / mse)


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """[C, H, W] images; cv::getGaussianKernel(11, 1.5) with BORDER_REFLECT, valid region."""
    a = np.clip(a, 0, 1).astype(np.float64)
    b = np.clip(b, 0, 1).astype(np.float64)
    win = min(11, a.shape[1], a.shape[2])
    sigma = 1.5 * win / 11.0
    g = np.exp(-((np.arange(win) - (win - 1) / 2) ** 2) / (2 * sigma * sigma))
    g /= g.sum()
    C1, C2 = 0.01 ** 2, 0.03 ** 2
    h, w = a.shape[1:]
    r = win // 2

    def blur(m):
        # separable correlation; the valid region never reads the (symmetric = BORDER_REFLECT) padding
        m = np.pad(m, r, mode="symmetric")
        m = sum(g[i] * m[i:i + h, :] for i in range(win))
        m = sum(g[i] * m[:, i:i + w] for i in range(win))
        return m[r:r + h - win + 1, r:r + w - win + 1]
    tot = 0.0
    for x, y in zip(a, b):
        mx, my = blur(x), blur(y)
        sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
        s = ((2 * mx * my + C1) * (2 * sxy + C2)) / ((mx * mx + my * my + C1) * (sxx + syy + C2))
        tot += float(s.mean())
    return tot / a.shape[0]


# ---- the CLI -----------------------------------------------------------------------------------------
def cli_metrics(cli: str, seq: Sequence, work: str, mode: str, model: Optional[str] = None,
                gate: str = "model") -> Dict[float, dict]:
    """metrics.csv rows of `vkunroll unroll --mode MODE --times gt`, by GT time."""
    out = os.path.join(work, f"{os.path.basename(seq.folder.rstrip('/'))}_{mode}")
    cmd = [cli, "unroll", seq.folder, "--out", out, "--mode", mode, "--times", "gt", "--no-video", "--quiet"]
    if model:
        cmd += ["--model", model, "--gate-radius", gate]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise DataError(f"{' '.join(cmd)} failed: {r.stderr.strip()[-400:]}")
    res = {float(row["t_us"]): row for row in csv.DictReader(open(os.path.join(out, "metrics.csv")))}
    summ = json.load(open(os.path.join(out, "summary.json")))
    res["_summary"] = summ
    return res


def kind_of(seq: Sequence) -> str:
    p = os.path.join(seq.folder, "natural.json")
    return json.load(open(p)).get("kind", "unknown") if os.path.isfile(p) else "unknown"


def noise_of(seq: Sequence) -> str:
    """The event noise the sequence was made with: `vkunroll simulate`'s preset (clean, realistic,
    noisy) or the second generator's `--noise` (none, dvs), from meta.json's source."""
    src = json.load(open(os.path.join(seq.folder, "meta.json"))).get("source", {})
    return str(src.get("preset") or src.get("noise") or "unknown")


def noisy(noise: str) -> str:
    """'yes' when the sequence has sensor noise (any preset or --noise but clean / none)."""
    return "unknown" if noise == "unknown" else ("no" if noise in ("clean", "none") else "yes")


# `vkunroll unroll --gate-radius auto` (host/unroll/unroll_plan.hpp, choose_gate_radius): the same
# constants, applied to what the contrast estimate measured (--mode physics's summary.json).
CLEAN_FRAME_NOISE, CLEAN_ISOLATED_EVENTS, NOISY_GATE_RADIUS = 0.01, 0.05, 2


def auto_gate_radius(physics: dict, model_radius: int) -> int:
    noise, iso = physics.get("frame_noise", -1.0), physics.get("isolated_event_fraction", -1.0)
    if model_radius < 0 or noise < 0 or iso < 0:
        return model_radius
    clean = noise < CLEAN_FRAME_NOISE and iso < CLEAN_ISOLATED_EVENTS
    return model_radius if clean else max(model_radius, NOISY_GATE_RADIUS)


def evaluate(data: List[str], models: Dict[str, str], cli: str = "", cli_modes=(), limit: int = 0,
             threads: int = 2, log=print, gate: str = "model", bands=()) -> dict:
    """gate "auto": each gated variant runs each sequence at the radius `unroll --gate-radius auto`
    chooses there (needs `cli`); "model": at its metadata's."""
    if gate == "auto" and not cli:
        raise DataError("--gate auto needs --cli (the noise measure is the contrast estimate's)")
    torch.set_num_threads(threads)
    nets = {name: load_model(path) for name, path in models.items()}
    for name, net in nets.items():
        net.eval_name = name  # the --model NAME, for post hoc variants that patch unroll_pair (results/eval/*)
    own_gate = {name: (net.cfg.physics_gate if net.cfg.physics_input else -1) for name, net in nets.items()}
    seqs = [Sequence(p, cache_images=True) for p in list_sequences(data)]
    rows = []
    t0 = time.time()
    with tempfile.TemporaryDirectory() as work:
        for seq in seqs:
            ts = time.time()
            gamma = pn.meta_gamma(seq)
            phys_cli = cli_metrics(cli, seq, work, "physics") if cli else None
            contrast, log_offset = ((float(phys_cli["_summary"]["physics"]["contrast"]),
                                     float(phys_cli["_summary"]["physics"].get("log_offset", 0.0))) if phys_cli else
                                    pn.estimate_physics(seq, None, gamma))
            radii = {}
            for name, net in nets.items():
                if own_gate[name] >= 0:
                    net.cfg.physics_gate = (auto_gate_radius(phys_cli["_summary"]["physics"], own_gate[name])
                                            if gate == "auto" else own_gate[name])
                    radii[name] = net.cfg.physics_gate
            info = SeqInfo(seq)
            info.gamma = gamma
            info.contrast = lambda c=contrast: c  # the contrast --mode physics estimated (the variant: log offset 0)
            cli_model = {}
            for name, path in models.items():
                for mode in cli_modes:
                    cli_model[(name, mode)] = cli_metrics(cli, seq, work, mode, path, gate)
            gts = [(i, g) for i, g in enumerate(seq.meta.get("ground_truth") or [])]
            if limit:
                gts = gts[:limit]
            frames = list(range(seq.num_frames))
            for i, g in gts:
                t = float(g["t_us"])
                k = pn.frame_for_time(seq, frames, t)
                tau = float(g.get("tau", (t - seq.frame_span(k)[0]) / (seq.frame_span(k)[1] - seq.frame_span(k)[0])))
                gt = seq.gt_image(i)
                row = {"sequence": os.path.basename(seq.folder.rstrip("/")), "kind": kind_of(seq), "noise": noise_of(seq),
                       "t_us": t, "frame": k, "tau": tau, "intra": 0.0 <= tau <= 1.0, "psnr": {}, "ssim": {},
                       "gate_radius": radii}
                rs = seq.frame(k)
                row["psnr"]["RS input"], row["ssim"]["RS input"] = psnr(rs, gt), ssim(rs, gt)
                # Frame k's physics image, computed once: the method's score (without the CLI) and the bands' centre.
                ph = pn.unroll_physics(seq, k, t, contrast, gamma, log_offset=log_offset) if bands or not phys_cli else None
                if phys_cli:
                    m = [v for tt, v in phys_cli.items() if tt != "_summary" and abs(tt - t) < 0.5][0]
                    row["psnr"]["physics"], row["ssim"]["physics"] = float(m["psnr"]), float(m["ssim"])
                else:
                    row["psnr"]["physics"], row["ssim"]["physics"] = psnr(ph, gt), ssim(ph, gt)
                full = (0, 0, seq.width, seq.height)
                for name, net in nets.items():
                    if k + 1 < seq.num_frames:
                        r = unroll_pair(net, seq, k, t, seq.exposure, net.cfg.N, full, info)
                        s_img = r["s1"][0].numpy()
                        m_img = r["m"][0].numpy() if "m" in r else s_img
                    else:  # the last frame: S only (as unroll --mode m); unroll_pair needs frame k+1
                        r = unroll_pair(net, seq, k - 1, t, seq.exposure, net.cfg.N, full, info)
                        s_img = m_img = r["s2"][0].numpy()
                    imgs = [(f"{name}-S", s_img), (f"{name}-M", m_img)]
                    if bands:  # the band around frame k's physics (pn.event_band), post hoc
                        imgs += [(f"{tag} band{w:g}", pn.event_band(img, ph, contrast, gamma, log_offset, w))
                                 for tag, img in list(imgs) for w in bands]
                    for tag, img in imgs:
                        row["psnr"][tag], row["ssim"][tag] = psnr(img, gt), ssim(img, gt)
                    for mode in cli_modes:
                        c = [v for tt, v in cli_model[(name, mode)].items() if tt != "_summary" and abs(tt - t) < 0.5][0]
                        tag = f"{name}-{mode.upper()}(cli)"
                        row["psnr"][tag], row["ssim"][tag] = float(c["psnr"]), float(c["ssim"])
                rows.append(row)
            log(f"{seq.folder}: {len(gts)} targets, contrast {contrast:.3f}, gamma {gamma:g}"
                + "".join(f", {n} gate radius {r}" for n, r in radii.items()) + f" ({time.time() - ts:.0f} s)")
    return {"data": data, "models": models, "cli": cli, "cli_modes": list(cli_modes), "gate": gate, "rows": rows,
            "seconds": round(time.time() - t0, 1), "summary": summarize(rows)}


def summarize(rows: List[dict]) -> dict:
    """Mean PSNR/SSIM per (group, intra|inter, method); groups: each sequence, each kind, each
    preset, with noise or without (`noisy`), each (kind, with noise or without), all."""
    out: Dict[str, dict] = {}
    for r in rows:
        noise = r.get("noise", "unknown")
        grps = (f"seq:{r['sequence']}", f"kind:{r['kind']}", f"preset:{noise}", f"noise:{noisy(noise)}",
                f"kind:{r['kind']} noise:{noisy(noise)}", "all")
        for grp in grps:
            d = out.setdefault(grp, {}).setdefault("intra" if r["intra"] else "inter", {})
            for meth in r["psnr"]:
                e = d.setdefault(meth, {"psnr": [], "ssim": []})
                e["psnr"].append(r["psnr"][meth])
                e["ssim"].append(r["ssim"][meth])
    for grp in out.values():
        for part in grp.values():
            for meth, e in part.items():
                part[meth] = {"psnr": float(np.mean(e["psnr"])), "ssim": float(np.mean(e["ssim"])), "n": len(e["psnr"])}
    return out


def markdown(res: dict, groups: Optional[List[str]] = None) -> str:
    s = res["summary"]
    methods = []
    for grp in s.values():
        for part in grp.values():
            methods += [m for m in part if m not in methods]
    groups = groups or sorted(s, key=lambda g: (g != "all", g.startswith("seq:"), g.startswith("preset:"), "noise:" in g, g))
    lines = ["| group | part | " + " | ".join(methods) + " |", "| --- | --- |" + " --- |" * len(methods)]
    for g in groups:
        for part in ("intra", "inter"):
            if part not in s[g]:
                continue
            cells = [f"{s[g][part][m]['psnr']:.2f}" if m in s[g][part] else "" for m in methods]
            n = max(v["n"] for v in s[g][part].values())
            lines.append(f"| {g} | {part} (n={n}) | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("SSIM, same groups:")
    lines.append("")
    lines.append("| group | part | " + " | ".join(methods) + " |")
    lines.append("| --- | --- |" + " --- |" * len(methods))
    for g in groups:
        for part in ("intra", "inter"):
            if part in s[g]:
                cells = [f"{s[g][part][m]['ssim']:.3f}" if m in s[g][part] else "" for m in methods]
                lines.append(f"| {g} | {part} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n", 1)[1])
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--model", action="append", default=[], metavar="NAME=FILE")
    ap.add_argument("--cli", default=os.environ.get("VKUNROLL_CLI", ""))
    ap.add_argument("--cli-modes", default="", help="comma list of unroll modes (s, m) to run each model through the CLI")
    ap.add_argument("--limit", type=int, default=0, help="at most this many GT instants per sequence")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json")
    ap.add_argument("--gate", choices=("model", "auto"), default="model",
                    help="gated variants: the metadata's radius, or per sequence the one `unroll --gate-radius auto` picks")
    ap.add_argument("--bands", default="", help="comma list of widths w: also score each model's output clamped "
                    "to its event band around physics, lin(phys) * exp(+-w c) (physics_numpy.event_band)")
    a = ap.parse_args(argv)
    models = {}
    for m in a.model:
        if "=" not in m:
            ap.error(f"--model {m}: expected NAME=FILE")
        name, path = m.split("=", 1)
        models[name] = path
    try:
        res = evaluate(a.data, models, a.cli, [x for x in a.cli_modes.split(",") if x], a.limit, a.threads, gate=a.gate,
                       bands=[float(x) for x in a.bands.split(",") if x])
    except DataError as e:
        print(f"natural_eval.py: error: {e}", file=sys.stderr)
        return 1
    print(markdown(res))
    if a.json:
        json.dump(res, open(a.json, "w"), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
