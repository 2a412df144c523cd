"""One rule for every option (issue 28, item 3), as a property: every valued option of `events`,
`simulate`, `unroll` and `voxelize` (read from the command's own --help, so a new option is covered
the day it is added) is given NaN, +-inf, 1e308, -1, 0, an empty string and a 10 kB string on top of
a valid command. Each run must end in exit 0 (the value is legal), 2 (usage) or 65 (bad data) with
a message naming the option, or 66 / 69 naming it for a file or device that does not exist; never a
signal, a hang or a silent result."""
import os
import re
import subprocess
from concurrent.futures import ThreadPoolExecutor

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))
VALUES = ["nan", "inf", "-inf", "1e308", "-1", "0", "", "x" * 10000]
# Options that name a file or a device: a value that names none is exit 66 or 69, naming the option.
PATH_OPTIONS = {"--events", "--texture", "--model", "--device"}


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
def seq(tmp_path_factory):
    root = tmp_path_factory.mktemp("rules")
    r = subprocess.run([CLI, "simulate", "--out", str(root / "seq"), "--size", "32x24", "--frames", "2", "--seed", "2"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return root / "seq"


def base(command, seq, out):
    return {
        "events": ["events", str(seq / "events.h5")],
        "simulate": ["simulate", "--out", str(out), "--size", "32x24", "--frames", "2"],
        "unroll": ["unroll", str(seq), "--out", str(out), "--mode", "physics", "--quiet", "--no-video"],
        "voxelize": ["voxelize", str(seq), "--frames", "0", "--times", "0.5", "--out", str(out) + ".safetensors", "--bins", "2"],
    }[command]


def check(command, option, value, seq, out):
    args = base(command, seq, out)
    if option in args:  # an option of the base command: the probe's value replaces it
        i = args.index(option)
        del args[i:i + 2]
    try:
        r = subprocess.run([CLI, *args, option, value], capture_output=True, text=True, timeout=120)
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


@pytest.mark.parametrize("command", ["events", "simulate", "unroll", "voxelize"])
def test_every_option_takes_hostile_values_with_a_named_error(command, seq, tmp_path):
    options = valued_options(command)
    assert len(options) >= 2, options
    cases = [(o, v, tmp_path / f"out{i}") for i, (o, v) in enumerate((o, v) for o in options for v in VALUES)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        problems = [p for p in pool.map(lambda c: check(command, c[0], c[1], seq, c[2]), cases) if p]
    assert not problems, "\n".join(problems)
