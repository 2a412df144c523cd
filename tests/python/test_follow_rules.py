"""Live streams fixed by rule (issue 52; the table in docs/reliability.md, "Issue 52: the rules and
their cases"): a GS frame knows whether its event window was whole; a partial window is a warning
(stderr, summary.json per frame) and the run is not `complete` (exit 3); drops are counted and said
as offline; the ring's cap is hard; time words are progress; the schema's image rules apply online;
a FIFO with no writer honours the idle limit; the Python stream never aborts nor hangs."""
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))
from tools.data import follow_feed  # noqa: E402  (the EVT encoders the live tests feed)

W, H, FRAMES = 64, 48, 4


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("rules")
    seq = d / "seq"
    subprocess.run([CLI, "simulate", "--out", str(seq), "--size", f"{W}x{H}", "--frames", str(FRAMES), "--gt-per-frame",
                    "0", "--seed", "3", "--motion", "pan", "--quiet"], check=True)
    meta, ev = follow_feed.load(str(seq))
    return seq, meta, ev


def stream_bytes(meta, ev, encoding="evt3", upto=None, width=W, height=H):
    follow_feed.ENCODING = encoding
    n = len(ev["t"]) if upto is None else upto
    return follow_feed.header(width, height) + follow_feed.words(ev["t"][:n], ev["x"][:n], ev["y"][:n], ev["p"][:n],
                                                                  width, height)


def live_folder(seq, d):
    live = d / "live"
    shutil.copytree(seq, live, ignore=shutil.ignore_patterns("events.*", ".vkunroll-manifest"))
    return live


def follow(live, out, data, *extra, timeout=120):
    idle = [] if "--follow-idle-s" in extra else ["--follow-idle-s", "2"]
    return subprocess.run([CLI, "unroll", str(live), "--follow", "--mode", "physics", "--contrast", "0.2", "--times",
                           "0,0.5,1", "--no-video", "--quiet", "--out", str(out), *idle, *extra],
                          input=data, capture_output=True, timeout=timeout)


def summary(out):
    return json.load(open(out / "summary.json"))


def window_end_us(meta, k):
    fr = meta["frames"][k]
    return fr["t0_us"] + meta["line_delay_us"] * (meta["height"] - 1) + meta["exposure_us"]


@pytest.mark.parametrize("encoding", ["evt3", "evt2", "evt21"])
def test_a_stream_cut_inside_a_word_is_a_truncated_stream_as_offline(recording, tmp_path, encoding):
    seq, meta, ev = recording
    data = stream_bytes(meta, ev, encoding)[:-1]  # the last word loses a byte
    raw = tmp_path / "cut.raw"
    raw.write_bytes(data)
    offline = subprocess.run([CLI, "events", str(raw)], capture_output=True, text=True)
    assert offline.returncode == 65 and "trailing bytes" in offline.stderr
    r = follow(live_folder(seq, tmp_path), tmp_path / "out", data)
    err = r.stderr.decode()
    assert r.returncode == 65, err
    assert "ends inside a" in err and "trailing bytes" in err, err
    s = summary(tmp_path / "out")  # what was written before is committed, and says failed
    assert s["follow"]["status"] == "failed"
    dropped = follow(live_folder(seq, tmp_path / "d"), tmp_path / "out_drop", data, "--on-bad", "drop")
    derr = dropped.stderr.decode()
    assert "--on-bad drop: 1 of" in derr and "unknown word" in derr, derr
    assert summary(tmp_path / "out_drop")["events"]["file_totals"]["dropped"] == 1


def test_a_stream_that_ends_inside_a_window_says_partial_per_frame(recording, tmp_path):
    seq, meta, ev = recording
    cut = int(np.searchsorted(ev["t"], (meta["frames"][1]["t0_us"] + window_end_us(meta, 1)) / 2))
    r = follow(live_folder(seq, tmp_path), tmp_path / "out", stream_bytes(meta, ev, upto=cut))
    err = r.stderr.decode()
    assert r.returncode == 3, err
    assert "inside the event window" in err, err
    s = summary(tmp_path / "out")
    assert s["follow"]["status"] == "partial"
    partial = {g["frame"] for g in s["gs_frames"] if g.get("events_window") == "partial"}
    assert 1 in partial and 0 not in partial, s["gs_frames"]
    assert s["follow"]["partial_window_frames"] == sorted(partial)


def test_a_whole_stream_is_complete(recording, tmp_path):
    seq, meta, ev = recording
    data = stream_bytes(meta, ev) + follow_feed.clock_words(window_end_us(meta, FRAMES - 1) + 2000)
    r = follow(live_folder(seq, tmp_path), tmp_path / "out", data)
    assert r.returncode == 0, r.stderr.decode()
    s = summary(tmp_path / "out")
    assert s["follow"]["status"] == "complete" and not s["follow"]["partial_window_frames"]


def test_drops_online_are_counted_and_said_as_offline(recording, tmp_path):
    seq, meta, ev = recording
    data = stream_bytes(meta, ev)
    head = data.index(b"% end\n") + len(b"% end\n")
    garbled = data[:head + 4000] + b"\x01\x02\x03" + data[head + 4000:]  # 3 stray bytes: misaligned words
    raw = tmp_path / "garbled.raw"
    raw.write_bytes(garbled)
    offline = subprocess.run([CLI, "events", str(raw), "--on-bad", "drop", "--json"], capture_output=True, text=True)
    r = follow(live_folder(seq, tmp_path), tmp_path / "out", garbled, "--on-bad", "drop")
    err = r.stderr.decode()
    s = summary(tmp_path / "out")
    assert "--on-bad drop:" in err and "dropped" in err, err
    assert s["events"]["file_totals"]["dropped"] == s["follow"]["events_dropped"] > 0
    assert offline.returncode == 0 and json.loads(offline.stdout)["dropped"]["total"] > 0


def test_the_ring_cap_is_hard_and_its_outcome_deterministic(recording, tmp_path):
    seq, meta, ev = recording
    data = stream_bytes(meta, ev)
    codes = set()
    for i in range(3):
        r = follow(live_folder(seq, tmp_path / str(i)), tmp_path / f"out{i}", data, "--follow-max-events", "1024")
        codes.add(r.returncode)
        if (tmp_path / f"out{i}" / "summary.json").exists():
            assert summary(tmp_path / f"out{i}")["follow"]["ring_peak_events"] <= 1024
    assert len(codes) == 1, codes


def test_time_words_count_as_progress(recording, tmp_path):
    """A quiet scene: no event after frame 0's window, only the clock's words; frames 1-2 are
    written while the pipe is still open."""
    seq, meta, ev = recording
    live = live_folder(seq, tmp_path)
    cut = int(np.searchsorted(ev["t"], window_end_us(meta, 0)))
    out = tmp_path / "out"
    run = subprocess.Popen([CLI, "unroll", str(live), "--follow", "--mode", "physics", "--contrast", "0.2", "--times", "0.5",
                            "--no-video", "--quiet", "--out", str(out), "--follow-idle-s", "0", "--frames", "0:2"],
                           stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    run.stdin.write(stream_bytes(meta, ev, upto=cut) + follow_feed.clock_words(window_end_us(meta, 2) + 1000))
    run.stdin.flush()
    staged, final = tmp_path / ".out.partial" / "frames", out / "frames"

    def frames_written():  # in the staging folder, or in the output once the job (all 3 frames) committed
        return max(len(list(d.glob("*.png"))) if d.exists() else 0 for d in (staged, final))

    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and frames_written() < 3:
        time.sleep(0.05)
    written = frames_written()  # counted before our end of the pipe closes
    run.stdin.close()
    run.wait(timeout=60)
    err = run.stderr.read().decode()
    assert written == 3, (written, err)


def test_the_header_size_against_meta_json_is_said_online_and_offline(recording, tmp_path):
    seq, meta, ev = recording
    data = stream_bytes(meta, ev, width=32, height=24) + follow_feed.clock_words(window_end_us(meta, FRAMES - 1) + 2000)
    r = follow(live_folder(seq, tmp_path), tmp_path / "out", data)
    assert "sensor size 32x24" in r.stderr.decode() and "differs" in r.stderr.decode(), r.stderr.decode()
    raw = tmp_path / "small.raw"
    raw.write_bytes(data)
    off = subprocess.run([CLI, "unroll", str(seq), "--events", str(raw), "--mode", "physics", "--contrast", "0.2",
                          "--quiet", "--no-video", "--out", str(tmp_path / "off")], capture_output=True, text=True)
    assert "sensor size 32x24" in off.stderr, off.stderr


def test_schema_image_rules_apply_online(recording, tmp_path):
    seq, meta, ev = recording
    live = live_folder(seq, tmp_path)
    from PIL import Image
    Image.open(live / meta["frames"][2]["file"]).convert("L").save(live / meta["frames"][2]["file"])
    data = stream_bytes(meta, ev) + follow_feed.clock_words(window_end_us(meta, FRAMES - 1) + 2000)
    r = follow(live, tmp_path / "out", data)
    assert r.returncode == 65 and "images-agree" in r.stderr.decode(), r.stderr.decode()
    live2 = live_folder(seq, tmp_path / "b")
    alias = live2 / meta["frames"][3]["file"]
    alias.unlink()
    os.link(live2 / meta["frames"][1]["file"], alias)  # a hard link: the same image as frame 1
    off = subprocess.run([CLI, "unroll", str(live2), "--mode", "physics", "--out", str(tmp_path / "o")],
                         capture_output=True, text=True)
    assert off.returncode == 65 and "distinct-frame-files" in off.stderr, off.stderr
    on = follow(live2, tmp_path / "out2", data)
    assert on.returncode == 65 and "distinct-frame-files" in on.stderr.decode(), on.stderr.decode()


def test_options_that_do_not_apply_or_cannot_work_are_refused(recording, tmp_path):
    seq, meta, ev = recording
    live = live_folder(seq, tmp_path)
    for extra, said in ((["--follow-idle-s", "1e-300"], "--follow-idle-s"), (["--follow-events", ""], "--follow-events")):
        r = follow(live, tmp_path / "o", b"", *extra)
        assert r.returncode == 2 and said in r.stderr.decode(), r.stderr.decode()
    r = subprocess.run([CLI, "unroll", str(seq), "--mode", "physics", "--out", str(tmp_path / "o"), "--follow-max-events",
                        "5000"], capture_output=True, text=True)
    assert r.returncode == 2 and "applies only with --follow" in r.stderr, r.stderr


def test_a_header_that_never_ends_is_validated(recording, tmp_path):
    seq, meta, ev = recording
    r = follow(live_folder(seq, tmp_path), tmp_path / "o", b"% evt 4.0\n% format EVT4;height=48;width=64\n")
    assert r.returncode in (3, 65) and "EVT 4.0" in r.stderr.decode(), r.stderr.decode()


def test_an_incomplete_frame_is_named_as_incomplete(recording, tmp_path):
    seq, meta, ev = recording
    live = live_folder(seq, tmp_path)
    png = live / meta["frames"][0]["file"]
    png.write_bytes(png.read_bytes()[:200])  # a half-written PNG that never completes
    r = follow(live, tmp_path / "o", stream_bytes(meta, ev))
    err = r.stderr.decode()
    assert r.returncode in (3, 65) and "incomplete PNG" in err and "did not appear" not in err, err


def test_a_fifo_with_no_writer_honours_the_idle_limit(recording, tmp_path):
    seq, meta, ev = recording
    fifo = tmp_path / "events.fifo"
    os.mkfifo(fifo)
    start = time.monotonic()
    r = subprocess.run([CLI, "unroll", str(live_folder(seq, tmp_path)), "--follow", "--follow-events", str(fifo),
                        "--follow-idle-s", "1", "--mode", "physics", "--contrast", "0.2", "--no-video", "--quiet", "--out",
                        str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert time.monotonic() - start < 30 and r.returncode in (3, 65), r.stderr


PY_STREAM = """
import sys, vkunroll
frames = vkunroll.stream(sys.argv[1], events=sys.argv[2], mode="physics", contrast=0.2, idle_s=1, backend="cpu")
for item in frames:
    break                     # out of the loop, no close(), no with: the interpreter must still exit cleanly
"""


def test_python_stream_never_aborts_at_exit_nor_hangs(recording, tmp_path):
    vkunroll = pytest.importorskip("vkunroll")
    seq, meta, ev = recording
    live = live_folder(seq, tmp_path)
    raw = tmp_path / "ev.raw"
    raw.write_bytes(stream_bytes(meta, ev))
    r = subprocess.run([sys.executable, "-c", PY_STREAM, str(live), str(raw)], capture_output=True, text=True, timeout=120,
                       env=dict(os.environ))
    assert r.returncode == 0 and "terminate called" not in r.stderr, r.stderr
    fifo = tmp_path / "none.fifo"
    os.mkfifo(fifo)
    start = time.monotonic()
    frames = vkunroll.stream(live_folder(seq, tmp_path / "b"), events=fifo, mode="physics", contrast=0.2, idle_s=1,
                             backend="cpu")
    for _ in frames:  # no writer ever: the stream ends after idle_s, the frames come from empty windows
        pass
    assert time.monotonic() - start < 30
    assert frames.report["follow"]["status"] == "partial"
    assert next(frames, "again") == "again" and next(frames, "again") == "again"  # exhausted: StopIteration again
