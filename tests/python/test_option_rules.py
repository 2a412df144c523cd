"""One rule for every option (issue 28, item 3), as a property: every valued option of every command
(read from the command's own --help, so a new option is covered the day it is added) is given NaN,
+-inf, 1e308, -1, 0, an empty string and a 10 kB string on top of a valid, cheap command (tiny
inputs). Each run must end in exit 0 (the value is legal), 2 (usage) or 65 (bad data) with a message
naming the option, or 66 / 69 naming it for a file or device that does not exist; never a signal, a
hang or a silent result. Also: `--help` usage lines name `vkunroll` once, and an --out that cannot be
a folder (an existing file, or a path under one) is exit 2 naming --out for every command."""
import os
import re
import subprocess
from concurrent.futures import ThreadPoolExecutor

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))
TINY_MODEL = os.path.join(ROOT, "tests", "data", "selfunroll_tiny.safetensors")
VALUES = ["nan", "inf", "-inf", "1e308", "-1", "0", "", "x" * 10000]
# Options that name a file or a device: a value that names none is exit 66 or 69, naming the option.
PATH_OPTIONS = {"--events", "--texture", "--model", "--device", "--inputs"}
COMMANDS = ["bag-sequence", "demo", "devices", "events", "infer", "simulate", "tune", "unroll", "voxelize"]


def commands_in_help():
    text = subprocess.run([CLI, "--help"], capture_output=True, text=True, check=True).stdout
    found, listing = [], False
    for line in text.splitlines():
        if line.strip().upper().startswith("SUBCOMMANDS"):
            listing = True
            continue
        m = re.match(r"^  ([a-z][a-z-]+)\s", line)
        if listing and m:
            found.append(m.group(1))
        elif listing and line and not line.startswith(" "):
            listing = False
    return found


def valued_options(command):
    """The options --help shows with a value (flags and --out excluded)."""
    text = subprocess.run([CLI, command, "--help"], capture_output=True, text=True, check=True).stdout
    found = []
    for line in text.splitlines():
        m = re.match(r"^  (--[a-z0-9-]+) (\S+)", line)
        if m and m.group(2) != "Excludes:" and m.group(1) not in ("--help", "--out"):
            found.append(m.group(1))
    return found


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    root = tmp_path_factory.mktemp("rules")
    r = subprocess.run([CLI, "simulate", "--out", str(root / "seq"), "--size", "32x24", "--frames", "2", "--seed", "2"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    made = {"seq": root / "seq", "cache": root / "cache"}
    # infer: the tiny model's inputs (batch 1, 32x32), written by the PyTorch mirror's tools.
    try:
        from tools.model import safetensors_io
        from tools.model.make_golden import make_inputs
        safetensors_io.save(str(root / "in.safetensors"), make_inputs(1, 32, 32, 4, seed=5))
        made["infer_inputs"] = root / "in.safetensors"
    except ImportError:  # no torch: infer is skipped
        pass
    # bag-sequence: a tiny DAVIS-like bag (Debian's python3-rosbag, the helpers of test_bindings_rosbag).
    try:
        made["bag"] = write_tiny_bag(root / "tiny.bag")
    except ImportError:
        pass
    return made


def write_tiny_bag(path):
    import numpy as np
    import rosbag
    from test_bindings_rosbag import DVS, IMAGE, array_message, image_message, write_raw
    w, h = 16, 12
    ev = np.zeros(200, [("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    ev["t"] = 1_000_000 + np.arange(200) * 100
    ev["x"], ev["y"], ev["p"] = np.arange(200) % w, np.arange(200) % h, 1
    with rosbag.Bag(str(path), "w") as bag:
        for k in range(0, 200, 100):
            write_raw(bag, "/dvs/events", DVS, array_message(k // 100, ev[k:k + 100], w, h), int(ev["t"][k + 99]))
        for k in range(2):
            t = 1_000_000 + 5000 * k + 1000
            write_raw(bag, "/dvs/image_raw", IMAGE, image_message(k, t, np.full((h, w), 40 * k, np.uint8), "mono8"), t)
    return path


def base(command, inputs, out):
    seq = inputs["seq"]
    if command == "infer" and "infer_inputs" not in inputs:
        pytest.skip("no torch: no inputs for infer")
    if command == "bag-sequence" and "bag" not in inputs:
        pytest.skip("no python3-rosbag: no bag for bag-sequence")
    return {
        "bag-sequence": lambda: ["bag-sequence", str(inputs["bag"]), str(out), "--line-delay-us", "10", "--exposure-us", "100"],
        "demo": lambda: ["demo", "--out", str(out), "--size", "16x16", "--frames", "2", "--physics-only"],
        "devices": lambda: ["devices"],
        "events": lambda: ["events", str(seq / "events.h5")],
        "infer": lambda: ["infer", "--model", TINY_MODEL, "--inputs", str(inputs["infer_inputs"]), "--out",
                          str(out) + ".safetensors", "--backend", "cpu"],
        "simulate": lambda: ["simulate", "--out", str(out), "--size", "32x24", "--frames", "2"],
        "tune": lambda: ["tune", "--model", TINY_MODEL, "--size", "16x16", "--tile", "0", "--reps", "1", "--no-compare"],
        "unroll": lambda: ["unroll", str(seq), "--out", str(out), "--mode", "physics", "--quiet", "--no-video"],
        "voxelize": lambda: ["voxelize", str(seq), "--frames", "0", "--times", "0.5", "--out", str(out) + ".safetensors",
                             "--bins", "2"],
    }[command]()


def run(args, inputs, cwd=None):
    env = dict(os.environ, VKUNROLL_CACHE_DIR=str(inputs["cache"]))  # tune writes its table there
    return subprocess.run([CLI, *args], capture_output=True, text=True, timeout=120, env=env, cwd=cwd)


def check(command, option, value, inputs, out):
    args = base(command, inputs, out)
    if option in args:  # an option of the base command: the probe's value replaces it
        i = args.index(option)
        del args[i:i + 2]
    # Each probe in a folder of its own: a value taken as a relative output (--trace nan) must not
    # become another probe's input (--events nan).
    cwd = out.parent / f"cwd_{out.name}"
    cwd.mkdir(parents=True, exist_ok=True)
    try:
        r = run([*args, option, value], inputs, cwd)
    except subprocess.TimeoutExpired:
        return f"{command} {option} {value[:12]!r}: hung (120 s)"
    allowed = {0, 2, 65} | ({66, 69} if option in PATH_OPTIONS else set())
    named = option in r.stderr
    if r.returncode < 0:
        return f"{command} {option} {value[:12]!r}: killed by signal {-r.returncode}"
    if r.returncode not in allowed or (r.returncode != 0 and not named):
        last = r.stderr.strip().splitlines()[:1]
        return f"{command} {option} {value[:12]!r}: exit {r.returncode} {last}"
    return None


def test_every_command_is_covered():
    assert sorted(commands_in_help()) == sorted(COMMANDS)


@pytest.mark.parametrize("command", COMMANDS)
def test_every_option_takes_hostile_values_with_a_named_error(command, inputs, tmp_path):
    options = valued_options(command)
    assert len(options) >= 1, options
    cases = [(o, v, tmp_path / f"out{i}") for i, (o, v) in enumerate((o, v) for o in options for v in VALUES)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        problems = [p for p in pool.map(lambda c: check(command, c[0], c[1], inputs, c[2]), cases) if p]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("command", COMMANDS)
def test_usage_line_names_vkunroll_once(command):
    text = subprocess.run([CLI, command, "--help"], capture_output=True, text=True, check=True).stdout
    usage = [line for line in text.splitlines() if line.startswith("usage:")]
    assert usage and usage[0].startswith(f"usage: vkunroll {command}") and "vkunroll vkunroll" not in text, usage


@pytest.mark.parametrize("command", [c for c in COMMANDS if c not in ("devices", "events", "tune")])
@pytest.mark.parametrize("where", ["file", "under_file"])
def test_an_out_that_cannot_be_written_is_a_usage_error(command, where, inputs, tmp_path):
    """An --out (or OUT) that is an existing file, or lies under one, is exit 2 naming it, whichever
    command writes it (a folder for unroll, simulate, demo, bag-sequence; a file for infer, voxelize:
    there only 'under a file')."""
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    out = blocker if where == "file" else blocker / "x"
    args = base(command, inputs, out)
    args = [str(blocker / "x.safetensors") if a == str(out) + ".safetensors" else a for a in args]
    if where == "file" and command in ("infer", "voxelize"):
        pytest.skip("a file output may replace a file")
    r = run(args, inputs)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "a_file" in r.stderr and ("--out" in r.stderr or "OUT" in r.stderr), r.stderr
    assert blocker.read_text() == "not a folder"
