"""tools/data/event_tensors_numpy.py: the committed golden fixture is what the tool writes, and the
NumPy float64 binning agrees with the exact Fraction implementation on integer timing."""
import os

import numpy as np

from tools.data import event_tensors_numpy as etn

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_golden_fixture_is_reproducible(tmp_path):
    out = tmp_path / "golden.safetensors"
    etn.write_golden(str(out))
    committed = os.path.join(ROOT, "tests", "data", "event_tensor_golden.safetensors")
    a, ma = etn.load_safetensors(str(out))
    b, mb = etn.load_safetensors(committed)
    assert ma == mb
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_float64_equals_exact_on_integer_timing():
    rng = np.random.default_rng(3)
    n, w, h = 3000, 12, 9
    t = np.sort(rng.integers(-100, 1500, n)).astype(np.int64)
    x, y = rng.integers(0, w, n), rng.integers(0, h, n)
    p = rng.choice(np.array([1, -1], dtype=np.int8), n)
    case = dict(t0="0", delay="20", exposure="400", readout="bottom-up", bins=16, crop=[0, 0, w, h], texp=None)
    for tau in ["0.25", "-0.5", "1.5"]:
        ts = etn.target_time(0.0, 20.0, 400.0, h, float(etn._f(tau)))
        pair = dict(t0=0.0, delay=20.0, exposure=400.0, readout="bottom-up", target=ts, texp=400.0)
        fast = etn.three_tensors((t, x, y, p), pair, h, 16, (0, 0, w, h))
        exact = etn.three_tensors_exact((t, x, y, p), case, tau, h)
        for f, e in zip(fast, exact):
            np.testing.assert_array_equal(f, e)
            assert f.sum() > 0
