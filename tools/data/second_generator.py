#!/usr/bin/python3
"""A second event-camera generator, different from `vkunroll simulate` on purpose, for
validation only (issue 26: a gain that vanishes here is a gain on the simulator, not on the world).
Never train on its sequences: they are marked `"split": "validation"` in natural.json.

  second_generator.py --out DIR --photo FILE --kind camera|static_movers|camera_occluders
                      [--size 240x180] [--frames 4] [--seed 1] [--noise none|dvs|heavy]
  second_generator.py --suite DIR [--size 240x180] [--frames 4] [--noise dvs] [--split train|heldout]
                      (three kinds x two photographs of that split of tools/data/photos.json;
                      heldout: an evaluation-only suite, marked split 'heldout')

Where it differs from host/sim (docs/simulator.md, "Events"):
- Rendering: bilinear resampling of the photograph (scipy map_coordinates) on a fixed 50 us
  grid (host/sim: its own renderer, adaptive steps); the moving object is a soft-edged disc cut
  from another part of the photograph.
- RS integration: the trapezoid rule over the grid (rows start 50 us apart and expose 3 ms: on
  the grid), then Gaussian read noise and 8-bit gamma 2.2.
- Photoreceptor low-pass: a time constant of 200 + 2000 (1 - I) us (host/sim: v2e's cutoff law).
- Thresholds: per-pixel ON from N(C, sigma) and OFF = ON x U(0.85, 1.15) (host/sim: two draws).
- Noise: background activity that does not reset the pixel, more in the dark; hot pixels; and
  Gaussian timestamp jitter (host/sim: shot noise that resets, leak, no hot pixels, no jitter).
Alike: events from log intensity, crossings timed linearly in time, a refractory period.
The thresholds and background rates of `dvs` sit inside the ranges docs/simulator.md cites.
Writes the generic sequence layout (meta.json, rs/, gs/, events.h5) and natural.json.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import h5py
import numpy as np
from PIL import Image
from scipy.ndimage import map_coordinates

HERE = os.path.dirname(os.path.abspath(__file__))
STEP_US = 50.0
NOISE = {  # background rate Hz/pixel at mid-grey, hot-pixel fraction and rate, jitter us, refractory us, threshold sigma
    "none": dict(ba_hz=0.0, hot_frac=0.0, hot_hz=0.0, jitter_us=0.0, refractory_us=0.0, sigma=0.0),
    "dvs": dict(ba_hz=0.5, hot_frac=2e-4, hot_hz=50.0, jitter_us=30.0, refractory_us=300.0, sigma=0.03),
    "heavy": dict(ba_hz=3.0, hot_frac=1e-3, hot_hz=200.0, jitter_us=100.0, refractory_us=1000.0, sigma=0.06),
}


def load_photo(path: str, w: int, h: int) -> np.ndarray:
    """Linear-light RGB float64 [H', W', 3], resized so that motion has room (2x the sensor)."""
    img = Image.open(path).convert("RGB")
    scale = max(2 * w / img.width, 2 * h / img.height)
    img = img.resize((max(1, int(img.width * scale)), max(1, int(img.height * scale))), Image.BICUBIC)
    return (np.asarray(img, dtype=np.float64) / 255.0) ** 2.2


class Scene:
    """A camera path over the photograph and, by kind, a disc patch moving across the view."""

    def __init__(self, photo: np.ndarray, w: int, h: int, kind: str, rng: np.random.Generator):
        self.photo, self.w, self.h, self.kind = photo, w, h, kind
        ph, pw = photo.shape[:2]
        self.origin = np.array([(pw - w) / 2, (ph - h) / 2])
        speed = rng.uniform(3.0, 6.0) * w  # px/s: a fast pan crosses the view in 0.2-0.3 s
        ang = rng.uniform(0, 2 * np.pi)
        self.cam_v = np.zeros(2) if kind == "static_movers" else speed * np.array([np.cos(ang), np.sin(ang)])
        self.cam_rot = 0.0 if kind == "static_movers" else rng.uniform(-0.3, 0.3)  # rad/s
        self.patch = kind in ("static_movers", "camera_occluders")
        self.r = rng.uniform(0.15, 0.25) * min(w, h)
        self.p0 = np.array([rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h])
        v = -self.cam_v if kind == "camera_occluders" else speed * np.array([np.cos(ang + 1), np.sin(ang + 1)])
        self.p_v = 1.5 * v
        self.p_src = np.array([rng.uniform(0, pw - 2 * self.r), rng.uniform(0, ph - 2 * self.r)])
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        self.xx, self.yy = xx, yy

    def sample(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.stack([map_coordinates(self.photo[..., c], [y, x], order=1, mode="reflect") for c in range(3)], -1)

    def render(self, t_s: float) -> np.ndarray:
        """Linear RGB [h, w, 3] at time t (seconds)."""
        a = self.cam_rot * t_s
        cx, cy = self.w / 2, self.h / 2
        dx, dy = self.xx - cx, self.yy - cy
        x = self.origin[0] + cx + np.cos(a) * dx - np.sin(a) * dy + self.cam_v[0] * t_s
        y = self.origin[1] + cy + np.sin(a) * dx + np.cos(a) * dy + self.cam_v[1] * t_s
        img = self.sample(x, y)
        if self.patch:
            c = self.p0 + self.p_v * t_s
            d = np.hypot(self.xx - c[0], self.yy - c[1])
            m = np.clip(self.r + 0.5 - d, 0, 1)[..., None]  # a one-pixel soft edge
            src = self.sample(self.p_src[0] + self.r + self.xx - c[0], self.p_src[1] + self.r + self.yy - c[1])
            img = m * src + (1 - m) * img
        return img


def luminance(img: np.ndarray) -> np.ndarray:
    return img @ np.array([0.2126, 0.7152, 0.0722])


class EventPixels:
    """The event pixels' state, stepped along the time grid with each luminance render."""

    def __init__(self, lum0: np.ndarray, c: float, noise: dict, rng: np.random.Generator):
        h, w = lum0.shape
        self.noise, self.rng = noise, rng
        self.thr_on = np.clip(c + noise["sigma"] * rng.standard_normal((h, w)), 0.5 * c, None)
        self.thr_off = self.thr_on * rng.uniform(0.85, 1.15, (h, w))  # ON/OFF asymmetry per pixel
        self.filt = np.log(lum0 + 1e-3)
        self.ref = self.filt.copy()
        self.last = np.full((h, w), -1e18)
        self.lum_sum, self.steps = lum0.copy(), 1
        self.out = []

    def step(self, lum: np.ndarray, t_prev: float, t: float):
        dt = t - t_prev
        tau = 200.0 + 2000.0 * (1.0 - np.clip(lum, 0, 1))  # us: dark pixels are slower
        prev = self.filt.copy()
        self.filt += (np.log(lum + 1e-3) - self.filt) * (1 - np.exp(-dt / tau))
        self.lum_sum += lum
        self.steps += 1
        for sign, thr in ((1, self.thr_on), (-1, self.thr_off)):
            while True:
                yy, xx = np.nonzero(sign * (self.filt - self.ref) >= thr)
                if len(yy) == 0:
                    break
                level = self.ref[yy, xx] + sign * thr[yy, xx]
                span = self.filt[yy, xx] - prev[yy, xx]
                safe = np.where(np.abs(span) > 1e-12, span, 1.0)
                frac = np.where(np.abs(span) > 1e-12, (level - prev[yy, xx]) / safe, 1.0)
                te = t_prev + np.clip(frac, 0, 1) * dt  # linear in time between grid points
                self.ref[yy, xx] = level
                ok = te - self.last[yy, xx] >= self.noise["refractory_us"]
                self.last[yy[ok], xx[ok]] = te[ok]
                self.out.append(np.stack([te[ok], xx[ok], yy[ok], np.full(ok.sum(), sign)], 1))

    def finish(self, t0: float, t1: float) -> np.ndarray:
        """All events, with background activity (more in the dark), hot pixels and jitter; sorted."""
        rng, noise, span = self.rng, self.noise, t1 - t0
        rate = noise["ba_hz"] * (0.5 / np.clip(self.lum_sum / self.steps, 0.05, 1))
        n = rng.poisson(rate * span * 1e-6)
        for y, x in zip(*np.nonzero(n)):
            k = n[y, x]
            self.out.append(np.stack([t0 + rng.uniform(0, span, k), np.full(k, x), np.full(k, y), rng.choice([-1, 1], k)], 1))
        for y, x in zip(*np.nonzero(rng.random(n.shape) < noise["hot_frac"])):
            k = rng.poisson(noise["hot_hz"] * span * 1e-6)
            self.out.append(np.stack([t0 + rng.uniform(0, span, k), np.full(k, x), np.full(k, y), np.ones(k)], 1))
        ev = np.concatenate(self.out) if self.out else np.zeros((0, 4))
        ev[:, 0] = np.clip(ev[:, 0] + noise["jitter_us"] * rng.standard_normal(len(ev)), t0, t1)
        return ev[np.argsort(ev[:, 0], kind="stable")]


def encode(img: np.ndarray) -> np.ndarray:
    return (np.clip(img, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)


def generate(out: str, photo: str, kind: str, w: int, h: int, frames: int, seed: int, noise_name: str, contrast: float) -> dict:
    rng = np.random.default_rng(seed)
    scene = Scene(load_photo(photo, w, h), w, h, kind, rng)
    # Every row's exposure starts and ends on the 50 us grid: the trapezoid rule needs no partial step.
    period, line_delay, exposure = 50000.0, 50.0, 3000.0
    span = (frames - 1) * period + (h - 1) * line_delay + exposure
    times = np.arange(0.0, span + STEP_US / 2, STEP_US)
    rs = np.zeros((frames, h, w, 3))
    first = np.array([[(f * period + y * line_delay) / STEP_US for y in range(h)] for f in range(frames)]).round().astype(int)
    last = first + int(round(exposure / STEP_US))
    img = scene.render(0.0)
    pixels = EventPixels(luminance(img), contrast, NOISE[noise_name], rng)
    for k in range(len(times)):
        if k:
            img = scene.render(times[k] * 1e-6)
            pixels.step(luminance(img), times[k - 1], times[k])
        weight = np.where((first == k) | (last == k), 0.5, np.where((first < k) & (k < last), 1.0, 0.0))  # [frames, h]
        for f in np.nonzero(weight.any(1))[0]:
            rs[f] += weight[f][:, None, None] * img
    rs /= exposure / STEP_US
    ev = pixels.finish(0.0, times[-1])
    os.makedirs(os.path.join(out, "rs"), exist_ok=True)
    os.makedirs(os.path.join(out, "gs"), exist_ok=True)
    meta = {"width": w, "height": h, "line_delay_us": line_delay, "exposure_us": exposure, "readout": "top-down",
            "events": "events.h5", "frames": [], "ground_truth": [],
            "source": {"generator": "tools/data/second_generator.py", "settings": {"gamma": 2.2},
                       "kind": kind, "seed": seed, "noise": noise_name, "contrast": contrast}}
    for f in range(frames):
        t0 = f * period
        name = f"rs/{f:06d}.png"
        Image.fromarray(encode(rs[f] + 0.005 * rng.standard_normal(rs[f].shape))).save(os.path.join(out, name))
        meta["frames"].append({"file": name, "t0_us": t0})
        frame_span = (h - 1) * line_delay + exposure
        # Inside the frame's span (intra) and, before the next frame, between frames (inter).
        taus = (0.25, 0.5, 0.75) + ((1.0 + 0.5 * (period / frame_span - 1),) if f + 1 < frames else ())
        for j, tau in enumerate(taus):
            t = t0 + tau * frame_span
            gname = f"gs/{f:06d}_{j}.png"
            Image.fromarray(encode(scene.render(t * 1e-6))).save(os.path.join(out, gname))
            meta["ground_truth"].append({"file": gname, "t_us": t})
    with h5py.File(os.path.join(out, "events.h5"), "w") as f5:
        g = f5.create_group("events")
        g["t"] = np.round(ev[:, 0]).astype(np.int64)
        g["x"] = ev[:, 1].astype(np.uint16)
        g["y"] = ev[:, 2].astype(np.uint16)
        g["p"] = (ev[:, 3] > 0).astype(np.int8)
    with open(os.path.join(out, "meta.json"), "w") as f:
        json.dump(meta, f, indent=1)
    info = {"kind": kind, "photo": photo, "split": "validation", "generator": "second_generator",
            "noise": noise_name, "seed": seed, "events": int(len(ev))}
    with open(os.path.join(out, "natural.json"), "w") as f:
        json.dump(info, f, indent=1)
    return info


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out")
    ap.add_argument("--suite")
    ap.add_argument("--photo")
    ap.add_argument("--kind", choices=("camera", "static_movers", "camera_occluders"), default="camera")
    ap.add_argument("--size", default="240x180")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise", choices=sorted(NOISE), default="dvs")
    ap.add_argument("--contrast", type=float, default=0.25)
    ap.add_argument("--split", choices=("train", "heldout"), default="train",
                    help="--suite: photographs of this split (heldout: an evaluation-only suite, marked so)")
    a = ap.parse_args()
    try:
        w, h = (int(v) for v in a.size.split("x"))
    except ValueError:
        sys.exit(f"second_generator: --size '{a.size}': expected WxH")
    if not (16 <= w <= 2048 and 16 <= h <= 2048) or not (2 <= a.frames <= 100) or not (0.05 <= a.contrast <= 1):
        sys.exit("second_generator: --size 16..2048 each, --frames 2..100, --contrast 0.05..1")
    if bool(a.out) == bool(a.suite):
        sys.exit("second_generator: give --out (one sequence, with --photo) or --suite")
    if a.out:
        if not a.photo or not os.path.isfile(a.photo):
            sys.exit(f"second_generator: --photo '{a.photo}': no such file")
        print(json.dumps(generate(a.out, a.photo, a.kind, w, h, a.frames, a.seed, a.noise, a.contrast)))
        return 0
    photos = [p["file"] for p in json.load(open(os.path.join(HERE, "photos.json")))["photos"] if p["split"] == a.split]
    photos = [p for p in photos if os.path.isfile(p)][:2]
    if len(photos) < 2:
        sys.exit(f"second_generator: --suite needs two '{a.split}' photographs of tools/data/photos.json installed")
    for i, kind in enumerate(("camera", "static_movers", "camera_occluders")):
        for j, photo in enumerate(photos):
            name = f"{kind}_{j}"
            info = generate(os.path.join(a.suite, name), photo, kind, w, h, a.frames, 100 + 10 * i + j, a.noise, a.contrast)
            if a.split == "heldout":  # held-out photographs: evaluation only (train.py refuses --data and --val)
                info["split"] = "heldout"
                with open(os.path.join(a.suite, name, "natural.json"), "w") as f:
                    json.dump(info, f, indent=1)
            print(name, json.dumps(info))
    return 0


if __name__ == "__main__":
    sys.exit(main())
