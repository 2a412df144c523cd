"""Every writer, one output rule (issue 52; docs/reliability.md, "Every writer, one output rule").

The writers are enumerated, not listed by hand only: every command whose --help shows an --out or an
OUT, and every public Python callable with a `path` parameter, must be in WRITERS (or be a reader);
a new writer that is not fails test_every_writer_is_enumerated. Each writer then:
  - refuses an existing output it did not write, with and without --overwrite / overwrite=True
    (exit 2 / ValueError naming the output), and leaves it byte for byte as it was;
  - refuses to replace its own earlier output without --overwrite, and replaces it with it;
  - never writes what its own loader refuses, nor leaves a staged file behind on failure.
"""
import inspect
import os
import subprocess

import numpy as np
import pytest

from test_option_rules import CLI, base, commands_in_help, inputs, run  # noqa: F401 (inputs: a fixture)

# command -> (what it writes, how the output is named, how to ask to replace it)
CLI_WRITERS = {
    "unroll": ("folder", "--out", "--overwrite"),
    "simulate": ("folder", "--out", "--overwrite"),
    "bag-sequence": ("folder", "OUT", "--overwrite"),
    "infer": ("file", "--out", "--overwrite"),
    "voxelize": ("file", "--out", "--overwrite"),
    "demo": ("outputs", "--out", None),  # replaces only its own sequence/, physics/, model/ (their manifests)
}
CLI_NOT_WRITERS = {"devices", "events", "tune"}  # tune writes its tuning table into its own cache folder
PY_WRITERS = {"Sequence.create", "simulate", "write_events"}
PY_READERS = {"read_events", "detect_event_format", "Sequence.open", "Model.load"}


def cli_output_name(command):
    text = subprocess.run([CLI, command, "--help"], capture_output=True, text=True, check=True).stdout
    if "--out " in text:
        return "--out"
    return "OUT" if any(line.strip().startswith("OUT ") for line in text.splitlines()) else None


def public_callables_with_path():
    import vkunroll
    found = set()
    for name in vkunroll.__all__:
        obj = getattr(vkunroll, name)
        members = [(name, obj)] if inspect.isfunction(obj) else []
        if inspect.isclass(obj):
            members = [(f"{name}.{m}", getattr(obj, m)) for m in dir(obj) if not m.startswith("_")]
        for full, fn in members:
            try:
                params = inspect.signature(fn).parameters
            except (TypeError, ValueError):
                continue
            if "path" in params or "out" in params:
                found.add(full)
    return found


def test_every_writer_is_enumerated():
    commands = set(commands_in_help())
    assert commands == set(CLI_WRITERS) | CLI_NOT_WRITERS, commands
    for c in commands:
        assert (cli_output_name(c) is not None) == (c in CLI_WRITERS), c
        if c in CLI_WRITERS:
            assert cli_output_name(c) == CLI_WRITERS[c][1], c
    pytest.importorskip("vkunroll")
    assert public_callables_with_path() == PY_WRITERS | PY_READERS


def user_output(kind, out):
    """What a user keeps where a careless command might write: a folder with a meta.json and a frame
    of their own (a sequence's names), or a file of their own."""
    if kind == "file":
        out.write_bytes(b"the user's own notes\n")
    else:
        (out / "rs").mkdir(parents=True)
        (out / "meta.json").write_text('{"hand": "written"}\n')
        (out / "rs" / "000001.png").write_bytes(b"not vkunroll's")
        if kind == "outputs":  # demo writes sequence/ and physics/ (and model/) under its --out
            (out / "physics").mkdir()
            (out / "physics" / "notes.txt").write_text("mine")


def snapshot(path):
    if path.is_file():
        return path.read_bytes()
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def writer_args(command, inputs, out):
    args = base(command, inputs, out)
    if command in ("infer", "voxelize"):  # base names its file out + ".safetensors"
        args = [str(out) if a == str(out) + ".safetensors" else a for a in args]
    return args


@pytest.mark.parametrize("command", sorted(CLI_WRITERS))
def test_cli_writer_never_replaces_what_it_did_not_write(command, inputs, tmp_path):
    kind, name, flag = CLI_WRITERS[command]
    out = tmp_path / ("out.safetensors" if kind == "file" else "out")
    user_output(kind, out)
    before = snapshot(out)
    attempts = [[]] + ([[flag]] if flag else [])
    for extra in attempts:
        r = run(writer_args(command, inputs, out) + extra, inputs)
        assert r.returncode == 2, (command, extra, r.returncode, r.stderr)
        assert name in r.stderr and str(out.name) in r.stderr, r.stderr
        assert snapshot(out) == before, f"{command} {extra} changed the user's output"
    assert not list(tmp_path.glob(".out*partial*")), list(tmp_path.iterdir())


@pytest.mark.parametrize("command", sorted(c for c, w in CLI_WRITERS.items() if w[2]))
def test_cli_writer_replaces_its_own_output_only_when_asked(command, inputs, tmp_path):
    kind, name, flag = CLI_WRITERS[command]
    out = tmp_path / ("out.safetensors" if kind == "file" else "out")
    first = run(writer_args(command, inputs, out), inputs)
    assert first.returncode == 0, first.stderr
    before = snapshot(out)
    again = run(writer_args(command, inputs, out), inputs)
    assert again.returncode == 2 and flag in again.stderr, again.stderr
    assert snapshot(out) == before
    replaced = run(writer_args(command, inputs, out) + [flag], inputs)
    assert replaced.returncode == 0, replaced.stderr


def test_infer_out_may_not_be_an_input(inputs, tmp_path):
    if "infer_inputs" not in inputs:
        pytest.skip("no torch: no inputs for infer")
    for given in ("--inputs", "--model"):
        args = writer_args("infer", inputs, tmp_path / "o.safetensors")
        target = args[args.index(given) + 1]
        before = open(target, "rb").read()
        args[args.index("--out") + 1] = target
        r = run(args + ["--overwrite"], inputs)
        assert r.returncode == 2 and "--out" in r.stderr and "input" in r.stderr, r.stderr
        assert open(target, "rb").read() == before


def test_bag_sequence_refuses_what_its_loader_would_refuse(inputs, tmp_path):
    """A converter validates its output with the loader's schema before committing: a readout longer
    than the frame period, or a t0 beyond the schema's limit, leaves nothing behind."""
    if "bag" not in inputs:
        pytest.skip("no python3-rosbag")
    out = tmp_path / "seq"
    for extra in (["--line-delay-us", "10000"], ["--t0-offset-us", str(2 ** 53 + 1)]):
        args = base("bag-sequence", inputs, out)
        i = args.index(extra[0]) if extra[0] in args else None
        if i is not None:
            del args[i:i + 2]
        r = run(args + extra, inputs)
        assert r.returncode in (2, 65), r.stderr
        assert not out.exists() and not list(tmp_path.glob(".seq*")), r.stderr


# ---- Python --------------------------------------------------------------------------------------

def tiny_sequence_args():
    import vkunroll
    ev = np.zeros(20, vkunroll.EVENT_DTYPE)
    ev["t"] = np.arange(20) * 100
    ev["x"], ev["y"], ev["p"] = np.arange(20) % 8, np.arange(20) % 6, 1
    frames = [np.full((6, 8), 100, np.uint8)]
    return frames, ev, vkunroll.RowTiming(6, 0, 100, 1000)


def py_writers(vkunroll, tmp):
    frames, ev, timing = tiny_sequence_args()
    return {
        "Sequence.create": ("folder", lambda p, **kw: vkunroll.Sequence.create(p, frames, ev, timing, **kw)),
        "simulate": ("folder", lambda p, **kw: vkunroll.simulate(p, width=16, height=12, frames=2, **kw)),
        "write_events": ("file", lambda p, **kw: vkunroll.write_events(p, ev, sensor_size=(8, 6), format="h5", **kw)),
    }


@pytest.mark.parametrize("writer", sorted(PY_WRITERS))
def test_python_writer_follows_the_rule(writer, tmp_path):
    vkunroll = pytest.importorskip("vkunroll")
    kind, write = py_writers(vkunroll, tmp_path)[writer]
    mine = tmp_path / "mine"
    user_output(kind, mine)
    before = snapshot(mine)
    for kw in ({}, {"overwrite": True}):
        with pytest.raises(ValueError, match="overwrite=True" if not kw else "did not write|cannot tell"):
            write(mine, **kw)
        assert snapshot(mine) == before
    ours = tmp_path / "ours"
    write(ours)
    with pytest.raises(ValueError, match="overwrite=True"):
        write(ours)
    write(ours, overwrite=True)
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]


def test_sequence_create_leaves_nothing_when_its_loader_refuses(tmp_path):
    vkunroll = pytest.importorskip("vkunroll")
    frames, ev, timing = tiny_sequence_args()
    ev["x"][3] = 50  # outside the 8-pixel-wide sensor
    with pytest.raises(ValueError, match="x|sensor"):
        vkunroll.Sequence.create(tmp_path / "s", frames, ev, timing)
    assert list(tmp_path.iterdir()) == []
