#!/usr/bin/python3
"""The weight-free physics unroller (event double integral, EDI) of kernels/physics_unroll.cpp and
host/unroll.cpp in NumPy/PyTorch, written to compute what `vkunroll unroll --mode physics` computes:

  I(t*) = I_rs * T / integral over the row's exposure [S, E] of exp(c (F(s) - F(t*))) ds

per pixel on linear intensity (PNG value ^ gamma), F the pixel's cumulative polarity, then
re-encoded with 1/gamma and capped at max_value. `physics_log_ratio` gives the per-pixel
log(T / integral) for any source rows and any (per-row) target time, so the trainer can apply it
to any image (also a network output, differentiably: `apply_log_ratio_torch`).

Rounding follows the C++ reference: times relative to t* are float32 (PixelEventLists), c and
gamma are float32 (PhysicsUnrollParams), the contrast term c * (F - F0) is a float32 product,
the rest is double; `estimate_physics` mirrors host/unroll/contrast_estimate.cpp and
`frame_for_time` host/unroll/unroll_plan.cpp.
tests/python/test_physics_variant.py compares this with the CLI's output.
"""
from __future__ import annotations

from typing import Optional, Sequence as Seq, Tuple

import numpy as np

MAX_VALUE = 1e4  # PhysicsUnrollParams::max_value


def _f32(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64).astype(np.float32).astype(np.float64)


def physics_log_ratio(ev, src_start: np.ndarray, src_end: np.ndarray, target, contrast: float,
                      crop: Tuple[int, int, int, int]) -> np.ndarray:
    """log(T / integral) [h, w] (float64) for the crop (x0, y0, w, h). src_start/src_end: float64
    exposure start/end per full-sensor row; target: t* (scalar) or one target time per row.
    `ev` = (t, x, y, p) with at least the events of each row's [min(S, t*), max(E, t*)]."""
    return log_ratio_from_segments(exposure_segments(ev, src_start, src_end, target, crop), contrast)


def log_ratio_from_segments(segs, contrast: float) -> np.ndarray:
    """log(T / sum_j len_j exp(c * level_j)) per pixel (log-sum-exp as the C++ reference)."""
    seg_pix, log_len, lvl, T, h, w = segs
    npx = h * w
    term = log_len + (np.float32(contrast) * lvl.astype(np.float32)).astype(np.float64)
    m = np.full(npx, -np.inf)
    np.maximum.at(m, seg_pix, term)
    acc = np.bincount(seg_pix, weights=np.exp(term - m[seg_pix]), minlength=npx)
    with np.errstate(divide="ignore", invalid="ignore"):
        lr = np.where(T > 0, np.log(T) - (m + np.log(acc)), 0.0)
    return lr.reshape(h, w)


def exposure_segments(ev, src_start: np.ndarray, src_end: np.ndarray, target, crop):
    """The exposure of every pixel cut at its events: (pixel, log length, level F - F(t*)) of each
    non-empty segment, the exposure length T per pixel, h, w. Independent of c."""
    x0, y0, w, h = crop
    t, x, y, p = ev
    H = len(src_start)
    tgt_rows = np.full(H, float(target)) if np.ndim(target) == 0 else np.asarray(target, dtype=np.float64)
    rows = np.arange(y0, y0 + h)
    S_row = _f32(src_start[rows] - tgt_rows[rows])  # float(s - t*) as gather_pixel_events
    E_row = _f32(src_end[rows] - tgt_rows[rows])
    inside = (x >= x0) & (x < x0 + w) & (y >= y0) & (y < y0 + h)
    t, x, y, p = np.asarray(t, np.float64)[inside], x[inside], y[inside], p[inside]
    ts = tgt_rows[y]
    keep = (t >= np.minimum(src_start[y], ts)) & (t <= np.maximum(src_end[y], ts))  # double, absolute
    t, x, y, p, ts = t[keep], x[keep], y[keep], p[keep], ts[keep]
    ly, lx = y - y0, x - x0
    tau = _f32(t - ts)
    pol = np.where(p > 0, 1, -1).astype(np.int64)
    pix = ly * w + lx
    npx = h * w
    S, E = S_row[ly], E_row[ly]
    f0 = np.bincount(pix, weights=pol * (tau <= 0), minlength=npx).round().astype(np.int64)
    fS = np.bincount(pix, weights=pol * (tau <= S), minlength=npx).round().astype(np.int64)
    rowS = np.repeat(S_row, w)
    rowE = np.repeat(E_row, w)
    # events strictly inside (S, E) split the exposure into segments; an event at exactly E ends it
    ins = (tau > S) & (tau < E)
    ti, pi, poli = tau[ins], pix[ins], pol[ins]
    order = np.lexsort((np.arange(len(ti)), pi))  # by pixel, keeping stream (time) order
    ti, pi, poli = ti[order], pi[order], poli[order]
    n = len(pi)
    first = np.r_[True, pi[1:] != pi[:-1]] if n else np.zeros(0, bool)
    last = np.r_[pi[1:] != pi[:-1], True] if n else np.zeros(0, bool)
    cs = np.cumsum(poli)
    start_idx = np.maximum.accumulate(np.where(first, np.arange(n), 0)) if n else np.zeros(0, np.int64)
    cp = cs - (cs[start_idx] - poli[start_idx]) if n else cs  # cumulative polarity within the pixel
    # segment after event i: [t_i, next event or E), level F = fS + cp_i
    t_next = np.where(last, rowE[pi], np.r_[ti[1:], 0.0]) if n else ti
    seg_len = np.concatenate([np.where(first, ti - rowS[pi], 0.0) if n else ti, t_next - ti])
    seg_pix = np.concatenate([pi, pi])
    lvl = np.concatenate([fS[pi] - f0[pi], fS[pi] + cp - f0[pi]]) if n else np.zeros(0, np.int64)
    # pixels without events inside: one segment [S, E] at level fS - f0
    t_first = np.full(npx, np.nan)
    if n:
        t_first[pi[first]] = ti[first]
    empty = np.isnan(t_first)
    seg_len = np.concatenate([seg_len, (rowE - rowS)[empty]])
    seg_pix = np.concatenate([seg_pix, np.nonzero(empty)[0]])
    lvl = np.concatenate([lvl, (fS - f0)[empty]])
    pos = seg_len > 0
    return seg_pix[pos], np.log(seg_len[pos]), lvl[pos], rowE - rowS, h, w


def apply_log_ratio(img: np.ndarray, log_ratio: np.ndarray, gamma: float, max_value: float = MAX_VALUE,
                    log_offset: float = 0.0) -> np.ndarray:
    """The C++ output formula: lin = v^gamma + eps, o = min(exp(min(log lin + lr, log max)), max) - eps,
    v' = o^(1/gamma) (eps: PhysicsUnrollParams::log_offset)."""
    g = float(np.float32(gamma))
    mv = float(np.float32(max_value))
    v = np.asarray(img, dtype=np.float64)
    lr = np.broadcast_to(log_ratio, v.shape)
    eps = float(np.float32(log_offset))
    with np.errstate(divide="ignore"):
        lin = np.where(v > 0, np.power(np.maximum(v, 0), g), 0.0) + eps
        o = np.where(lin > 0, np.minimum(np.exp(np.minimum(np.log(np.maximum(lin, 1e-300)) + lr, np.log(mv))), mv) - eps, 0.0)
        out = np.where(o > 0, np.power(np.maximum(o, 0), 1.0 / g), 0.0)
    return out.astype(np.float32)


def event_band(img: np.ndarray, phys: np.ndarray, contrast: float, gamma: float, log_offset: float,
               width: float) -> np.ndarray:
    """img clamped per pixel to the physics estimate's event band: lin(v) = v^gamma + eps within
    lin(phys) * exp(+-width * c). A pixel's log intensity moves by one threshold per event, so its
    events bound how far the truth can be from physics (2c for an ideal sensor, whatever happened
    between them); the network's output is kept inside that bound."""
    g, eps, wc = float(gamma), float(log_offset), float(width) * float(contrast)
    lin = np.power(np.maximum(np.asarray(phys, np.float64), 0.0), g) + eps
    inv = lambda l: np.power(np.maximum(l - eps, 0.0), 1.0 / g)  # noqa: E731
    return np.clip(np.asarray(img, np.float64), inv(lin * np.exp(-wc)), inv(lin * np.exp(wc))).astype(np.float32)


def apply_log_ratio_torch(img, log_ratio, gamma: float, max_value: float = MAX_VALUE, log_offset: float = 0.0):
    """apply_log_ratio in torch, differentiable in img. At log offset 0 (the variant's input):
    v * exp(lr / gamma), capped at max_value^(1/gamma), 0 where v <= 0. img [B, C, H, W],
    log_ratio [B, 1, H, W]."""
    import torch
    g = float(np.float32(gamma))
    eps = float(np.float32(log_offset))
    if eps != 0.0:  # the offset form of apply_log_ratio, term by term
        lin = torch.where(img > 0, img.clamp(min=0) ** g, torch.zeros_like(img)) + eps
        o = torch.clamp(torch.exp(torch.clamp(torch.log(lin.clamp(min=1e-300)) + log_ratio,
                                              max=float(np.log(np.float32(max_value))))),
                        max=float(np.float32(max_value))) - eps
        return torch.where(o > 0, o.clamp(min=0) ** (1.0 / g), torch.zeros_like(o))
    cap = float(np.log(np.float32(max_value))) / g
    pos = img > 0
    safe = torch.where(pos, img, torch.ones_like(img))
    out = torch.exp(torch.clamp(torch.log(safe) + log_ratio / g, max=cap))
    return torch.where(pos, out, torch.zeros_like(out))


# ---- host/unroll.cpp: frame choice and contrast estimate -------------------------------------------
def frame_mid(seq, k: int) -> float:
    s, e = seq.frame_span(k)
    return 0.5 * (s + e)


def frame_for_time(seq, frames: Seq[int], t: float) -> int:
    """The frame whose exposure span holds t (nearest middle among those), else the nearest middle."""
    best, best_d = frames[0], 1e300
    for k in frames:
        s, e = seq.frame_span(k)
        d = abs(t - frame_mid(seq, k)) - (1e12 if s <= t <= e else 0.0)
        if d < best_d:
            best_d, best = d, k
    return best


# host/unroll/contrast_estimate.cpp's method (summary.json's contrast_method) and constants
CONTRAST_ESTIMATOR = "event_count_fit"
_MAX_PAIRS, _MIN_EVENTS, _MIN_SUPPORT, _MIN_PIXELS = 4, 2, 3, 200
_ENCODED_LOW, _ENCODED_HIGH = 0.02, 0.98
_OFFSETS = (0.0, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05)


def _pair_evidence(seq, a: int, b: int, gamma: float):
    """Samples (L_a, L_b, N) of the pixels whose events between the rows' mid-exposures are signal,
    and the log change of in-range pixels with no event in their 3x3 (contrast_estimate.cpp)."""
    W, H = seq.width, seq.height
    (sa, ea), (sb, eb) = seq.row_times(a), seq.row_times(b)
    mid_a, mid_b = 0.5 * (sa + ea), 0.5 * (sb + eb)
    t, x, y, p = seq.events_in(np.floor(mid_a.min()), np.ceil(mid_b.max()) + 1, (0, 0, W, H))
    t, x, y = np.asarray(t, np.float64), np.asarray(x, np.int64), np.asarray(y, np.int64)
    k = (t > mid_a[y]) & (t <= mid_b[y])
    pix = (y * W + x)[k]
    net = np.bincount(pix, weights=np.where(np.asarray(p)[k] > 0, 1, -1), minlength=W * H).round().astype(np.int64).reshape(H, W)
    count = np.bincount(pix, minlength=W * H).reshape(H, W)
    wl = (0.0722, 0.7152, 0.2126)  # B, G, R as the C++ sums them
    def lum(img):
        lin = np.power(np.maximum(np.asarray(img, np.float64), 0.0), gamma)
        return wl[0] * lin[2] + wl[1] * lin[1] + wl[2] * lin[0]
    la, lb = lum(seq.frame(a)), lum(seq.frame(b))
    lo, hi = _ENCODED_LOW ** gamma, _ENCODED_HIGH ** gamma
    ok = (la > lo) & (la < hi) & (lb > lo) & (lb < hi)
    sign = np.sign(net)
    ps, pc = np.pad(sign, 1), np.pad(count, 1)
    support, around = np.zeros((H, W), np.int64), np.zeros((H, W), np.int64)
    for dy in range(3):
        for dx in range(3):
            around += pc[dy:dy + H, dx:dx + W]
            if dy != 1 or dx != 1:
                support += (ps[dy:dy + H, dx:dx + W] == sign) & (sign != 0)
    quiet = ok & (around == 0)
    sel = ok & (np.abs(net) >= _MIN_EVENTS) & (support >= _MIN_SUPPORT)
    return la[sel], lb[sel], net[sel], np.log(lb[quiet] + 0.01) - np.log(la[quiet] + 0.01)


def _weighted_median(v: np.ndarray, w: np.ndarray) -> float:
    o = np.lexsort((w, v))
    cw = np.cumsum(w[o])
    return float(v[o][np.searchsorted(cw, 0.5 * cw[-1])])


def signal_samples(seq, frames: Optional[Seq[int]] = None, gamma: float = 1.0):
    """The estimate's evidence: (L_a, L_b, N) of the signal pixels of up to four pairs (k, k + 1),
    those whose change beyond 3x the frames' own noise agrees with their events' sign."""
    frames = list(range(seq.num_frames)) if frames is None else list(frames)
    pairs = [(k, k + 1) for k in frames if k + 1 < seq.num_frames][:_MAX_PAIRS]
    if not pairs:
        return np.zeros(0), np.zeros(0), np.zeros(0, np.int64)
    parts = [_pair_evidence(seq, a, b, gamma) for a, b in pairs]
    la, lb, n, quiet = (np.concatenate([p[i] for p in parts]) for i in range(4))
    sigma = 0.0
    if len(quiet) >= 100:
        m = np.partition(quiet, len(quiet) // 2)[len(quiet) // 2]
        dev = np.abs(quiet - m)
        sigma = 1.4826 * np.partition(dev, len(dev) // 2)[len(dev) // 2]
    d0 = np.log(lb + 0.01) - np.log(la + 0.01)
    keep = (np.abs(d0) > 3 * sigma) & ((d0 > 0) == (n > 0))
    return la[keep], lb[keep], n[keep]


def estimate_physics(seq, frames: Optional[Seq[int]] = None, gamma: float = 1.0) -> Tuple[float, float]:
    """host/unroll/contrast_estimate.cpp estimate_contrast: (c, log offset eps), both float32 as
    PhysicsUnrollParams; (0.2, 0.0) where it is no estimate. For up to four pairs (k, k+1), the
    L1 fit of each signal pixel's luminance log change against its net event count."""
    la, lb, n = signal_samples(seq, frames, gamma)
    if len(n) < _MIN_PIXELS:
        return 0.2, 0.0
    best = (0.2, 0.0, np.inf)
    for eps in _OFFSETS:
        c, r = offset_fit(la, lb, n, eps)
        if r < best[2]:
            best = (c, eps, r)
    return float(np.float32(best[0])), float(np.float32(best[1]))


def offset_fit(la: np.ndarray, lb: np.ndarray, n: np.ndarray, eps: float) -> Tuple[float, float]:
    """(c, residual in events) of the signal samples at log offset eps: c is the L1 fit of log change
    against net event count; residual = sum |change / c - N|, inf where c <= 0 (contrast_estimate.cpp fit_at)."""
    d = np.log(lb + eps) - np.log(la + eps)
    c = _weighted_median(d / n, np.abs(n).astype(np.float64))
    return (c, float(np.abs(d / c - n).sum())) if c > 0 else (c, np.inf)


def estimate_contrast(seq, frames: Optional[Seq[int]] = None, gamma: float = 1.0) -> float:
    """The contrast c of estimate_physics (what `--mode physics` and the variant's physics input use)."""
    return estimate_physics(seq, frames, gamma)[0]


def meta_gamma(seq) -> float:
    """host/unroll.cpp read_meta_gamma: source.settings.gamma, else source.gamma, else 1."""
    src = seq.meta.get("source") or {}
    if isinstance(src.get("settings"), dict) and "gamma" in src["settings"]:
        return float(src["settings"]["gamma"])
    if "gamma" in src:
        return float(src["gamma"])
    return 1.0


def unroll_physics(seq, k: int, t_star: float, contrast: float, gamma: float,
                   crop: Optional[Tuple[int, int, int, int]] = None, log_offset: float = 0.0) -> np.ndarray:
    """`vkunroll unroll --mode physics` for frame k toward t*: [3, h, w] float32 (not clamped)."""
    crop = crop or (0, 0, seq.width, seq.height)
    s, e = seq.row_times(k)
    lo, hi = min(s.min(), t_star), max(e.max(), t_star)
    ev = seq.events_in(np.floor(lo), np.ceil(hi) + 1, crop)
    lr = physics_log_ratio(ev, s, e, t_star, contrast, crop)
    x0, y0, w, h = crop
    return apply_log_ratio(seq.frame(k)[:, y0:y0 + h, x0:x0 + w], lr, gamma, log_offset=log_offset)
