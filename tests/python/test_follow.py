"""`vkunroll unroll --follow` (docs/follow.md): a simulated recording played through a pipe at
20x real time (EVT 3.0 on stdin, RS frames appearing in the folder) gives exactly the GS frames of
the offline run on the same data; SIGINT mid-stream leaves only valid frames and a summary that
says stopped."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))
FEED = os.path.join(ROOT, "tools", "data", "follow_feed.py")
FRAMES = 8


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("follow")
    seq = d / "seq"
    subprocess.run([CLI, "simulate", "--out", str(seq), "--size", "64x48", "--frames", str(FRAMES), "--gt-per-frame", "0",
                    "--seed", "1", "--motion", "pan", "--quiet"], check=True)
    raw = d / "events.raw"
    subprocess.run([sys.executable, FEED, "evt3", str(seq), str(raw)], check=True)
    offline = d / "offline"
    subprocess.run([CLI, "unroll", str(seq), "--events", str(raw), "--mode", "physics", "--times", "0,0.5,1",
                    "--no-video", "--quiet", "--out", str(offline)], check=True)
    return seq, offline


def follow(seq, live, out, speed, encoding="evt3", **popen):
    subprocess.run([sys.executable, FEED, "prepare", str(seq), str(live)], check=True)
    feed = subprocess.Popen([sys.executable, FEED, "play", str(seq), str(live), "--speed", str(speed), "--encoding", encoding],
                            stdout=subprocess.PIPE)
    run = subprocess.Popen([CLI, "unroll", str(live), "--follow", "--mode", "physics", "--times", "0,0.5,1", "--no-video",
                            "--quiet", "--out", str(out), "--follow-idle-s", "5"], stdin=feed.stdout,
                           stderr=subprocess.PIPE, text=True)
    feed.stdout.close()
    return feed, run


def gs_files(out):
    summary = json.load(open(out / "summary.json"))
    return summary, {g["file"]: (out / g["file"]).read_bytes() for g in summary["gs_frames"]}


def test_follow_on_a_pipe_equals_the_offline_run(recording, tmp_path):
    seq, offline = recording
    feed, run = follow(seq, tmp_path / "live", tmp_path / "out", 20)
    _, err = run.communicate(timeout=120)
    feed.wait(timeout=30)
    assert run.returncode == 0, err
    summary, frames = gs_files(tmp_path / "out")
    _, expected = gs_files(offline)
    assert len(expected) == 3 * FRAMES
    assert frames.keys() == expected.keys()
    assert all(frames[f] == expected[f] for f in expected), "a followed GS frame differs from the offline one"
    fo = summary["follow"]
    assert fo["status"] == "complete" and fo["stopped_because"] is None
    # the camera clock passed the last window: the run may end before the pipe closes
    assert fo["pipe"] and fo["gs_frames"] == 3 * FRAMES and not fo["partial_window_frames"]
    assert fo["events_kept"] == fo["records"] > 0
    assert fo["events_released"] > 0  # events no later frame needs left the ring
    assert fo["frames"] == FRAMES and fo["latency_ms"]["max"] >= fo["latency_ms"]["median"] >= 0


@pytest.mark.parametrize("encoding", ["evt2", "evt21"])
def test_follow_reads_evt2_streams_like_evt3(recording, tmp_path, encoding):
    """EVT 2.0 and 2.1 words through the pipe (the readers' shared decoders) give the offline frames."""
    seq, offline = recording
    feed, run = follow(seq, tmp_path / "live", tmp_path / "out", 50, encoding)
    _, err = run.communicate(timeout=120)
    feed.wait(timeout=30)
    assert run.returncode == 0, err
    summary, frames = gs_files(tmp_path / "out")
    _, expected = gs_files(offline)
    assert frames.keys() == expected.keys() and all(frames[f] == expected[f] for f in expected)
    assert summary["follow"]["events_kept"] == summary["follow"]["records"] > 0


def test_sigint_mid_stream_leaves_valid_frames_and_says_stopped(recording, tmp_path):
    seq, offline = recording
    out = tmp_path / "out"
    feed, run = follow(seq, tmp_path / "live", out, 0.5)  # 2x slower than real time: 0.8 s per frame
    staged = tmp_path / ".out.partial" / "frames"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(list(staged.glob("*.png")) if staged.exists() else []) < 3:
        time.sleep(0.05)
    run.send_signal(signal.SIGINT)
    _, err = run.communicate(timeout=60)
    feed.kill()
    feed.wait()
    assert run.returncode == 0, err
    assert "stopped: SIGINT" in err
    summary, frames = gs_files(out)
    _, expected = gs_files(offline)
    fo = summary["follow"]
    assert fo["status"] == "stopped" and "SIGINT" in fo["stopped_because"]
    assert 3 <= len(frames) < len(expected) and fo["gs_frames"] == len(frames)
    assert all(frames[f] == expected[f] for f in frames)  # every frame written is whole and right
    assert sorted(p.name for p in (out / "frames").iterdir()) == sorted(os.path.basename(f) for f in frames)


def test_follow_refuses_resume_and_a_sorted_stream(recording, tmp_path):
    seq, _ = recording
    r = subprocess.run([CLI, "unroll", str(seq), "--follow", "--resume", "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2 and "--resume does not apply" in r.stderr
    r = subprocess.run([CLI, "unroll", str(seq), "--follow", "--on-bad", "sort", "--mode", "physics", "--out", str(tmp_path / "o")],
                       stdin=subprocess.DEVNULL, capture_output=True, text=True)
    assert r.returncode == 2 and "sort cannot apply to a live stream" in r.stderr


def test_python_stream_yields_the_offline_frames(recording, tmp_path):
    vkunroll = pytest.importorskip("vkunroll")
    import numpy as np
    from vkunroll import _vkunroll
    seq, offline = recording
    live, fifo = tmp_path / "live", tmp_path / "events.fifo"
    subprocess.run([sys.executable, FEED, "prepare", str(seq), str(live)], check=True)
    os.mkfifo(fifo)
    feed = subprocess.Popen(f"exec {sys.executable} {FEED} play {seq} {live} --speed 20 > {fifo}", shell=True)
    summary, _ = gs_files(offline)
    expected = {(g["frame"], g["t_us"]): _vkunroll._read_image(str(offline / g["file"]), 64, 48) for g in summary["gs_frames"]}
    got = {}
    with vkunroll.stream(live, events=fifo, times=[0, 0.5, 1], mode="physics", idle_s=5) as frames:
        for item in frames:
            assert item["total"] == 3 * FRAMES and len(item["images"]) == 3
            for t, im in zip(item["targets"], item["images"]):
                got[(t["frame"], float(t["t_us"]))] = im
    feed.wait(timeout=30)
    assert frames.report["follow"]["status"] == "complete"
    assert got.keys() == expected.keys()
    for k, im in got.items():
        assert np.abs(im - expected[k]).max() <= 0.5 / 255 + 1e-6  # the offline PNGs are the same images in 8 bits
