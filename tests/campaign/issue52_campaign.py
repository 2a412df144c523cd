#!/usr/bin/python3
"""A fourth campaign of hostile cases (issue 52, after its fixes) over the surfaces the third one
covered: writers, --follow, ROS bags and bag-sequence, EVT streams, meta.json, the Python API.
Each case is run as a careful user would (the CLI through a shell-less subprocess, Python in a child
interpreter where a crash or a hang could happen) and judged against what a user must get: a named
error, a said warning, or the right result; never data loss, a crash, a hang, a silent result.

  VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json PYTHONPATH=build/python:.:tests/python \\
    /usr/bin/python3 tests/campaign/issue52_campaign.py --cli build/vkunroll --table tests/campaign/issue52_table.md

The table (tests/campaign/issue52_table.md) lists every case, its outcome and its verdict.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

from tools.data import follow_feed  # PYTHONPATH holds the repository root and tests/python

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

CASES = []


def case(surface, name):
    def add(fn):
        CASES.append((surface, name, fn))
        return fn
    return add


class Env:
    def __init__(self, cli, root):
        self.cli, self.root, self.n = cli, root, 0
        self.seq = os.path.join(root, "seq")
        self.run(["simulate", "--out", self.seq, "--size", "64x48", "--frames", "4", "--gt-per-frame", "1", "--seed", "7",
                  "--motion", "pan", "--quiet"], check=True)
        self.meta, self.ev = follow_feed.load(self.seq)

    def fresh(self, name="d"):
        self.n += 1
        return os.path.join(self.root, f"{name}{self.n}")

    def run(self, args, input=None, check=False, timeout=120):
        try:
            r = subprocess.run([self.cli, *args], input=input, capture_output=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"rc": "hang", "err": "", "out": ""}
        if check and r.returncode:
            raise SystemExit(r.stderr.decode())
        return {"rc": r.returncode, "err": r.stderr.decode(errors="replace"), "out": r.stdout.decode(errors="replace")}

    def py(self, code, timeout=120):
        env = dict(os.environ)
        try:
            r = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=timeout, env=env, text=True)
        except subprocess.TimeoutExpired:
            return {"rc": "hang", "err": "", "out": ""}
        return {"rc": r.returncode, "err": r.stderr, "out": r.stdout}

    def stream(self, encoding="evt3", upto=None, width=64, height=48, clock=True):
        follow_feed.ENCODING = encoding
        t, x, y, p = (self.ev[k] for k in "txyp")
        n = len(t) if upto is None else upto
        data = follow_feed.header(width, height) + follow_feed.words(t[:n], x[:n], y[:n], p[:n], width, height)
        if clock:
            data += follow_feed.clock_words(self.window_end(len(self.meta["frames"]) - 1) + 3000)
        return data

    def window_end(self, k):
        fr = self.meta["frames"][k]
        return fr["t0_us"] + self.meta["line_delay_us"] * (self.meta["height"] - 1) + self.meta["exposure_us"]

    def live(self):
        d = self.fresh("live")
        shutil.copytree(self.seq, d, ignore=shutil.ignore_patterns("events.*", ".vkunroll-manifest"))
        return d

    def follow(self, data, *extra, live=None):
        out = self.fresh("fo")
        idle = [] if "--follow-idle-s" in extra else ["--follow-idle-s", "2"]
        r = self.run(["unroll", live or self.live(), "--follow", "--mode", "physics", "--contrast", "0.2", "--times", "0.5",
                      "--no-video", "--quiet", "--out", out, *idle, *extra], input=data)
        r["summary"] = json.load(open(os.path.join(out, "summary.json"))) if os.path.exists(os.path.join(out, "summary.json")) else None
        return r


def first_line(r):
    """The line that says what happened: the first error, else the first warning, else the last line."""
    lines = [line for line in r["err"].splitlines() if line.strip()]
    for word in ("error", "Error", "warning"):
        said = [line for line in lines if word in line]
        if said:
            return said[0][:160]
    return lines[-1][:160] if lines else ""


def verdict(ok, finding="silent"):
    return "handled" if ok else f"FINDING ({finding})"


# ---- writers -------------------------------------------------------------------------------------

def user_folder(env):
    d = env.fresh("user")
    os.makedirs(os.path.join(d, "rs"))
    open(os.path.join(d, "meta.json"), "w").write('{"mine": 1}')
    open(os.path.join(d, "rs", "000001.png"), "wb").write(b"mine")
    return d


def unchanged(d):
    return open(os.path.join(d, "meta.json")).read() == '{"mine": 1}'


def bag(env):
    if not hasattr(env, "_bag"):
        from test_option_rules import write_tiny_bag
        import pathlib
        env._bag = str(write_tiny_bag(pathlib.Path(env.fresh("bag") + ".bag")))
    return env._bag


BAG_ARGS = ["--line-delay-us", "10", "--exposure-us", "100"]
for _flag in ([], ["--overwrite"]):
    @case("writers", f"bag-sequence into a user's folder {' '.join(_flag)}".strip())
    def _(env, flag=_flag):
        d = user_folder(env)
        r = env.run(["bag-sequence", bag(env), d, *BAG_ARGS, *flag])
        return r, verdict(r["rc"] == 2 and unchanged(d), "data loss")

    @case("writers", f"simulate into a user's folder {' '.join(_flag)}".strip())
    def _(env, flag=_flag):
        d = user_folder(env)
        r = env.run(["simulate", "--out", d, "--size", "16x12", "--frames", "2", *flag])
        return r, verdict(r["rc"] == 2 and unchanged(d), "data loss")

    @case("writers", f"unroll into a user's folder {' '.join(_flag)}".strip())
    def _(env, flag=_flag):
        d = user_folder(env)
        r = env.run(["unroll", env.seq, "--out", d, "--mode", "physics", "--no-video", *flag])
        return r, verdict(r["rc"] == 2 and unchanged(d), "data loss")

    for _cmd in ("voxelize", "infer"):
        @case("writers", f"{_cmd} --out a user's file {' '.join(_flag)}".strip())
        def _(env, flag=_flag, cmd=_cmd):
            f = env.fresh("notes") + ".txt"
            open(f, "w").write("mine")
            if cmd == "voxelize":
                args = ["voxelize", env.seq, "--frames", "0", "--times", "0.5", "--out", f, "--bins", "2", "--cpu"]
            else:
                args = ["infer", "--model", os.path.join(ROOT, "tests/data/selfunroll_tiny.safetensors"), "--inputs",
                        os.path.join(ROOT, "tests/data/selfunroll_golden_s_64x48.safetensors"), "--out", f, "--backend", "cpu"]
            r = env.run(args + flag)
            return r, verdict(r["rc"] == 2 and open(f).read() == "mine", "data loss")


@case("writers", "bag-sequence twice into the same OUT")
def _(env):
    d = env.fresh("bs")
    env.run(["bag-sequence", bag(env), d, *BAG_ARGS])
    r = env.run(["bag-sequence", bag(env), d, *BAG_ARGS])
    r2 = env.run(["bag-sequence", bag(env), d, *BAG_ARGS, "--overwrite"])
    return r, verdict(r["rc"] == 2 and r2["rc"] == 0)


@case("writers", "bag-sequence OUT inside the bag's folder, named as the bag")
def _(env):
    r = env.run(["bag-sequence", bag(env), bag(env), *BAG_ARGS])
    return r, verdict(r["rc"] == 2 and os.path.isfile(bag(env)), "data loss")


for _opt in ("--inputs", "--model"):
    @case("writers", f"infer --out equal to {_opt}")
    def _(env, opt=_opt):
        inputs = env.fresh("in") + ".safetensors"
        model = env.fresh("m") + ".safetensors"
        shutil.copy(os.path.join(ROOT, "tests/data/selfunroll_golden_s_64x48.safetensors"), inputs)
        shutil.copy(os.path.join(ROOT, "tests/data/selfunroll_tiny.safetensors"), model)
        target = inputs if opt == "--inputs" else model
        before = open(target, "rb").read()
        r = env.run(["infer", "--model", model, "--inputs", inputs, "--out", target, "--backend", "cpu", "--overwrite"])
        return r, verdict(r["rc"] == 2 and open(target, "rb").read() == before, "data loss")


@case("writers", "voxelize --out equal to the sequence's events.h5 --overwrite")
def _(env):
    target = os.path.join(env.seq, "events.h5")
    before = open(target, "rb").read()
    r = env.run(["voxelize", env.seq, "--frames", "0", "--times", "0.5", "--out", target, "--overwrite", "--cpu"])
    return r, verdict(r["rc"] == 2 and open(target, "rb").read() == before, "data loss")


@case("writers", "voxelize --out its own earlier output, then --overwrite")
def _(env):
    f = env.fresh("v") + ".safetensors"
    args = ["voxelize", env.seq, "--frames", "0", "--times", "0.5", "--out", f, "--bins", "2", "--cpu"]
    env.run(args)
    r = env.run(args)
    r2 = env.run(args + ["--overwrite"])
    return r, verdict(r["rc"] == 2 and r2["rc"] == 0)


@case("writers", "demo into a folder whose physics/ holds a user's file")
def _(env):
    d = env.fresh("demo")
    os.makedirs(os.path.join(d, "physics"))
    open(os.path.join(d, "physics", "notes.txt"), "w").write("mine")
    r = env.run(["demo", "--out", d, "--size", "16x16", "--frames", "2", "--physics-only"])
    return r, verdict(r["rc"] == 2 and open(os.path.join(d, "physics", "notes.txt")).read() == "mine", "data loss")


@case("writers", "bag-sequence with a 10 ms readout over 5 ms frame spacing")
def _(env):
    d = env.fresh("bs")
    r = env.run(["bag-sequence", bag(env), d, "--line-delay-us", "1000", "--exposure-us", "100"])
    return r, verdict(r["rc"] in (2, 65) and not os.path.exists(d) and "readout" in r["err"])


@case("writers", "bag-sequence --t0-offset-us 2^53+1")
def _(env):
    d = env.fresh("bs")
    r = env.run(["bag-sequence", bag(env), d, *BAG_ARGS, "--t0-offset-us", str(2 ** 53 + 1)])
    return r, verdict(r["rc"] in (2, 65) and not os.path.exists(d))


PY_WRITER = {
    "Sequence.create": "vkunroll.Sequence.create(P, [np.zeros((6, 8), np.uint8)], ev, vkunroll.RowTiming(6, 0, 10, 100){kw})",
    "simulate": "vkunroll.simulate(P, width=16, height=12, frames=2{kw})",
    "write_events": "vkunroll.write_events(P, ev, sensor_size=(8, 6), format='txt'{kw})",
}
PY_HEAD = ("import os, sys, numpy as np, vkunroll\nev = np.zeros(5, vkunroll.EVENT_DTYPE); ev['t'] = np.arange(5) * 10\n"
           "ev['x'] = 1; ev['y'] = 1; ev['p'] = 1\nP = sys.argv[-1] if False else {path!r}\n")
for _w, _call in PY_WRITER.items():
    for _kw in ("", ", overwrite=True"):
        @case("python writers", f"{_w} over a user's {'file' if _w == 'write_events' else 'folder'}{_kw}")
        def _(env, call=_call, kw=_kw, w=_w):
            if w == "write_events":
                path = env.fresh("notes") + ".txt"
                open(path, "w").write("mine")
                check = lambda: open(path).read() == "mine"  # noqa: E731
            else:
                path = user_folder(env)
                check = lambda: unchanged(path)  # noqa: E731
            r = env.py(PY_HEAD.format(path=path) + call.format(kw=kw))
            return r, verdict(r["rc"] == 1 and "ValueError" in r["err"] and check(), "data loss")


# ---- live streams --------------------------------------------------------------------------------

for _enc in ("evt3", "evt2", "evt21"):
    for _cut in (1, 3):
        @case("follow", f"{_enc} stream cut {_cut} byte(s) inside its last word")
        def _(env, enc=_enc, cut=_cut):
            unit = {"evt3": 2, "evt2": 4, "evt21": 8}[enc]
            if cut >= unit:
                cut = unit - 1
            r = env.follow(env.stream(enc, clock=False)[:-cut])
            return r, verdict(r["rc"] == 65 and "trailing bytes" in r["err"])

    @case("follow", f"{_enc} stream cut inside its last word, --on-bad drop")
    def _(env, enc=_enc):
        r = env.follow(env.stream(enc, clock=False)[:-1], "--on-bad", "drop")
        s = r["summary"] or {}
        return r, verdict("--on-bad drop: 1 of" in r["err"] and s.get("events", {}).get("file_totals", {}).get("dropped") == 1)

    @case("follow", f"{_enc} whole stream with the camera clock past the last frame")
    def _(env, enc=_enc):
        r = env.follow(env.stream(enc))
        return r, verdict(r["rc"] == 0 and r["summary"]["follow"]["status"] == "complete")

for _k in range(4):
    @case("follow", f"stream ends inside frame {_k}'s window")
    def _(env, k=_k):
        fr = env.meta["frames"][k]
        cut = int(np.searchsorted(env.ev["t"], (fr["t0_us"] + env.window_end(k)) / 2))
        r = env.follow(env.stream(upto=cut, clock=False))
        s = r["summary"] or {"gs_frames": [], "follow": {}}
        partial = {g["frame"] for g in s["gs_frames"] if g.get("events_window") == "partial"}
        return r, verdict(r["rc"] == 3 and k in partial and "inside the event window" in r["err"])

for _n in (1, 2, 3, 5):
    @case("follow", f"{_n} stray byte(s) mid-stream, --on-bad drop, against the offline reader")
    def _(env, n=_n):
        data = env.stream()
        at = data.index(b"% end\n") + 6 + 3000
        bad = data[:at] + b"\x7f" * n + data[at:]
        r = env.follow(bad, "--on-bad", "drop")
        raw = env.fresh("stray") + ".raw"
        open(raw, "wb").write(bad)
        off = env.run(["events", raw, "--on-bad", "drop", "--json"])
        offline = json.loads(off["out"])["dropped"]["total"]
        s = r["summary"] or {}
        online = s.get("events", {}).get("file_totals", {}).get("dropped", -1)
        said = ("--on-bad drop:" in r["err"]) == (online > 0)  # 0x7f7f is a CONTINUED_4 word: skipped, not bad
        return r, verdict(online == offline == s.get("follow", {}).get("events_dropped", -1) and said)

    @case("follow", f"{_n} stray byte(s) mid-stream, --on-bad error")
    def _(env, n=_n):
        data = env.stream()
        at = data.index(b"% end\n") + 6 + 3000
        r = env.follow(data[:at] + b"\x7f" * n + data[at:])
        failed = r["rc"] == 65 and (r["summary"] is None or r["summary"]["follow"]["status"] == "failed")
        # 2 bytes 0x7f7f are one EVT 3.0 CONTINUED_4 word, which the format lets a reader skip
        return r, verdict(failed or (n % 2 == 0 and r["rc"] == 0))

for _cap in ("1024", "2048", "100000"):
    @case("follow", f"--follow-max-events {_cap}, three runs")
    def _(env, cap=_cap):
        data = env.stream()
        runs = [env.follow(data, "--follow-max-events", cap) for _ in range(3)]
        peaks = [r["summary"]["follow"]["ring_peak_events"] for r in runs if r["summary"]]
        same = len({r["rc"] for r in runs}) == 1
        return runs[0], verdict(same and all(p <= int(cap) for p in peaks), "cap not hard / not deterministic")

for _idle, _rc in (("1e-300", 2), ("0.05", 2), ("nan", 2), ("1e7", 2), ("-1", 2), ("0.1", 0)):
    @case("follow", f"--follow-idle-s {_idle}")
    def _(env, idle=_idle, rc=_rc):
        r = env.follow(env.stream(), "--follow-idle-s", idle)
        return r, verdict(r["rc"] == rc and (rc == 0 or "--follow-idle-s" in r["err"]))

for _hdr, _said in ((b"% evt 4.0\n% format EVT4;height=48;width=64\n", "EVT 4.0"), (b"% evt 4.0\n% end\n", "EVT 4.0"),
                    (b"% format EVT3;height=48;width=64\n", None), (b"% format XYZ\n", "no encoding"), (b"", None),
                    (b"% evt 3.0\n", None),
                    (b"% evt 3.0\n% end\n\x01", "trailing")):
    @case("follow", f"stream of only the header {_hdr[:30]!r}")
    def _(env, hdr=_hdr, said=_said):
        r = env.follow(hdr)
        ok = r["rc"] == 65 and said in r["err"] if said else r["rc"] == 3 and r["summary"]["follow"]["status"] == "partial"
        return r, verdict(ok)


@case("follow", "--follow-events '' ")
def _(env):
    r = env.follow(b"", "--follow-events", "")
    return r, verdict(r["rc"] == 2 and "empty" in r["err"], "vague")


for _opt, _val in (("--follow-events", "-"), ("--follow-idle-s", "3"), ("--follow-max-events", "5000")):
    @case("follow", f"{_opt} without --follow")
    def _(env, opt=_opt, val=_val):
        r = env.run(["unroll", env.seq, "--mode", "physics", "--out", env.fresh("o"), opt, val])
        return r, verdict(r["rc"] == 2 and "only with --follow" in r["err"])


@case("follow", "--follow-events a FIFO no writer opens, idle 1 s")
def _(env):
    fifo = env.fresh("fifo")
    os.mkfifo(fifo)
    start = time.monotonic()
    r = env.follow(b"", "--follow-events", fifo, "--follow-idle-s", "1")
    return r, verdict(r["rc"] == 3 and time.monotonic() - start < 30, "hang")


def frame_case(name, mutate, expect_rc, said):
    @case("follow frames", name)
    def _(env):
        live = env.live()
        mutate(env, live)
        r = env.follow(env.stream(), live=live)
        return r, verdict(r["rc"] == expect_rc and said in r["err"], "vague")


def _half_png(env, live):
    p = os.path.join(live, env.meta["frames"][1]["file"])
    open(p, "r+b").truncate(300)


def _six_bytes(env, live):
    open(os.path.join(live, env.meta["frames"][1]["file"]), "wb").write(b"\x89PNG\r\n")


def _gray(env, live):
    from PIL import Image
    p = os.path.join(live, env.meta["frames"][2]["file"])
    Image.open(p).convert("L").save(p)


def _hardlink(env, live):
    p = os.path.join(live, env.meta["frames"][3]["file"])
    os.unlink(p)
    os.link(os.path.join(live, env.meta["frames"][1]["file"]), p)


def _symlink(env, live):
    p = os.path.join(live, env.meta["frames"][3]["file"])
    os.unlink(p)
    os.symlink(os.path.join(live, env.meta["frames"][1]["file"]), p)


def _missing(env, live):
    os.unlink(os.path.join(live, env.meta["frames"][2]["file"]))


def _folder(env, live):
    p = os.path.join(live, env.meta["frames"][2]["file"])
    os.unlink(p)
    os.mkdir(p)


def _small(env, live):
    from PIL import Image
    p = os.path.join(live, env.meta["frames"][1]["file"])
    Image.open(p).resize((32, 24)).save(p)


frame_case("a half-written PNG that never completes", _half_png, 3, "incomplete PNG")
frame_case("a 6-byte file as a frame", _six_bytes, 3, "too short")
frame_case("a gray frame among colour frames", _gray, 65, "images-agree")
frame_case("a hard link to another frame", _hardlink, 65, "distinct-frame-files")
frame_case("a symlink to another frame", _symlink, 65, "distinct-frame-files")
frame_case("a frame that never appears", _missing, 3, "does not exist")
frame_case("a folder where a frame should be", _folder, 3, "not a regular file")
frame_case("a 32x24 frame in a 64x48 sequence", _small, 65, "images-agree")


@case("follow", "EVT header 32x24 in a 64x48 sequence")
def _(env):
    r = env.follow(env.stream(width=32, height=24))
    return r, verdict("sensor size 32x24" in r["err"] and "differs" in r["err"])


@case("follow", "a quiet scene: time words only after frame 0")
def _(env):
    cut = int(np.searchsorted(env.ev["t"], env.window_end(0)))
    r = env.follow(env.stream(upto=cut))
    s = r["summary"] or {"follow": {}}
    return r, verdict(r["rc"] == 0 and s["follow"].get("status") == "complete")


# ---- offline events and meta.json ----------------------------------------------------------------

def seq_copy(env):
    d = env.fresh("s")
    shutil.copytree(env.seq, d)
    return d


def with_meta(env, change):
    d = seq_copy(env)
    m = json.load(open(os.path.join(d, "meta.json")))
    change(m)
    json.dump(m, open(os.path.join(d, "meta.json"), "w"))
    return d


for _text in ("10 000", "1 0 0 0 0", " 10000 ", "10000/1", "0x2710", "1e4", "10_000", "10,000", "10000.", "+10000"):
    @case("meta.json", f"frames[0].t0_us {_text!r} (its own value, 10000)")
    def _(env, text=_text):
        good = text in (" 10000 ", "10000/1", "1e4", "10000.", "+10000")  # the grammar: spaces only around
        d = with_meta(env, lambda m: m["frames"][0].__setitem__("t0_us", text))
        r = env.run(["unroll", d, "--mode", "physics", "--contrast", "0.2", "--out", env.fresh("o"), "--no-video", "--quiet"])
        return r, verdict((r["rc"] == 0) == good and (good or "frames[0].t0_us" in r["err"]))


@case("events", "text events in two swapped halves, unroll")
def _(env):
    d = seq_copy(env)
    t, x, y, p = (env.ev[k] for k in "txyp")
    half = len(t) // 2
    lines = [f"{t[i]} {x[i]} {y[i]} {int(p[i] > 0)}" for i in list(range(half, len(t))) + list(range(half))]
    open(os.path.join(d, "events.txt"), "w").write("\n".join(lines) + "\n")
    m = json.load(open(os.path.join(d, "meta.json")))
    m["events"] = "events.txt"
    json.dump(m, open(os.path.join(d, "meta.json"), "w"))
    r = env.run(["unroll", d, "--mode", "physics", "--contrast", "0.2", "--frames", "0:1", "--out", env.fresh("o"),
                 "--no-video", "--quiet"])
    return r, verdict(r["rc"] == 65 and "time" in r["err"])


for _fmt in ("h5", "txt", "raw"):
    @case("events", f"--events-topic on a .{_fmt} file")
    def _(env, fmt=_fmt):
        d = seq_copy(env)
        ev = os.path.join(d, "events.h5")
        if fmt == "txt":
            ev = env.fresh("e") + ".txt"
            t, x, y, p = (env.ev[k] for k in "txyp")
            open(ev, "w").write("".join(f"{t[i]} {x[i]} {y[i]} {int(p[i] > 0)}\n" for i in range(len(t))))
        elif fmt == "raw":
            ev = env.fresh("e") + ".raw"
            open(ev, "wb").write(env.stream())
        r = env.run(["unroll", d, "--events", ev, "--events-topic", "/dvs/events", "--mode", "physics", "--out", env.fresh("o")])
        return r, verdict(r["rc"] == 2 and "not a ROS bag" in r["err"])


for _t in ("5000000", "-5000000", "99999999999"):
    @case("events", f"voxelize --times-us {_t} outside the recording")
    def _(env, t=_t):
        r = env.run(["voxelize", env.seq, "--frames", "0", "--times-us", t, "--out", env.fresh("v") + ".st", "--cpu"])
        return r, verdict(r["rc"] == 2 and "outside the recording" in r["err"])


@case("events", "events file whose header says 32x24, meta.json 64x48")
def _(env):
    raw = env.fresh("e") + ".raw"
    open(raw, "wb").write(env.stream(width=32, height=24))
    r = env.run(["unroll", env.seq, "--events", raw, "--mode", "physics", "--contrast", "0.2", "--out", env.fresh("o"),
                 "--no-video", "--quiet", "--on-bad", "drop"])
    return r, verdict("sensor size 32x24" in r["err"])


# ---- Python --------------------------------------------------------------------------------------

PY_SETUP = ("import math, numpy as np, vkunroll\nseq = vkunroll.Sequence.open({seq!r})\nev = seq.events()\n"
            "tm = seq.timing(0)\nimg = np.full((48, 64, 3), 0.5, np.float32)\n")
PY_CASES = [
    ("read_events(t_start=1000.7)", "vkunroll.read_events(seq.event_files[0], t_start=1000.7, t_end=5000.2)", "t_start"),
    ("read_events(t_start=nan)", "vkunroll.read_events(seq.event_files[0], t_start=math.nan)", "t_start"),
    ("read_events(t_end=inf)", "vkunroll.read_events(seq.event_files[0], t_end=math.inf)", "t_end"),
    ("read_events(topic=) on HDF5", "vkunroll.read_events(seq.event_files[0], topic='/dvs/events')", "topic"),
    ("read_events(sensor_size='64x48')", "vkunroll.read_events(seq.event_files[0], sensor_size='64x48')", "sensor_size"),
    ("read_events(on_bad='ignore')", "vkunroll.read_events(seq.event_files[0], on_bad='ignore')", "on_bad"),
    ("physics_unroll with shuffled events", "vkunroll.physics_unroll(img, ev[::-1].copy(), tm, 20000, backend='cpu')", "sorted"),
    ("event_tensors with no events, no sensor_size", "vkunroll.event_tensors(ev[:0], tm, 20000, backend='cpu')", "sensor_size"),
    ("event_tensors(target_exposure_us=-5)", "vkunroll.event_tensors(ev, tm, 20000, target_exposure_us=-5, backend='cpu')",
     "target_exposure_us"),
    ("event_tensors(bins=0)", "vkunroll.event_tensors(ev, tm, 20000, bins=0, backend='cpu')", "bins"),
    ("event_tensors(bins=2.0)", "vkunroll.event_tensors(ev, tm, 20000, bins=2.0, backend='cpu')", "bins"),
    ("event_tensors(context=) with backend='cpu'",
     "vkunroll.event_tensors(ev, tm, 20000, backend='cpu', context=vkunroll.default_context())", "context"),
    ("write_events with a NaN polarity",
     "e = ev.astype([('t','<i8'),('x','<u2'),('y','<u2'),('p','<f4')]); e['p'][2] = np.nan; vkunroll.write_events('/nonexistent/x.h5', e, sensor_size=(64, 48))",
     "p[2]"),
    ("physics_unroll on an image with 1.5", "vkunroll.physics_unroll(img * 3, ev, tm, 20000, backend='cpu')", "rs"),
    ("physics_unroll on an int64 0..255 image",
     "vkunroll.physics_unroll((img * 255).astype(np.int64), ev, tm, 20000, backend='cpu')", "int64"),
    ("physics_unroll(contrast=0)", "vkunroll.physics_unroll(img, ev, tm, 20000, contrast=0, backend='cpu')", "contrast"),
    ("physics_unroll(gamma=nan)", "vkunroll.physics_unroll(img, ev, tm, 20000, gamma=math.nan, backend='cpu')", "gamma"),
    ("psnr with a NaN pixel", "vkunroll.psnr(np.where(img > 0, np.nan, img), img)", "a"),
    ("ssim with a NaN pixel", "vkunroll.ssim(img, np.where(img > 0, np.nan, img))", "b"),
    ("psnr of two shapes", "vkunroll.psnr(img, img[:10])", "b"),
    ("Sequence.create with a float frame at 1.5",
     "vkunroll.Sequence.create('/tmp/never_made_52', [img * 3], ev[:10], tm)", "frames"),
    ("Sequence.create(bit_depth=12)", "vkunroll.Sequence.create('/tmp/never_made_52', [img], ev[:10], tm, bit_depth=12)",
     "bit_depth"),
    ("Sequence.open(check_frame_sizes='no')", "vkunroll.Sequence.open(seq.root, check_frame_sizes='no')", "check_frame_sizes"),
    ("Sequence.open(typo_option=1)", "vkunroll.Sequence.open(seq.root, exposre_us=1)", "exposre_us"),
    ("seq.events(0.5, 10.5)", "seq.events(0.5, 10.5)", "t_start"),
    ("seq.frame(1.0)", "seq.frame(1.0)", "k"),
    ("RowTiming(height=48.5)", "vkunroll.RowTiming(48.5, 0, 10, 100)", "height"),
    ("RowTiming(readout=1)", "vkunroll.RowTiming(48, 0, 10, 100, readout=1)", "readout"),
    ("RowTiming(exposure_us=nan)", "vkunroll.RowTiming(48, 0, 10, math.nan)", "exposure_us"),
    ("tm.start_us(48)", "tm.start_us(48)", "y"),
    ("unroll(tile=33.0)", "vkunroll.unroll(seq, mode='physics', backend='cpu', tile=33.0)", "tile"),
    ("unroll(frames=[0, 0])", "vkunroll.unroll(seq, mode='physics', backend='cpu', frames=[0, 0])", "frames"),
    ("unroll(times_us=...) and times", "vkunroll.unroll(seq, times=[0, 1], times_us=[20000], mode='physics', backend='cpu')",
     "times"),
    ("unroll(progress=3)", "vkunroll.unroll(seq, mode='physics', backend='cpu', progress=3)", "progress"),
    ("unroll(session=..., backend='vulkan' ignored?)",
     "s = vkunroll.UnrollSession(backend='cpu'); vkunroll.unroll(seq, mode='physics', session=s, precision='fp16')",
     "precision"),
    ("UnrollSession(device=0, backend='cpu')", "vkunroll.UnrollSession(backend='cpu', device=0)", "device"),
    ("stream(max_events=-1)", "vkunroll.stream(seq.root, events=seq.event_files[0], max_events=-1)", "max_events"),
    ("stream(max_events=2**65)", "vkunroll.stream(seq.root, events=seq.event_files[0], max_events=2**65)", "max_events"),
    ("stream(contrast='0.2')", "vkunroll.stream(seq.root, events=seq.event_files[0], contrast='0.2')", "contrast"),
    ("stream(idle_s=1e-300)", "vkunroll.stream(seq.root, events=seq.event_files[0], idle_s=1e-300)", "idle_s"),
    ("stream(on_bad='sort')", "vkunroll.stream(seq.root, events=seq.event_files[0], on_bad='sort')", "on_bad"),
    ("stream(events='')", "vkunroll.stream(seq.root, events='')", "events"),
    ("Model.load(gate_radius=16)", "vkunroll.Model.load({tiny!r}, backend='cpu', gate_radius=16)", "gate_radius"),
    ("Model.load(threads=-1)", "vkunroll.Model.load({tiny!r}, backend='cpu', threads=-1)", "threads"),
    ("convert_events(dtype=object())", "vkunroll.convert_events(ev, dtype=object())", "dtype"),
    ("devices(validation=1)", "vkunroll.devices(validation=1)", "validation"),
]
for _name, _code, _named in PY_CASES:
    @case("python", _name)
    def _(env, code=_code, named=_named):
        r = env.py(PY_SETUP.format(seq=env.seq) + code.format(tiny=os.path.join(ROOT, "tests/data/selfunroll_tiny.safetensors")))
        last = r["err"].strip().splitlines()[-1] if r["err"].strip() else ""
        named_ok = ("TypeError" in last or "ValueError" in last or "IndexError" in last) and named in last
        r["err"] = last
        return r, verdict(r["rc"] == 1 and named_ok, "vague" if r["rc"] == 1 else "silent")


@case("python", "break out of stream() without close, then exit")
def _(env):
    raw = env.fresh("e") + ".raw"
    open(raw, "wb").write(env.stream())
    code = (f"import vkunroll\nfr = vkunroll.stream({env.live()!r}, events={raw!r}, mode='physics', contrast=0.2, "
            "idle_s=1, backend='cpu')\nfor item in fr:\n    break\n")
    r = env.py(code)
    return r, verdict(r["rc"] == 0 and "terminate" not in r["err"], "crash")


@case("python", "next() on an exhausted stream")
def _(env):
    raw = env.fresh("e") + ".raw"
    open(raw, "wb").write(env.stream())
    code = (f"import vkunroll\nfr = vkunroll.stream({env.live()!r}, events={raw!r}, mode='physics', contrast=0.2, "
            "idle_s=1, backend='cpu')\nlist(fr)\nprint(next(fr, 'a'), next(fr, 'b'))\n")
    r = env.py(code, timeout=60)
    return r, verdict(r["rc"] == 0 and "a b" in r["out"], "hang")


@case("python", "stream(events=FIFO) with no writer, idle_s=1")
def _(env):
    fifo = env.fresh("fifo")
    os.mkfifo(fifo)
    code = (f"import vkunroll\nfr = vkunroll.stream({env.live()!r}, events={fifo!r}, mode='physics', contrast=0.2, "
            "idle_s=1, backend='cpu')\nlist(fr)\nprint(fr.report['follow']['status'])\n")
    r = env.py(code, timeout=60)
    return r, verdict(r["rc"] == 0 and "partial" in r["out"], "hang")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cli", default=os.path.join(ROOT, "build", "vkunroll"))
    ap.add_argument("--table", help="write the markdown table here")
    ap.add_argument("-k", help="only cases whose name contains this")
    a = ap.parse_args()
    rows, findings = [], 0
    with tempfile.TemporaryDirectory() as root:
        env = Env(os.path.abspath(a.cli), root)
        for i, (surface, name, fn) in enumerate(CASES, 1):
            if a.k and a.k not in name:
                continue
            try:
                r, v = fn(env)
            except Exception as e:  # noqa: BLE001 (a case that cannot run is a finding too)
                r, v = {"rc": "?", "err": f"{type(e).__name__}: {e}"}, "FINDING (case error)"
            findings += v != "handled"
            line = first_line(r).replace(root, "$T").replace("|", "\\|")
            rows.append(f"| {i} | {surface} | {name} | {r['rc']} | {v} | {line} |")
            print(rows[-1], flush=True)
    table = ("| # | surface | case | exit | verdict | first line of stderr |\n| --- | --- | --- | --- | --- | --- |\n" +
             "\n".join(rows) + "\n")
    summary = f"\n{len(rows)} cases, {len(rows) - findings} handled, {findings} findings\n"
    if a.table:
        open(a.table, "w").write(table + summary)
    print(summary)
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
