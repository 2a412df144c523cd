"""vkunroll (Python): Sequence.create writes the generic layout the CLI reads; event tensors from
Python (GPU and CPU) equal `vkunroll voxelize` and tools/data/event_tensors_numpy.py exactly, on a
real recording's events; physics_unroll on the GPU equals the CPU reference."""
import fractions
import os
import subprocess

import numpy as np
import pytest

import vkunroll

from tools.data import event_tensors_numpy as etn

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
REAL = os.path.join(ROOT, "tests", "data", "real", "sample.aedat4")
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))

W, H = 320, 240


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """The real DVXplorer events with two made-up RS frames (integer timing: float64 is exact)."""
    ev = vkunroll.read_events(REAL)
    base = int(ev["t"][0])
    rng = np.random.default_rng(5)
    frames = [rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)]
    timings = [vkunroll.RowTiming(H, base + 50000 + k * 200000, 100, 5000) for k in range(2)]
    path = tmp_path_factory.mktemp("seq") / "real"
    seq = vkunroll.Sequence.create(path, frames, ev, timings, source={"camera": "DVXplorer (events only)"})
    return seq, ev, frames, timings


def test_sequence_create_round_trips(recording, tmp_path):
    seq, ev, frames, timings = recording
    assert (seq.layout, seq.sensor_size, len(seq)) == ("generic", (W, H), 2)
    assert seq.timings == timings
    np.testing.assert_allclose(seq.frame(1), frames[1].astype(np.float32) / 255, rtol=0, atol=1e-7)
    before = seq.event_totals()
    np.testing.assert_array_equal(seq.events(), ev)
    lo, hi = int(ev["t"][100]), int(ev["t"][5000])
    np.testing.assert_array_equal(seq.events(lo, hi), ev[(ev["t"] >= lo) & (ev["t"] < hi)])
    totals = seq.event_totals()  # two overlapping reads more, every record counted once
    assert (totals["reads"] - before["reads"], totals["records"], totals["dropped"]) == (2, len(ev), 0), totals
    assert totals["delivered"] - before["delivered"] == len(ev) + int(((ev["t"] >= lo) & (ev["t"] < hi)).sum())
    # Inexact times and float frames: the times come back exact, the frames within 16-bit rounding.
    tm = [vkunroll.RowTiming(H, fractions.Fraction(1, 3) + k * 100000, "100/3", "5000/7") for k in range(2)]
    gray = np.random.default_rng(1).random((2, H, W)).astype(np.float32)
    small = vkunroll.Sequence.create(tmp_path / "exact", gray, ev[:1000], tm,
                                     ground_truth=[(fractions.Fraction(7, 2), gray[0])])
    assert small.timings == tm
    assert small.ground_truth[0][0] == fractions.Fraction(7, 2)
    assert np.abs(small.frame(0) - gray[0][:, :, None]).max() <= 0.5 / 65535 + 1e-7
    with pytest.raises(ValueError, match="one line delay and readout for all frames"):
        vkunroll.Sequence.create(tmp_path / "bad", gray, ev[:10], [tm[0], vkunroll.RowTiming(H, 0, 1, 1)])
    assert not (tmp_path / "bad" / "meta.json").exists()


def numpy_reference(ev, timing, t_star, bins, crop):
    pair = dict(t0=float(timing.t0_us), delay=float(timing.line_delay_us), exposure=float(timing.exposure_us),
                readout=timing.readout, target=float(t_star), texp=float(timing.exposure_us))
    p = np.where(ev["p"] > 0, 1, -1)
    return etn.three_tensors((ev["t"], ev["x"].astype(np.int64), ev["y"].astype(np.int64), p), pair, H, bins, crop)


@pytest.mark.parametrize("crop,bins,cpu", [(None, 8, False), ((40, 30, 200, 150), 16, True)])
def test_event_tensors_equal_voxelize_and_numpy(recording, tmp_path, crop, bins, cpu):
    seq, ev, _, timings = recording
    taus = ["0.25", "0.5", "1.5"]
    out = tmp_path / "vox.safetensors"
    cmd = [CLI, "voxelize", seq.root, "--frames", "0:1", "--times", ",".join(taus), "--bins", str(bins), "--out", str(out)]
    if crop:
        cmd += ["--crop", ",".join(map(str, crop))]
    if cpu:
        cmd += ["--cpu"]
    subprocess.run(cmd, check=True, capture_output=True)
    cli, _meta = etn.load_safetensors(str(out))
    pair_timing = [tm for tm in timings for _ in taus]  # frame-major, as voxelize
    t_star = [tm.target_time(tau) for tm in timings for tau in taus]
    for backend in ("vulkan", "cpu"):
        got = vkunroll.event_tensors_batch(ev, pair_timing, t_star, bins, crop=crop, sensor_size=(W, H), backend=backend)
        for name, g in zip(("ev1", "ev2", "ev3"), got):
            assert g.dtype == np.float32 and g.shape == cli[name].shape
            np.testing.assert_array_equal(g, cli[name], err_msg=f"{name} {backend}")
    ref_crop = crop or (0, 0, W, H)
    for i in (0, 5):  # one target inside the frame, one between frames
        want = numpy_reference(ev, pair_timing[i], t_star[i], bins, ref_crop)
        single = vkunroll.event_tensors(ev, pair_timing[i], t_star[i], bins, crop=crop, sensor_size=(W, H))
        for name, g, w in zip(("ev1", "ev2", "ev3"), single, want):
            np.testing.assert_array_equal(g, w, err_msg=f"{name} pair {i}")
            assert w.sum() > 100, "the window holds events"


def test_event_tensors_take_other_dtypes_and_exact_times(recording):
    _, ev, _, timings = recording
    theirs = vkunroll.convert_events(ev, vkunroll.METAVISION_DTYPE)
    t_star = timings[0].target_time(fractions.Fraction(1, 3))  # not an integer: exact rational binning
    a = vkunroll.event_tensors(ev, timings[0], t_star, 4, sensor_size=(W, H))
    b = vkunroll.event_tensors(theirs, timings[0], str(t_star), 4, sensor_size=(W, H), backend="cpu")
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(ValueError, match="outside the sensor width 100"):
        vkunroll.event_tensors(ev, timings[0], t_star, sensor_size=(100, H))


def test_physics_unroll_gpu_equals_cpu(recording):
    seq, ev, _, timings = recording
    rs = seq.frame(0)
    t_star = timings[0].target_time(0.5)
    gpu = vkunroll.physics_unroll(rs, ev, timings[0], t_star, contrast=0.25, gamma=2.2)
    cpu = vkunroll.physics_unroll(rs, ev, timings[0], t_star, contrast=0.25, gamma=2.2, backend="cpu")
    assert gpu.shape == rs.shape and gpu.dtype == np.float32
    np.testing.assert_allclose(gpu, cpu, atol=1e-4, rtol=1e-4)
    assert np.abs(cpu - rs).max() > 0.01  # the events changed the image
    gray = vkunroll.physics_unroll(rs[:, :, 1], ev, timings[0], t_star, backend="cpu")
    assert gray.shape == (H, W)
    # A log offset: GPU == CPU again, and another image (dark pixels change most)
    gpu_o = vkunroll.physics_unroll(rs, ev, timings[0], t_star, contrast=0.25, gamma=2.2, log_offset=0.05)
    cpu_o = vkunroll.physics_unroll(rs, ev, timings[0], t_star, contrast=0.25, gamma=2.2, log_offset=0.05, backend="cpu")
    np.testing.assert_allclose(gpu_o, cpu_o, atol=1e-4, rtol=1e-4)
    assert np.abs(cpu_o - cpu).max() > 0.01
    with pytest.raises(ValueError, match="log_offset"):
        vkunroll.physics_unroll(rs, ev, timings[0], t_star, log_offset=-1.0, backend="cpu")


def test_threads_share_a_context(recording):
    """Four Python threads building event tensors on one context at once (the GIL released, the
    context's queue serialized) get what one thread gets."""
    import threading
    _, ev, _, timings = recording
    t_star = [timings[0].target_time(tau) for tau in (0.2, 0.8)]
    want = vkunroll.event_tensors_batch(ev, timings[0], t_star, 4, sensor_size=(W, H))
    got, errors = [None] * 4, []

    def work(i):
        try:
            got[i] = vkunroll.event_tensors_batch(ev, timings[0], t_star, 4, sensor_size=(W, H))
        except Exception as e:  # noqa: BLE001  (reported below)
            errors.append(e)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors, errors
    for g in got:
        for a, b in zip(g, want):
            np.testing.assert_array_equal(a, b)
