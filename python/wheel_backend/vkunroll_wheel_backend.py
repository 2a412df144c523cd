"""The PEP 517 backend of `pip install .`: builds the Python module with the project's own CMake
and packs a wheel (pyproject.toml names it; docs/python.md says how to use it).

The wheel holds the package `vkunroll` (its Python files and the compiled `_vkunroll`), the `vkunroll`
CLI as a script, and the default model as data under `share/vkunroll/models/`, where the library
looks for it beside an installed module (host/unroll/default_model.hpp). The extension links
Debian's shared libraries (OpenCV, HDF5, ...) and loads the system's Vulkan loader at run time.

Why in-tree and not scikit-build: it needs nothing that pip must fetch (an isolated build works
offline too), it runs the CMake build the rest of the project uses, and it can pack an already
built tree (VKUNROLL_WHEEL_BUILD_DIR), which keeps the suite's wheel test at seconds.

Environment:
  VKUNROLL_WHEEL_BUILD_DIR  an already configured and built CMake tree of this source: packed as it
                            is, nothing is built (the suite's test uses its own build)
  CMAKE_BUILD_PARALLEL_LEVEL  parallel jobs of the full build (default: all cores)
Without VKUNROLL_WHEEL_BUILD_DIR, the build goes to build-wheel/ in the source tree (kept, so a second
`pip install .` only rebuilds what changed).
"""
import base64
import hashlib
import os
import re
import shutil
import stat
import subprocess
import sys
import sysconfig
import tempfile
import tomllib
import zipfile

ROOT = os.getcwd()  # PEP 517: the backend runs in the source tree
NAME = "vkunroll"


class BuildError(RuntimeError):
    pass


def cmake_version(root=ROOT):
    """The one version: CMakeLists.txt's project(vkunroll VERSION x.y.z)."""
    text = open(os.path.join(root, "CMakeLists.txt"), encoding="utf-8").read()
    m = re.search(r"project\(\s*vkunroll\s+VERSION\s+([0-9][0-9.]*)", text)
    if not m:
        raise BuildError("CMakeLists.txt: no project(vkunroll VERSION x.y.z) to take the wheel's version from")
    return m.group(1)


def wheel_tag():
    v = sys.version_info
    abi = f"cp{v.major}{v.minor}" + (sys.abiflags or "")
    return f"cp{v.major}{v.minor}-{abi}-" + sysconfig.get_platform().replace("-", "_").replace(".", "_")


def metadata_text(version):
    project = tomllib.load(open(os.path.join(ROOT, "pyproject.toml"), "rb"))["project"]
    lines = ["Metadata-Version: 2.1", f"Name: {project['name']}", f"Version: {version}",
             f"Summary: {project['description']}", f"License: {project['license']['text']}",
             f"Requires-Python: {project['requires-python']}"]
    lines += [f"Requires-Dist: {d}" for d in project.get("dependencies", [])]
    lines += [f"Classifier: {c}" for c in project.get("classifiers", [])]
    lines += ["Description-Content-Type: text/markdown", "",
              open(os.path.join(ROOT, project["readme"]), encoding="utf-8").read()]
    return "\n".join(lines) + "\n"


def dist_info_files(version):
    wheel = f"Wheel-Version: 1.0\nGenerator: vkunroll_wheel_backend\nRoot-Is-Purelib: false\nTag: {wheel_tag()}\n"
    files = {"METADATA": metadata_text(version), "WHEEL": wheel}
    for name in ("LICENSE", "models/LICENSE.md"):  # the code's and the shipped model's
        path = os.path.join(ROOT, name)
        if os.path.exists(path):
            files["licenses/" + name.replace("/", "_")] = open(path, encoding="utf-8").read()
    return files


def run(cmd):
    print("vkunroll_wheel_backend:", " ".join(cmd), flush=True)
    r = subprocess.run(cmd)
    if r.returncode != 0:
        raise BuildError(f"{' '.join(cmd)} failed (exit {r.returncode})")


def cache_value(build_dir, key):
    for line in open(os.path.join(build_dir, "CMakeCache.txt"), encoding="utf-8", errors="replace"):
        if line.startswith(key + ":"):
            return line.split("=", 1)[1].strip()
    return None


def given_build_dir(build_dir):
    """VKUNROLL_WHEEL_BUILD_DIR: checked to be a built tree of this source with the module in it."""
    build_dir = os.path.abspath(build_dir)
    if not os.path.exists(os.path.join(build_dir, "CMakeCache.txt")):
        raise BuildError(f"VKUNROLL_WHEEL_BUILD_DIR={build_dir}: no CMakeCache.txt (expected a configured CMake build of vkunroll)")
    home = cache_value(build_dir, "CMAKE_HOME_DIRECTORY")
    if not home or os.path.realpath(home) != os.path.realpath(ROOT):
        raise BuildError(f"VKUNROLL_WHEEL_BUILD_DIR={build_dir}: configured from {home}, not from this source tree {ROOT}")
    if cache_value(build_dir, "VKUNROLL_BUILD_PYTHON") not in ("ON", "TRUE", "1"):
        raise BuildError(f"VKUNROLL_WHEEL_BUILD_DIR={build_dir}: configured with VKUNROLL_BUILD_PYTHON off (expected on)")
    return build_dir


def full_build():
    """A fresh (or resumed) Release build of the module and the CLI in build-wheel/."""
    build_dir = os.path.join(ROOT, "build-wheel")
    gen = ["-G", "Ninja"] if shutil.which("ninja") and not os.path.exists(os.path.join(build_dir, "Makefile")) else []
    run(["cmake", "-S", ROOT, "-B", build_dir, *gen, "-DCMAKE_BUILD_TYPE=Release", "-DVKUNROLL_BUILD_TESTS=OFF",
         "-DVKUNROLL_BUILD_BENCH=OFF", "-DVKUNROLL_BUILD_PYTHON=ON", f"-DVKUNROLL_PYTHON={sys.executable}"])
    jobs = os.environ.get("CMAKE_BUILD_PARALLEL_LEVEL") or str(os.cpu_count() or 1)
    run(["cmake", "--build", build_dir, "--target", "vkunroll_python", "vkunroll_cli", "--parallel", jobs])
    return build_dir


def staged_files(build_dir, stage, version):
    """{path in the wheel: file on disk}: `cmake --install --component python` into `stage`, mapped."""
    run(["cmake", "--install", build_dir, "--prefix", stage, "--component", "python"])
    files, data = {}, f"{NAME}-{version}.data"
    for dirpath, _, names in os.walk(stage):
        for n in names:
            path = os.path.join(dirpath, n)
            rel = os.path.relpath(path, stage).replace(os.sep, "/")
            m = re.match(r"lib/python[^/]*/(?:dist|site)-packages/(.*)$", rel)
            files[m.group(1) if m else f"{data}/data/{rel}"] = path
    ext_suffix = sysconfig.get_config_var("EXT_SUFFIX")
    modules = [k for k in files if k.startswith(f"{NAME}/_vkunroll.")]
    if modules != [f"{NAME}/_vkunroll{ext_suffix}"]:
        raise BuildError(f"{build_dir}: the compiled module is {modules or 'missing'}, expected {NAME}/_vkunroll{ext_suffix} "
                         f"for {sys.executable} (build with -DVKUNROLL_PYTHON={sys.executable})")
    if not any(k.endswith(".safetensors") for k in files):
        raise BuildError(f"{build_dir}: `cmake --install --component python` installed no model (models/*.safetensors)")
    cli = os.path.join(build_dir, "vkunroll")
    if not os.path.exists(cli):
        raise BuildError(f"{build_dir}: no vkunroll CLI built (target vkunroll_cli)")
    files[f"{data}/scripts/vkunroll"] = cli
    return files


def record_line(arcname, data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{arcname},sha256={digest},{len(data)}"


def write_wheel(wheel_directory, files, version):
    dist_info = f"{NAME}-{version}.dist-info"
    name = f"{NAME}-{version}-{wheel_tag()}.whl"
    path = os.path.join(wheel_directory, name)
    record = []
    with zipfile.ZipFile(path + ".part", "w", zipfile.ZIP_DEFLATED) as z:
        for arcname in sorted(files):
            data = open(files[arcname], "rb").read()
            info = zipfile.ZipInfo(arcname, date_time=(2026, 1, 1, 0, 0, 0))
            # a regular file's mode: pip keeps the executable bit only where S_IFREG is set too
            info.external_attr = (stat.S_IFREG | (0o755 if os.access(files[arcname], os.X_OK) else 0o644)) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, data)
            record.append(record_line(arcname, data))
        for n, text in dist_info_files(version).items():
            z.writestr(f"{dist_info}/{n}", text)
            record.append(record_line(f"{dist_info}/{n}", text.encode()))
        z.writestr(f"{dist_info}/RECORD", "\n".join(record + [f"{dist_info}/RECORD,,"]) + "\n")
    os.replace(path + ".part", path)  # a failed build leaves no wheel that looks whole
    return name


# ---- the PEP 517 hooks ----------------------------------------------------------------------
def get_requires_for_build_wheel(config_settings=None):
    return []  # CMake, a compiler and the -dev packages come from Debian (scripts/bootstrap.sh)


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    version = cmake_version()
    dist_info = os.path.join(metadata_directory, f"{NAME}-{version}.dist-info")
    os.makedirs(dist_info, exist_ok=True)
    for n, text in dist_info_files(version).items():
        os.makedirs(os.path.dirname(os.path.join(dist_info, n)), exist_ok=True)
        open(os.path.join(dist_info, n), "w", encoding="utf-8").write(text)
    return os.path.basename(dist_info)


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    version = cmake_version()
    given = os.environ.get("VKUNROLL_WHEEL_BUILD_DIR")
    build_dir = given_build_dir(given) if given else full_build()
    with tempfile.TemporaryDirectory(prefix="vkunroll-wheel-") as stage:
        return write_wheel(wheel_directory, staged_files(build_dir, stage, version), version)
