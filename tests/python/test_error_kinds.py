"""Errors by kind (docs/errors.md): the check that every library throw has a kind, run on planted
trees (it must fail on a bare Error and pass on a classified one), and Python's exception types for
kinds the event readers throw."""
import pathlib
import subprocess
import sys

import pytest

import vkunroll

ROOT = pathlib.Path(__file__).resolve().parents[2]
CHECK = ROOT / "tools" / "checks" / "check_error_kinds.py"


def run_check(tree):
    return subprocess.run([sys.executable, str(CHECK), str(tree)], capture_output=True, text=True)


def planted(tmp_path, body):
    (tmp_path / "tools" / "checks").mkdir(parents=True)
    (tmp_path / "tools" / "checks" / "bare_errors_allowed.txt").write_text("# none\n")
    (tmp_path / "host" / "x").mkdir(parents=True)
    (tmp_path / "host" / "x" / "a.cpp").write_text(body)
    return tmp_path


@pytest.mark.parametrize("body, bare", [
    ('void f() { throw Error("x: " + std::to_string(1)); }\n', True),
    ('void f() {\n  throw vkunroll::Error(std::string("a, b") +\n    g(1, 2));\n}\n', True),
    ('void f() { throw DataError("x"); }\n', False),
    ('void f() { throw Error("x", ErrorKind::internal); }\n', False),
    ('// throw Error("in a comment")\nconst char* s = "throw Error(\\"in a string\\")";\n', False),
    ('void f() { throw Error(msg(a, b)); }\n', True),
    ("int x = 1'000'000;\nvoid f() { throw Error(\"x\"); }\n", True),
])
def test_the_check_fails_on_a_bare_error_only(tmp_path, body, bare):
    r = run_check(planted(tmp_path, body))
    assert (r.returncode != 0) == bare, r.stdout + r.stderr
    if bare:
        assert "host/x/a.cpp" in r.stdout


def test_the_library_passes_its_check():
    r = run_check(ROOT)
    assert r.returncode == 0, r.stdout + r.stderr


def test_python_types_follow_the_kinds(tmp_path):
    with pytest.raises(FileNotFoundError):  # input_missing
        vkunroll.read_events(str(tmp_path / "missing.raw"))
    bad = tmp_path / "bad.txt"
    bad.write_text("# width 4 height 4\n5 1 1 1\n3 1 1 1\n")
    with pytest.raises(ValueError, match="earlier than"):  # data
        vkunroll.read_events(str(bad))
    with pytest.raises(ValueError, match="format"):  # usage
        vkunroll.read_events(str(bad), format="nope")
