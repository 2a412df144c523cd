"""One version, CMake's project(vkunroll VERSION x.y.z), wherever one is shown: `vkunroll --version`,
`vkunroll.__version__`, the package config, summary.json's provenance, CITATION.cff and the
changelog's newest entry (the wheel's name and METADATA: test_wheel.py). pyproject.toml has none of
its own."""
import json
import os
import re
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CLI = os.environ.get("VKUNROLL_CLI")
BUILD = os.environ.get("VKUNROLL_BUILD_DIR")
needs_build = pytest.mark.skipif(not CLI or not BUILD, reason="VKUNROLL_CLI / VKUNROLL_BUILD_DIR not set (run through ctest)")


def read(*path):
    return open(os.path.join(ROOT, *path), encoding="utf-8").read()


def cmake_version():
    m = re.search(r"^project\(vkunroll VERSION (\d+\.\d+\.\d+) ", read("CMakeLists.txt"), re.M)
    assert m, "CMakeLists.txt: no project(vkunroll VERSION x.y.z ...)"
    return m.group(1)


def test_files_that_state_the_version_state_cmakes():
    v = cmake_version()
    assert re.search(r'^version: "([^"]+)"$', read("CITATION.cff"), re.M).group(1) == v
    newest = re.search(r"^## (?!Unreleased)(\S+)", read("CHANGELOG.md"), re.M).group(1)  # Unreleased: not yet a version
    assert newest == v, f"CHANGELOG.md's newest entry is {newest}, CMake's version {v}"
    pyproject = read("pyproject.toml")
    assert 'dynamic = ["version"]' in pyproject and not re.search(r"^version\s*=", pyproject, re.M)


@needs_build
def test_cli_module_package_config_and_summary_show_it(tmp_path):
    v = cmake_version()
    r = subprocess.run([CLI, "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and re.match(rf"vkunroll {re.escape(v)} \(git ", r.stdout), r.stdout + r.stderr
    r = subprocess.run(["/usr/bin/python3", "-c", "import vkunroll; print(vkunroll.__version__)"], capture_output=True, text=True)
    assert r.stdout.strip() == v, r.stdout + r.stderr
    config = open(os.path.join(BUILD, "vkunrollConfigVersion.cmake")).read()
    assert f'set(PACKAGE_VERSION "{v}")' in config
    seq, out = tmp_path / "seq", tmp_path / "out"
    r = subprocess.run([CLI, "simulate", "--out", seq, "--preset", "clean", "--size", "32x24", "--frames", "2", "--quiet"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([CLI, "unroll", seq, "--out", out, "--mode", "physics", "--frames", "0", "--no-video", "--quiet"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["provenance"]["vkunroll_version"] == v
