"""Every output path under one rule, driven by the output table (issue 58).

The table is host/unroll/output_paths.cpp (every option, keyword or environment variable that names
an output path, declared once; read here through vkunroll._vkunroll._output_paths()). Each entry has
a RUNNER below (an entry without one fails test_every_entry_has_a_runner), and every entry is tried
against every case of the rule:

  - an empty name: a usage error before any work (nothing written in the working folder);
  - a user's file (or folder) at the name: refused, with and without --overwrite, left as it was;
  - an input of the run: refused, the input left as it was;
  - a FIFO, a symbolic link, a character device: refused, each left what it was (no hang);
  - a file inside a vkunroll output folder (another run's, or the run's own --out): refused;
  - its own earlier output: replaced only when asked.

The front ends cannot declare an output past the table: every CLI option whose --help value is a
FILE or DIR is either in the table or one of INPUT_OPTIONS, and every public Python callable with a
path argument is either in the table or one of PY_READERS.
"""
import os
import re
import shutil
import stat
import subprocess

import pytest

from test_option_rules import CLI, TINY_MODEL, base, commands_in_help, inputs  # noqa: F401 (inputs: a fixture)

vkunroll = pytest.importorskip("vkunroll")
ENTRIES = {e["id"]: e for e in vkunroll._vkunroll._output_paths()}
# Options whose --help value is FILE or DIR and that name no output: what a command reads, and
# --readout (its DIR is a direction: top-down | bottom-up).
INPUT_OPTIONS = {"--model", "--inputs", "--events", "--texture", "--follow-events", "--readout"}
PY_READERS = {"read_events", "detect_event_format", "Sequence.open", "Model.load"}


def run(args, env_extra=None, cwd=None, timeout=180):
    env = dict(os.environ, **(env_extra or {}))
    env.setdefault("VKUNROLL_CACHE_DIR", "/tmp/vkunroll-test-output-paths-cache")
    return subprocess.run([CLI, *args], capture_output=True, text=True, timeout=timeout, env=env, cwd=cwd)


# ---- how each entry is run: (command line for output `out`, its inputs, the flag that asks to replace) --

def unroll_out(inputs, out, tmp):
    return base("unroll", inputs, out) + ["--times", "0.5"], [inputs["seq"] / "meta.json"], "--overwrite"


def unroll_trace(inputs, out, tmp):
    o = tmp / f"run{len(list(tmp.glob('run*')))}"
    events = tmp / "ev.h5"  # --events ev.h5 --trace ev.h5
    if not events.exists():
        shutil.copy(inputs["seq"] / "events.h5", events)
    args = base("unroll", inputs, o) + ["--times", "0.5", "--trace", str(out), "--model", TINY_MODEL, "--events", str(events)]
    return args, [inputs["seq"] / "meta.json", inputs["seq"] / "events.h5", TINY_MODEL, events], "--overwrite"


def file_command(command):
    def runner(inputs, out, tmp):
        args = base(command, inputs, out)
        args = [str(out) if a == str(out) + ".safetensors" else a for a in args]
        ins = [inputs["seq"] / "events.h5"] if command == "voxelize" else [TINY_MODEL, inputs["infer_inputs"]]
        return args, ins, "--overwrite"
    return runner


def folder_command(command):
    def runner(inputs, out, tmp):
        ins = {"bag-sequence": [inputs.get("bag")], "demo": []}.get(command, [])
        return base(command, inputs, out), [i for i in ins if i], "--overwrite" if command != "demo" else None
    return runner


RUNNERS = {
    "unroll.out": unroll_out,
    "unroll.trace": unroll_trace,
    "voxelize.out": file_command("voxelize"),
    "infer.out": file_command("infer"),
    "simulate.out": folder_command("simulate"),
    "demo.out": folder_command("demo"),
    "bag-sequence.out": folder_command("bag-sequence"),
    "tune.table": None,            # test_tune_table_* below: the name is the cache folder's
    "Sequence.create.path": None,  # the Python entries: test_python_entry_*
    "simulate.path": None,
    "write_events.path": None,
}
CLI_IDS = sorted(i for i, e in ENTRIES.items() if e["front_end"] == "cli")
FILE_IDS = sorted(i for i in CLI_IDS if ENTRIES[i]["shape"] == "file")


def test_every_entry_has_a_runner():
    assert set(RUNNERS) == set(ENTRIES), set(RUNNERS) ^ set(ENTRIES)


def test_every_cli_path_option_is_an_output_or_an_input():
    declared = {(e["command"], e["spelled"]) for e in ENTRIES.values() if e["front_end"] == "cli"}
    for command in commands_in_help():
        text = subprocess.run([CLI, command, "--help"], capture_output=True, text=True, check=True).stdout
        for option, value in re.findall(r"^  (--[a-z0-9-]+|[A-Z]+) (FILE\S*|DIR)\b", text, re.M):
            assert (command, option) in declared or option in INPUT_OPTIONS, f"{command} {option} {value}"
        for e in ENTRIES.values():
            if e["front_end"] == "cli" and e["command"] == command:
                assert re.search(rf"^  {re.escape(e['spelled'])} ", text, re.M), (command, e["spelled"])


def test_every_python_path_keyword_is_an_output_or_a_reader():
    from test_output_rule import public_callables_with_path
    writers = {e["command"] for e in ENTRIES.values() if e["front_end"] == "python"}
    assert public_callables_with_path() == writers | PY_READERS


def state(p):
    """What is at `p`, to compare before and after: kind, and the bytes of a file or a link's target."""
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


def refused(r, entry, what):
    assert r.returncode == 2, (entry["id"], what, r.returncode, r.stderr[-2000:])
    assert entry["spelled"] in r.stderr, (entry["id"], what, r.stderr[-2000:])


def hostile_targets(tmp, inputs, ins, is_file):
    """(name, path, prepare) for every case of the rule where a path already holds something."""
    targets = [("user's file", tmp / "user.json", lambda p: p.write_text("the user's notes\n"))]
    targets.append(("fifo", tmp / "fifo", lambda p: os.mkfifo(p)))
    def link(p):
        (tmp / "link-target").write_text("mine")
        os.symlink(tmp / "link-target", p)
    targets.append(("symlink", tmp / "link", link))
    if os.geteuid() == 0:  # a character device of our own (1, 7 is /dev/full's)
        targets.append(("char device", tmp / "full", lambda p: os.mknod(p, 0o666 | stat.S_IFCHR, os.makedev(1, 7))))
    for k, i in enumerate(ins):
        targets.append((f"input {os.path.basename(str(i))}", i, None))
    if is_file:  # another run's output: its manifest lists what it holds
        targets.append(("another run's summary.json", inputs["other_run"] / "summary.json", None))
        targets.append(("a new file in another run's output", inputs["other_run"] / "new.json", None))
    return targets


@pytest.fixture(scope="module")
def other_run(inputs, tmp_path_factory):
    o = tmp_path_factory.mktemp("other") / "o1"
    r = run(base("unroll", inputs, o) + ["--times", "0.5"])
    assert r.returncode == 0, r.stderr
    inputs["other_run"] = o
    return o


@pytest.mark.parametrize("entry_id", CLI_IDS)
def test_cli_entry_refuses_an_empty_name_before_any_work(entry_id, inputs, tmp_path):
    entry = ENTRIES[entry_id]
    args, _, _ = RUNNERS[entry_id](inputs, tmp_path / "placeholder", tmp_path)
    i = args.index(entry["spelled"]) + 1 if entry["spelled"].startswith("-") else args.index(str(tmp_path / "placeholder"))
    args[i] = ""
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    r = run(args, cwd=cwd)
    refused(r, entry, "empty")
    assert "empty" in r.stderr, r.stderr
    assert os.listdir(cwd) == [], os.listdir(cwd)


@pytest.mark.parametrize("entry_id", CLI_IDS)
def test_cli_entry_refuses_what_it_did_not_write(entry_id, inputs, other_run, tmp_path):
    entry = ENTRIES[entry_id]
    is_file = entry["shape"] == "file"
    _, ins, flag = RUNNERS[entry_id](inputs, tmp_path / "x", tmp_path)
    for what, path, prepare in hostile_targets(tmp_path, inputs, ins, is_file):
        if prepare:
            prepare(path)
        before = state(path)
        args, _, _ = RUNNERS[entry_id](inputs, path, tmp_path)
        for extra in [[]] + ([[flag]] if flag else []):
            try:
                r = run(args + extra, timeout=120)
            except subprocess.TimeoutExpired:
                pytest.fail(f"{entry_id} {what}: hung")
            refused(r, entry, what)
            assert state(path) == before, f"{entry_id} {what} {extra}: changed"


def test_trace_is_never_the_out_folder_nor_inside_it(inputs, tmp_path):
    entry = ENTRIES["unroll.trace"]
    out = tmp_path / "o14"
    for trace in (out, out / "trace.json"):
        r = run(base("unroll", inputs, out) + ["--times", "0.5", "--trace", str(trace)])
        refused(r, entry, str(trace))
        assert not out.exists()


@pytest.mark.parametrize("entry_id", FILE_IDS)
def test_cli_file_entry_replaces_its_own_output_only_when_asked(entry_id, inputs, tmp_path):
    entry = ENTRIES[entry_id]
    out = tmp_path / "own.json"
    args, _, flag = RUNNERS[entry_id](inputs, out, tmp_path)
    first = run(args)
    assert first.returncode == 0, first.stderr
    written = out.read_bytes()
    args, _, flag = RUNNERS[entry_id](inputs, out, tmp_path)
    refused(run(args), entry, "its own, not asked")
    assert out.read_bytes() == written
    args, _, flag = RUNNERS[entry_id](inputs, out, tmp_path)
    again = run(args + [flag])
    assert again.returncode == 0, again.stderr
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name or ".tmp" in p.name]


# ---- tune's table (VKUNROLL_CACHE_DIR) ------------------------------------------------------------

TUNE = ["tune", "--model", TINY_MODEL, "--size", "16x16", "--tile", "0", "--reps", "1", "--no-compare",
        "--warm-ms", "0", "--candidate-ms", "0"]


@pytest.fixture(scope="module")
def table_name(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    r = run(TUNE, {"VKUNROLL_CACHE_DIR": str(cache)}, timeout=600)
    assert r.returncode == 0, r.stderr
    tables = [p.name for p in cache.glob("conv-choices-*.tsv")]
    assert len(tables) == 1, tables
    return tables[0]


def test_tune_table_that_is_not_a_table_is_refused_before_timing(table_name, tmp_path):
    for what, prepare in [("user's file", lambda p: p.write_text("my notes\n")),
                          ("fifo", lambda p: os.mkfifo(p)),
                          ("symlink", lambda p: os.symlink(tmp_path / "elsewhere", p))]:
        cache = tmp_path / what.replace(" ", "_").replace("'", "")
        cache.mkdir()
        table = cache / table_name
        prepare(table)
        before = state(table)
        r = run(TUNE, {"VKUNROLL_CACHE_DIR": str(cache)}, timeout=120)
        refused(r, ENTRIES["tune.table"], what)
        assert "FMA ceiling" not in r.stdout, "timed before refusing"
        assert state(table) == before


def test_tune_cache_dir_that_cannot_take_the_table_says_why_before_timing(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for cache, why in [(blocker, "Not a directory"), (blocker / "sub", "Not a directory")]:
        r = run(TUNE, {"VKUNROLL_CACHE_DIR": str(cache)}, timeout=120)
        assert r.returncode == 74, (cache, r.returncode, r.stderr)
        assert "VKUNROLL_CACHE_DIR" in r.stderr and why in r.stderr, r.stderr
        assert "FMA ceiling" not in r.stdout
    assert blocker.read_text() == "x"


# ---- the Python entries ---------------------------------------------------------------------------

def py_writer(entry_id):
    from test_output_rule import py_writers
    return py_writers(vkunroll, None)[ENTRIES[entry_id]["command"]][1]


PY_IDS = sorted(i for i, e in ENTRIES.items() if e["front_end"] == "python")


@pytest.mark.parametrize("entry_id", PY_IDS)
def test_python_entry_refuses_an_empty_name(entry_id, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="empty"):
        py_writer(entry_id)("")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("entry_id", PY_IDS)
def test_python_entry_refuses_links_and_special_files(entry_id, tmp_path):
    write = py_writer(entry_id)
    (tmp_path / "target").write_text("mine")
    os.symlink(tmp_path / "target", tmp_path / "link")
    os.mkfifo(tmp_path / "fifo")
    for name in ("link", "fifo"):
        before = state(tmp_path / name)
        for kw in ({}, {"overwrite": True}):
            with pytest.raises(ValueError, match="path"):
                write(tmp_path / name, **kw)
            assert state(tmp_path / name) == before
    assert (tmp_path / "target").read_text() == "mine"
