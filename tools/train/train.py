#!/usr/bin/python3
"""Trains a SelfUnroll model with the paper's self-supervised losses, from sequences in the generic
layout (simulated by `vkunroll simulate`, or a real recording), and exports vkunroll's weights file.
Details, formulas and the shipped model's command: docs/training.md.

  # simulated data (calls the vkunroll CLI once a sequence)
  train.py --make-data data/train --sequences 24 --seed-base 1000 [--size 240x180 --frames 8]
  # stage 1 (SelfUnroll-S: Llc + Lcc + Ltc + 0.01 Ltv), then stage 2 (MOA alone, dual cycle)
  train.py --data data/train --val data/val --out runs/small --steps-s 3000 --steps-m 600 --max-minutes 50
  train.py --resume runs/small/checkpoint.pt          # continues where it stopped (same arguments)
  train.py --export-checkpoint runs/small/checkpoint.pt models/small.safetensors
  # physics-informed variant (docs/model.md), prepared samples, chunks of 5 minutes on a GPU
  train.py --data data/natural/train --physics-variant --make-cache cache/ --cache-samples 4096
  train.py --cache cache/ --physics-variant --device cuda --chunk-minutes 5 --out runs/v   (then --resume ...)
  # adaptation to one recording (self-supervised only)
  train.py --adapt data/rec1 --from models/selfunroll_small_physics.safetensors --minutes 10 --out runs/rec1

The self-supervised losses read no ground truth. --supervised (L1 to the simulated GS frames at t*)
trains on simulated sequences only; it is how the shipped photo model was fine-tuned (docs/training.md).
--adapt (a user's recording) is always self-supervised; the recording's last frames are held out of
its crops and the export is the step with the lowest self-supervised loss on them, the input model if
none is lower (tools/train/adapt_guard.py); inside exposure spans its outputs are pulled toward the input
model's (--adapt-anchor, default ADAPT_ANCHOR).
Validation (--val) uses the ground truth of held-out sequences to print PSNRs, nothing else.
"""
from __future__ import annotations

import datetime
import json
import math
import os
import random
import shlex
import sys
import time
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch
from torch import nn

from tools.model import physics_numpy as pn
from tools.model import safetensors_io
from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig, Unet, UnetConfig
from tools.data.sequence_data import DataError, Sequence, list_sequences
from tools.train.adapt_guard import AdaptGuard, IntraAnchor, one_way_pair, selected_so_far
from tools.train.train_args import build_parser, check_args
from tools.train.train_schedule import ThreadChooser, cosine_lr
from tools.train.train_data import (CacheSampler, Sample, Sampler, SeqInfo, crop_img, describe_data, find_cli,  # noqa: F401
                                    SUPERVISED_PASSES, from_model_encoding, gt_targets, images, make_data,
                                    make_sample, stack, stack_lr, write_cache)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LOSS_WEIGHTS = {"lc": 1.0, "cc": 1.0, "tc": 1.0, "tv": 0.01}
# --adapt's pull toward the input model inside frames: chosen on the second generator's validation suite
# (weight 1 still lost 0.59 dB inside frames, 10 gained 0.16; docs/journal/training.md, "The intra-frame anchor")
ADAPT_ANCHOR = 10.0
BRANCHES = ("sys", "warped", "fused")  # E-IC_T, E-IC_S, E-IC_S+T: every consistency applies to all three

# ---- configurations ---------------------------------------------------------------------------------
PRESETS = {
    # the shipped model: ~1M parameters (4 MB F32), ~62k multiply-adds a pixel for SelfUnroll-S
    # (the published model: ~2.3M), cheap enough to learn something on 2 CPU cores in under an hour
    "small": dict(D=2, C=3, G=12, G0=24, N=4, upnet_width=48, flownet=(8, 3), fusion_net=(8, 3),
                  attfusion_net=(8, 3)),
    "medium": dict(D=3, C=3, G=16, G0=32, N=4, upnet_width=64, flownet=(16, 3), fusion_net=(16, 3),
                   attfusion_net=(8, 3)),
    "tiny": dict(D=1, C=2, G=8, G0=16, N=2, upnet_width=32, flownet=(8, 2), fusion_net=(8, 2),
                 attfusion_net=(4, 2)),
    "published": dict(D=10, C=5, G=48, G0=96, N=16, upnet_width=256, flownet=(32, 4), fusion_net=(32, 3),
                      attfusion_net=(32, 3)),
}


def make_config(preset: str, n_bins: Optional[int] = None) -> SelfUnrollConfig:
    p = dict(PRESETS[preset])
    cfg = SelfUnrollConfig()
    for k in ("D", "C", "G", "G0", "N", "upnet_width"):
        setattr(cfg, k, p[k])
    for k in ("flownet", "fusion_net", "attfusion_net"):
        setattr(cfg, k, UnetConfig(*p[k]))
    if n_bins:
        cfg.N = n_bins
    return cfg


def _identity_rows(conv: nn.Conv2d, rows, src_offset: int = 0) -> None:
    """Output channels `rows` of `conv` copy input channels src_offset + row (centre tap 1, the rest 0)."""
    k = conv.weight.shape[-1] // 2
    for j in rows:
        conv.weight[j].zero_()
        conv.weight[j, src_offset + j, k, k] = 1.0
        conv.bias[j] = 0.0


def init_fusion_passthrough(unet: Unet, channels: int = 3) -> None:
    """Makes a fresh UNet pass its first `channels` inputs through to its output: an identity path
    head -> level-0 ResBlock -> skip (conv2) -> up_path[0] (conv_skip, conv1, ResBlock) -> pred,
    on feature channels 0..channels-1; every other weight keeps its random init. fusion_net's first
    inputs are `sys`, so SelfUnroll-S starts as E-IC_T (= the RS image while E ~ 0) instead of a
    random UNet that must first learn to reproduce the image (a small UNet trained for an hour on
    a CPU never does: 24-25 dB even where nothing moved). LeakyReLU keeps values >= 0 unchanged."""
    rows = range(channels)
    _identity_rows(unet.head, rows)
    for rb in (unet.down_path[0].conv1, unet.up_path[0].conv2):  # ResBlock: x + conv(x), zero the added rows
        rb.conv[1].weight[list(rows)] = 0.0
        rb.conv[1].bias[list(rows)] = 0.0
    _identity_rows(unet.down_path[0].conv2[0], rows)
    up = unet.up_path[0]
    _identity_rows(up.conv_skip[0], rows)
    _identity_rows(up.conv1[0], rows, src_offset=up.conv1[0].weight.shape[1] // 2)  # cat(deconv, skip)
    _identity_rows(unet.pred, rows)


def init_model(net: SelfUnroll, seed: int, fusion_passthrough: bool = True) -> None:
    """PyTorch's default init, except that the flow head and the residual head start near zero
    (flow = 100 tanh(raw) would otherwise start with random displacements of tens of pixels), and,
    with `fusion_passthrough`, fusion_net starts as the identity on its `sys` input. The physics
    variant's residual head starts at exactly zero, so E = 0, sys = phys and (with the pass-through)
    SelfUnroll-S outputs the physics estimate exactly at step 0."""
    torch.manual_seed(seed)
    for m in net.modules():
        if hasattr(m, "reset_parameters"):
            m.reset_parameters()
    with torch.no_grad():
        heads = (net.flownet.pred, net.UPNet[2]) + ((net.attfusion_net.pred,) if net.cfg.physics_input and net.cfg.moa else ())
        for conv in heads:
            conv.weight.mul_(0.0 if net.cfg.physics_input and conv is net.UPNet[2] else 0.01)
            conv.bias.zero_()
        if fusion_passthrough:
            init_fusion_passthrough(net.fusion_net)


def lift_to_physics(src: SelfUnroll, seed: int) -> SelfUnroll:
    """The physics variant of a trained model: its weights, SFENet1 widened by zero weights for the
    phys channels, the residual head zeroed (E = 0: sys = phys) and fusion_net re-initialised as the
    pass-through, so the result starts exactly at the physics estimate and keeps the learned trunk."""
    cfg = SelfUnrollConfig(**{**src.cfg.__dict__})
    cfg.physics_input, cfg.gamma = True, src.cfg.gamma or 2.2
    net = SelfUnroll(cfg)
    init_model(net, seed)
    sd = net.state_dict()
    for k, v in src.state_dict().items():
        # attfusion_net restarts (m ~ 0.5): a trained MOA whose score sits beyond hardsigmoid's +-3
        # has zero gradient there, and stage 2 could not move it (see reset_moa)
        if k.startswith("fusion_net.") or k.startswith("UPNet.2.") or k.startswith("attfusion_net."):
            continue
        if k == "SFENet1.weight":
            w = torch.zeros_like(sd[k])
            w[:, :v.shape[1]] = v
            v = w
        sd[k] = v
    net.load_state_dict(sd)
    return net


def reset_moa(net: SelfUnroll, seed: int) -> None:
    """attfusion_net restarts from PyTorch's default init, its head at 0.01 x that with zero bias
    (m = hardsigmoid ~ 0.5): a MOA whose score saturated beyond +-3 has no gradient left for
    stage 2, and resetting the head alone is not enough where the UNet's features reach 1e5-1e8."""
    torch.manual_seed(seed + 17)
    with torch.no_grad():
        for m in net.attfusion_net.modules():
            if m is not net.attfusion_net and hasattr(m, "reset_parameters"):
                m.reset_parameters()
        net.attfusion_net.pred.weight.mul_(0.01)
        net.attfusion_net.pred.bias.zero_()


# ---- losses -----------------------------------------------------------------------------------------
def l1(a, b):
    return (a - b).abs().mean()


def tv(flow):
    return (flow[:, :, 1:, :] - flow[:, :, :-1, :]).abs().mean() + (flow[:, :, :, 1:] - flow[:, :, :, :-1]).abs().mean()


def run_s(net: SelfUnroll, img, ev, lr=None, gate_radii=None):
    """SelfUnroll-S on a batch; `lr` (physics variant): the passes' physics log ratios [B,1,H,W],
    applied to `img` itself (also a network output: the cycle passes), so phys follows the input;
    `gate_radii`: each item's event gate radius (None: the model's)."""
    phys = None
    if net.cfg.physics_input:
        if lr is None:
            raise DataError("the physics-informed variant needs samples with physics log ratios")
        phys = pn.apply_log_ratio_torch(img, lr, net.cfg.gamma or 1.0)
    sys_, E, flow, warped, fused, _, _ = net(img, ev[0], ev[1], ev[2], moa=False, phys=phys, gate_radii=gate_radii)
    return {"sys": sys_, "E": E, "flow": flow, "warped": warped, "fused": fused, "ev1": ev[0]}


def run_passes(net: SelfUnroll, img, samples: List[Sample], passes, device):
    """run_s on the event tensors of `passes` batched pass after pass (B items each); `img` is the
    input batch in the same order."""
    ev = [torch.cat(t) for t in zip(*(stack(samples, p, device) for p in passes))]
    radii = (None if all(s.gate_radius < 0 for s in samples) else  # -1: the model's own radius
             [s.gate_radius if s.gate_radius >= 0 else net.cfg.physics_gate for s in samples] * len(passes))
    return run_s(net, img, ev, stack_lr(samples, passes, device), radii)


def split(o: dict, n: int):
    return {k: v[:n] for k, v in o.items()}, {k: v[n:] for k, v in o.items()}


def stage_s_losses(net: SelfUnroll, samples: List[Sample], supervised: bool = False, anchor=None,
                   lc_one_way: bool = False):
    """Stage 1 (SelfUnroll-S). B = len(samples); one batched pass for g1, g2, r12, r21 (4B) and one
    for the cycle's second half c1, c2 (2B), whose input images are the fused GS results of g1, g2.
      Llc = sum_b |b(g1) - b(g2)|,  Ltc = sum_b |b(r12) - rs2| + |b(r21) - rs1|,
      Lcc = sum_b |b(c1) - rs1| + |b(c2) - rs2|,  Ltv = mean TV of the flow of all 6B passes,
    b over the E-IC outputs sys (E-IC_T), warped (E-IC_S), fused (E-IC_S+T); |.| = mean abs.
    `anchor` (adaptation, adapt_guard.IntraAnchor): adds its pull toward the input model, weighted;
    `lc_one_way` (adaptation): Llc inside exposure spans teaches one way (adapt_guard.one_way_pair)."""
    B = len(samples)
    dv = next(net.parameters()).device
    rs1, rs2 = images(samples, "rs1", dv), images(samples, "rs2", dv)
    L = {}
    if supervised:  # only the two passes toward t* (g1, g2) meet the ground truth
        g = run_passes(net, torch.cat([rs1, rs2]), samples, SUPERVISED_PASSES, dv)
        g1, g2 = split(g, B)
        gt = images(samples, "gt", dv)
        L["sup"] = sum(l1(g1[b], gt) + l1(g2[b], gt) for b in BRANCHES)
        L["tv"] = tv(g["flow"])
        L["total"] = L["sup"] + LOSS_WEIGHTS["tv"] * L["tv"]
        return L
    first = run_passes(net, torch.cat([rs1, rs2, rs1, rs2]), samples, ("g1", "g2", "r12", "r21"), dv)
    g, r = split(first, 2 * B)
    g1, g2 = split(g, B)
    r12, r21 = split(r, B)
    second = run_passes(net, torch.cat([g1["fused"], g2["fused"]]), samples, ("c1", "c2"), dv)
    c1, c2 = split(second, B)
    L["lc"] = sum(l1(*(one_way_pair(samples, g1[b], g2[b]) if lc_one_way else (g1[b], g2[b]))) for b in BRANCHES)
    L["cc"] = sum(l1(c1[b], rs1) + l1(c2[b], rs2) for b in BRANCHES)
    L["tc"] = sum(l1(r12[b], rs2) + l1(r21[b], rs1) for b in BRANCHES)
    L["tv"] = (tv(first["flow"]) * 4 + tv(second["flow"]) * 2) / 6
    L["total"] = sum(LOSS_WEIGHTS[k] * L[k] for k in ("lc", "cc", "tc", "tv"))
    if anchor:
        L["anchor"] = anchor(samples, rs1, rs2, g1, g2)
        L["total"] = L["total"] + anchor.weight * L["anchor"]
    return L


# Stage 2's gradient leak through hardsigmoid's flat parts: without it the blend saturated at one
# frame (m = 0 or 1 everywhere) within the first few hundred steps of every run and never moved again.
MOA_GRAD_LEAK = 0.05


def moa(net: SelfUnroll, a: dict, b: dict):
    leak = MOA_GRAD_LEAK if torch.is_grad_enabled() and net.training else 0.0
    return net.moa_blend(a["E"], b["E"], a["ev1"], b["ev1"], a["flow"], b["flow"], a["fused"], b["fused"],
                         grad_leak=leak)[1]


def stage_m_losses(net: SelfUnroll, samples: List[Sample], supervised: bool = False):
    """Stage 2 (MOA alone, SelfUnroll-S frozen), the dual cycle consistency:
      G = M(rs1 -> t*, rs2 -> t*);  rs1~ = M(G -> rs1, rs2 -> rs1);  rs2~ = M(G -> rs2, rs1 -> rs2);
      Ldcc = |rs1~ - rs1| + |rs2~ - rs2|."""
    B = len(samples)
    dv = next(net.parameters()).device
    rs1, rs2 = images(samples, "rs1", dv), images(samples, "rs2", dv)
    L = {}
    if supervised:  # the M result of g1 and g2 against the ground truth
        g = run_passes(net, torch.cat([rs1, rs2]), samples, SUPERVISED_PASSES, dv)
        g1, g2 = split(g, B)
        L["sup"] = l1(moa(net, g1, g2), images(samples, "gt", dv))
        L["total"] = L["sup"]
        return L
    first = run_passes(net, torch.cat([rs1, rs2, rs1, rs2]), samples, ("g1", "g2", "r12", "r21"), dv)
    g, r = split(first, 2 * B)
    g1, g2 = split(g, B)
    r12, r21 = split(r, B)
    G = moa(net, g1, g2)
    second = run_passes(net, torch.cat([G, G]), samples, ("c1", "c2"), dv)
    c1, c2 = split(second, B)
    rs1_t = moa(net, c1, r21)
    rs2_t = moa(net, c2, r12)
    L["dcc"] = l1(rs1_t, rs1) + l1(rs2_t, rs2)
    L["total"] = L["dcc"]
    return L


# ---- validation (uses ground truth of held-out sequences; never used for training) -------------------
def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a.clamp(0, 1) - b.clamp(0, 1)) ** 2).mean())
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def unroll_pair(net: SelfUnroll, seq: Sequence, k: int, t_star: float, texp: float, bins: int, crop,
                info: Optional[SeqInfo] = None):
    """S results from frames k and k+1 and the M result, all toward t*: dict of [1,3,h,w], in the
    sequence's own encoding (the model runs in its gamma when its metadata states one)."""
    dv = next(net.parameters()).device
    info = info or SeqInfo(seq)
    smp = make_sample(seq, k, crop, t_star, texp, bins, None, info, net.cfg.gamma, net.cfg.physics_input)
    ev = [torch.from_numpy(np.stack([smp.ev["g1"][i], smp.ev["g2"][i]])).to(dv) for i in range(3)]
    lr = stack_lr([smp], ("g1", "g2"), dv)
    rs = torch.from_numpy(np.stack([smp.rs1, smp.rs2])).to(dv)
    back = lambda x: from_model_encoding(x, info.gamma, net.cfg.gamma).cpu()  # noqa: E731
    with torch.no_grad():
        o = run_s(net, rs, ev, lr)
        a, b = split(o, 1)
        res = {"rs1": torch.from_numpy(crop_img(seq.frame(k), crop))[None],
               "rs2": torch.from_numpy(crop_img(seq.frame(k + 1), crop))[None],
               "s1": back(a["fused"]), "s2": back(b["fused"])}
        if net.cfg.physics_input:
            res["phys1"] = back(pn.apply_log_ratio_torch(rs[:1], lr[:1], net.cfg.gamma or 1.0))
        if net.cfg.moa:
            res["m"] = back(moa(net, a, b))
    return res


def refuse_heldout(paths: List[str], option: str) -> None:
    """DataError naming the first sequence natural_data.py marked held-out (natural.json "split":
    "heldout": evaluation only, so neither trained nor tuned on), or, for --data, validation-only
    ("split": "validation": the second generator's, for decisions but never for training)."""
    for p in list_sequences(paths):
        nat = os.path.join(p, "natural.json")
        if not os.path.isfile(nat):
            continue
        try:
            split = json.load(open(nat)).get("split")
        except (OSError, ValueError) as e:
            raise DataError(f"{nat}: cannot be read ({e}): it says whether the sequence is held out")
        if split == "heldout":
            raise DataError(f"{option} {p}: the sequence is marked held-out ({nat}: split 'heldout', evaluation only); "
                            "training and validation must not use it")
        if split == "validation" and option == "--data":
            raise DataError(f"{option} {p}: the sequence is marked validation-only ({nat}: split 'validation', e.g. "
                            "tools/data/second_generator.py's); it may serve --val, never training")


def seq_kind(seq: Sequence) -> str:
    """The motion kind natural_data.py recorded (natural.json), else ''."""
    p = os.path.join(seq.folder, "natural.json")
    if not os.path.isfile(p):
        return ""
    return str(json.load(open(p)).get("kind", ""))


def validate(net: SelfUnroll, seqs: List[Sequence], bins: int, target_exposure: Optional[float],
             max_targets: int = 12, crop_size: Optional[Tuple[int, int]] = None,
             infos: Optional[Dict[str, SeqInfo]] = None) -> Dict[str, float]:
    """Mean PSNR of the RS frame k, S (frame k) and M on up to max_targets GT instants in total
    (spread over the sequences), on a centre crop of crop_size or the full frame."""
    net.eval()
    sums: Dict[str, List[float]] = {}
    per_seq = max(1, max_targets // max(1, len(seqs)))
    for seq in seqs:
        targets = gt_targets(seq)
        step = max(1, len(targets) // per_seq)
        for i, k, _ in targets[::step][:per_seq]:
            if crop_size:
                cw, ch = min(crop_size[0], seq.width), min(crop_size[1], seq.height)
                crop = ((seq.width - cw) // 2, (seq.height - ch) // 2, cw, ch)
            else:
                crop = (0, 0, seq.width, seq.height)
            texp = target_exposure or seq.exposure
            info = (infos or {}).get(seq.folder)
            r = unroll_pair(net, seq, k, seq.gt[i][1], texp, bins, crop, info)
            gt = torch.from_numpy(crop_img(seq.gt_image(i), crop))[None]
            kind = seq_kind(seq)
            for name, key in (("rs", "rs1"), ("phys", "phys1"), ("S", "s1"), ("M", "m")):
                if key in r:
                    sums.setdefault(name, []).append(psnr(r[key], gt))
                    if kind and name != "rs":  # per motion kind of tools/data/natural_data.py
                        sums.setdefault(f"{name}/{kind}", []).append(sums[name][-1])
    net.train()
    return {k: float(np.mean(v)) for k, v in sums.items()}


# ---- export -----------------------------------------------------------------------------------------
def export(net: SelfUnroll, path: str, info: Dict[str, str]) -> int:
    md = net.cfg.to_metadata()
    md.update({f"training.{k}": str(v) for k, v in info.items()})
    tensors = {k: v.detach().float().contiguous() for k, v in net.state_dict().items()}
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    safetensors_io.save(path, tensors, md)
    return os.path.getsize(path)


def export_checkpoint(ckpt_path: str, out: str) -> None:
    """An adaptation's checkpoint exports the guard's choice so far (never worse by its measure), not the running weights."""
    ck = torch.load(ckpt_path, map_location="cpu", weights_only=False)
    cfg = config_from_dict(ck["config"])
    net = SelfUnroll(cfg)
    chosen = selected_so_far(os.path.dirname(os.path.abspath(ckpt_path))) if ck["info"].get("adapt") else None
    net.load_state_dict(chosen[0] if chosen else ck["model"])
    size = export(net, out, dict(ck["info"], **({"adapt_selected": chosen[1]} if chosen else {})))
    print(f"wrote {out}: {size / 1e6:.2f} MB, {sum(p.numel() for p in net.parameters())} parameters")


def config_from_dict(d: dict) -> SelfUnrollConfig:
    d = dict(d)
    for k in ("flownet", "fusion_net", "attfusion_net"):
        d[k] = UnetConfig(**d[k])
    return SelfUnrollConfig(**d)


# ---- training -------------------------------------------------------------------------------------------
def build_model(a, state):
    """The network to train: from a checkpoint (--resume), a weights file (--from; lifted to the
    physics variant with --physics-variant), a checkpoint's weights (--init), or a fresh init."""
    if state:
        net = SelfUnroll(config_from_dict(state["config"]))
        net.load_state_dict(state["model"])
        return net
    if a.from_model:
        from tools.model import selfunroll_torch
        net = selfunroll_torch.load_model(a.from_model)
        if a.physics_variant and not net.cfg.physics_input:
            net = lift_to_physics(net, a.seed)
        if a.gamma is not None:
            net.cfg.gamma = a.gamma
        if a.description:
            net.cfg.description = a.description
        if a.physics_gate is not None:
            net.cfg.physics_gate = a.physics_gate
        if a.physics_confidence:
            net = selfunroll_torch.add_confidence(net)
        if a.reset_moa and net.cfg.moa:
            reset_moa(net, a.seed)
        return net.train()
    cfg = make_config(a.config, a.bins)
    cfg.physics_input = bool(a.physics_variant)
    if a.physics_gate is not None:
        cfg.physics_gate = a.physics_gate
    cfg.gamma = a.gamma if a.gamma is not None else 2.2
    cfg.description = a.description or f"vkunroll {a.config}{' physics-informed' if cfg.physics_input else ''} " \
                                        "SelfUnroll trained with tools/train/train.py"
    net = SelfUnroll(cfg)
    if a.init:
        ck = torch.load(a.init, map_location="cpu", weights_only=False)
        net.load_state_dict(ck["model"] if "model" in ck else ck)
    else:
        init_model(net, a.seed, fusion_passthrough=not a.no_fusion_passthrough)
    return net


def make_sampler(a, cfg, rng, out):
    """Samples from a cache (--cache), else drawn from the sequences of --data (or --adapt)."""
    if a.gate_radii and cfg.physics_gate < 0:
        raise DataError(f"--gate-radii {a.gate_radii}: the model has no event gate (--physics-gate)")
    if a.contrast_jitter > 1.0 and not cfg.physics_input:
        raise DataError(f"--contrast-jitter {a.contrast_jitter:g}: the model has no physics input (--physics-variant)")
    if a.cache:
        cs = CacheSampler(a.cache, rng, cfg.N, cfg.physics_input, a.supervised)
        return cs, [], f"cache {a.cache}: {len(cs)} samples of {len(cs.seqs)} sequences", [a.cache]
    paths = [a.adapt] if a.adapt else a.data
    seqs = [Sequence(p) for p in list_sequences(paths)]
    cw, ch = a.crop
    if a.adapt:  # one recording: crops as large as asked, at most the sensor
        cw, ch = min(cw, seqs[0].width), min(ch, seqs[0].height)
    sampler = Sampler(seqs, cw, ch, cfg.N, a.target_exposure_us, rng, a.supervised, cfg.physics_input, cfg.gamma,
                      a.data_gamma, os.path.join(out, "contrast_cache.json"), a.event_crops, a.gate_radii,
                      a.contrast_jitter)
    return sampler, seqs, describe_data(paths, seqs), paths


def run_info(a, state, data_desc, dev) -> Dict[str, str]:
    """The metadata the exported weights carry: the command, the data, the losses and the settings."""
    info = dict(state["info"]) if state else {}
    info.setdefault("command", shlex.join(["python3", "-m", "tools.train.train"] + sys.argv[1:]))
    info.update({"data": data_desc, "crop": f"{a.crop[0]}x{a.crop[1]}", "batch": str(a.batch), "seed": str(a.seed),
                 "lr": str(a.lr), "supervised": "true" if a.supervised else "false", "device": str(dev),
                 "losses": ("stage s: 1*Llc + 1*Lcc + 1*Ltc + 0.01*Ltv on sys/warped/fused; "
                            "stage m: Ldcc (attfusion_net alone)") if not a.supervised else
                 "supervised (simulated ground truth): stage s: L1 of sys/warped/fused of g1 and g2 to the GS frame "
                 "at t* + 0.01*Ltv; stage m: L1 of the M result",
                 "target_exposure_us": str(a.target_exposure_us or "rs exposure")})
    if a.confidence_only:
        info["trained"] = "the learned confidence alone (fusion_net.pred row 3); every other weight as loaded"
    if a.adapt:
        info.update({"adapt": a.adapt, "adapt_from": a.from_model or "", "adapt_minutes": str(a.max_minutes),
                     "adapt_anchor": str(a.adapt_anchor), "adapt_lc_one_way": str(a.adapt_lc_one_way).lower()})
    return info


class TrainRun:
    """What every stage of one run shares: the model, the data, validation, the guard and the metadata."""

    def __init__(self, a):
        self.a = a
        self.dev = torch.device(a.device)
        self.threads = ThreadChooser(a.threads if self.dev.type == "cpu" else "1")
        os.makedirs(a.out, exist_ok=True)
        self.ckpt_path = os.path.join(a.out, "checkpoint.pt")
        self.state = None
        if a.resume:
            self.state = torch.load(a.resume, map_location="cpu", weights_only=False)
            print(f"resuming {a.resume}: stage {self.state['stage']}, step {self.state['step']}", flush=True)
        self.net = build_model(a, self.state).to(self.dev)
        if a.confidence_only:  # the rest stays as loaded (masked gradients), and stage M has nothing to train
            from tools.model import selfunroll_torch
            try:
                selfunroll_torch.confidence_only(self.net)
            except ValueError as e:
                raise DataError(f"--confidence-only: {e} (add --physics-confidence)")
        self.cfg = self.net.cfg
        self.n_params = sum(p.numel() for p in self.net.parameters())
        self.val = [Sequence(p) for p in list_sequences(a.val)] if a.val else []
        self.rng = random.Random(a.seed)
        if self.state and "rng" in self.state:
            self.rng.setstate(self.state["rng"])
        self.sampler, self.seqs, self.data_desc, self.paths = make_sampler(a, self.cfg, self.rng, a.out)
        self.val_infos = {v.folder: SeqInfo(v, a.data_gamma, os.path.join(a.out, "contrast_cache.json")) for v in self.val}
        self.guard = AdaptGuard(self.seqs[0], self.sampler, self.net, stage_s_losses, a.out, a.ckpt_every, batch=a.batch,
                                resumed=bool(a.resume), log=lambda m: print(m, flush=True)) if a.adapt else None
        # the input model as --from gives it, also on --resume (the anchor never moves)
        self.anchor = IntraAnchor(build_model(a, None).to(self.dev), a.adapt_anchor, run_passes, BRANCHES) \
            if a.adapt_anchor else None
        self.info = run_info(a, self.state, self.data_desc, self.dev)
        self.t_run0 = time.time()
        self.session_steps = 0

    def describe(self):
        a, cfg = self.a, self.cfg
        print(f"model: {self.n_params} parameters ({self.n_params * 4 / 1e6:.2f} MB F32), N={cfg.N}, "
              f"{'physics-informed, ' if cfg.physics_input else ''}gamma {cfg.gamma}; data: {self.data_desc}; "
              f"crop {a.crop[0]}x{a.crop[1]}, batch {a.batch}, device {self.dev}, threads {a.threads}"
              + (f"; physics contrast x [1/{a.contrast_jitter:g}, {a.contrast_jitter:g}]" if a.contrast_jitter > 1 else ""),
              flush=True)

    def save(self, opt, stage, step, elapsed):
        save_ckpt(self.ckpt_path, self.net, opt, stage, step, elapsed, self.rng, self.info, self.cfg)

    def step(self, stage, opt, params, step, lr):
        """One optimizer step of `stage`: its losses (floats) and the seconds spent drawing the samples."""
        a = self.a
        for g in opt.param_groups:
            g["lr"] = lr
        self.threads.before_step(step)
        t_step = t_data = time.time()
        samples = [self.sampler.draw() for _ in range(a.batch)]
        t_data = time.time() - t_data
        L = stage_s_losses(self.net, samples, a.supervised, self.anchor, a.adapt_lc_one_way) if stage == "s" else \
            stage_m_losses(self.net, samples, a.supervised)
        opt.zero_grad(set_to_none=True)
        L["total"].backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        self.threads.after_step(time.time() - t_step)
        return L, t_data

    def between_steps(self, stage, step, opt, t0) -> bool:
        """New sequences, validation, the guard and checkpoints after `step`; True when the session stops here."""
        a = self.a
        if a.rescan_every and step % a.rescan_every == 0 and not a.cache:
            known = {q.folder for q in self.sampler.seqs}
            if not a.adapt:
                refuse_heldout(self.paths, "--data")  # one written into the folder since
            new = [Sequence(p) for p in list_sequences(self.paths) if p not in known]
            new = [q for q in new if q.num_frames >= 2]
            if new:
                self.sampler.add(new)
                self.seqs += new
                print(f"[{stage}] step {step}: {len(new)} new sequences, {len(self.sampler.seqs)} in all", flush=True)
        if a.val_every and step % a.val_every == 0 and self.val:
            v = validate(self.net, self.val, self.cfg.N, a.target_exposure_us, a.val_targets, a.val_crop, self.val_infos)
            print(f"[{stage}] step {step} validation PSNR " + " ".join(f"{k} {x:.2f} dB" for k, x in v.items()), flush=True)
        if self.guard:
            self.guard.check(self.net, step)
        if step % a.ckpt_every == 0:
            self.save(opt, stage, step, time.time() - t0)
        self.session_steps += 1
        chunk_over = a.chunk_minutes and time.time() - self.t_run0 >= 60 * a.chunk_minutes
        if (a.stop_after and self.session_steps >= a.stop_after) or chunk_over:
            self.save(opt, stage, step, time.time() - t0)
            why = "--chunk-minutes" if chunk_over else "--stop-after"
            print(f"[{stage}] stopped after {self.session_steps} steps ({why}); resume with --resume {self.ckpt_path}",
                  flush=True)
            return True
        return False

    def stage(self, stage, steps, stage_budget, step, elapsed_before) -> bool:
        """Trains `stage` for `steps` steps or its time budget, from `step`; True when the session stopped inside it."""
        a, net, state = self.a, self.net, self.state
        if stage == "m":
            for n, p in net.named_parameters():
                p.requires_grad_(n.startswith("attfusion_net."))
        params = [p for p in net.parameters() if p.requires_grad]
        opt = torch.optim.Adam(params, lr=a.lr)
        if state and state["stage"] == stage and "opt" in state:
            opt.load_state_dict(state["opt"])
        else:
            step, elapsed_before = 0, 0.0
        t0 = time.time() - elapsed_before
        t_sess0, step_sess0 = time.time(), step
        last_print, ema, done_reason = 0.0, {}, "steps"
        net.train()
        while True:
            elapsed = time.time() - t0
            progress = step / steps
            if stage_budget:
                progress = max(progress, elapsed / stage_budget)
            if progress >= 1.0:
                done_reason = "time" if step < steps else "steps"
                break
            lr = a.lr if a.constant_lr else cosine_lr(a.lr, progress)
            L, t_data = self.step(stage, opt, params, step, lr)
            step += 1
            for k, v in L.items():
                ema[k] = float(v) if k not in ema else 0.9 * ema[k] + 0.1 * float(v)
            now = time.time()
            if now - last_print >= a.print_every or step == 1 or step == steps:
                last_print = now
                rate = (step - step_sess0) / max(1e-9, now - t_sess0)
                parts = " ".join(f"{k} {v:.4f}" for k, v in ema.items() if k != "total")
                print(f"[{stage}] step {step}/{steps} lr {lr:.2e} loss {ema['total']:.4f} ({parts}) "
                      f"{rate:.2f} step/s data {t_data:.2f}s elapsed {(now - t0) / 60:.1f} min", flush=True)
            if self.between_steps(stage, step, opt, t0):
                return True
        if self.guard and step % self.guard.every:
            self.guard.check(net, step, last=True)  # the last step, between two evaluations
        if not a.cache:
            self.info["data"] = describe_data(self.paths, self.seqs)
        self.info[f"steps_{stage}"] = str(step)
        self.info[f"minutes_{stage}"] = f"{(time.time() - t0) / 60:.1f}"
        self.info[f"final_loss_{stage}"] = f"{ema.get('total', float('nan')):.4f}"
        print(f"[{stage}] done after {step} steps ({done_reason}), {(time.time() - t0) / 60:.1f} min", flush=True)
        self.save(opt, stage, step, time.time() - t0)
        for p in net.parameters():
            p.requires_grad_(True)
        self.state = None
        return False

    def finish(self):
        a, net, info = self.a, self.net, self.info
        if self.val:
            v = validate(net, self.val, self.cfg.N, a.target_exposure_us, a.val_targets, a.val_crop, self.val_infos)
            info["val_psnr"] = " ".join(f"{k}={x:.2f}dB" for k, x in v.items())
            print("final validation PSNR " + " ".join(f"{k} {x:.2f} dB" for k, x in v.items()), flush=True)
        if self.guard:
            self.guard.finish(net, info)
        info["finished_utc"] = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
        save_ckpt(self.ckpt_path, net, None, "done", 0, 0.0, self.rng, info, self.cfg)
        out = a.export or os.path.join(a.out, "adapted.safetensors" if a.adapt else "model.safetensors")
        size = export(net, out, info)
        print(f"wrote {out}: {size / 1e6:.2f} MB ({self.n_params} parameters), run time "
              f"{(time.time() - self.t_run0) / 60:.1f} min", flush=True)


def train(a) -> None:
    run = TrainRun(a)
    run.describe()
    if a.make_cache:
        write_cache(run.sampler, a.make_cache, a.cache_samples, log=lambda m: print(m, flush=True))
        return
    steps_m = a.steps_m if run.cfg.moa and not a.adapt and not a.confidence_only else 0
    stages = [("s", a.steps_s), ("m", steps_m)]
    budget = a.max_minutes * 60 if a.max_minutes else None
    # share of the time budget per stage: proportional to steps, an M step costing ~1.3 S steps
    w = {"s": a.steps_s, "m": 1.3 * steps_m}
    stage_budget = {k: (budget * w[k] / max(1e-9, sum(w.values())) if budget else None) for k in w}
    state = run.state
    start_stage = state["stage"] if state else "s"
    step = state["step"] if state else 0
    elapsed_before = state.get("elapsed_stage", 0.0) if state else 0.0
    run.t_run0 = time.time()
    for stage, steps in stages:
        if (stage == "s" and start_stage == "m") or steps <= 0:
            continue
        if run.stage(stage, steps, stage_budget[stage], step, elapsed_before):
            return
    run.finish()


def save_ckpt(path, net, opt, stage, step, elapsed, rng, info, cfg):
    ck = {"model": {k: v.detach().cpu() for k, v in net.state_dict().items()}, "stage": stage, "step": step, "elapsed_stage": elapsed, "rng": rng.getstate(),
          "info": dict(info), "config": {**cfg.__dict__, **{k: getattr(cfg, k).__dict__ for k in
                                                            ("flownet", "fusion_net", "attfusion_net")}}}
    if opt is not None:
        ck["opt"] = opt.state_dict()
    tmp = path + ".tmp"
    torch.save(ck, tmp)
    os.replace(tmp, path)  # a kill during the save never leaves a broken checkpoint


def main(argv=None) -> int:
    ap = build_parser(__doc__, PRESETS, ADAPT_ANCHOR)
    a = ap.parse_args(argv)
    try:
        if a.make_data:
            make_data(a.make_data, a.sequences, a.seed_base, a.size, a.frames, a.gt_per_frame, find_cli(a.cli),
                      a.sim_arg, [float(x) for x in a.speeds.split(",")])
            return 0
        if a.export_checkpoint:
            export_checkpoint(*a.export_checkpoint)
            return 0
        check_args(ap, a, ADAPT_ANCHOR)
        refuse_heldout(a.data or [], "--data")
        refuse_heldout(a.val, "--val")
        train(a)
    except DataError as e:
        print(f"train.py: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
