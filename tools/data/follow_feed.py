#!/usr/bin/python3
"""Plays a simulated sequence as a live camera for `vkunroll unroll --follow` (docs/follow.md).

  follow_feed.py evt3 SEQ OUT.raw        # the sequence's events.h5 as a Prophesee EVT 3.0 .raw file
                                         # (--encoding evt2 | evt21: EVT 2.0 / 2.1 words; play takes it too)
  follow_feed.py prepare SEQ LIVE        # LIVE: meta.json (the frames to come), an empty rs/
  follow_feed.py play SEQ LIVE --speed K # each RS frame into LIVE when its last row is read out;
                                         # EVT 3.0 on stdout at K x real time
  follow_feed.py bench --speeds 1,4,0    # latency and throughput of --follow on a simulated recording
                                         # (speed 0: everything there at once, cat into the pipe)

`play` writes frames by rename (never half-written) and paces the events in 2 ms slices of the
scaled timeline; SIGPIPE (the reader stopped) ends it quietly.
"""
import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import h5py
import numpy as np


def evt3_bytes(t, x, y, p, width, height):
    """EVT 3.0 words: TIME_HIGH, TIME_LOW, ADDR_Y, ADDR_X per event (24-bit time, so t < 2^24 us)."""
    t = np.asarray(t, np.int64)
    if len(t) and (t.min() < 0 or t.max() >= 1 << 24):
        raise SystemExit("follow_feed: event times must lie in [0, 2^24) us for this encoder")
    w = np.empty((len(t), 4), np.uint16)
    w[:, 0] = 0x8000 | ((t >> 12) & 0xFFF)
    w[:, 1] = 0x6000 | (t & 0xFFF)
    w[:, 2] = np.asarray(y, np.uint16) & 0x7FF
    w[:, 3] = 0x2000 | (np.asarray(p > 0, np.uint16) << 11) | (np.asarray(x, np.uint16) & 0x7FF)
    return w.astype("<u2").tobytes()


def evt2_bytes(t, x, y, p, width, height):
    """EVT 2.0 words: a TIME_HIGH, then a CD_ON/CD_OFF word per event (34-bit time)."""
    t = np.asarray(t, np.int64)
    w = np.empty((len(t), 2), np.uint32)
    w[:, 0] = (0x8 << 28) | ((t >> 6) & 0x0FFFFFFF)
    w[:, 1] = (np.asarray(p > 0, np.uint32) << 28) | ((t & 0x3F) << 22).astype(np.uint32) \
        | (np.asarray(x, np.uint32) & 0x7FF) << 11 | (np.asarray(y, np.uint32) & 0x7FF)
    return w.astype("<u4").tobytes()


def evt21_bytes(t, x, y, p, width, height):
    """EVT 2.1 little-endian 64-bit words: a TIME_HIGH, then one EVT_POS/EVT_NEG word per event
    (x aligned on 32 in the word, the event's bit in the mask)."""
    t = np.asarray(t, np.int64)
    x = np.asarray(x, np.uint64)
    w = np.empty((len(t), 2), np.uint64)
    w[:, 0] = np.uint64(0x8 << 28 | 0) << np.uint64(32) | ((t >> 6) & 0x0FFFFFFF).astype(np.uint64) << np.uint64(32)
    hi = (np.asarray(p > 0, np.uint64) << np.uint64(28)) | ((t & 0x3F).astype(np.uint64) << np.uint64(22)) \
        | ((x & np.uint64(0x7E0)) << np.uint64(11)) | (np.asarray(y, np.uint64) & np.uint64(0x7FF))
    w[:, 1] = (hi << np.uint64(32)) | (np.uint64(1) << (x & np.uint64(31)))
    return w.astype("<u8").tobytes()


ENCODERS = {"evt3": (evt3_bytes, "3.0", "EVT3"), "evt2": (evt2_bytes, "2.0", "EVT2"), "evt21": (evt21_bytes, "2.1", "EVT21")}
ENCODING = "evt3"  # --encoding: what evt3_bytes' callers write


def words(t, x, y, p, width, height):
    return ENCODERS[ENCODING][0](t, x, y, p, width, height)


def clock_words(t):
    """The sensor clock's words at time t (us) and no event: what a camera sends through a quiet
    scene (EVT 3.0 TIME_HIGH + TIME_LOW; EVT 2.0 / 2.1 TIME_HIGH, 64 us steps)."""
    t = int(t)
    if ENCODING == "evt3":
        return np.array([0x8000 | ((t >> 12) & 0xFFF), 0x6000 | (t & 0xFFF)], "<u2").tobytes()
    high = (0x8 << 28) | ((t >> 6) & 0x0FFFFFFF)
    if ENCODING == "evt2":
        return np.array([high], "<u4").tobytes()
    return np.array([high << 32], "<u8").tobytes()


def header(width, height):
    _, evt, fmt = ENCODERS[ENCODING]
    return f"% evt {evt}\n% format {fmt};height={height};width={width}\n% end\n".encode()


def load(seq):
    meta = json.load(open(os.path.join(seq, "meta.json")))
    with h5py.File(os.path.join(seq, meta["events"])) as f:
        ev = {k: f["events/" + k][:] for k in "txyp"}
    return meta, ev


def cmd_evt3(seq, out):
    meta, ev = load(seq)
    with open(out, "wb") as f:
        f.write(header(meta["width"], meta["height"]))
        f.write(words(ev["t"], ev["x"], ev["y"], ev["p"], meta["width"], meta["height"]))


def frame_done_us(meta, fr):
    return fr["t0_us"] + meta["line_delay_us"] * (meta["height"] - 1) + meta["exposure_us"]


def cmd_prepare(seq, live):
    meta = json.load(open(os.path.join(seq, "meta.json")))
    os.makedirs(os.path.join(live, "rs"), exist_ok=True)
    with open(os.path.join(live, "meta.json"), "w") as f:
        json.dump(meta, f)


def cmd_play(seq, live, speed, slice_us=2000):
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    meta, ev = load(seq)
    out = sys.stdout.buffer
    out.write(header(meta["width"], meta["height"]))
    out.flush()
    t = ev["t"]
    frames = sorted(meta["frames"], key=lambda fr: frame_done_us(meta, fr))
    t_begin = int(t[0]) if len(t) else 0
    t_end = max(int(t[-1]) if len(t) else 0, int(max(frame_done_us(meta, fr) for fr in frames))) + slice_us
    start = time.monotonic()
    i = 0
    for s in range(t_begin, t_end + slice_us, slice_us):
        delay = start + (s - t_begin) / 1e6 / speed - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        while frames and frame_done_us(meta, frames[0]) <= s:
            fr = frames.pop(0)
            dst = os.path.join(live, fr["file"])
            shutil.copyfile(os.path.join(seq, fr["file"]), dst + ".tmp")
            os.rename(dst + ".tmp", dst)
        j = int(np.searchsorted(t, s, side="left"))
        if j > i:
            out.write(words(t[i:j], ev["x"][i:j], ev["y"][i:j], ev["p"][i:j], meta["width"], meta["height"]))
            out.flush()
            i = j
    out.write(words(t[i:], ev["x"][i:], ev["y"][i:], ev["p"][i:], meta["width"], meta["height"]))
    out.write(clock_words(t_end))  # the camera's clock ran past the last frame: every window is whole
    out.flush()


def cmd_bench(cli, size, frames, speeds):
    """One run per speed; prints summary.json's follow section (latency, GS frames per second)."""
    with tempfile.TemporaryDirectory() as d:
        seq = os.path.join(d, "seq")
        subprocess.run([cli, "simulate", "--out", seq, "--size", size, "--frames", str(frames), "--gt-per-frame", "0",
                        "--seed", "1", "--motion", "pan", "--quiet"], check=True)
        for k in speeds:
            live, out = os.path.join(d, f"live{k}"), os.path.join(d, f"out{k}")
            cmd_prepare(seq, live)
            if k == 0:  # as fast as it goes: every frame there, the events from a file through cat
                shutil.copytree(os.path.join(seq, "rs"), os.path.join(live, "rs"), dirs_exist_ok=True)
                cmd_evt3(seq, os.path.join(d, "events.raw"))
                feed = subprocess.Popen(["cat", os.path.join(d, "events.raw")], stdout=subprocess.PIPE)
            else:
                feed = subprocess.Popen([sys.executable, __file__, "play", seq, live, "--speed", str(k)], stdout=subprocess.PIPE)
            subprocess.run([cli, "unroll", live, "--follow", "--mode", "physics", "--contrast", "0.2", "--no-video",
                            "--quiet", "--out", out, "--follow-idle-s", "5"], stdin=feed.stdout, check=True)
            feed.wait()
            fo = json.load(open(os.path.join(out, "summary.json")))["follow"]
            print(json.dumps({"speed": k if k else "all at once", "size": size, "frames": frames, "status": fo["status"],
                              "latency_ms": fo.get("latency_ms"), "gs_frames_per_s": fo.get("gs_frames_per_s")}))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("evt3")
    e.add_argument("seq")
    e.add_argument("out")
    r = sub.add_parser("prepare")
    r.add_argument("seq")
    r.add_argument("live")
    p = sub.add_parser("play")
    p.add_argument("seq")
    p.add_argument("live")
    p.add_argument("--speed", type=float, default=1.0)
    b = sub.add_parser("bench")
    b.add_argument("--cli", default=os.environ.get("VKUNROLL_CLI", "build/vkunroll"))
    b.add_argument("--size", default="346x260")
    b.add_argument("--frames", type=int, default=40)
    b.add_argument("--speeds", default="1,4,0")
    for q in (e, p):
        q.add_argument("--encoding", choices=sorted(ENCODERS), default="evt3", help="the stream's words (default evt3)")
    a = ap.parse_args()
    global ENCODING
    ENCODING = getattr(a, "encoding", "evt3")
    if a.cmd == "evt3":
        cmd_evt3(a.seq, a.out)
    elif a.cmd == "prepare":
        cmd_prepare(a.seq, a.live)
    elif a.cmd == "play":
        cmd_play(a.seq, a.live, a.speed)
    else:
        cmd_bench(a.cli, a.size, a.frames, [float(s) for s in a.speeds.split(",")])


if __name__ == "__main__":
    main()
