"""tools/data/second_generator.py, the validation-only event generator: seeded and deterministic,
its noise options change what they say, and `vkunroll unroll` reads every event it writes."""
import json
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
GEN = os.path.join(ROOT, "tools", "data", "second_generator.py")
CLI = os.environ.get("VKUNROLL_CLI")


@pytest.fixture(scope="module")
def photo(tmp_path_factory):
    """A smooth random texture (no reserved image): blurred noise at several scales."""
    rng = np.random.default_rng(3)
    img = np.zeros((200, 260, 3))
    for s in (4, 16, 64):
        small = rng.random((200 // s + 2, 260 // s + 2, 3))
        img += np.asarray(Image.fromarray((small * 255).astype(np.uint8)).resize((260, 200), Image.BICUBIC)) / 255.0
    path = tmp_path_factory.mktemp("photo") / "texture.png"
    Image.fromarray((img / 3 * 255).astype(np.uint8)).save(path)
    return str(path)


def generate(out, photo, seed=1, noise="dvs", kind="camera_occluders"):
    r = subprocess.run([sys.executable, GEN, "--out", str(out), "--photo", photo, "--kind", kind, "--size", "48x36",
                        "--frames", "2", "--seed", str(seed), "--noise", noise], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with h5py.File(os.path.join(out, "events.h5")) as f:
        ev = {k: f["events"][k][()] for k in "txyp"}
    return json.loads(r.stdout), ev


def test_same_seed_same_bytes_other_seed_other_events(tmp_path, photo):
    _, a = generate(tmp_path / "a", photo, seed=5)
    _, b = generate(tmp_path / "b", photo, seed=5)
    _, c = generate(tmp_path / "c", photo, seed=6)
    for k in "txyp":
        assert np.array_equal(a[k], b[k])
    for name in ("rs/000000.png", "gs/000001_2.png"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert len(a["t"]) != len(c["t"]) or not np.array_equal(a["t"], c["t"])


def test_noise_levels_order_the_event_counts_and_events_are_valid(tmp_path, photo):
    counts = {}
    for noise in ("none", "dvs", "heavy"):
        info, ev = generate(tmp_path / noise, photo, noise=noise, kind="static_movers")
        counts[noise] = len(ev["t"])
        assert info["events"] == len(ev["t"]) and info["split"] == "validation"
        assert np.all(np.diff(ev["t"]) >= 0) and ev["x"].max() < 48 and ev["y"].max() < 36
        assert set(np.unique(ev["p"])) <= {0, 1}
    assert counts["none"] > 0, "a moving disc on a static camera gives events"
    assert counts["none"] < counts["dvs"] < counts["heavy"], counts


@pytest.mark.skipif(not CLI or not os.path.exists(CLI or ""), reason="VKUNROLL_CLI not set (run through ctest)")
def test_vkunroll_reads_every_event_and_unrolls_it(tmp_path, photo):
    info, ev = generate(tmp_path / "seq", photo)
    r = subprocess.run([CLI, "unroll", str(tmp_path / "seq"), "--out", str(tmp_path / "out"), "--mode", "physics",
                        "--times", "gt", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    s = json.load(open(tmp_path / "out" / "summary.json"))
    totals = s["events"]["file_totals"]
    assert totals["valid"] == len(ev["t"]) and totals["dropped"] == 0, totals
    assert s["metrics"]["count"] == 7  # 3 ground-truth instants per frame, 1 between the two
