#!/usr/bin/python3
"""Row-aware event tensors (docs/event_tensors.md, docs/network.md) in NumPy, the way the reference does
it: float64 row times, boolean masks and np.add.at. Used as an independent check of the C++/GPU
builder (golden fixture) and as the baseline of bench/bench_event_tensor.cpp.

  event_tensors_numpy.py --golden OUT.safetensors     write tests/data/event_tensor_golden.safetensors
  event_tensors_numpy.py --bench IN.safetensors       time the binning of the events in IN (see bench)

Timing conventions (same as base/row_timing.hpp): row y is read as r = y (top-down) or H-1-y
(bottom-up); start[y] = t0 + r*delay, end[y] = start[y] + exposure; tau -> t* = t0 + tau *
(t0 + (H-1)*delay + exposure - t0), i.e. start[0] + tau*(end[H-1]-start[0]) for top-down.
"""
import argparse
import json
import struct
import sys
import time
from fractions import Fraction

import numpy as np


# ---- section 4, float64 + np.add.at ------------------------------------------------------------
def selected_cells(t, x, y, p, a_rows, b_rows, bins, crop):
    """The (channel, row, column) in the crop of every event between its row's a and b: channel
    2k + (signed polarity > 0), k its bin; a_rows/b_rows are float64 per full-sensor row."""
    x0, y0, w, h = crop
    inside = (x >= x0) & (x < x0 + w) & (y >= y0) & (y < y0 + h)
    t, x, y, p = t[inside].astype(np.float64), x[inside], y[inside], p[inside]
    a, b = a_rows[y], b_rows[y]
    sel = (t >= np.minimum(a, b)) & (t < np.maximum(a, b))
    t, x, y, p, a, b = t[sel], x[sel], y[sel], p[sel], a[sel], b[sel]
    s = np.where(p > 0, 1, -1)
    s = np.where(t < a, -s, s)
    k = np.floor(np.abs(t - a) * bins / np.abs(b - a)).astype(np.int64)
    k[k == bins] = bins - 1
    return 2 * k + (s > 0), y - y0, x - x0


def event_tensor(t, x, y, p, a_rows, b_rows, bins, crop):
    """One tensor [2N, h, w]: a_rows/b_rows are float64 per full-sensor row; crop = (x0, y0, w, h)."""
    _, _, w, h = crop
    out = np.zeros((2 * bins, h, w), dtype=np.float32)
    np.add.at(out, selected_cells(t, x, y, p, a_rows, b_rows, bins, crop), 1)
    return out


def event_tensor_fast(t, x, y, p, a_rows, b_rows, bins, crop):
    """event_tensor with np.bincount instead of np.add.at (same counts, ~20x faster; used by
    tools/train/train.py; tests/python/test_train.py checks it against event_tensor)."""
    _, _, w, h = crop
    ch, yy, xx = selected_cells(t, x, y, p, a_rows, b_rows, bins, crop)
    flat = (ch * h + yy) * w + xx
    return np.bincount(flat, minlength=2 * bins * h * w).astype(np.float32).reshape(2 * bins, h, w)


def row_times(t0, delay, exposure, rows, readout):
    r = np.arange(rows, dtype=np.float64)
    if readout == "bottom-up":
        r = rows - 1 - r
    start = t0 + r * delay
    return start, start + exposure


def target_time(t0, delay, exposure, rows, tau):
    last_end = t0 + (rows - 1) * delay + exposure
    return t0 + tau * (last_end - t0)


def three_tensors(ev, pair, rows, bins, crop):
    """ev = (t, x, y, p); pair: dict with float t0, delay, exposure, readout, target (t*), texp."""
    start, end = row_times(pair["t0"], pair["delay"], pair["exposure"], rows, pair["readout"])
    ts = np.full(rows, pair["target"], dtype=np.float64)
    return (event_tensor(*ev, ts, start, bins, crop),
            event_tensor(*ev, ts, end, bins, crop),
            event_tensor(*ev, ts, ts + pair["texp"], bins, crop))


def event_tensor_exact(t, x, y, p, a_rows, b_rows, bins, crop):
    """The same formula in exact rational arithmetic (fractions.Fraction), one event at a time."""
    x0, y0, w, h = crop
    out = np.zeros((2 * bins, h, w), dtype=np.float32)
    for ti, xi, yi, pi in zip(t.tolist(), x.tolist(), y.tolist(), p.tolist()):
        if not (x0 <= xi < x0 + w and y0 <= yi < y0 + h):
            continue
        a, b = a_rows[yi], b_rows[yi]
        if not (min(a, b) <= ti < max(a, b)):
            continue
        s = 1 if pi > 0 else -1
        if ti < a:
            s = -s
        k = int(abs(ti - a) * bins // abs(b - a))
        k = min(k, bins - 1)
        out[2 * k + (s > 0), yi - y0, xi - x0] += 1
    return out


def three_tensors_exact(ev, case, tau, rows):
    t0, d, e = _f(case["t0"]), _f(case["delay"]), _f(case["exposure"])
    texp = _f(case["texp"]) if case["texp"] else e
    r = [y if case["readout"] == "top-down" else rows - 1 - y for y in range(rows)]
    start = [t0 + ri * d for ri in r]
    end = [s + e for s in start]
    ts = t0 + _f(tau) * ((rows - 1) * d + e)
    a = [ts] * rows
    return (event_tensor_exact(*ev, a, start, case["bins"], case["crop"]),
            event_tensor_exact(*ev, a, end, case["bins"], case["crop"]),
            event_tensor_exact(*ev, a, [ts + texp] * rows, case["bins"], case["crop"]))


# ---- minimal safetensors I/O -------------------------------------------------------------------
_DT = {"F32": np.float32, "I64": np.int64, "I32": np.int32, "U16": np.uint16, "I8": np.int8, "U8": np.uint8}


def save_safetensors(path, tensors, metadata):
    header, offset, blobs = {"__metadata__": metadata}, 0, []
    for name, arr in tensors.items():
        arr = np.ascontiguousarray(arr)
        dt = [k for k, v in _DT.items() if v == arr.dtype.type][0]
        header[name] = {"dtype": dt, "shape": list(arr.shape), "data_offsets": [offset, offset + arr.nbytes]}
        offset += arr.nbytes
        blobs.append(arr.tobytes())
    h = json.dumps(header, separators=(",", ":")).encode()
    h += b" " * ((8 - (8 + len(h)) % 8) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(h)) + h + b"".join(blobs))


def load_safetensors(path):
    data = open(path, "rb").read()
    (n,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8:8 + n])
    meta = header.pop("__metadata__", {})
    out = {}
    for name, e in header.items():
        b, en = e["data_offsets"]
        out[name] = np.frombuffer(data[8 + n + b:8 + n + en], dtype=_DT[e["dtype"]]).reshape(e["shape"])
    return out, meta


# ---- golden fixture ----------------------------------------------------------------------------
def _golden_cases():
    # Times are strings: exact rationals for C++, float64 (the reference's view) for NumPy.
    return [
        dict(name="topdown_int", t0="1000", delay="50", exposure="400", readout="top-down", bins=16,
             crop=[0, 0, 20, 14], taus=["0.5", "-0.25", "1.25", "0", "1"], texp=None),
        dict(name="bottomup_dyadic", t0="1000.5", delay="12.5", exposure="333", readout="bottom-up", bins=16,
             crop=[0, 0, 20, 14], taus=["0.3", "0.75"], texp=None),
        dict(name="fractional_crop_n5", t0="0", delay="1000/7", exposure="500", readout="top-down", bins=5,
             crop=[3, 2, 12, 9], taus=["0.75", "0.25"], texp=None),
        dict(name="interframe_texp", t0="-200", delay="100", exposure="256", readout="top-down", bins=16,
             crop=[0, 0, 20, 14], taus=["2", "-1"], texp="256"),
    ]


def _f(s):
    return Fraction(s)


def _boundary_times(case, rows, bins):
    """Integer times next to every exact boundary of every row: row starts/ends, t*, t*+texp, bins."""
    t0, d, e = _f(case["t0"]), _f(case["delay"]), _f(case["exposure"])
    texp = _f(case["texp"]) if case["texp"] else e
    per_row = [set() for _ in range(rows)]
    for tau in case["taus"]:
        ts = t0 + _f(tau) * ((rows - 1) * d + e)
        for y in range(rows):
            r = y if case["readout"] == "top-down" else rows - 1 - y
            st = t0 + r * d
            for a, b in ((ts, st), (ts, st + e), (ts, ts + texp)):
                vals = [a, b] + [a + k * (b - a) / bins for k in range(1, bins)]
                for v in vals:
                    fl = v.numerator // v.denominator
                    per_row[y].update({fl - 1, fl, fl + 1, fl + 2})
    return [sorted(s) for s in per_row]


def write_golden(path, width=20, height=14, n_events=2500, seed=7):
    rng = np.random.default_rng(seed)
    tensors, cases_meta = {}, []
    for ci, case in enumerate(_golden_cases()):
        bins = case["bins"]
        cand = _boundary_times(case, height, bins)
        y = rng.integers(0, height, n_events)
        x = rng.integers(0, width, n_events)
        lo = min(min(c) for c in cand) - 50
        hi = max(max(c) for c in cand) + 50
        t = rng.integers(lo, hi, n_events)
        on_edge = rng.random(n_events) < 0.5
        for i in np.nonzero(on_edge)[0]:
            c = cand[y[i]]
            t[i] = c[rng.integers(0, len(c))]
        # every polarity encoding the readers normalize to: +1, -1 and also 0 (treated as "not > 0")
        p = rng.choice(np.array([1, -1, 0], dtype=np.int8), n_events, p=[0.45, 0.45, 0.10])
        order = np.argsort(t, kind="stable")
        t, x, y, p = t[order].astype(np.int64), x[order].astype(np.uint16), y[order].astype(np.uint16), p[order]
        ev = (t, x.astype(np.int64), y.astype(np.int64), p)
        t0, d, e = float(_f(case["t0"])), float(_f(case["delay"])), float(_f(case["exposure"]))
        texp = float(_f(case["texp"])) if case["texp"] else e
        pre = f"c{ci}_"
        tensors[pre + "t"], tensors[pre + "x"], tensors[pre + "y"], tensors[pre + "p"] = t, x, y, p
        outs, exact = [[], [], []], [[], [], []]
        for tau in case["taus"]:
            target = target_time(t0, d, e, height, float(_f(tau)))
            pair = dict(t0=t0, delay=d, exposure=e, readout=case["readout"], target=target, texp=texp)
            for k, ten in enumerate(three_tensors(ev, pair, height, bins, case["crop"])):
                outs[k].append(ten)
            for k, ten in enumerate(three_tensors_exact(ev, case, tau, height)):
                exact[k].append(ten)
        diffs = []
        for k in range(3):
            arr, ex = np.stack(outs[k]), np.stack(exact[k])
            assert arr.max() < 256
            tensors[pre + f"ev{k + 1}"] = arr.astype(np.uint8)
            # float64 and exact rationals disagree only where float64 rounds a row time that sits
            # on an integer event time (non-dyadic fractions); store the exact answer too.
            diffs.append(int((arr != ex).sum()))
            if diffs[-1]:
                tensors[pre + f"ev{k + 1}_exact"] = ex.astype(np.uint8)
        case = dict(case, float64_differs_from_exact=diffs)
        cases_meta.append(case)
    save_safetensors(path, tensors, {"width": str(width), "height": str(height),
                                     "cases": json.dumps(cases_meta), "generator": "tools/data/event_tensors_numpy.py"})


# ---- bench ----------------------------------------------------------------------------------------
def bench(path, repeat):
    ts, meta = load_safetensors(path)
    height, width, bins = int(meta["height"]), int(meta["width"]), int(meta["bins"])
    pair = dict(t0=float(meta["t0"]), delay=float(meta["delay"]), exposure=float(meta["exposure"]),
                readout=meta.get("readout", "top-down"), target=float(meta["target"]), texp=float(meta["exposure"]))
    ev = (ts["t"], ts["x"].astype(np.int64), ts["y"].astype(np.int64), ts["p"])
    best, outs = float("inf"), None
    for _ in range(repeat):
        t1 = time.perf_counter()
        outs = three_tensors(ev, pair, height, bins, (0, 0, width, height))
        best = min(best, time.perf_counter() - t1)
    sums = [float(o.sum()) for o in outs]
    # A position-sensitive checksum the C++ side computes the same way.
    checks = [float((o.reshape(-1).astype(np.float64) * (np.arange(o.size) % 9973)).sum()) for o in outs]
    print(json.dumps({"seconds": best, "events": int(ts["t"].size), "sums": sums, "checks": checks}))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--golden", help="write the golden fixture here")
    ap.add_argument("--bench", help="time the NumPy binning of this safetensors input")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    if a.golden:
        write_golden(a.golden)
    elif a.bench:
        bench(a.bench, a.repeat)
    else:
        ap.print_help()
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
