"""`pip install .`'s wheel (python/wheel_backend): `python3 -m build --no-isolation --wheel` packs this
suite's build tree (VKUNROLL_WHEEL_BUILD_DIR: nothing rebuilt), the wheel goes into a fresh venv, and
from a folder outside the source tree examples/python/unroll_folder.py runs `vkunroll.unroll` with the
default model the wheel installed; the wheel's CLI and every place that shows the version agree."""
import json
import os
import re
import subprocess
import sys
import zipfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BUILD = os.environ.get("VKUNROLL_BUILD_DIR")
MODEL = "selfunroll_small_physics.safetensors"


def cmake_version():
    text = open(os.path.join(ROOT, "CMakeLists.txt")).read()
    return re.search(r"project\(vkunroll VERSION ([0-9.]+)", text).group(1)


def outside_env(venv):
    """The environment of a user's shell: no build tree on PYTHONPATH, no VKUNROLL_MODEL."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VKUNROLL_MODEL", "VKUNROLL_CLI")}
    env.update(VIRTUAL_ENV=str(venv), PATH=f"{venv}/bin:" + env.get("PATH", ""), PYTHONNOUSERSITE="1")
    return env


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    if not BUILD or not os.path.exists(os.path.join(BUILD, "CMakeCache.txt")):
        pytest.skip("VKUNROLL_BUILD_DIR is not a build tree (run through ctest)")
    dist = tmp_path_factory.mktemp("dist")
    r = subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--wheel", "--outdir", str(dist), ROOT],
                       env=dict(os.environ, VKUNROLL_WHEEL_BUILD_DIR=BUILD), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    wheels = sorted(dist.glob("*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def test_the_wheel_holds_package_module_cli_model_and_licenses(wheel):
    version = cmake_version()
    assert re.fullmatch(rf"vkunroll-{re.escape(version)}-cp3\d+-cp3\d+-linux_x86_64\.whl", wheel.name), wheel.name
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"vkunroll/__init__.py", "vkunroll/_unroll.py"} <= names
    assert [n for n in names if re.fullmatch(r"vkunroll/_vkunroll\..*\.so", n)], sorted(names)
    data = f"vkunroll-{version}.data"
    assert f"{data}/data/share/vkunroll/models/{MODEL}" in names
    assert f"{data}/scripts/vkunroll" in names
    meta = zipfile.ZipFile(wheel).read(f"vkunroll-{version}.dist-info/METADATA").decode()
    assert f"\nVersion: {version}\n" in meta and "Requires-Dist: numpy" in meta
    assert {f"vkunroll-{version}.dist-info/licenses/LICENSE", f"vkunroll-{version}.dist-info/licenses/models_LICENSE.md"} <= names


def test_installed_wheel_unrolls_with_its_default_model_outside_the_tree(wheel, tmp_path):
    venv = tmp_path / "venv"
    r = subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    env = outside_env(venv)
    r = subprocess.run([str(venv / "bin" / "pip"), "install", "--no-index", "--quiet", str(wheel)], env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    away = tmp_path / "elsewhere"
    away.mkdir()
    cli = venv / "bin" / "vkunroll"
    r = subprocess.run([str(cli), "--version"], cwd=away, env=env, capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.startswith(f"vkunroll {cmake_version()}"), r.stdout + r.stderr
    r = subprocess.run([str(cli), "simulate", "--out", "seq", "--preset", "clean", "--size", "48x32", "--frames", "2",
                        "--gt-per-frame", "1", "--seed", "3", "--quiet"], cwd=away, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    example = os.path.join(ROOT, "examples", "python", "unroll_folder.py")
    r = subprocess.run([str(venv / "bin" / "python"), example, "seq", "gs.npy"], cwd=away, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    first = r.stdout.splitlines()[0]
    m = re.match(r"vkunroll (\S+): (\d+) GS frames of 48x32 from 2 RS frames, mode (\w+), model (\S+)$", first)
    assert m, r.stdout
    assert m.group(1) == cmake_version() and int(m.group(2)) == 2 and m.group(3) in ("m", "s", "auto"), first
    model = os.path.realpath(m.group(4))
    assert model == os.path.realpath(venv / "share" / "vkunroll" / "models" / MODEL), model  # the wheel's, not the tree's
    assert re.search(r"^PSNR [0-9.]+ dB against the ground truth", r.stdout, re.M), r.stdout
    import numpy as np
    frames = np.load(away / "gs.npy")
    assert frames.shape == (2, 32, 48, 3) and 0 < float(frames.mean()) < 1
    where = subprocess.run([str(venv / "bin" / "python"), "-c", "import vkunroll, json; print(json.dumps(vkunroll.__file__))"],
                           cwd=away, env=env, capture_output=True, text=True)
    assert json.loads(where.stdout).startswith(str(venv)), where.stdout + where.stderr


def backend_module(monkeypatch):
    """The backend as pip loads it: from the source root (its working directory is the tree)."""
    import importlib.util
    monkeypatch.chdir(ROOT)
    path = os.path.join(ROOT, "python", "wheel_backend", "vkunroll_wheel_backend.py")
    spec = importlib.util.spec_from_file_location("vkunroll_wheel_backend", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_wrong_build_dir_is_named_with_what_was_expected(tmp_path, monkeypatch):
    backend = backend_module(monkeypatch)
    monkeypatch.setenv("VKUNROLL_WHEEL_BUILD_DIR", str(tmp_path))
    with pytest.raises(backend.BuildError, match=rf"VKUNROLL_WHEEL_BUILD_DIR={re.escape(str(tmp_path))}: no CMakeCache.txt"):
        backend.build_wheel(str(tmp_path))
    (tmp_path / "CMakeCache.txt").write_text("CMAKE_HOME_DIRECTORY:INTERNAL=/elsewhere\nVKUNROLL_BUILD_PYTHON:BOOL=ON\n")
    with pytest.raises(backend.BuildError, match=r"configured from /elsewhere, not from this source tree"):
        backend.build_wheel(str(tmp_path))
    (tmp_path / "CMakeCache.txt").write_text(f"CMAKE_HOME_DIRECTORY:INTERNAL={ROOT}\nVKUNROLL_BUILD_PYTHON:BOOL=OFF\n")
    with pytest.raises(backend.BuildError, match=r"VKUNROLL_BUILD_PYTHON off \(expected on\)"):
        backend.build_wheel(str(tmp_path))
    assert not list(tmp_path.glob("*.whl")) and not list(tmp_path.glob("*.part"))
    assert backend.cmake_version() == cmake_version() and backend.get_requires_for_build_wheel() == []
