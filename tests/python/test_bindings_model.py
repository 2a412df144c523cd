"""vkunroll (Python): Model.run on the golden fixtures matches the PyTorch mirror within the C++
tests' bound (1e-4, tests/test_model.cpp) on lavapipe and on the CPU backend, and equals
`vkunroll infer`; the GIL is released during a model call; errors are the right Python types
with the library's messages; the library's stderr goes to logging."""
import json
import logging
import os
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import vkunroll

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DATA = os.path.join(ROOT, "tests", "data")
TINY = os.path.join(DATA, "selfunroll_tiny.safetensors")
TINY_PHYSICS = os.path.join(DATA, "selfunroll_tiny_physics.safetensors")
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))
FIXTURES = [("selfunroll_golden_s_64x48.safetensors", "s"), ("selfunroll_golden_m_64x48.safetensors", "m"),
            ("selfunroll_golden_m_37x29.safetensors", "m")]


def load_safetensors(path):
    """F16/F32 tensors of a safetensors file as float32 numpy arrays."""
    blob = open(path, "rb").read()
    n = struct.unpack("<Q", blob[:8])[0]
    header = json.loads(blob[8:8 + n])
    out = {}
    for name, e in header.items():
        if name == "__metadata__":
            continue
        b, en = e["data_offsets"]
        dt = {"F16": np.float16, "F32": np.float32}[e["dtype"]]
        out[name] = np.frombuffer(blob[8 + n + b:8 + n + en], dtype=dt).reshape(e["shape"]).astype(np.float32)
    return out


@pytest.fixture(scope="module")
def models():
    return {"vulkan": vkunroll.Model.load(TINY), "cpu": vkunroll.Model.load(TINY, backend="cpu")}


@pytest.mark.parametrize("fixture,mode", FIXTURES)
@pytest.mark.parametrize("backend", ["vulkan", "cpu"])
def test_golden_fixtures(models, fixture, mode, backend):
    g = load_safetensors(os.path.join(DATA, fixture))
    model = models[backend]
    assert model.backend == backend and model.config["N"] == 4 and model.config["moa"]
    out = model.run(g["rs"], g["ev1"], g["ev2"], g["ev3"], mode=mode)
    assert sorted(out) == sorted(["sys", "E", "flow", "warped", "fused"] + (["m", "out"] if mode == "m" else []))
    for name, arr in out.items():
        assert arr.dtype == np.float32 and arr.shape == g[name].shape, name
        err = float(np.abs(arr - g[name]).max())
        assert err <= 1e-4, f"{name}: max |diff| {err} on {backend}, {fixture}"


@pytest.mark.parametrize("fixture,mode", [("selfunroll_golden_physics_s_64x48.safetensors", "s"),
                                          ("selfunroll_golden_physics_m_37x29.safetensors", "m")])
@pytest.mark.parametrize("backend", ["vulkan", "cpu"])
def test_physics_variant_golden_fixtures(fixture, mode, backend):
    g = load_safetensors(os.path.join(DATA, fixture))
    model = vkunroll.Model.load(TINY_PHYSICS, backend=backend)
    assert model.config["physics_input"] and model.config["gamma"] == 2.2
    assert model.config["physics_contrast"] == "estimate"
    out = model.run(g["rs"], g["ev1"], g["ev2"], g["ev3"], mode=mode, phys=g["phys"])
    for name, arr in out.items():
        err = float(np.abs(arr - g[name]).max())
        assert err <= 1e-4, f"{name}: max |diff| {err} on {backend}, {fixture}"
    with pytest.raises(ValueError, match="'phys'"):
        model.run(g["rs"], g["ev1"], g["ev2"], g["ev3"], mode=mode)


def test_fp16_golden_fixture_within_the_cpp_bound():
    """fp16 on lavapipe against the fp32 mirror: within 1% of the output's scale, the bound of
    tests/test_model_fp16.cpp, and not bit-equal to fp32 (fp16 ran)."""
    g = load_safetensors(os.path.join(DATA, "selfunroll_golden_m_37x29.safetensors"))
    model = vkunroll.Model.load(TINY, precision="fp16")
    assert model.precision == "fp16"
    out = model.run(g["rs"], g["ev1"], g["ev2"], g["ev3"], mode="m", precision="fp16")
    for name, arr in out.items():
        err = float(np.abs(arr - g[name]).max())
        scale = max(1.0, float(np.abs(g[name]).max()))
        assert 0 < err <= 0.01 * scale, f"{name}: max |diff| {err} (scale {scale})"
    with pytest.raises(ValueError, match="precision fp32 asked of the vulkan backend, which runs in fp16"):
        model.run(g["rs"], g["ev1"], g["ev2"], g["ev3"], mode="m", precision="fp32")


def test_run_equals_cli_infer(models, tmp_path):
    fixture = os.path.join(DATA, "selfunroll_golden_m_64x48.safetensors")
    out = tmp_path / "out.safetensors"
    subprocess.run([CLI, "infer", "--model", TINY, "--inputs", fixture, "--out", str(out), "--mode", "m"],
                   check=True, capture_output=True)
    cli = load_safetensors(str(out))
    g = load_safetensors(fixture)
    ours = models["vulkan"].run(g["rs"], g["ev1"], g["ev2"], g["ev3"], mode="m")
    assert sorted(ours) == sorted(cli)
    for name in ours:
        np.testing.assert_array_equal(ours[name], cli[name], err_msg=name)
    only = models["vulkan"].run(g["rs"], g["ev1"], g["ev2"], g["ev3"], mode="m", outputs=["out"])
    assert list(only) == ["out"]


def test_model_call_releases_the_gil(models):
    g = load_safetensors(os.path.join(DATA, "selfunroll_golden_s_64x48.safetensors"))
    model = models["vulkan"]
    batch = [np.repeat(g[k], 8, axis=0) for k in ("rs", "ev1", "ev2", "ev3")]
    model.run(*batch)  # warm: every pipeline compiled
    count = [0]
    stop = threading.Event()

    def counter():
        while not stop.is_set():
            count[0] += 1

    th = threading.Thread(target=counter)
    th.start()
    try:
        time.sleep(0.05)
        t0, c0 = time.perf_counter(), count[0]
        model.run(*batch)
        t1, c1 = time.perf_counter(), count[0]
        # Control: a C call that keeps the GIL (sum over a range) starves the thread.
        h0 = count[0]
        sum(range(20_000_000))
        held = count[0] - h0
    finally:
        stop.set()
        th.join()
    # Holding the GIL, the call would leave the counter where it was (a switch interval at most).
    assert t1 - t0 > 0.05, "the call is long enough to tell"
    assert c1 - c0 > 10000, f"the thread counted {c1 - c0} times during a {t1 - t0:.2f} s model call"
    # The control is not zero on a loaded machine: after the GIL-holding call the counter may run
    # until the main thread is scheduled again (seen: 1/9 of the model call's count under ctest -j2).
    assert held < (c1 - c0) / 3, f"control: {held} counts while a GIL-holding call ran, {c1 - c0} during the model call"


def test_errors_have_python_types_and_library_messages(models, tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.safetensors"):
        vkunroll.Model.load(tmp_path / "nope.safetensors")
    (tmp_path / "junk.safetensors").write_bytes(b"\x01\x00\x00\x00\x00\x00\x00\x00{")
    with pytest.raises(ValueError, match="junk.safetensors"):
        vkunroll.Model.load(tmp_path / "junk.safetensors")
    with pytest.raises(FileNotFoundError, match="path=.*missing.raw.: no such file"):
        vkunroll.read_events(tmp_path / "missing.raw")
    bad = tmp_path / "bad.txt"
    bad.write_text("# width 10 height 10\n0 1 1 1\n5 2 2 0\n3 12 2 1\n")
    with pytest.raises(ValueError, match="bad.txt") as e:
        vkunroll.read_events(bad)
    assert "record" in str(e.value) or "line" in str(e.value)
    assert len(vkunroll.read_events(bad, on_bad="drop")) == 2
    with pytest.raises(ValueError, match="on_bad='maybe': expected one of 'error', 'drop', 'sort'"):
        vkunroll.read_events(bad, on_bad="maybe")
    with pytest.raises(FileNotFoundError, match="no-such-sequence"):
        vkunroll.Sequence.open(tmp_path / "no-such-sequence")
    z = np.zeros((1, 3, 16, 16), np.float32)
    with pytest.raises(ValueError, match="ev1 has 3 channels, the model expects 8"):
        models["cpu"].run(z, z, z, z)
    e8 = np.zeros((1, 8, 16, 16), np.float32)
    with pytest.raises(ValueError, match="precision fp16 asked of the cpu backend, which runs in fp32"):
        models["cpu"].run(z, e8, e8, e8, precision="fp16")
    with pytest.raises(ValueError, match="precision fp16 needs backend vulkan"):
        vkunroll.Model.load(TINY, backend="cpu", precision="fp16")
    with pytest.raises(ValueError, match="precision='fp8': expected one of 'fp32', 'fp16'"):
        vkunroll.Model.load(TINY, precision="fp8")
    with pytest.raises(ValueError, match="not the physics-informed variant"):
        models["cpu"].run(z, e8, e8, e8, phys=z)
    with pytest.raises(ValueError, match="mode='x'"):
        models["cpu"].run(z, e8, e8, e8, mode="x")
    with pytest.raises(ValueError, match="no device name contains it"):
        vkunroll.Context(device="no-such-gpu")
    tm = vkunroll.RowTiming(16, 0, 1, 10)
    with pytest.raises(ValueError, match="mode='x'"):
        vkunroll.unroll(([np.zeros((16, 16, 3))], [tm], np.zeros(0, vkunroll.EVENT_DTYPE)), mode="x")


def test_no_driver_is_a_runtime_error():
    env = dict(os.environ, VK_DRIVER_FILES="/nonexistent/icd.json", VK_ICD_FILENAMES="/nonexistent/icd.json")
    code = ("import vkunroll\n"
            "try:\n    vkunroll.devices()\nexcept RuntimeError as e:\n    print('RuntimeError:', e)\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.startswith("RuntimeError:") and "lavapipe" in out, out


def test_library_output_goes_to_logging(caplog, capfd):
    with caplog.at_level(logging.INFO, logger="vkunroll"):
        ctx = vkunroll.Context()
    assert any(r.name == "vkunroll" and r.message.startswith("device [") and ctx.name in r.message for r in caplog.records)
    assert "device [" not in capfd.readouterr().err  # not on the process's stderr


def test_gate_radius_is_set_at_load_as_the_cli_sets_it():
    """Model.load(gate_radius=N) runs the variant's event gate at N, as `unroll --gate-radius N`:
    None and the weights' own radius give the same outputs, a wider gate lets the network change
    more pixels; a radius for a model without a gate, or out of range, is refused."""
    shipped = os.path.join(ROOT, "models", "selfunroll_small_physics.safetensors")
    own = vkunroll.Model.load(shipped, backend="cpu")
    r = own.config["physics_gate"]
    assert r >= 0 and vkunroll.Model.load(TINY, backend="cpu").config["physics_gate"] == -1
    rng = np.random.default_rng(5)
    h, w, ev = 32, 32, 2 * own.config["N"]
    rs, phys = rng.random((1, 3, h, w), dtype=np.float32), rng.random((1, 3, h, w), dtype=np.float32)
    evs = [np.zeros((1, ev, h, w), np.float32) for _ in range(3)]
    evs[0][0, 0, 16, 16] = evs[1][0, 1, 16, 16] = 3.0  # one pixel with events: the gate decides how far the network reaches
    def fused(model):
        return model.run(rs, *evs, mode="s", phys=phys, outputs=["fused"])["fused"]
    same = vkunroll.Model.load(shipped, backend="cpu", gate_radius=r)
    assert same.config["physics_gate"] == r
    np.testing.assert_array_equal(fused(same), fused(own))
    wide = vkunroll.Model.load(shipped, backend="cpu", gate_radius=r + 3)
    assert wide.config["physics_gate"] == r + 3
    changed = lambda m: int((np.abs(fused(m) - np.clip(phys, 0, 1)) > 0).any(axis=1).sum())  # noqa: E731
    assert changed(wide) > changed(own) > 0
    with pytest.raises(ValueError, match="no event gate"):
        vkunroll.Model.load(TINY, backend="cpu", gate_radius=1)
    for bad in (16, -2, "2", True, 1.0):
        with pytest.raises(ValueError, match="gate_radius"):
            vkunroll.Model.load(shipped, backend="cpu", gate_radius=bad)
