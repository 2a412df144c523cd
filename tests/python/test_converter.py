"""tools/model/convert_checkpoint.py on checkpoints saved by the PyTorch mirror, and `vkunroll infer`
against the mirror on a converted checkpoint (needs VKUNROLL_CLI, set by ctest)."""
import os
import subprocess
import sys

import pytest
import torch

from tools.model import safetensors_io
from tools.model.convert_checkpoint import convert
from tools.model.make_golden import make_inputs, tiny_model
from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig, run_named

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

CONVERTER = [sys.executable, "-m", "tools.model.convert_checkpoint"]  # run from ROOT: tools/ is a package


def run_converter(*args):
    return subprocess.run([*CONVERTER, *map(str, args)], capture_output=True, text=True, cwd=ROOT)


@pytest.fixture(scope="module")
def net():
    return tiny_model()


def test_dataparallel_prefix_in_wrapped_state_dict(tmp_path, net):
    ck = tmp_path / "dp.pth"
    torch.save({"state_dict": {"module." + k: v for k, v in net.state_dict().items()}, "epoch": 7}, ck)
    r = run_converter(ck, tmp_path / "dp.safetensors")
    assert r.returncode == 0, r.stderr
    assert "missing keys (0): none" in r.stdout and "unexpected keys (0): none" in r.stdout
    tensors, meta = safetensors_io.load(str(tmp_path / "dp.safetensors"))
    assert set(tensors) == set(net.state_dict())
    for k, v in net.state_dict().items():
        assert tensors[k].dtype == torch.float32
        assert torch.equal(tensors[k], v), k
    cfg = SelfUnrollConfig.from_metadata(meta)
    assert (cfg.D, cfg.C, cfg.G, cfg.G0, cfg.N, cfg.upnet_width) == (2, 2, 8, 16, 4, 32)
    assert (cfg.flownet.base, cfg.flownet.depth, cfg.fusion_net.depth, cfg.attfusion_net.base) == (4, 4, 3, 8)
    assert cfg.moa and cfg.channel_order == "rgb" and meta["format"] == "vkunroll-selfunroll"


def test_model_key_fp16_and_bgr(tmp_path, net):
    ck = tmp_path / "m.pth"
    torch.save({"model": net.state_dict()}, ck)
    r = run_converter(ck, tmp_path / "m.safetensors", "--fp16", "--channel-order", "bgr")
    assert r.returncode == 0, r.stderr
    tensors, meta = safetensors_io.load(str(tmp_path / "m.safetensors"))
    assert all(t.dtype == torch.float16 for t in tensors.values())
    assert meta["channel_order"] == "bgr"
    # the tiny model's weights are fp16-exact
    assert all(torch.equal(tensors[k].float(), v) for k, v in net.state_dict().items())


def test_missing_moa_converts_to_s_only(tmp_path, net):
    sd = {k: v for k, v in net.state_dict().items() if not k.startswith("attfusion_net.")}
    sd["old_head.weight"] = torch.zeros(3)
    ck = tmp_path / "s.pth"
    torch.save(sd, ck)
    r = run_converter(ck, tmp_path / "s.safetensors")
    assert r.returncode == 0, r.stderr
    assert "SelfUnroll-S only" in r.stdout
    assert "unexpected keys (1): old_head.weight" in r.stdout
    tensors, meta = safetensors_io.load(str(tmp_path / "s.safetensors"))
    assert meta["moa"] == "false" and "old_head.weight" not in tensors
    s_net = SelfUnroll(SelfUnrollConfig.from_metadata(meta))
    s_net.load_state_dict(tensors, strict=True)
    with pytest.raises(ValueError, match="SelfUnroll-S only"):
        x = make_inputs(2, 32, 32, 4, 1)
        s_net(x["rs"], x["ev1"], x["ev2"], x["ev3"], moa=True)


def test_missing_key_and_wrong_shape_fail(tmp_path, net):
    sd = dict(net.state_dict())
    del sd["fusion_net.up_path.1.conv1.0.bias"]
    torch.save(sd, tmp_path / "missing.pth")
    r = run_converter(tmp_path / "missing.pth", tmp_path / "x.safetensors")
    assert r.returncode == 1 and "fusion_net.up_path.1.conv1.0.bias" in r.stdout + r.stderr
    assert not (tmp_path / "x.safetensors").exists()

    sd = dict(net.state_dict())
    sd["RDBs.1.LFF.weight"] = torch.zeros(16, 31, 1, 1)
    torch.save(sd, tmp_path / "shape.pth")
    r = run_converter(tmp_path / "shape.pth", tmp_path / "y.safetensors")
    assert r.returncode == 1 and "RDBs.1.LFF.weight" in r.stderr and "expected (16, 32, 1, 1)" in r.stderr

    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    r = run_converter(tmp_path / "junk.pth", tmp_path / "z.safetensors")
    assert r.returncode == 1 and "junk.pth" in r.stderr


def test_published_configuration_is_inferred(tmp_path):
    net = SelfUnroll()
    assert sum(p.numel() for p in net.parameters()) == 33914185
    ck = tmp_path / "full.pth"
    torch.save({"module." + k: v for k, v in net.state_dict().items()}, ck)
    cfg, missing, unexpected = convert(str(ck), str(tmp_path / "full.safetensors"), fp16=True)
    assert (cfg.D, cfg.C, cfg.G, cfg.G0, cfg.N) == (10, 5, 48, 96, 16)
    assert (cfg.flownet.base, cfg.flownet.depth, cfg.fusion_net.depth, cfg.attfusion_net.depth) == (32, 4, 3, 3)
    assert not missing and not unexpected


CLI = os.environ.get("VKUNROLL_CLI")


@pytest.mark.skipif(not CLI or not os.path.exists(CLI or ""), reason="VKUNROLL_CLI not set (run through ctest)")
@pytest.mark.parametrize("mode,size,backend", [("m", (48, 64), "vulkan"), ("s", (30, 38), "vulkan"),
                                               ("m", (29, 37), "cpu")])
def test_vkunroll_infer_reproduces_the_mirror(tmp_path, net, mode, size, backend):
    ck = tmp_path / "tiny.pth"
    torch.save({"state_dict": {"module." + k: v for k, v in net.state_dict().items()}}, ck)
    assert run_converter(ck, tmp_path / "tiny.safetensors").returncode == 0
    h, w = size
    inputs = make_inputs(2 if mode == "m" else 1, h, w, net.cfg.N, seed=99)
    safetensors_io.save(str(tmp_path / "in.safetensors"), inputs)
    r = subprocess.run([CLI, "infer", "--model", tmp_path / "tiny.safetensors", "--inputs", tmp_path / "in.safetensors",
                        "--out", tmp_path / "out.safetensors", "--mode", mode, "--backend", backend],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    got, _ = safetensors_io.load(str(tmp_path / "out.safetensors"))
    want = run_named(net, inputs, mode)
    assert set(want) <= set(got)
    for k, v in want.items():
        assert got[k].shape == v.shape, k
        err = (got[k].float() - v).abs().max().item()
        assert err <= 1e-4, f"{k}: max abs error {err}"


@pytest.mark.skipif(not CLI or not os.path.exists(CLI or ""), reason="VKUNROLL_CLI not set (run through ctest)")
def test_vkunroll_infer_fp16_is_within_the_fp16_bound(tmp_path, net):
    """--precision fp16 on the Vulkan backend: within tests/test_model_fp16.cpp's bound (1% of
    max(1, |value|)) of the fp32 mirror, and not bit-equal to it (fp16 really ran)."""
    ck = tmp_path / "tiny.pth"
    torch.save({"state_dict": net.state_dict()}, ck)
    assert run_converter(ck, tmp_path / "tiny.safetensors").returncode == 0
    inputs = make_inputs(2, 40, 48, net.cfg.N, seed=7)
    safetensors_io.save(str(tmp_path / "in.safetensors"), inputs)
    r = subprocess.run([CLI, "infer", "--model", tmp_path / "tiny.safetensors", "--inputs", tmp_path / "in.safetensors",
                        "--out", tmp_path / "out.safetensors", "--mode", "m", "--precision", "fp16"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    got, meta = safetensors_io.load(str(tmp_path / "out.safetensors"))
    assert meta["precision"] == "fp16"
    want = run_named(net, inputs, "m")
    for k, v in want.items():
        err = (got[k].float() - v).abs().max().item()
        assert 0 < err <= 0.01 * max(1.0, v.abs().max().item()), f"{k}: max abs error {err}"


@pytest.mark.skipif(not CLI or not os.path.exists(CLI or ""), reason="VKUNROLL_CLI not set (run through ctest)")
def test_vkunroll_infer_bad_inputs_fail_clearly(tmp_path):
    model = os.path.join(ROOT, "tests", "data", "selfunroll_tiny.safetensors")
    inputs = make_inputs(1, 32, 32, 4, seed=5)

    def infer(inp, *extra):
        safetensors_io.save(str(tmp_path / "in.safetensors"), inp)
        return subprocess.run([CLI, "infer", "--model", model, "--inputs", tmp_path / "in.safetensors",
                               "--out", tmp_path / "out.safetensors", "--backend", "cpu", *extra],
                              capture_output=True, text=True)

    r = infer({k: v for k, v in inputs.items() if k != "ev3"})
    assert r.returncode == 65 and "no tensor 'ev3'" in r.stderr  # sysexits EX_DATAERR: bad input data
    r = infer(dict(inputs, ev2=inputs["ev2"][:, :6]))
    assert r.returncode == 65 and "'ev2' has shape 1x6x32x32, expected 1x8x32x32" in r.stderr
    r = infer(inputs, "--mode", "m")
    assert r.returncode == 2 and "even batch" in r.stderr  # usage: --mode m with this batch
    r = infer(inputs, "--precision", "fp16")
    assert r.returncode == 2 and "fp16" in r.stderr
    assert not (tmp_path / "out.safetensors").exists()


def test_mirror_save_and_load_round_trip(tmp_path, net):
    from tools.model.selfunroll_torch import load_model, save_model
    save_model(net, str(tmp_path / "w.safetensors"))
    back = load_model(str(tmp_path / "w.safetensors"))
    assert back.cfg.to_metadata() == net.cfg.to_metadata()
    for k, v in net.state_dict().items():
        assert torch.equal(back.state_dict()[k], v), k
