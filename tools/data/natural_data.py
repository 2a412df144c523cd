#!/usr/bin/python3
"""Sequences from real photographs: `vkunroll simulate --texture PHOTO` with the motions, sensor
timings, event models and encodings real rigs see (docs/training_data.md).

  natural_data.py --check                                   # manifest files present, sha256 as recorded
  natural_data.py --heldout data/natural/heldout            # the fixed held-out suite (evaluation only)
  natural_data.py --train data/natural/train --count 48 --seed-base 1  # random training sequences
  natural_data.py --list-heldout                            # what the held-out suite holds
  natural_data.py --heldout-draw data/natural/draw --count 12 --seed-base 3001 --kinds ...  # random
                  held-out sequences: training's draws, held-out photographs (evaluation only)

Photographs come from tools/data/photos.json: split 'train' feeds --train only, split 'heldout'
and scikit-image's sample images (reserved for evaluation) feed --heldout only. Each sequence
folder gets `natural.json` (photo, package, licence, split, motion kind, simulator command).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import shlex
import subprocess
import sys
import time
from typing import Dict, List, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
MANIFEST = os.path.join(HERE, "photos.json")
SKIMAGE_DIR = "/usr/lib/python3/dist-packages/skimage/data"

# Motion kinds scored separately by tools/eval/natural_eval.py.
KINDS = ("camera", "static_movers", "camera_occluders")
PRESETS = ("clean", "realistic", "noisy")  # vkunroll simulate --preset


class DataError(ValueError):
    pass


def load_manifest(path: str = MANIFEST) -> dict:
    if not os.path.isfile(path):
        raise DataError(f"{path}: photo manifest not found")
    return json.load(open(path))


def photos(split: str, manifest: Optional[dict] = None) -> List[dict]:
    m = manifest or load_manifest()
    out = [p for p in m["photos"] if p["split"] == split]
    if split == "heldout":
        for name in m["skimage"]["images"]:
            out.append({"file": os.path.join(SKIMAGE_DIR, name + ".png"), "package": "python3-skimage",
                        "license": m["skimage"]["license"], "split": "heldout", "content": f"skimage.data.{name}"})
    return out


def check(manifest: dict) -> List[str]:
    """Problems with the manifest's files: missing, or content not as recorded."""
    bad = []
    for p in manifest["photos"]:
        if not os.path.isfile(p["file"]):
            bad.append(f"{p['file']}: missing (install: apt-get install {p['package']})")
        elif hashlib.sha256(open(p["file"], "rb").read()).hexdigest() != p["sha256"]:
            bad.append(f"{p['file']}: sha256 differs from the manifest (package {p['package']} changed?)")
    for name in manifest["skimage"]["images"]:
        f = os.path.join(SKIMAGE_DIR, name + ".png")
        if not os.path.isfile(f):
            bad.append(f"{f}: missing (install: apt-get install python3-skimage)")
    return bad


def photo_by_name(name: str, split: str) -> dict:
    for p in photos(split):
        if os.path.basename(p["file"]).startswith(name) or f"/{name}/" in p["file"] or p["content"].endswith(name):
            return p
    raise DataError(f"no {split} photo named '{name}' in {MANIFEST}")


# ---- the held-out suite: fixed, never trained or tuned on ---------------------------------------------
# (name, photo, kind, simulator arguments). DAVIS346 timing (346x260, 60-80 us line delay) and a
# Prophesee-size 640x480 sensor; gamma 2.2 and 1; thresholds 0.1-0.5 with mismatch; clean and noisy.
DAVIS = ["--size", "346x260", "--frames", "4", "--gt-per-frame", "4"]
VGA = ["--size", "640x480", "--frames", "3", "--gt-per-frame", "4", "--line-delay-us", "40", "--exposure-us", "4000"]
HELDOUT = [
    # the three scenes: clean events, contrast 0.2 with mismatch, 61.5 us, 2.5 ms exposure
    ("h01_pan_shake_roll", "LadyBird", "camera", DAVIS + ["--preset", "clean", "--sigma", "0.03", "--line-delay-us", "61.5",
     "--exposure-us", "2500", "--motion", "mixed", "--speed", "1.5", "--sprites", "0", "--seed", "101"]),
    ("h02_static_fast_object", "picosdeeuropa", "static_movers", DAVIS + ["--preset", "clean", "--sigma", "0.03",
     "--line-delay-us", "61.5", "--exposure-us", "2500", "--motion", "static", "--sprites", "1", "--speed", "2",
     "--seed", "102"]),
    ("h03_pan_occluder", "Bridge", "camera_occluders", DAVIS + ["--preset", "clean", "--sigma", "0.03",
     "--line-delay-us", "61.5", "--exposure-us", "2500", "--motion", "pan", "--sprites", "2", "--seed", "103"]),
    # realistic event model (refractory, leak, shot noise, frame noise), other timings and thresholds
    ("h04_accelerate_gamma1", "Kleiber", "camera", DAVIS + ["--preset", "realistic", "--line-delay-us", "70",
     "--exposure-us", "3000", "--motion", "accelerate", "--sprites", "0", "--gamma", "1", "--seed", "104"]),
    ("h05_zoom_noisy_c03", "EveningGlow", "camera", DAVIS + ["--preset", "noisy", "--c-on", "0.3", "--c-off", "0.3",
     "--line-delay-us", "65", "--exposure-us", "2000", "--motion", "zoom", "--speed", "1.5", "--sprites", "0",
     "--seed", "105"]),
    ("h06_shake_c045", "Path", "camera", DAVIS + ["--preset", "realistic", "--c-on", "0.4", "--c-off", "0.45",
     "--line-delay-us", "80", "--exposure-us", "3000", "--motion", "shake", "--speed", "2", "--sprites", "0",
     "--seed", "106"]),
    ("h07_roll_movers_c015", "friends", "camera_occluders", DAVIS + ["--preset", "realistic", "--c-on", "0.15",
     "--c-off", "0.18", "--line-delay-us", "60", "--exposure-us", "2500", "--motion", "rotate", "--sprites", "2",
     "--gamma", "1", "--seed", "107"]),
    ("h08_fast_pan_bottomup", "Storm", "camera", DAVIS + ["--preset", "realistic", "--line-delay-us", "75",
     "--exposure-us", "1500", "--motion", "pan", "--speed", "2.5", "--readout", "bottom-up", "--sprites", "0",
     "--seed", "108"]),
    # Prophesee-size sensor
    ("h09_vga_pan_occluders", "EveningGlow", "camera_occluders", VGA + ["--preset", "realistic", "--motion", "mixed",
     "--sprites", "2", "--seed", "109"]),
    ("h10_vga_static_movers", "Path", "static_movers", VGA + ["--preset", "realistic", "--motion", "static",
     "--sprites", "3", "--speed", "1.5", "--seed", "110"]),
    # scikit-image sample images (evaluation only): scenes unlike the training photographs
    ("h11_coffee_pan_shake", "coffee", "camera", DAVIS + ["--preset", "realistic", "--line-delay-us", "61.5",
     "--exposure-us", "2500", "--motion", "mixed", "--speed", "1.5", "--sprites", "0", "--seed", "111"]),
    ("h12_astronaut_static_movers", "astronaut", "static_movers", DAVIS + ["--preset", "clean", "--sigma", "0.03",
     "--motion", "static", "--sprites", "2", "--speed", "2", "--line-delay-us", "61.5", "--exposure-us", "2500",
     "--seed", "112"]),
]


def simulate(cli: str, out: str, photo: dict, args: List[str], kind: str, extra: Optional[Dict] = None) -> float:
    if os.path.isfile(os.path.join(out, "natural.json")):
        return 0.0
    # --overwrite: a folder without natural.json is an unfinished earlier attempt
    cmd = [cli, "simulate", "--out", out, "--texture", photo["file"], "--quiet", "--overwrite"] + args
    t0 = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise DataError(f"'{shlex.join(cmd)}' failed ({r.returncode}): {r.stderr.strip()}")
    info = {"photo": photo["file"], "package": photo["package"], "license": photo["license"], "split": photo["split"],
            "content": photo["content"], "kind": kind, "simulate": shlex.join(["vkunroll"] + cmd[1:])}
    info.update(extra or {})
    tmp = os.path.join(out, "natural.json.tmp")
    json.dump(info, open(tmp, "w"), indent=1)
    os.replace(tmp, os.path.join(out, "natural.json"))  # written last: a folder with it is complete
    return time.time() - t0


def make_heldout(out: str, cli: str, only: Optional[List[str]] = None) -> None:
    os.makedirs(out, exist_ok=True)
    for name, photo, kind, args in HELDOUT:
        if only and name not in only:
            continue
        d = os.path.join(out, name)
        sec = simulate(cli, d, photo_by_name(photo, "heldout"), args, kind)
        print(f"{d}: {kind} ({sec:.1f} s)", flush=True)


EVENT_MODELS = ("presets", "wide")  # --event-model: a preset with drawn thresholds, or every option drawn


def log_uniform(rng: random.Random, lo: float, hi: float) -> float:
    return lo * (hi / lo) ** rng.random()


def wide_event_args(rng: random.Random) -> (List[str], dict):
    """Every option of the event and frame noise model drawn on its own, over ranges wider than any
    one camera's (docs/simulator.md gives the realistic ranges these enclose): the model must not
    learn one simulator's sensor. Returns the simulate arguments and what was drawn."""
    c_on = rng.uniform(0.08, 0.6)
    d = {"c-on": c_on, "c-off": min(0.9, max(0.05, c_on * rng.uniform(0.6, 1.7))),
         "sigma": rng.uniform(0.0, 0.08),
         "refractory-us": rng.choice([0.0, log_uniform(rng, 20, 2000)]),
         "leak-hz": rng.uniform(0.0, 1.0),
         "shot-hz": 0.0 if rng.random() < 0.2 else log_uniform(rng, 0.01, 20),
         "cutoff-hz": 0.0 if rng.random() < 0.25 else log_uniform(rng, 20, 1000),
         "eps": log_uniform(rng, 0.005, 0.2),
         "hot-pixels": 0.0 if rng.random() < 0.3 else log_uniform(rng, 1e-4, 3e-3),
         "hot-hz": log_uniform(rng, 20, 2000),
         "jitter-us": 0.0 if rng.random() < 0.3 else log_uniform(rng, 5, 500),
         "full-well": log_uniform(rng, 1000, 20000),
         "read-noise": rng.uniform(0.0, 0.012)}
    d = {k: round(v, 6) for k, v in d.items()}
    args = ["--preset", "clean"]
    for k, v in d.items():
        args += [f"--{k}", f"{v:g}"]
    return args, d


def train_args(rng: random.Random, force_kind: Optional[str] = None, gt_per_frame: int = 2,
               force_preset: Optional[str] = None, event_model: str = "presets") -> (List[str], str, dict):
    """Random simulator settings for one training sequence (what the issue asks to cover).
    `force_kind` (one of KINDS) and `force_preset` replace the drawn motion kind and event preset;
    every other draw is unchanged. `event_model` 'wide' replaces the preset and its thresholds by
    wide_event_args (drawn after every other setting, so the rest is the same draw)."""
    vga = rng.random() < 0.25
    if vga:  # Prophesee-size sensor, simulated at 640x480 (training takes crops)
        size, rows = "640x480", 480
        line_delay = rng.uniform(20, 40)
    else:    # DAVIS346
        size, rows = "346x260", 260
        line_delay = rng.uniform(60, 80)
    fps = 20.0
    exposure = rng.choice([1000, 1500, 2000, 2500, 3000, 4000, 5000])
    exposure = min(exposure, 1e6 / fps - rows * line_delay - 100)
    r = rng.random()
    if force_kind:
        r = {"static_movers": 0.1, "camera_occluders": 0.4, "camera": 0.8}[force_kind]
    if r < 0.2:
        kind, motion, sprites = "static_movers", "static", rng.randint(1, 3)
    elif r < 0.55:
        kind, motion, sprites = "camera_occluders", rng.choice(["pan", "accelerate", "mixed", "shake"]), rng.randint(1, 3)
    else:
        kind, motion, sprites = "camera", rng.choice(["pan", "accelerate", "rotate", "zoom", "shake", "mixed"]), 0
    preset = rng.choice(["clean", "realistic", "realistic", "noisy"])
    preset = force_preset or preset
    c_on = round(rng.uniform(0.1, 0.5), 3)
    c_off = round(min(0.5, c_on * rng.uniform(0.9, 1.3)), 3)
    sigma = round(rng.uniform(0.01, 0.06), 3)
    gamma = rng.choice(["2.2", "1"])
    speed = round(rng.choice([0.5, 1, 1, 1.5, 2, 2.5]), 2)
    args = ["--size", size, "--frames", "4", "--gt-per-frame", str(gt_per_frame), "--fps", f"{fps:g}",
            "--line-delay-us", f"{line_delay:.1f}", "--exposure-us", f"{exposure:.0f}", "--preset", preset,
            "--c-on", str(c_on), "--c-off", str(c_off), "--sigma", str(sigma), "--motion", motion,
            "--sprites", str(sprites), "--speed", str(speed), "--gamma", gamma, "--step-fraction", "1",
            "--readout", rng.choice(["top-down", "top-down", "bottom-up"])]
    if event_model == "wide":
        drawn_flags = {"--preset", "--c-on", "--c-off", "--sigma"}
        kept = [a for i, a in enumerate(args) if a not in drawn_flags and (i == 0 or args[i - 1] not in drawn_flags)]
        wide, drawn = wide_event_args(rng)
        return kept + wide, kind, {"preset": "wide", "gamma": gamma, "event_model": drawn}
    if event_model != "presets":
        raise DataError(f"event model '{event_model}': expected one of {', '.join(EVENT_MODELS)}")
    return args, kind, {"preset": preset, "gamma": gamma}


def make_train(out: str, cli: str, count: int, seed_base: int, kinds: Optional[List[str]] = None,
               gt_per_frame: int = 2, presets: Optional[List[str]] = None, split: str = "train",
               event_model: str = "presets") -> None:
    """`count` sequences nat_<seed>; `kinds`, `presets`: motion kinds and event presets cycled over
    the seeds (else drawn); `split` 'heldout' draws the photographs from the held-out ones and
    scikit-image's (evaluation only)."""
    os.makedirs(out, exist_ok=True)
    pool = photos(split)
    for i in range(count):
        seed = seed_base + i
        rng = random.Random(1000003 * seed + 7)
        photo = pool[rng.randrange(len(pool))]
        args, kind, info = train_args(rng, kinds[i % len(kinds)] if kinds else None, gt_per_frame,
                                      presets[i % len(presets)] if presets else None, event_model)
        d = os.path.join(out, f"nat_{seed:05d}")
        extra = {"event_model": info["event_model"]} if event_model == "wide" else None
        sec = simulate(cli, d, photo, args + ["--seed", str(seed)], kind, extra)
        print(f"{d}: {os.path.basename(photo['file'])} {kind} {' '.join(args[:2])} ({sec:.1f} s)", flush=True)


def find_cli(explicit: Optional[str]) -> str:
    for c in (explicit, os.environ.get("VKUNROLL_CLI"), os.path.join(ROOT, "build", "vkunroll")):
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return c
    raise DataError("vkunroll CLI not found: pass --cli PATH or set VKUNROLL_CLI")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n", 1)[1])
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--list-heldout", action="store_true")
    ap.add_argument("--heldout", metavar="DIR")
    ap.add_argument("--only", nargs="*", help="with --heldout: only these sequence names")
    ap.add_argument("--train", metavar="DIR")
    ap.add_argument("--heldout-draw", metavar="DIR", help="random sequences as --train draws them, from held-out "
                    "photographs only (evaluation only)")
    ap.add_argument("--count", type=int, default=32)
    ap.add_argument("--seed-base", type=int, default=1)
    ap.add_argument("--kinds", help="with --train: comma list of motion kinds cycled over the seeds "
                    f"({', '.join(KINDS)}) instead of drawn")
    ap.add_argument("--presets", help="with --train: comma list of event presets (clean, realistic, noisy) cycled "
                    "over the seeds instead of drawn")
    ap.add_argument("--gt-per-frame", type=int, default=2, help="with --train: ground-truth instants per frame [2]")
    ap.add_argument("--event-model", choices=EVENT_MODELS, default="presets",
                    help="with --train: 'presets' (a preset with drawn thresholds) or 'wide' (every event and frame "
                    "noise option drawn on its own, wider than any camera) [presets]")
    ap.add_argument("--cli")
    a = ap.parse_args(argv)
    try:
        m = load_manifest()
        if a.check:
            bad = check(m)
            for b in bad:
                print(b)
            print(f"{len(m['photos'])} photographs in the manifest, {len(bad)} problems")
            return 1 if bad else 0
        if a.list_heldout:
            for name, photo, kind, args in HELDOUT:
                print(f"{name}: {photo} [{kind}] {' '.join(args)}")
            return 0
        if a.heldout:
            make_heldout(a.heldout, find_cli(a.cli), a.only)
        if a.train or a.heldout_draw:
            def cycled(flag: str, value: Optional[str], allowed) -> Optional[List[str]]:
                """The comma list of `flag`, each item checked against `allowed`; None when not given."""
                items = value.split(",") if value else None
                for x in items or []:
                    if x not in allowed:
                        ap.error(f"{flag}: '{x}' is not one of {', '.join(allowed)}")
                return items
            kinds = cycled("--kinds", a.kinds, KINDS)
            presets = cycled("--presets", a.presets, PRESETS)
            if presets and a.event_model == "wide":
                ap.error("--presets and --event-model wide exclude each other (wide draws every option)")
            for out, split in ((a.train, "train"), (a.heldout_draw, "heldout")):
                if out:
                    make_train(out, find_cli(a.cli), a.count, a.seed_base, kinds, a.gt_per_frame, presets, split,
                               a.event_model)
        if not (a.heldout or a.train or a.heldout_draw):
            ap.error("nothing to do: --check, --list-heldout, --heldout DIR, --heldout-draw DIR or --train DIR")
    except DataError as e:
        print(f"natural_data.py: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
