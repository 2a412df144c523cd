#!/usr/bin/python3
"""The campaign of issue 58, after its fixes: hostile cases over the families of the issue's own
campaign (writers and every output path of the output table, --trace and --profile, tune and its
table, the GPU family on this CPU device, the Python argument layer, stream(), event detection and
meta.json, SwiftShader), each run as a careful user would: the CLI in a shell-less subprocess, Python
in a child interpreter (where a crash or a hang could happen). Each case is judged against what the
user must get: a named error, a said warning, or the right result; never data loss, a crash, a hang
or a silent result.

  VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json PYTHONPATH=build/python:.:tests/python:tests/campaign \\
    /usr/bin/python3 tests/campaign/issue58_campaign.py --cli build/vkunroll --table tests/campaign/issue58_table.md

Not run here: `pip install` of the wheel (it builds the whole project again; tests/python/test_wheel.py
covers it in the suite).
"""
import argparse
import json
import os
import stat
import sys
import tempfile

from issue52_campaign import ROOT, Env, bag, BAG_ARGS, first_line, unchanged, user_folder  # noqa: F401

CASES = []
TINY = os.path.join(ROOT, "tests/data/selfunroll_tiny.safetensors")
GOLDEN = os.path.join(ROOT, "tests/data/selfunroll_golden_s_64x48.safetensors")
SWIFTSHADER = "/usr/lib/chromium/vk_swiftshader_icd.json"


def case(surface, name):
    def add(fn):
        CASES.append((surface, name, fn))
        return fn
    return add


def judged(r, ok, finding="silent"):
    if r["rc"] == "hang":
        return "FINDING (hang)"
    if isinstance(r["rc"], int) and (r["rc"] < 0 or r["rc"] in (70, 134, 139)):
        return "FINDING (crash)"
    return "handled" if ok else f"FINDING ({finding})"


def state(p):
    """What is at `p`: kind and bytes (a file), target (a link), names (a folder), device numbers."""
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        return None
    if stat.S_ISLNK(st.st_mode):
        return ("link", os.readlink(p))
    if stat.S_ISREG(st.st_mode):
        return ("file", open(p, "rb").read())
    if stat.S_ISDIR(st.st_mode):
        return ("dir", sorted(os.listdir(p)))
    return ("special", stat.S_IFMT(st.st_mode), st.st_rdev)


# ---- the writers of the output table, each against every hostile target ----------------------------

def seq_copy(env):
    d = env.fresh("seqc")
    import shutil
    shutil.copytree(env.seq, d, ignore=shutil.ignore_patterns(".vkunroll-manifest"))
    return d


def other_run(env):
    if not hasattr(env, "_other"):
        env._other = env.fresh("o")
        env.run(["unroll", env.seq, "--out", env._other, "--mode", "physics", "--times", "0.5", "--no-video", "--quiet"], check=True)
    return env._other


# id -> (how to run it with output P, the flag that asks to replace, file or folder, inputs of the run)
def writer_args(env, wid, p):
    seq = env.seq
    if wid == "bag-sequence.out":
        return ["bag-sequence", bag(env), p, *BAG_ARGS]
    return {
        "unroll.out": ["unroll", seq, "--out", p, "--mode", "physics", "--times", "0.5", "--no-video", "--quiet"],
        "unroll.trace": ["unroll", seq, "--out", env.fresh("to"), "--mode", "physics", "--times", "0.5", "--no-video",
                         "--quiet", "--model", TINY, "--trace", p],
        "voxelize.out": ["voxelize", seq, "--frames", "0", "--times", "0.5", "--bins", "2", "--out", p],
        "infer.out": ["infer", "--model", TINY, "--inputs", GOLDEN, "--out", p, "--backend", "cpu"],
        "simulate.out": ["simulate", "--out", p, "--size", "16x12", "--frames", "2", "--quiet"],
        "demo.out": ["demo", "--out", p, "--size", "16x16", "--frames", "2", "--physics-only"],
    }[wid]


WRITERS = {"unroll.out": "folder", "unroll.trace": "file", "voxelize.out": "file", "infer.out": "file",
           "simulate.out": "folder", "demo.out": "folder", "bag-sequence.out": "folder"}
SPELLED = {"unroll.trace": "--trace", "bag-sequence.out": "OUT"}


def prepare_target(env, what):
    d = env.fresh("t")
    os.makedirs(d)
    p = os.path.join(d, "target")
    if what == "a user's file":
        open(p, "w").write("the user's notes\n")
    elif what == "a FIFO":
        os.mkfifo(p)
    elif what == "a symlink to a user's file":
        open(p + "-real", "w").write("mine")
        os.symlink(p + "-real", p)
    elif what == "a symlink to a folder":
        os.makedirs(p + "-dir")
        os.symlink(p + "-dir", p)
    elif what == "a character device":
        os.mknod(p, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
    elif what == "a path under a user's file":
        open(p, "w").write("mine")
        return os.path.join(p, "x"), p
    elif what == "the sequence's meta.json":
        s = seq_copy(env)
        return os.path.join(s, "meta.json"), os.path.join(s, "meta.json")
    elif what == "another run's summary.json":
        o = other_run(env)
        return os.path.join(o, "summary.json"), os.path.join(o, "summary.json")
    elif what == "a new file inside another run's output":
        o = other_run(env)
        return os.path.join(o, "new.json"), o
    return p, p


TARGETS = ["a user's file", "a FIFO", "a symlink to a user's file", "a symlink to a folder", "a character device",
           "a path under a user's file", "the sequence's meta.json", "another run's summary.json",
           "a new file inside another run's output"]

for _wid, _shape in WRITERS.items():
    for _what in TARGETS:
        for _flag in ([], ["--overwrite"]):
            if _wid == "demo.out" and _flag:
                continue
            if _shape == "folder" and _what in ("another run's summary.json", "a new file inside another run's output"):
                continue

            @case("writers", f"{_wid} over {_what} {' '.join(_flag)}".strip())
            def _(env, wid=_wid, what=_what, flag=_flag):
                p, watched = prepare_target(env, what)
                before = state(watched)
                args = writer_args(env, wid, p)
                if wid == "unroll.out" and what == "the sequence's meta.json":
                    args[1] = os.path.dirname(p)  # the run reads that sequence
                r = env.run(args + flag, timeout=180)
                return r, judged(r, r["rc"] == 2 and state(watched) == before and SPELLED.get(wid, "--out") in r["err"], "data loss")

    @case("empty paths", f"{_wid} with an empty name")
    def _(env, wid=_wid):
        cwd = env.fresh("cwd")
        os.makedirs(cwd)
        args = writer_args(env, wid, "")
        old = os.getcwd()
        os.chdir(cwd)
        try:
            r = env.run(args)
        finally:
            os.chdir(old)
        return r, judged(r, r["rc"] == 2 and "empty" in r["err"] and os.listdir(cwd) == [], "silent or work done")

for _wid in ("unroll.trace", "voxelize.out", "infer.out"):
    @case("writers", f"{_wid}: its own earlier output, then --overwrite")
    def _(env, wid=_wid):
        p = env.fresh("own") + ".out"
        first = env.run(writer_args(env, wid, p))
        again = env.run(writer_args(env, wid, p))
        forced = env.run(writer_args(env, wid, p) + ["--overwrite"])
        return again, judged(again, first["rc"] == 0 and again["rc"] == 2 and forced["rc"] == 0)

for _wid in ("unroll.out", "simulate.out", "bag-sequence.out"):
    @case("writers", f"{_wid}: its own earlier output, then --overwrite")
    def _(env, wid=_wid):
        p = env.fresh("own")
        first = env.run(writer_args(env, wid, p))
        again = env.run(writer_args(env, wid, p))
        forced = env.run(writer_args(env, wid, p) + ["--overwrite"])
        return again, judged(again, first["rc"] == 0 and again["rc"] == 2 and forced["rc"] == 0)


# ---- --trace and --profile: the issue's own cases -----------------------------------------------------

def unroll_with(env, *extra, seq=None, out=None):
    out = out or env.fresh("u")
    return env.run(["unroll", seq or env.seq, "--out", out, "--mode", "physics", "--times", "0.5", "--no-video", "--quiet", *extra])


@case("--trace", "--trace seq/meta.json of the run's own sequence")
def _(env):
    s = seq_copy(env)
    before = state(os.path.join(s, "meta.json"))
    r = unroll_with(env, "--trace", os.path.join(s, "meta.json"), seq=s)
    return r, judged(r, r["rc"] == 2 and state(os.path.join(s, "meta.json")) == before, "data loss")


@case("--trace", "--trace seqB/events.h5 (the run's events)")
def _(env):
    s = seq_copy(env)
    before = state(os.path.join(s, "events.h5"))
    r = unroll_with(env, "--trace", os.path.join(s, "events.h5"), seq=s)
    return r, judged(r, r["rc"] == 2 and state(os.path.join(s, "events.h5")) == before, "data loss")


@case("--trace", "--model m.safetensors --trace m.safetensors")
def _(env):
    import shutil
    m = env.fresh("m") + ".safetensors"
    shutil.copy(TINY, m)
    before = state(m)
    r = env.run(["unroll", env.seq, "--out", env.fresh("u"), "--mode", "s", "--model", m, "--times", "0.5", "--no-video",
                 "--quiet", "--trace", m])
    return r, judged(r, r["rc"] == 2 and state(m) == before, "data loss")


@case("--trace", "--events ev.h5 --trace ev.h5")
def _(env):
    import shutil
    ev = env.fresh("ev") + ".h5"
    shutil.copy(os.path.join(env.seq, "events.h5"), ev)
    before = state(ev)
    r = unroll_with(env, "--events", ev, "--trace", ev)
    return r, judged(r, r["rc"] == 2 and state(ev) == before, "data loss")


@case("--trace", "--trace o14 --out o14")
def _(env):
    o = env.fresh("o14")
    r = unroll_with(env, "--trace", o, out=o)
    return r, judged(r, r["rc"] == 2 and not os.path.exists(o))


@case("--trace", "--trace inside --out")
def _(env):
    o = env.fresh("o")
    r = unroll_with(env, "--trace", os.path.join(o, "trace.json"), out=o)
    return r, judged(r, r["rc"] == 2 and not os.path.exists(o))


@case("--trace", "--trace in a folder that does not exist")
def _(env):
    r = unroll_with(env, "--trace", os.path.join(env.fresh("none"), "t.json"))
    return r, judged(r, r["rc"] == 2 and "does not exist" in r["err"])


@case("--trace", "--trace an existing folder")
def _(env):
    d = env.fresh("dir")
    os.makedirs(d)
    r = unroll_with(env, "--trace", d)
    return r, judged(r, r["rc"] == 2 and os.path.isdir(d))


@case("--trace", "--trace a 300-byte file name")
def _(env):
    r = unroll_with(env, "--trace", os.path.join(env.root, "t" * 300 + ".json"))
    return r, judged(r, r["rc"] == 2 and "--trace" in r["err"])


@case("--trace", "--trace a fresh file: written, marked, replaced with --overwrite")
def _(env):
    t = env.fresh("t") + ".json"
    o = env.fresh("o")
    r = unroll_with(env, "--trace", t, out=o)
    ok = r["rc"] == 0 and json.load(open(t))["traceEvents"][0]["args"]["name"] == "vkunroll"
    r2 = unroll_with(env, "--trace", t, "--overwrite", out=o)
    return r2, judged(r2, ok and r2["rc"] == 0)


@case("--trace", "--trace with --resume over a vkunroll trace")
def _(env):
    t = env.fresh("t") + ".json"
    o = env.fresh("o")
    unroll_with(env, "--trace", t, out=o)
    r = unroll_with(env, "--trace", t, "--resume", out=o)
    return r, judged(r, r["rc"] == 0)


@case("--trace", "--trace a hard link to the sequence's meta.json")
def _(env):
    s = seq_copy(env)
    link = env.fresh("hl") + ".json"
    os.link(os.path.join(s, "meta.json"), link)
    before = state(link)
    r = unroll_with(env, "--trace", link, "--overwrite", seq=s)
    return r, judged(r, r["rc"] == 2 and state(link) == before, "data loss")


@case("--trace", "--trace relative, in the working folder")
def _(env):
    cwd = env.fresh("cwd")
    os.makedirs(cwd)
    old = os.getcwd()
    os.chdir(cwd)
    try:
        r = unroll_with(env, "--trace", "t.json")
    finally:
        os.chdir(old)
    return r, judged(r, r["rc"] == 0 and os.path.isfile(os.path.join(cwd, "t.json")))


for _opt in (["--trace", "T"], ["--profile"], ["--conv-choice", "gpu"]):
    @case("--trace", f"{_opt[0]} with --backend cpu")
    def _(env, opt=_opt):
        opt = [env.fresh("t") + ".json" if o == "T" else o for o in opt]
        r = env.run(["unroll", env.seq, "--out", env.fresh("u"), "--mode", "s", "--model", TINY, "--backend", "cpu",
                     "--times", "0.5", "--no-video", "--quiet", *opt])
        return r, judged(r, r["rc"] == 2 and opt[0] in r["err"])


@case("--trace", "--profile: GPU times per op in summary.json")
def _(env):
    o = env.fresh("o")
    r = unroll_with(env, "--profile", out=o)
    s = json.load(open(os.path.join(o, "summary.json"))) if r["rc"] == 0 else {}
    return r, judged(r, r["rc"] == 0 and "gpu_ms_per_gs_frame_by_op" in json.dumps(s))


# ---- tune and its table ------------------------------------------------------------------------------

TUNE = ["tune", "--model", TINY, "--size", "16x16", "--tile", "0", "--reps", "1", "--no-compare", "--warm-ms", "0",
        "--candidate-ms", "0"]


def tune(env, cache, *extra):
    old = os.environ.get("VKUNROLL_CACHE_DIR")
    os.environ["VKUNROLL_CACHE_DIR"] = cache
    try:
        return env.run(TUNE + list(extra), timeout=600)
    finally:
        if old is None:
            del os.environ["VKUNROLL_CACHE_DIR"]
        else:
            os.environ["VKUNROLL_CACHE_DIR"] = old


def table_name(env):
    if not hasattr(env, "_table"):
        cache = env.fresh("cache")
        tune(env, cache)
        names = [n for n in os.listdir(cache) if n.startswith("conv-choices-")]
        env._table = names[0] if names else "conv-choices-unknown.tsv"
    return env._table


@case("tune", "a fresh cache folder: the table is written")
def _(env):
    cache = env.fresh("cache")
    r = tune(env, cache)
    return r, judged(r, r["rc"] == 0 and any(n.endswith(".tsv") for n in os.listdir(cache)))


for _what in ("a file", "a path under a file"):
    @case("tune", f"VKUNROLL_CACHE_DIR is {_what}")
    def _(env, what=_what):
        f = env.fresh("f")
        open(f, "w").write("x")
        r = tune(env, f if what == "a file" else os.path.join(f, "sub"))
        return r, judged(r, r["rc"] == 74 and "Not a directory" in r["err"] and "FMA" not in r["out"] and open(f).read() == "x", "vague")

for _what in ("a user's file", "a FIFO", "a symlink", "a folder", "an empty file", "a table of another format"):
    @case("tune", f"the table's name holds {_what}")
    def _(env, what=_what):
        cache = env.fresh("cache")
        os.makedirs(cache)
        t = os.path.join(cache, table_name(env))
        if what == "a user's file":
            open(t, "w").write("my notes\n")
        elif what == "a FIFO":
            os.mkfifo(t)
        elif what == "a symlink":
            open(t + ".real", "w").write("mine")
            os.symlink(t + ".real", t)
        elif what == "a folder":
            os.makedirs(t)
        elif what == "an empty file":
            open(t, "w").close()
        else:
            open(t, "w").write("# vkunroll conv algorithm choices v0: old\nkey\talgo\n")
        before = state(t)
        r = tune(env, cache)
        if what == "a table of another format":  # vkunroll's own table: replaced with a warning
            return r, judged(r, r["rc"] == 0 and "warning" in r["err"])
        return r, judged(r, r["rc"] == 2 and state(t) == before and "FMA" not in r["out"], "data loss")


@case("tune", "a table with a damaged line: merged, the line said")
def _(env):
    cache = env.fresh("cache")
    tune(env, cache)
    t = os.path.join(cache, table_name(env))
    open(t, "a").write("garbage line\n")
    r = tune(env, cache)
    return r, judged(r, r["rc"] == 0 and "line ignored" in r["err"])


@case("tune", "VKUNROLL_CACHE_DIR empty")
def _(env):
    r = tune(env, "", "--plan")
    return r, judged(r, r["rc"] in (0, 2))


@case("tune", "--plan writes no table")
def _(env):
    cache = env.fresh("cache")
    os.makedirs(cache)
    r = tune(env, cache, "--plan")
    return r, judged(r, r["rc"] == 0 and not any(n.endswith(".tsv") for n in os.listdir(cache)))


for _opt, _val in (("--size", "0x0"), ("--size", ""), ("--reps", "0"), ("--budget-s", "nan"), ("--warm-ms", "1e9"),
                   ("--modes", "x"), ("--precision", "fp64"), ("--tile", "-1"), ("--candidate-ms", "inf"), ("--model", "")):
    @case("tune", f"tune {_opt} {_val!r}")
    def _(env, opt=_opt, val=_val):
        args = list(TUNE)
        if opt in args:
            i = args.index(opt)
            del args[i:i + 2]
        r = env.run(args + [opt, val], timeout=120)
        return r, judged(r, r["rc"] in (2, 66) and opt in r["err"], "vague")


# ---- the GPU family on this CPU device ------------------------------------------------------------------

for _choice in ("gpu", "heuristic", "cached", "measured", "retune", "auto"):
    for _prec in ("fp32", "fp16"):
        @case("GPU family", f"unroll --mode s --conv-choice {_choice} --precision {_prec}")
        def _(env, choice=_choice, prec=_prec):
            o = env.fresh("g")
            r = env.run(["unroll", env.seq, "--out", o, "--mode", "s", "--model", TINY, "--conv-choice", choice, "--precision",
                         prec, "--times", "0.5", "--no-video", "--quiet", "--frames", "0"], timeout=300)
            return r, judged(r, r["rc"] == 0 and os.path.isfile(os.path.join(o, "summary.json")))

for _choice in ("gpu", "fast", ""):
    @case("GPU family", f"infer --conv-choice {_choice!r}")
    def _(env, choice=_choice):
        r = env.run(["infer", "--model", TINY, "--inputs", GOLDEN, "--out", env.fresh("i") + ".safetensors",
                     "--conv-choice", choice])
        return r, judged(r, (r["rc"] == 0 and choice == "gpu") or (r["rc"] == 2 and "--conv-choice" in r["err"]))


@case("GPU family", "SwiftShader: unroll --mode s --conv-choice gpu")
def _(env):
    if not os.path.exists(SWIFTSHADER):
        return {"rc": "skip", "err": "no SwiftShader"}, "handled"
    old = os.environ.get("VK_DRIVER_FILES")
    os.environ["VK_DRIVER_FILES"] = SWIFTSHADER
    try:
        o = env.fresh("sw")
        r = env.run(["unroll", env.seq, "--out", o, "--mode", "s", "--model", TINY, "--conv-choice", "gpu", "--times", "0.5",
                     "--no-video", "--quiet", "--frames", "0", "--trace", env.fresh("swt") + ".json"], timeout=600)
    finally:
        os.environ["VK_DRIVER_FILES"] = old or ""
    return r, judged(r, r["rc"] == 0)


@case("GPU family", "SwiftShader: --precision fp16 (no shaderFloat16) is said")
def _(env):
    if not os.path.exists(SWIFTSHADER):
        return {"rc": "skip", "err": "no SwiftShader"}, "handled"
    old = os.environ.get("VK_DRIVER_FILES")
    os.environ["VK_DRIVER_FILES"] = SWIFTSHADER
    try:
        r = env.run(["unroll", env.seq, "--out", env.fresh("sw"), "--mode", "s", "--model", TINY, "--precision", "fp16",
                     "--times", "0.5", "--no-video", "--quiet", "--frames", "0"], timeout=600)
    finally:
        os.environ["VK_DRIVER_FILES"] = old or ""
    return r, judged(r, r["rc"] == 0 or (r["rc"] in (2, 65, 69) and "fp16" in r["err"]))


# ---- the Python argument layer ---------------------------------------------------------------------------

PY_HEAD = ("import os, sys, threading, numpy as np, vkunroll\n"
           "seq = vkunroll.Sequence.open({seq!r})\nT = seq.timing(0)\nev = seq.frame_events(0)\n")


def py(env, code, timeout=180):
    return env.py(PY_HEAD.format(seq=env.seq) + code, timeout=timeout)


def py_ok(r, expect_error=None):
    """expect_error None: exit 0; else a ValueError/TypeError naming `expect_error`, no bare traceback elsewhere."""
    if expect_error is None:
        return r["rc"] == 0
    return r["rc"] == 1 and ("ValueError" in r["err"] or "TypeError" in r["err"]) and expect_error in r["err"].splitlines()[-1]


NUMPY_SCALARS = ["float16", "float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64"]
for _t in NUMPY_SCALARS:
    @case("python arguments", f"unroll(times=np.{_t}(0 or 0.5))")
    def _(env, t=_t):
        v = "0.5" if t.startswith("float") else "0"
        r = py(env, f"vkunroll.unroll(seq, times=np.{t}({v}), mode='physics', frames=[0])")
        return r, judged(r, py_ok(r))

    @case("python arguments", f"RowTiming(48, np.{_t}(10000), 10, 100)")
    def _(env, t=_t):
        r = py(env, f"vkunroll.RowTiming(48, np.{t}(10000 if '{t}' not in ('int8', 'uint8', 'float16') else 100), 10, 100)")
        return r, judged(r, py_ok(r))

for _t in ("float32", "float16", "int32"):
    @case("python arguments", f"event_tensors(t_us=np.{_t}(...))")
    def _(env, t=_t):
        r = py(env, f"vkunroll.event_tensors(ev, T, np.{t}(T.t0_us + 100 if '{t}' != 'float16' else 0), bins=2, sensor_size=(64, 48))")
        return r, judged(r, py_ok(r) or py_ok(r, "t_us"))

    @case("python arguments", f"unroll(times_us=np.{_t}(...))")
    def _(env, t=_t):
        r = py(env, f"vkunroll.unroll(seq, times_us=np.{t}(T.t0_us + 500), mode='physics', frames=[0])")
        return r, judged(r, py_ok(r) or py_ok(r, "times_us"))

    @case("python arguments", f"physics_unroll(t_us=np.{_t}(...))")
    def _(env, t=_t):
        r = py(env, f"vkunroll.physics_unroll(seq.frame(0), ev, T, np.{t}(T.t0_us + 500))")
        return r, judged(r, py_ok(r) or py_ok(r, "t_us"))

    @case("python arguments", f"target_time(np.{_t}(0.5))")
    def _(env, t=_t):
        r = py(env, f"T.target_time(np.{t}(0))")
        return r, judged(r, py_ok(r))

for _call, _kw in (("vkunroll.unroll(seq, times=float('nan'), mode='physics')", "times"),
                   ("T.target_time(float('nan'))", "tau"),
                   ("vkunroll.unroll(seq, times=[0.5, 0.5], mode='physics')", "times"),
                   ("vkunroll.unroll(seq, times=[], mode='physics')", "times"),
                   ("vkunroll.event_tensors(ev, T, T.t0_us + 100, crop=(0, 0, 0, 0), sensor_size=(64, 48))", "crop"),
                   ("vkunroll.event_tensors(ev, T, T.t0_us + 100, crop=(0, 0, 100, 100), sensor_size=(64, 48))", "crop"),
                   ("vkunroll.unroll(seq, mode='s', session=vkunroll.UnrollSession())", "model"),
                   ("vkunroll.physics_unroll(np.zeros((0, 0)), ev, T, T.t0_us)", "rs"),
                   ("vkunroll.unroll(seq, times='0.5', mode='physics')", "times"),
                   ("vkunroll.unroll(seq, frames=[99], mode='physics')", "frames"),
                   ("vkunroll.unroll(seq, mode='physics', contrast=-1)", "contrast"),
                   ("vkunroll.unroll(seq, mode='physics', gamma=float('inf'))", "gamma"),
                   ("vkunroll.UnrollSession(backend='cpu', precision='fp16')", "precision"),
                   ("vkunroll.UnrollSession(backend='cpu', profile=True)", "profile"),
                   ("vkunroll.UnrollSession(backend='cpu', conv_choice='gpu')", "conv_choice"),
                   ("vkunroll.UnrollSession(backend='gpu')", "backend"),
                   ("vkunroll.RowTiming(48, 0, -1, 100)", "line_delay_us"),
                   ("vkunroll.RowTiming(0, 0, 10, 100)", "height"),
                   ("vkunroll.event_tensors(ev, T, T.t0_us, bins=0, sensor_size=(64, 48))", "bins"),
                   ("vkunroll.event_tensors(ev, T, T.t0_us, target_exposure_us=np.float32(-5), sensor_size=(64, 48))",
                    "target_exposure_us"),
                   ("vkunroll.psnr(np.zeros((4, 4)), np.full((4, 4), np.nan))", "b"),
                   ("vkunroll.write_events('', ev, sensor_size=(64, 48))", "path"),
                   ("vkunroll.Sequence.create('', [seq.frame(0)], ev, [T])", "path"),
                   ("vkunroll.simulate('', width=16, height=12, frames=2)", "path"),
                   ("vkunroll.read_events('')", "path"),
                   ("vkunroll.Sequence.open('')", "path")):
    @case("python arguments", _call.replace("vkunroll.", "")[:90])
    def _(env, call=_call, kw=_kw):
        r = py(env, call)
        return r, judged(r, py_ok(r, kw), "silent or vague")


@case("python arguments", "read_events(h5, time_unit='ms')")
def _(env):
    r = py(env, f"vkunroll.read_events({os.path.join(env.seq, 'events.h5')!r}, time_unit='ms')")
    return r, judged(r, py_ok(r, "time_unit"))


@case("python arguments", "read_events(h5, columns=...)")
def _(env):
    r = py(env, f"vkunroll.read_events({os.path.join(env.seq, 'events.h5')!r}, columns=('t', 'x', 'y', 'p'))")
    return r, judged(r, py_ok(r, "columns"))


# ---- the Python writers: every hostile target ------------------------------------------------------------

PY_WRITERS = {
    "write_events": "vkunroll.write_events(P, ev, sensor_size=(64, 48), format='h5'{kw})",
    "Sequence.create": "vkunroll.Sequence.create(P, [seq.frame(0)], ev, [T]{kw})",
    "simulate": "vkunroll.simulate(P, width=16, height=12, frames=2{kw})",
}
for _w, _call in PY_WRITERS.items():
    for _what in ("a user's file", "a FIFO", "a symlink to a user's file", "a character device", "a path under a user's file",
                  "another run's summary.json", "a new file inside another run's output"):
        if _w != "write_events" and _what in ("another run's summary.json", "a new file inside another run's output"):
            continue
        for _kw in ("", ", overwrite=True"):
            @case("python writers", f"{_w} over {_what}{_kw}")
            def _(env, call=_call, what=_what, kw=_kw):
                p, watched = prepare_target(env, what)
                before = state(watched)
                r = py(env, f"P = {p!r}\n" + call.format(kw=kw))
                return r, judged(r, r["rc"] == 1 and "ValueError" in r["err"] and state(watched) == before, "data loss")


# ---- stream() --------------------------------------------------------------------------------------------

STREAM_HEAD = ("live = {live!r}\nraw = {raw!r}\n"
               "it = vkunroll.stream(live, events=raw, mode='physics', contrast=0.2, idle_s=1)\n")


def stream_case(env, code, timeout=120):
    live = env.live()
    raw = env.fresh("raw") + ".raw"
    open(raw, "wb").write(env.stream())
    return py(env, STREAM_HEAD.format(live=live, raw=raw) + code, timeout=timeout)


@case("stream()", "one iterator read from two threads")
def _(env):
    r = stream_case(env, "got, errs = [], []\n"
                         "def read():\n"
                         "    try:\n        got.extend(list(it))\n"
                         "    except Exception as e:\n        errs.append(repr(e))\n"
                         "ts = [threading.Thread(target=read) for _ in range(2)]\n"
                         "[t.start() for t in ts]; [t.join(60) for t in ts]\n"
                         "assert not any(t.is_alive() for t in ts), 'a thread blocked'\n"
                         "print(len(got), errs)\nassert len(got) == 4 or errs, (len(got), errs)\n")
    return r, judged(r, r["rc"] == 0, "hang or lost frames")


@case("stream()", "break out of the loop, then exit")
def _(env):
    r = stream_case(env, "for f in it:\n    break\n")
    return r, judged(r, r["rc"] == 0)


@case("stream()", "next() after exhaustion")
def _(env):
    r = stream_case(env, "n = len(list(it))\ntry:\n    next(it)\nexcept StopIteration:\n    print('stop', n)\n")
    return r, judged(r, r["rc"] == 0 and "stop" in r["out"])


@case("stream()", "close() twice, then next()")
def _(env):
    r = stream_case(env, "it.close(); it.close()\ntry:\n    next(it)\nexcept StopIteration:\n    pass\n")
    return r, judged(r, r["rc"] == 0)


for _kw in ("max_events=-1", "max_events=2**65", "idle_s=float('nan')", "idle_s=-1", "on_bad='ignore'", "times=[]"):
    @case("stream()", f"stream({_kw})")
    def _(env, kw=_kw):
        r = py(env, f"it = vkunroll.stream({env.live()!r}, events='-', mode='physics', {kw})\nnext(it)")
        name = kw.split("=")[0]
        return r, judged(r, py_ok(r, name), "silent or vague")


# ---- event detection, meta.json, images ---------------------------------------------------------------------

@case("events", "detect_event_format on a FIFO")
def _(env):
    f = env.fresh("ff")
    os.mkfifo(f)
    r = py(env, f"vkunroll.detect_event_format({f!r})", timeout=30)
    return r, judged(r, r["rc"] == 1 and "FIFO" in r["err"], "hang or vague")


@case("events", "vkunroll events on a FIFO")
def _(env):
    f = env.fresh("ff")
    os.mkfifo(f)
    r = env.run(["events", f], timeout=30)
    return r, judged(r, r["rc"] == 65 and "FIFO" in r["err"])


def meta_with(env, edit):
    s = seq_copy(env)
    text = open(os.path.join(s, "meta.json")).read()
    open(os.path.join(s, "meta.json"), "w").write(edit(text))
    return s


@case("meta.json", "a repeated key (line_delay_us twice)")
def _(env):
    s = meta_with(env, lambda t: t.replace("{", '{"line_delay_us": 1, ', 1))
    r = unroll_with(env, seq=s)
    return r, judged(r, r["rc"] == 65 and "line_delay_us" in r["err"] and "meta.json" in r["err"])


@case("meta.json", "a repeated key inside a frame")
def _(env):
    s = meta_with(env, lambda t: t.replace('"t0_us"', '"t0_us": 0, "t0_us"', 1))
    r = unroll_with(env, seq=s)
    return r, judged(r, r["rc"] == 65 and "t0_us" in r["err"])


for _time in ("60000/1/1", "1/2/3", "6e4/1", "1//2", "/5", "5/"):
    @case("meta.json", f"exact time {_time!r} in --t0s-us")
    def _(env, time=_time):
        r = unroll_with(env, "--t0s-us", f"{time},200000,300000,400000")
        return r, judged(r, r["rc"] == 2 and "--t0s-us" in r["err"])


for _cut in ("half", "header"):
    for _fmt in ("jpg", "png"):
        @case("images", f"a {_fmt} frame cut ({_cut})")
        def _(env, cut=_cut, fmt=_fmt):
            import cv2  # noqa: F401 (only to encode the frame; skipped where missing)
            s = seq_copy(env)
            meta = json.load(open(os.path.join(s, "meta.json")))
            name = meta["frames"][1]["file"]
            img = cv2.imread(os.path.join(s, name))
            ok, data = cv2.imencode("." + fmt, img)
            data = bytes(data)
            data = data[:len(data) // 2] if cut == "half" else data[:40]
            new = name.rsplit(".", 1)[0] + "." + fmt
            open(os.path.join(s, new), "wb").write(data)
            meta["frames"][1]["file"] = new
            json.dump(meta, open(os.path.join(s, "meta.json"), "w"))
            r = unroll_with(env, seq=s)
            return r, judged(r, r["rc"] == 65 and os.path.basename(new) in r["err"])


# ---- the run ---------------------------------------------------------------------------------------------

def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cli", default=os.path.join(ROOT, "build", "vkunroll"))
    ap.add_argument("--table", help="write the markdown table here")
    ap.add_argument("-k", help="only cases whose name contains this")
    ap.add_argument("--cases", help="only these case numbers (comma-separated), e.g. to re-run the flagged ones")
    ap.add_argument("--surfaces", help="only these surfaces (comma-separated), e.g. 'stream(),tune'")
    a = ap.parse_args()
    rows, findings = [], []
    with tempfile.TemporaryDirectory() as root:
        env = Env(os.path.abspath(a.cli), root)
        for i, (surface, name, fn) in enumerate(CASES, 1):
            if (a.k and a.k not in name) or (a.surfaces and surface not in a.surfaces.split(",")) or \
                    (a.cases and str(i) not in a.cases.split(",")):
                continue
            try:
                r, v = fn(env)
            except Exception as e:  # noqa: BLE001 (a case that cannot run is a finding too)
                r, v = {"rc": "?", "err": f"{type(e).__name__}: {e}"}, "FINDING (case error)"
            if v != "handled":
                findings.append(f"{i} {name}: {v}")
            line = first_line(r).replace(root, "$T").replace("|", "\\|")
            rows.append(f"| {i} | {surface} | {name.replace('|', '/')} | {r['rc']} | {v} | {line} |")
            print(rows[-1], flush=True)
    table = ("| # | surface | case | exit | verdict | first line of stderr |\n| --- | --- | --- | --- | --- | --- |\n" +
             "\n".join(rows) + "\n")
    summary = f"\n{len(rows)} cases, {len(rows) - len(findings)} handled, {len(findings)} findings\n"
    if a.table:
        open(a.table, "w").write(table + summary)
    print(summary + "\n".join(findings))
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
