"""A clone needs nothing beside it (issue 57, item 1): no file of the project names a folder outside
the repository; the real recordings the tests read are in tests/data/real/ with the hashes its
README gives; every skip in the tests is one of the known, environment-only skips below, so a clone
runs as many tests as CI; and docs/network.md describes the checkpoint keys of the PyTorch mirror."""
import hashlib
import os
import pathlib
import re
import subprocess

ROOT = pathlib.Path(__file__).resolve().parents[2]
# Spelled in pieces, so that this file names neither.
OUTSIDE = ".." + "/shared"
OUTSIDE_DEFINE = "VKUNROLL_" + "SHARED_DIR"
TEXT_SUFFIXES = {"", ".md", ".txt", ".cmake", ".cpp", ".hpp", ".h", ".c", ".py", ".sh", ".json", ".toml", ".cff",
                 ".yml", ".yaml", ".comp", ".glsl", ".in", ".cfg", ".smk"}


def project_files():
    """The tracked files (git ls-files), or every file outside build folders without git."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, check=True, capture_output=True).stdout
        files = [ROOT / p for p in out.decode().split("\0") if p]
        files += [ROOT / p for p in subprocess.run(["git", "ls-files", "-z", "--others", "--exclude-standard"],
                                                   cwd=ROOT, check=True, capture_output=True).stdout.decode().split("\0")
                  if p]
        return [f for f in files if f.is_file()]
    except (OSError, subprocess.CalledProcessError):  # a copy without git: every file outside build folders
        files = []
        for folder, dirs, names in os.walk(ROOT):
            dirs[:] = [d for d in dirs if d not in (".git", "build", "__pycache__")]
            files += [pathlib.Path(folder) / n for n in names]
        return files


def test_no_file_names_a_folder_outside_the_repository():
    found = []
    for path in project_files():
        if path.suffix not in TEXT_SUFFIXES and path.name not in ("CMakeLists.txt", "Snakefile", "run"):
            continue
        try:
            text = path.read_text(errors="replace")
        except OSError:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if OUTSIDE in line or OUTSIDE_DEFINE in line:
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()[:120]}")
    assert not found, "names a folder a user's clone does not have:\n" + "\n".join(found)


def test_real_recordings_are_in_the_checkout_as_the_readme_lists_them():
    real = ROOT / "tests" / "data" / "real"
    readme = (real / "README.md").read_text()
    hashes = dict((name, digest) for digest, name in re.findall(r"^([0-9a-f]{64})  (\S+)$", readme, re.M))
    assert set(hashes) == {"evt3_sample.raw", "sample.aedat4"}, hashes
    for name, digest in hashes.items():
        data = (real / name).read_bytes()
        assert hashlib.sha256(data).hexdigest() == digest, name
        assert f"| `{name}` | {len(data):,} |" in readme, f"README gives another size for {name}"
    for path in real.iterdir():  # nothing unlisted: each file's source and license are in the README
        assert path.name in hashes or path.name == "README.md" or path.name in re.findall(r"\((LICENSE[^)]*)\)", readme), \
            path.name


# Every skip in tests/: (file, text of the skip) -> why a clone and CI skip it alike. None depends on
# a file outside the repository. A new skip must be added here, with its reason; a removed one, taken out.
ALLOWED_SKIPS = {
    # device: what the device in use can do (CI: lavapipe and SwiftShader)
    ("test_conv2d_coopmat.cpp", "GTEST_SKIP() << why"): "NVIDIA only: VK_NV_cooperative_matrix",
    ("test_conv2d_coopmat.cpp", "no subgroup size control"): "device feature",
    ("test_conv2d_igemm.cpp", "VKUNROLL_EXPECT_SUBGROUP unset"): "runs in the subgroup4.op_parity pass only",
    ("test_conv_choice_cli.cpp", "on a GPU both choices are the GPU rule"): "device type",
    ("test_runtime.cpp", "device has no timestamps"): "device feature",
    ("test_command_stream.cpp", "the device writes no timestamps"): "device feature",
    ("test_physics_variant.py", "a CUDA device is present"): "device present",
    ("test_devices.cpp", "the swiftshader label's test"): "runs in the swiftshader label only",
    # the GPU device bundle (docs/gpu_nvidia.md) carries the test binary without the CLI
    ("test_conv_choice_cli.cpp", "the device bundle carries no CLI"): "device bundle",
    ("test_conv_choice.cpp", "the device bundle carries no CLI"): "device bundle",
    # Debian packages that `bootstrap.sh test` installs
    ("test_sequence.cpp", "with numpy is needed"): "package",
    ("test_event_readers.cpp", "HDF5 Blosc filter"): "package",
    ("test_event_readers.cpp", "with numpy is not available"): "package",
    ("test_event_readers.cpp", "with h5py and numpy is not available"): "package",
    ("test_workflow.py", "snakemake (Debian package) not installed"): "package",
    ("test_output_rule.py", "no torch"): "package",
    ("test_output_rule.py", "no python3-rosbag"): "package",
    ("test_option_rules.py", "no torch"): "package",
    ("test_option_rules.py", "no python3-rosbag"): "package",
    ("test_bindings_rosbag.py", 'importorskip("rosbag")'): "package",
    ("test_issue58_args.py", 'importorskip("PIL")'): "package",
    # run outside ctest, which builds and names the module, the CLI and the build folder
    ("test_output_rule.py", 'importorskip("vkunroll")'): "outside ctest",
    ("test_follow_rules.py", 'importorskip("vkunroll")'): "outside ctest",
    ("test_follow.py", 'importorskip("vkunroll")'): "outside ctest",
    ("test_python_arguments.py", 'importorskip("vkunroll")'): "outside ctest",
    ("test_issue58_args.py", 'importorskip("vkunroll")'): "outside ctest",
    ("test_output_paths.py", 'importorskip("vkunroll")'): "outside ctest",
    ("test_wheel.py", "run through ctest"): "outside ctest",
    ("test_train.py", "run through ctest"): "outside ctest",
    ("test_version.py", "run through ctest"): "outside ctest",
    ("test_second_generator.py", "run through ctest"): "outside ctest",
    ("test_natural_data.py", "ctest sets it"): "outside ctest",
    ("test_physics_variant.py", "run through ctest"): "outside ctest",
    ("test_converter.py", "run through ctest"): "outside ctest",
    # one parameter of a parametrized test that does not apply
    ("test_option_rules.py", "a file output may replace a file"): "case",
}
SKIP = re.compile(r"GTEST_SKIP|pytest\.skip\(|skipif\(|importorskip\(|unittest\.skip")


def test_every_skip_is_a_known_environment_skip():
    sites, unknown = [], []
    for path in sorted((ROOT / "tests").rglob("*")):
        if path.suffix not in (".cpp", ".hpp", ".py") or path.name == pathlib.Path(__file__).name:
            continue
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if not SKIP.search(line):
                continue
            keys = [k for k in ALLOWED_SKIPS if k[0] == path.name and k[1] in line]
            (sites if keys else unknown).append((path.name, n, line.strip(), keys))
    assert not unknown, ("skips that are not known environment skips (a test that needs a file must find it in the "
                         "checkout and fail without it):\n" + "\n".join(f"{f}:{n}: {t}" for f, n, t, _ in unknown))
    used = {k for *_, keys in sites for k in keys}
    assert used == set(ALLOWED_SKIPS), f"listed skips no test has any more: {sorted(set(ALLOWED_SKIPS) - used)}"
    assert len(sites) == 40, f"{len(sites)} skip sites (update the count with the list)"


def doc_key_patterns():
    text = (ROOT / "docs" / "network.md").read_text()
    table = text.split("## Checkpoint keys", 1)[1].split("\n## ", 1)[0]
    patterns = set()
    for row in re.findall(r"^\| (`[^|]*) \|", table, re.M):
        patterns.update(re.findall(r"`([^`]+)`", row))
    return patterns, text


def test_network_doc_names_every_checkpoint_key_of_the_mirror():
    import sys
    sys.path.insert(0, str(ROOT))
    from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig
    state = SelfUnroll(SelfUnrollConfig()).state_dict()
    found = set()
    for key in state:
        p = re.sub(r"\.(weight|bias)$", "", key)
        p = re.sub(r"^RDBs\.\d+", "RDBs.d", p)
        p = re.sub(r"\.convs\.\d+", ".convs.c", p)
        p = re.sub(r"(down_path|up_path)\.\d+", r"\1.i", p)
        p = re.sub(r"^(flownet|fusion_net|attfusion_net)\.", "<unet>.", p)
        found.add(p)
    documented, text = doc_key_patterns()
    assert found - documented == set(), f"keys the page does not give: {sorted(found - documented)}"
    assert documented - found == set(), f"keys the page gives that the model lacks: {sorted(documented - found)}"
    params = sum(t.numel() for t in state.values())
    assert f"{params:,} parameters" in text, params
    assert f"{len(state)} tensors" in text, len(state)


def test_the_paper_is_cited_by_its_reference():
    cff = (ROOT / "CITATION.cff").read_text()
    assert "2304.06930" in cff
    for page in ("README.md", "docs/network.md"):
        assert "arXiv:2304.06930" in (ROOT / page).read_text(), page
