"""Issue 58's argument rules, each case through both front ends where it has two: numpy scalars are
numbers (one conversion rule, vkunroll/_args.plain_number); normalized instants are not called
microseconds; options that cannot apply are refused by one table per place (the backend's and the
event formats'); --frames bounds the targets; the library's list and crop rules serve the CLI and
Python alike; special files never block detection; a stream shared by threads is served one
caller at a time; a repeated JSON key, an exact time with two '/' and a truncated image are errors
naming what is wrong."""
import json
import os
import shutil
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

vkunroll = pytest.importorskip("vkunroll")

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))
W, H = 64, 48
NUMPY_FLOATS = (np.float16, np.float32, np.float64, np.longdouble)
NUMPY_INTS = (np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64)


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    d = tmp_path_factory.mktemp("issue58") / "seq"
    subprocess.run([CLI, "simulate", "--out", str(d), "--size", f"{W}x{H}", "--frames", "3", "--gt-per-frame", "2",
                    "--seed", "5", "--quiet"], check=True)
    return d


def cli(*args, timeout=300):
    return subprocess.run([CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def physics(seq, **kw):
    return vkunroll.unroll(seq, **{"mode": "physics", "backend": "cpu", "contrast": 0.2, **kw})


# ---- crashes: every numpy scalar type is a number -----------------------------------------------

@pytest.mark.parametrize("kind", NUMPY_FLOATS + NUMPY_INTS)
def test_every_numpy_scalar_is_a_time(seq, kind):
    s = vkunroll.Sequence.open(seq)
    tau = kind(0) if kind in NUMPY_INTS else kind(0.5)
    r = physics(seq, times=tau, frames=[0])
    assert float(r.targets[0]["tau"]) == float(tau)
    t_us = kind(100)  # within every type's range (int8 holds up to 127)
    timing = vkunroll.RowTiming(H, kind(0), kind(10), kind(100))
    assert timing.target_time(kind(1)) == timing.last_end_us
    assert timing.tau_of(kind(0)) == 0
    ev = s.events()
    e1, e2, e3 = vkunroll.event_tensors(ev, timing, t_us, bins=2, target_exposure_us=kind(100), sensor_size=(W, H),
                                        backend="cpu")
    assert e1.shape == (4, H, W)
    img = s.frame(0)
    assert vkunroll.physics_unroll(img, ev, timing, t_us, backend="cpu").shape == img.shape
    vkunroll.event_tensors_batch(ev, timing, np.array([t_us, t_us + kind(1)]), bins=1, sensor_size=(W, H), backend="cpu")


def test_times_us_takes_numpy_scalars(seq):
    t = vkunroll.Sequence.open(seq).timing(1).target_time(0.5)
    r = physics(seq, times_us=np.float32(int(t)), frames=[1])
    assert r.targets[0]["frame"] == 1


@pytest.mark.parametrize("kind", (np.float16, np.float32))
def test_a_non_finite_numpy_time_names_the_keyword(seq, kind):
    with pytest.raises(ValueError, match="t0_us"):
        vkunroll.RowTiming(H, kind("nan"), 10, 100)
    s = vkunroll.Sequence.open(seq)
    with pytest.raises(ValueError, match="target_exposure_us"):
        vkunroll.event_tensors(s.events(), s.timing(0), 1000, target_exposure_us=kind("inf"), sensor_size=(W, H),
                               backend="cpu")


# ---- vague: units, a session without a model, a keyword that does not exist ---------------------

def test_normalized_instants_are_not_called_microseconds(seq):
    with pytest.raises(ValueError) as e:
        physics(seq, times=float("nan"))
    assert "times=nan" in str(e.value) and "normalized instant" in str(e.value) and "a time in microseconds" not in str(e.value)
    tm = vkunroll.RowTiming(H, 0, 10, 100)
    with pytest.raises(ValueError) as e:
        tm.target_time(float("nan"))
    assert "tau" in str(e.value) and "normalized instant" in str(e.value) and "a time in microseconds" not in str(e.value)
    with pytest.raises(ValueError, match="times"):
        physics(seq, times=2e6)  # +-1e6 frame spans, as the CLI


def test_a_session_without_a_model_points_at_its_model_keyword(seq):
    session = vkunroll.UnrollSession(backend="cpu")
    for mode in ("s", "m", "choose"):
        with pytest.raises(ValueError, match=r"UnrollSession\(model="):
            vkunroll.unroll(seq, mode=mode, session=session)


def test_physics_unroll_names_its_own_keywords(seq):
    s = vkunroll.Sequence.open(seq)
    ev, tm = s.events(), s.timing(0)
    for empty in (np.zeros((0, 0), np.float32), np.zeros((0, 0, 3), np.float32), np.zeros((H, 0), np.float32)):
        with pytest.raises(ValueError) as e:
            vkunroll.physics_unroll(empty, ev, tm, 1000, backend="cpu")
        assert "rs=" in str(e.value) and "sensor_size" not in str(e.value)
    with pytest.raises(ValueError) as e:  # a height other than the timing's
        vkunroll.physics_unroll(np.zeros((H - 1, W), np.float32), ev, tm, 1000, backend="cpu")
    assert "rs=" in str(e.value) and "sensor_size" not in str(e.value)


# ---- silent: options that cannot apply -------------------------------------------------------------

@pytest.mark.parametrize("keyword, value", [("profile", True), ("conv_choice", "gpu"), ("conv_choice", "heuristic"),
                                            ("precision", "fp16")])
def test_vulkan_only_session_options_are_refused_on_cpu(keyword, value):
    with pytest.raises(ValueError, match=keyword):
        vkunroll.UnrollSession(backend="cpu", **{keyword: value})


@pytest.mark.parametrize("extra, flag", [(["--profile"], "--profile"), (["--trace", "{d}/t.json"], "--trace"),
                                         (["--conv-choice", "gpu"], "--conv-choice"), (["--device", "0"], "--device"),
                                         (["--precision", "fp16"], "--precision")])
def test_vulkan_only_flags_are_refused_with_the_cpu_backend(seq, tmp_path, extra, flag):
    r = cli("unroll", seq, "--out", tmp_path / "o", "--mode", "physics", "--backend", "cpu", "--no-video", "--quiet",
            *[a.format(d=tmp_path) for a in extra])
    assert r.returncode == 2 and flag in r.stderr and "--backend" in r.stderr, r.stderr
    assert not (tmp_path / "o").exists() and not (tmp_path / "t.json").exists()


def test_reading_options_apply_to_their_formats_only(seq, tmp_path):
    h5 = seq / "events.h5"
    for kw in (dict(time_unit="ms"), dict(columns="tx_yp"), dict(columns="xytp")):
        with pytest.raises(ValueError) as e:
            vkunroll.read_events(h5, **kw)
        assert next(iter(kw)) in str(e.value) and "h5" in str(e.value), str(e.value)
    txt = tmp_path / "e.txt"
    txt.write_text("10 1 1 1\n20 2 2 0\n")
    with pytest.raises(ValueError, match="array_time_unit"):
        vkunroll.read_events(txt, array_time_unit="ms", sensor_size=(W, H))
    assert len(vkunroll.read_events(txt, time_unit="us", columns="txyp", sensor_size=(W, H))) == 2
    r = cli("events", h5, "--time-unit", "ms")
    assert r.returncode == 2 and "--time-unit" in r.stderr, r.stderr
    r = cli("events", h5, "--columns", "xytp")
    assert r.returncode == 2 and "--columns" in r.stderr, r.stderr


# ---- silent: --frames bounds the targets -----------------------------------------------------------

def test_frames_bound_ground_truth_targets(seq, tmp_path):
    meta = json.load(open(seq / "meta.json"))
    r = cli("unroll", seq, "--out", tmp_path / "o", "--mode", "physics", "--contrast", "0.2", "--times", "gt",
            "--frames", "0:0", "--no-video", "--quiet", "--backend", "cpu")
    assert r.returncode == 0, r.stderr
    summary = json.load(open(tmp_path / "o" / "summary.json"))
    frames = {g["frame"] for g in summary["gs_frames"]}
    assert frames == {0}, frames
    left_out = len(meta["ground_truth"]) - len(summary["gs_frames"])
    assert left_out > 0 and any("outside --frames" in n and str(left_out) in n for n in summary["notes"]), summary["notes"]
    res = physics(seq, times="gt", frames=[0])
    assert len(res.targets) == len(summary["gs_frames"]) and {t["frame"] for t in res.targets} == {0}
    assert any("outside frames" in n for n in res.stats["notes"]), res.stats["notes"]


def test_frames_bound_absolute_targets(seq, tmp_path):
    t = vkunroll.Sequence.open(seq).timing(2).target_time(0.5)
    r = cli("unroll", seq, "--out", tmp_path / "o", "--mode", "physics", "--times-us", t, "--frames", "0:0",
            "--no-video", "--quiet", "--backend", "cpu")
    assert r.returncode == 2 and "--times-us" in r.stderr and "frame 2" in r.stderr and "--frames" in r.stderr, r.stderr
    with pytest.raises(ValueError, match="frame 2"):
        physics(seq, times_us=t, frames=[0])
    assert physics(seq, times_us=t, frames=[2]).targets[0]["frame"] == 2


# ---- silent: one rule for both front ends ----------------------------------------------------------

def test_a_target_twice_is_refused_by_both_front_ends(seq, tmp_path):
    with pytest.raises(ValueError, match="listed twice"):
        physics(seq, times=[0.5, 0.5])
    with pytest.raises(ValueError, match="listed twice"):
        physics(seq, times=[0.5, "1/2"])
    t = int(vkunroll.Sequence.open(seq).timing(0).target_time(0.5))
    with pytest.raises(ValueError, match="listed twice"):
        physics(seq, times_us=[t, t])
    r = cli("unroll", seq, "--out", tmp_path / "o", "--times", "0.5,0.5", "--mode", "physics")
    assert r.returncode == 2 and "listed twice" in r.stderr


def test_an_empty_crop_is_refused_by_both_front_ends(seq, tmp_path):
    s = vkunroll.Sequence.open(seq)
    for crop in ((0, 0, 0, 0), (0, 0, W, 0), (0, 0, 0, H)):
        with pytest.raises(ValueError, match="crop"):
            vkunroll.event_tensors(s.events(), s.timing(0), 1000, crop=crop, sensor_size=(W, H), backend="cpu")
    e1, _, _ = vkunroll.event_tensors(s.events(), s.timing(0), 1000, bins=1, crop=(1, 2, 3, 4), sensor_size=(W, H),
                                      backend="cpu")
    assert e1.shape == (2, 4, 3)
    r = cli("voxelize", seq, "--frames", "0", "--times", "0.5", "--out", tmp_path / "v.safetensors", "--crop", "0,0,0,0")
    assert r.returncode == 2 and "--crop" in r.stderr, r.stderr


# ---- hangs -----------------------------------------------------------------------------------------

def test_detection_refuses_special_files_at_once(tmp_path):
    fifo = tmp_path / "ff"
    os.mkfifo(fifo)
    code = f"import vkunroll\ntry:\n    vkunroll.detect_event_format({str(fifo)!r})\nexcept ValueError as e:\n    print(e)\n"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=dict(os.environ))
    assert r.returncode == 0 and "FIFO" in r.stdout, (r.stdout, r.stderr)
    with pytest.raises(ValueError, match="character device"):
        vkunroll.detect_event_format("/dev/null")


def test_a_stream_shared_by_two_threads_is_served_one_caller_at_a_time(seq, tmp_path):
    from tools.data import follow_feed
    live = tmp_path / "live"
    shutil.copytree(seq, live, ignore=shutil.ignore_patterns("events.*", ".vkunroll-manifest"))
    meta, ev = follow_feed.load(str(seq))
    follow_feed.ENCODING = "evt3"
    raw = tmp_path / "ev.raw"
    raw.write_bytes(follow_feed.header(W, H) + follow_feed.words(ev["t"], ev["x"], ev["y"], ev["p"], W, H))
    frames = vkunroll.stream(live, events=raw, mode="physics", contrast=0.2, idle_s=1, backend="cpu")
    got, ends = [], []

    def consume():
        while True:
            try:
                got.append(next(frames)["frame"])
            except StopIteration:
                ends.append(True)
                return

    threads = [threading.Thread(target=consume, daemon=True) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not any(t.is_alive() for t in threads), "a thread blocked in next()"
    assert sorted(got) == list(range(len(meta["frames"]))) and len(ends) == 2
    # close() from another thread while one waits in next(): the waiter ends too
    frames2 = vkunroll.stream(live, events=raw, mode="physics", contrast=0.2, idle_s=1, backend="cpu")
    next(frames2)
    waiter = threading.Thread(target=lambda: list(frames2), daemon=True)
    waiter.start()
    frames2.close()
    waiter.join(timeout=60)
    assert not waiter.is_alive()


# ---- still open from the last round -----------------------------------------------------------------

def test_a_repeated_json_key_is_refused_naming_the_key_and_the_file(seq, tmp_path):
    copy = tmp_path / "dup"
    shutil.copytree(seq, copy)
    text = (copy / "meta.json").read_text()
    (copy / "meta.json").write_text(text.replace('"exposure_us":', '"exposure_us": 1, "exposure_us":', 1))
    with pytest.raises(ValueError) as e:
        vkunroll.Sequence.open(copy)
    assert '"exposure_us"' in str(e.value) and "meta.json" in str(e.value) and "twice" in str(e.value)
    r = cli("unroll", copy, "--out", tmp_path / "o", "--mode", "physics")
    assert r.returncode == 65 and '"exposure_us"' in r.stderr and "meta.json" in r.stderr, r.stderr
    nested = tmp_path / "nested"
    shutil.copytree(seq, nested)
    meta = (nested / "meta.json").read_text()
    (nested / "meta.json").write_text(meta.replace('"t0_us":', '"t0_us": 0, "t0_us":', 1))
    with pytest.raises(ValueError, match=r'"t0_us" appears twice in the object frames'):
        vkunroll.Sequence.open(nested)


@pytest.mark.parametrize("text", ["60000/1/1", "1/2/3", "1//2"])
def test_an_exact_time_has_one_grammar(seq, tmp_path, text):
    with pytest.raises(ValueError, match="times_us"):
        physics(seq, times_us=text)
    with pytest.raises(ValueError, match="t0_us"):
        vkunroll.RowTiming(H, text, 10, 100)
    r = cli("unroll", seq, "--out", tmp_path / "o", "--mode", "physics", "--times-us", text)
    assert r.returncode == 2 and "--times-us" in r.stderr, r.stderr
    assert vkunroll.RowTiming(H, "60000/7", 10, 100).t0_us == vkunroll.RowTiming(H, "120000/14", 10, 100).t0_us


def jpeg_sequence(seq, d):
    """The sequence with its frames as JPEGs (PIL), meta.json naming them."""
    from PIL import Image
    shutil.copytree(seq, d)
    meta = json.load(open(d / "meta.json"))
    for f in meta["frames"]:
        src = d / f["file"]
        f["file"] = f["file"].rsplit(".", 1)[0] + ".jpg"
        Image.open(src).convert("RGB").save(d / f["file"], quality=95)
    (d / "meta.json").write_text(json.dumps(meta, indent=1))
    return meta


def test_a_truncated_jpeg_is_an_error_naming_the_file(seq, tmp_path):
    pytest.importorskip("PIL")
    d = tmp_path / "jpg"
    meta = jpeg_sequence(seq, d)
    assert physics(d, frames=[0]).frames.shape[0] == 1  # whole JPEGs unroll
    cut = d / meta["frames"][1]["file"]
    data = cut.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError) as e:
        vkunroll.Sequence.open(d)
    assert cut.name in str(e.value) and "truncated JPEG" in str(e.value)
    r = cli("unroll", d, "--out", tmp_path / "o", "--mode", "physics", "--contrast", "0.2")
    assert r.returncode == 65 and cut.name in r.stderr and "truncated JPEG" in r.stderr, r.stderr


def test_frame_noise_reads_motion_below_the_threshold_as_the_docs_say(tmp_path):
    """docs/usage.md: physics.frame_noise is ~0 on the clean preset with a static camera and above the
    gate rule's 0.01 on the clean preset with its default motion (so --gate-radius auto picks 2)."""
    noise = {}
    for motion in ("static", "pan"):
        seq = tmp_path / motion
        subprocess.run([CLI, "simulate", "--out", seq, "--size", f"{W}x{H}", "--frames", "3", "--gt-per-frame", "0",
                        "--seed", "5", "--preset", "clean", "--motion", motion, "--quiet"], check=True)
        r = cli("unroll", seq, "--out", tmp_path / f"o_{motion}", "--mode", "physics", "--no-video", "--quiet",
                "--backend", "cpu")
        assert r.returncode == 0, r.stderr
        noise[motion] = json.load(open(tmp_path / f"o_{motion}" / "summary.json"))["physics"]["frame_noise"]
    assert noise["static"] < 0.01 <= noise["pan"], noise
