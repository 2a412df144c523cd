"""tools/data/natural_data.py's training draws: the 'wide' event model draws every noise option on its
own within its stated range, replaces the preset's flags, leaves the 'presets' draws as they were,
and every draw is a command `vkunroll simulate` accepts."""
import json
import os
import random
import subprocess

import pytest

from tools.data import natural_data

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

CLI = os.environ.get("VKUNROLL_CLI")
RANGES = {"c-on": (0.08, 0.6), "c-off": (0.05, 0.9), "sigma": (0, 0.08), "refractory-us": (0, 2000),
          "leak-hz": (0, 1), "shot-hz": (0, 20), "cutoff-hz": (0, 1000), "eps": (0.005, 0.2),
          "hot-pixels": (0, 3e-3), "hot-hz": (20, 2000), "jitter-us": (0, 500), "full-well": (1000, 20000),
          "read-noise": (0, 0.012)}


def flags(args):
    return {args[i][2:]: args[i + 1] for i in range(len(args) - 1) if args[i].startswith("--")}


def test_wide_draws_every_option_within_its_range_and_varies_it():
    seen = {k: set() for k in RANGES}
    for seed in range(200):
        args, drawn = natural_data.wide_event_args(random.Random(seed))
        f = flags(args)
        assert f["preset"] == "clean"
        for k, (lo, hi) in RANGES.items():
            v = float(f[k])
            assert lo - 1e-9 <= v <= hi + 1e-6, (k, v)
            assert drawn[k] == pytest.approx(v, rel=1e-5)
            seen[k].add(round(v, 6))
    for k, values in seen.items():
        assert len(values) > 20, f"{k} barely varies: {sorted(values)[:5]}"
    # Asymmetric thresholds both ways.
    ratios = [d["c-off"] / d["c-on"] for d in (natural_data.wide_event_args(random.Random(s))[1] for s in range(200))]
    assert min(ratios) < 0.8 and max(ratios) > 1.4


def test_wide_replaces_the_preset_flags_and_presets_are_unchanged():
    for seed in range(30):
        old, kind_old, info_old = natural_data.train_args(random.Random(seed))
        same, kind_same, _ = natural_data.train_args(random.Random(seed), event_model="presets")
        assert old == same and kind_old == kind_same
        wide, kind_wide, info = natural_data.train_args(random.Random(seed), event_model="wide")
        assert kind_wide == kind_old
        for flag in ("--preset", "--c-on", "--c-off", "--sigma", "--jitter-us", "--hot-pixels"):
            assert wide.count(flag) == 1, (flag, wide)
        assert info["preset"] == "wide" and set(info["event_model"]) == set(RANGES)
        # Everything but the event model is the same draw.
        fo, fw = flags(old), flags(wide)
        for k in ("size", "motion", "speed", "exposure-us", "line-delay-us", "gamma", "readout"):
            assert fo[k] == fw[k], k
    with pytest.raises(natural_data.DataError):
        natural_data.train_args(random.Random(1), event_model="v2e")


@pytest.mark.skipif(not CLI, reason="VKUNROLL_CLI not set (ctest sets it)")
def test_the_simulator_accepts_every_wide_draw_and_records_it(tmp_path):
    for seed in range(6):
        args, drawn = natural_data.wide_event_args(random.Random(seed))
        out = tmp_path / f"s{seed}"
        r = subprocess.run([CLI, "simulate", "--out", str(out), "--size", "48x36", "--frames", "2", "--quiet",
                            "--seed", str(seed)] + args, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        model = json.load(open(out / "meta.json"))["source"]["settings"]["event_model"]
        for key, flag in (("hot_fraction", "hot-pixels"), ("jitter_us", "jitter-us"), ("eps", "eps"),
                          ("refractory_us", "refractory-us")):
            assert model[key] == pytest.approx(drawn[flag], rel=1e-5)
