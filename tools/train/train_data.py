#!/usr/bin/python3
"""Training samples for tools/train/train.py: crops of two consecutive RS frames, a target time t*, the
event tensors of the six E-IC passes the self-supervised losses need, and (physics-informed
variant) the physics unroller's log ratio of each pass; the intensity encoding conversion to the
model's gamma; per-sequence contrast estimates; a cache of pre-drawn samples (shards) so a short
GPU slot spends no time on event binning; the procedural data generator (--make-data).
"""
from __future__ import annotations

import glob
import json
import math
import os
import random
import shlex
import subprocess
import time
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch

from tools.model import physics_numpy as pn
from tools.data.sequence_data import DataError, Sequence, eic_tensors

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PASSES = ("g1", "g2", "r12", "r21", "c1", "c2")
SUPERVISED_PASSES = ("g1", "g2")  # the supervised loss compares the g1/g2 results with the ground truth


@dataclass
class Sample:
    """One training example: RS frames k and k+1 of a sequence, a crop, a GS target time t*, and
    the event tensors of the six E-IC passes the losses need (each a tuple ev1, ev2, ev3):
      g1: rs1 -> GS(t*)    g2: rs2 -> GS(t*)      (latent consistency; stage 2: the M result)
      r12: rs1 -> rs2      r21: rs2 -> rs1        (temporal consistency)
      c1: GS(t*) -> rs1    c2: GS(t*) -> rs2      (cycle consistency, second pass)
    `lr` (physics-informed variant): per pass, the physics log ratio [1, h, w] that maps the pass's
    input image to the physics estimate of its target (physics_numpy.apply_log_ratio_torch).
    Images are in the model's encoding (see `Encoding`)."""
    rs1: np.ndarray
    rs2: np.ndarray
    ev: Dict[str, Tuple[np.ndarray, np.ndarray, np.ndarray]]
    gt: Optional[np.ndarray] = None  # only in --supervised mode
    lr: Optional[Dict[str, np.ndarray]] = None
    gate_radius: int = -1  # the event gate radius for this sample's recording; -1: the model's
    exposing: int = -1  # the frame whose exposure span holds t*: 0 (frame k), 1 (frame k+1), -1 (neither)

    @property
    def intra(self) -> bool:  # t* inside frame k's or frame k+1's exposure span (natural_eval's "intra")
        return self.exposing >= 0


def stack(samples: List[Sample], key: str, device="cpu"):
    """Batched (ev1, ev2, ev3) tensors of pass `key` over the samples."""
    return [torch.from_numpy(np.stack([s.ev[key][i] for s in samples])).to(device) for i in range(3)]


def stack_lr(samples: List[Sample], keys, device="cpu"):
    """Batched physics log ratios of the passes `keys` (concatenated in that order), or None."""
    if samples[0].lr is None:
        return None
    return torch.cat([torch.from_numpy(np.stack([s.lr[k] for s in samples])) for k in keys]).to(device)


def images(samples: List[Sample], key: str, device="cpu"):
    return torch.from_numpy(np.stack([getattr(s, key) for s in samples])).to(device)


def load_gate_radii(path: Optional[str]) -> Dict[str, int]:
    """{absolute sequence folder: radius} from tools/train/gate_radii.py's file ({} without one)."""
    if not path:
        return {}
    try:
        got = json.load(open(path))
        return {os.path.abspath(k): int(v["radius"]) for k, v in got.items()}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise DataError(f"{path}: expected tools/train/gate_radii.py's JSON ({{folder: {{\"radius\": R, ...}}}}): {e}")


def crop_img(img: np.ndarray, crop) -> np.ndarray:
    x0, y0, w, h = crop
    return img[:, y0:y0 + h, x0:x0 + w]


# ---- intensity encoding and physics contrast per sequence ---------------------------------------------
def to_model_encoding(img: np.ndarray, file_gamma: float, model_gamma: Optional[float]) -> np.ndarray:
    """PNG values encoded with file_gamma (value = linear^(1/file_gamma)) re-encoded with the model's."""
    if model_gamma is None or abs(file_gamma - model_gamma) < 1e-9:
        return img
    return np.power(np.maximum(img, 0), file_gamma / model_gamma).astype(np.float32)


def from_model_encoding(img, file_gamma: float, model_gamma: Optional[float]):
    if model_gamma is None or abs(file_gamma - model_gamma) < 1e-9:
        return img
    return img.clamp(min=0) ** (model_gamma / file_gamma)


class SeqInfo:
    """What training needs to know of a sequence beyond its files: its encoding gamma (meta.json
    source.settings.gamma as `unroll --mode physics` reads it, else `default_gamma`) and, for the
    physics variant, its contrast threshold estimated as `unroll --mode physics` does."""
    _contrast: Dict[str, float] = {}

    def __init__(self, seq: Sequence, default_gamma: float = 1.0, cache_file: Optional[str] = None):
        self.seq = seq
        src = seq.meta.get("source") or {}
        has = "gamma" in (src.get("settings") or {}) or "gamma" in src
        self.gamma = pn.meta_gamma(seq) if has else default_gamma
        self.cache_file = cache_file

    def contrast(self) -> float:
        # the estimator's name in the key: a cache written by the earlier (consistency) estimator is not reused
        key = f"{os.path.abspath(self.seq.folder)}|{self.gamma}|{pn.CONTRAST_ESTIMATOR}"
        if key in SeqInfo._contrast:
            return SeqInfo._contrast[key]
        stored = {}
        if self.cache_file and os.path.isfile(self.cache_file):
            stored = json.load(open(self.cache_file))
        if key not in stored:
            stored[key] = pn.estimate_contrast(self.seq, None, self.gamma)
            if self.cache_file:
                tmp = self.cache_file + ".tmp"
                json.dump(stored, open(tmp, "w"), indent=0)
                os.replace(tmp, self.cache_file)
        SeqInfo._contrast.update(stored)
        return stored[key]


def make_sample(seq: Sequence, k: int, crop, t_star: float, texp: float, bins: int, gt_index: Optional[int] = None,
                info: Optional[SeqInfo] = None, model_gamma: Optional[float] = None, physics: bool = False,
                passes=PASSES, contrast_scale: float = 1.0) -> Sample:
    """`passes`: the E-IC passes to bin (the supervised loss needs only g1 and g2); `contrast_scale`:
    the physics input at that multiple of the sequence's estimated contrast."""
    s1, e1 = seq.row_times(k)
    s2, e2 = seq.row_times(k + 1)
    H = seq.height
    ts = np.full(H, t_star, dtype=np.float64)
    lo = min(s1.min(), t_star) - 1.0
    hi = max(e2.max(), t_star + texp) + 1.0
    ev = seq.events_in(lo, hi, crop)
    windows = {  # pass: (source start, source end, target rows, target exposure)
        "g1": (s1, e1, ts, texp), "g2": (s2, e2, ts, texp),
        "r12": (s1, e1, s2, seq.exposure), "r21": (s2, e2, s1, seq.exposure),
        "c1": (ts, ts + texp, s1, seq.exposure), "c2": (ts, ts + texp, s2, seq.exposure)}
    windows = {p: w for p, w in windows.items() if p in passes}
    tens = {p: eic_tensors(ev, a, b, tg, te, bins, crop) for p, (a, b, tg, te) in windows.items()}
    lr = None
    if physics:
        c = info.contrast() * contrast_scale
        lr = {p: pn.physics_log_ratio(ev, a, b, tg, c, crop)[None].astype(np.float32)
              for p, (a, b, tg, _) in windows.items()}
    fg = info.gamma if info else 1.0
    enc = lambda img: to_model_encoding(crop_img(img, crop), fg, model_gamma)  # noqa: E731
    gt = enc(seq.gt_image(gt_index)) if gt_index is not None else None
    return Sample(enc(seq.frame(k)), enc(seq.frame(k + 1)), tens, gt, lr)


class Sampler:
    def __init__(self, seqs: List[Sequence], crop_w: int, crop_h: int, bins: int, target_exposure: Optional[float],
                 rng: random.Random, supervised: bool = False, physics: bool = False,
                 model_gamma: Optional[float] = None, default_gamma: float = 1.0, contrast_cache: Optional[str] = None,
                 event_crops: float = 0.0, gate_radii: Optional[str] = None, contrast_jitter: float = 1.0):
        self.seqs = [s for s in seqs if s.num_frames >= 2]
        if not self.seqs:
            raise DataError("training needs sequences with at least 2 RS frames")
        for s in self.seqs:
            if s.width < crop_w or s.height < crop_h:
                raise DataError(f"{s.folder}: {s.width}x{s.height} is smaller than the crop {crop_w}x{crop_h}")
        self.crop_w, self.crop_h, self.bins = crop_w, crop_h, bins
        self.target_exposure = target_exposure
        self.rng = rng
        self.supervised = supervised
        self.physics, self.model_gamma = physics, model_gamma
        self.default_gamma, self.contrast_cache = default_gamma, contrast_cache
        self.event_crops = event_crops
        if not contrast_jitter >= 1.0:
            raise DataError(f"contrast jitter {contrast_jitter}: expected a factor >= 1")
        self.contrast_jitter = contrast_jitter
        self.gate_radii_file, self.gate_radii = gate_radii, load_gate_radii(gate_radii)
        self.check_gate_radii(self.seqs)
        self.infos: Dict[str, SeqInfo] = {}
        self.pairs: Dict[str, List[int]] = {}  # folder -> the pairs k (k, k+1) to draw from; absent: all

    def info(self, seq: Sequence) -> SeqInfo:
        if seq.folder not in self.infos:
            self.infos[seq.folder] = SeqInfo(seq, self.default_gamma, self.contrast_cache)
        return self.infos[seq.folder]

    def check_gate_radii(self, seqs: List[Sequence]) -> None:
        missing = [s.folder for s in seqs if self.gate_radii and os.path.abspath(s.folder) not in self.gate_radii]
        if missing:
            raise DataError(f"{self.gate_radii_file}: no gate radius for {len(missing)} training sequences, "
                            f"e.g. {missing[0]}")

    def add(self, seqs: List[Sequence]) -> None:
        self.check_gate_radii(seqs)
        self.seqs += [s for s in seqs if s.num_frames >= 2]

    def draw(self) -> Sample:
        r = self.rng
        seq = r.choice(self.seqs)
        k = r.choice(self.pairs[seq.folder]) if seq.folder in self.pairs else r.randrange(seq.num_frames - 1)
        x0 = r.randrange(seq.width - self.crop_w + 1)
        y0 = r.randrange(seq.height - self.crop_h + 1)
        texp = self.target_exposure or seq.exposure
        gt_index = None
        lo, hi = seq.frame_span(k)[0], seq.frame_span(k + 1)[1]
        if self.event_crops and r.random() < self.event_crops:
            # centred on a random event of the pair: crops land where something changes (a static
            # scene's movers) in proportion to the event activity, not to the area
            t, x, y, _ = seq.events_in(lo, hi, (0, 0, seq.width, seq.height))
            if len(t):
                j = r.randrange(len(t))
                x0 = min(max(int(x[j]) - self.crop_w // 2, 0), seq.width - self.crop_w)
                y0 = min(max(int(y[j]) - self.crop_h // 2, 0), seq.height - self.crop_h)
        if self.supervised:
            cands = [i for i, (_, t) in enumerate(seq.gt) if lo <= t <= hi]
            if not cands:
                raise DataError(f"{seq.folder}: --supervised needs ground truth between frames {k} and {k + 1}")
            gt_index = r.choice(cands)
            t_star = seq.gt[gt_index][1]
        else:
            t_star = r.uniform(lo, hi)
        # log-uniform in [1/J, J]; no draw at J = 1, so runs without jitter keep their samples
        scale = math.exp(r.uniform(-1.0, 1.0) * math.log(self.contrast_jitter)) if self.contrast_jitter > 1.0 else 1.0
        smp = make_sample(seq, k, (x0, y0, self.crop_w, self.crop_h), t_star, texp, self.bins, gt_index,
                          self.info(seq), self.model_gamma, self.physics,
                          SUPERVISED_PASSES if self.supervised else PASSES, scale)
        smp.gate_radius = self.gate_radii.get(os.path.abspath(seq.folder), -1)
        inside = [i for i, (a, b) in enumerate((seq.frame_span(k), seq.frame_span(k + 1))) if a <= t_star <= b]
        smp.exposing = inside[0] if inside else -1  # spans that overlap: frame k
        return smp


# ---- cache of pre-drawn samples -------------------------------------------------------------------------
def write_cache(sampler: Sampler, out: str, count: int, shard: int = 256, log=print) -> None:
    """`count` samples drawn by `sampler` into OUT/shard_*.pt (images fp16, event counts uint8,
    log ratios fp32) and OUT/cache.json (written last). Shards already there are kept (resumable)."""
    os.makedirs(out, exist_ok=True)
    n_shards = (count + shard - 1) // shard
    clipped = 0
    t0 = time.time()
    for i in range(n_shards):
        path = os.path.join(out, f"shard_{i:05d}.pt")
        k = min(shard, count - i * shard)
        if os.path.isfile(path):
            for _ in range(k):  # keep the sampler's RNG where a full run would have it
                sampler.draw()
            continue
        samples = [sampler.draw() for _ in range(k)]
        d = {"rs1": torch.from_numpy(np.stack([s.rs1 for s in samples])).half(),
             "rs2": torch.from_numpy(np.stack([s.rs2 for s in samples])).half()}
        if samples[0].gt is not None:
            d["gt"] = torch.from_numpy(np.stack([s.gt for s in samples])).half()
        for p in samples[0].ev:  # the passes the samples hold (supervised: g1 and g2)
            for j in range(3):
                a = np.stack([s.ev[p][j] for s in samples])
                clipped += int((a > 255).sum())
                d[f"ev_{p}_{j}"] = torch.from_numpy(np.minimum(a, 255).astype(np.uint8))
            if samples[0].lr is not None:
                d[f"lr_{p}"] = torch.from_numpy(np.stack([s.lr[p] for s in samples]))
        torch.save(d, path + ".tmp")
        os.replace(path + ".tmp", path)
        log(f"cache: {path} ({k} samples, {(time.time() - t0) / 60:.1f} min)")
    meta = {"count": count, "shard": shard, "bins": sampler.bins, "crop": [sampler.crop_w, sampler.crop_h],
            "physics": sampler.physics, "model_gamma": sampler.model_gamma, "supervised": sampler.supervised,
            "sequences": [s.folder for s in sampler.seqs], "event_counts_clipped_at_255": clipped}
    json.dump(meta, open(os.path.join(out, "cache.json"), "w"), indent=1)
    log(f"cache: {count} samples in {n_shards} shards under {out} ({clipped} counts clipped at 255)")


class CacheSampler:
    """Draws samples (with a random horizontal flip) from a cache written by write_cache."""

    def __init__(self, folder: str, rng: random.Random, bins: int, physics: bool, supervised: bool = False):
        mp = os.path.join(folder, "cache.json")
        if not os.path.isfile(mp):
            raise DataError(f"{mp}: not found (write the cache with train.py --make-cache)")
        self.meta = json.load(open(mp))
        if self.meta["bins"] != bins or bool(self.meta["physics"]) != physics:
            raise DataError(f"{folder}: cache has N={self.meta['bins']} physics={self.meta['physics']}, "
                            f"the model needs N={bins} physics={physics}")
        if supervised and not self.meta.get("supervised"):
            raise DataError(f"{folder}: cache holds no ground truth (written without --supervised)")
        if not supervised and self.meta.get("supervised"):
            raise DataError(f"{folder}: cache was written for --supervised (passes g1, g2 only); "
                            "the self-supervised losses need all six passes")
        self.shards = [torch.load(f, weights_only=True) for f in sorted(glob.glob(os.path.join(folder, "shard_*.pt")))]
        self.index = [(i, j) for i, s in enumerate(self.shards) for j in range(s["rs1"].shape[0])]
        if not self.index:
            raise DataError(f"{folder}: the cache has no shards")
        self.rng = rng
        self.seqs = self.meta["sequences"]

    def __len__(self):
        return len(self.index)

    def draw(self) -> Sample:
        i, j = self.index[self.rng.randrange(len(self.index))]
        s = self.shards[i]
        flip = self.rng.random() < 0.5  # a mirrored scene is as real as the scene; rows keep their times
        f = (lambda a: np.ascontiguousarray(a[..., ::-1])) if flip else (lambda a: a)  # noqa: E731
        img = lambda k: f(s[k][j].float().numpy())  # noqa: E731
        passes = [p for p in PASSES if f"ev_{p}_0" in s]
        ev = {p: tuple(f(s[f"ev_{p}_{q}"][j].numpy().astype(np.float32)) for q in range(3)) for p in passes}
        lr = {p: f(s[f"lr_{p}"][j].numpy()) for p in passes} if "lr_g1" in s else None
        return Sample(img("rs1"), img("rs2"), ev, img("gt") if "gt" in s else None, lr)


# ---- validation targets ---------------------------------------------------------------------------------
def gt_targets(seq: Sequence):
    """(gt index, frame k, intra) for every GT instant with RS frames k and k+1 around it: k is the
    last frame whose first row starts at or before t; intra = t inside frame k's exposure span."""
    out = []
    for i, (_, t) in enumerate(seq.gt):
        k = int(np.searchsorted(seq.frame_t0, t, "right")) - 1
        if k < 0 or k + 1 >= seq.num_frames:
            continue
        lo, hi = seq.frame_span(k)
        out.append((i, k, lo <= t <= hi))
    return out


# ---- procedural data generation --------------------------------------------------------------------------
MOTIONS = ("pan", "accelerate", "rotate", "zoom", "shake", "mixed")
PRESET_CYCLE = ("realistic", "clean", "realistic", "noisy")


def find_cli(explicit: Optional[str]) -> str:
    for c in (explicit, os.environ.get("VKUNROLL_CLI"), os.path.join(ROOT, "build", "vkunroll")):
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return c
    raise DataError("vkunroll CLI not found: pass --cli PATH or set VKUNROLL_CLI (build it: cmake --build build)")


def make_data(out: str, count: int, seed_base: int, size: str, frames: int, gt_per_frame: int,
              cli: str, extra: List[str], speeds: List[float] = (1.0,)) -> None:
    """`count` sequences seq_<seed> with seeds seed_base.., cycling motions, presets, speeds and readouts."""
    os.makedirs(out, exist_ok=True)
    for i in range(count):
        seed = seed_base + i
        d = os.path.join(out, f"seq_{seed:06d}")
        if os.path.isfile(os.path.join(d, "meta.json")):
            print(f"{d}: exists, kept")
            continue
        cmd = [cli, "simulate", "--out", d, "--seed", str(seed), "--preset", PRESET_CYCLE[i % len(PRESET_CYCLE)],
               "--motion", MOTIONS[i % len(MOTIONS)], "--size", size, "--frames", str(frames),
               "--gt-per-frame", str(gt_per_frame), "--speed", f"{speeds[i % len(speeds)]:g}", "--quiet",
               "--overwrite"]  # a folder without meta.json is a killed earlier run
        if (i // len(MOTIONS)) % 3 == 2:
            cmd += ["--readout", "bottom-up"]
        cmd += extra
        t0 = time.time()
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise DataError(f"'{shlex.join(cmd)}' failed ({r.returncode}): {r.stderr.strip()}")
        print(f"{d}: {' '.join(cmd[4:])} ({time.time() - t0:.1f} s)", flush=True)


def describe_data(paths: List[str], seqs: List[Sequence]) -> str:
    presets, motions, seeds, photos = set(), set(), [], set()
    for s in seqs:
        src = s.meta.get("source") or {}
        nat = os.path.join(s.folder, "natural.json")
        info = json.load(open(nat)) if os.path.isfile(nat) else {}
        if "event_model" in info:  # natural_data.py --event-model wide: every option drawn, the preset only a base
            presets.add("wide event model")
        elif "preset" in src:
            presets.add(str(src["preset"]))
        st = src.get("settings") or {}
        if "motion" in st:
            motions.add(str(st["motion"]))
        if "seed" in src:
            seeds.append(int(src["seed"]))
        if "photo" in info:
            photos.add(os.path.basename(info["photo"]))
    sizes = sorted({f"{s.width}x{s.height}" for s in seqs})
    d = f"{len(seqs)} sequences ({', '.join(sizes)}; {sum(s.num_frames for s in seqs)} RS frames) from {', '.join(paths)}"
    if presets:
        d += f"; presets {'/'.join(sorted(presets))}"
    if motions:
        d += f"; motions {'/'.join(sorted(motions))}"
    if seeds:
        d += f"; seeds {min(seeds)}..{max(seeds)}"
    if photos:
        d += f"; {len(photos)} photographs (tools/data/photos.json)"
    return d
