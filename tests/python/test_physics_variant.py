"""The physics unroller in NumPy (tools/model/physics_numpy.py) against `vkunroll unroll --mode physics`,
the physics-informed variant of the mirror (starts exactly at the physics estimate, export,
metadata, converter), the sample cache, and a CI-sized adaptation to one recording whose
self-supervised loss falls without ground truth being read."""
import json
import os
import random
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from tools.model import convert_checkpoint
from tools.eval import natural_eval
from tools.model import physics_numpy as pn
from tools.model import safetensors_io
from tools.train import train
from tools.train import train_data
from tools.model import selfunroll_torch
from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig, infer_config, load_model
from tools.data.sequence_data import Sequence, read_image
from test_train import edi_pixel, write_sequence  # tests/python is on sys.path under pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))

CLI = os.environ.get("VKUNROLL_CLI")
TRAIN = [sys.executable, "-m", "tools.train.train"]  # run from ROOT: tools/ is a package
needs_cli = pytest.mark.skipif(not CLI or not os.path.exists(CLI or ""), reason="VKUNROLL_CLI not set (run through ctest)")


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    return write_sequence(str(tmp_path_factory.mktemp("pv") / "s0"))


# ---- physics ---------------------------------------------------------------------------------------
def test_log_ratio_matches_the_cpp_formula_for_rs_targets(seq_dir):
    """Per-row targets (the RS -> RS passes of training) and a GS source window, pixel by pixel
    against the C++ loop (edi_pixel), which the scalar-t* case reduces to."""
    s = Sequence(seq_dir)
    s1, e1 = s.row_times(0)
    s2, _ = s.row_times(1)
    t_star = s.gt[1][1]
    ts = np.full(s.height, t_star)
    crop = (4, 6, 40, 30)
    ev = s.events_in(min(s1.min(), t_star) - 1, max(s2.max(), e1.max(), t_star + s.exposure) + 1, crop)
    t, x, y, p = s.events
    for src_s, src_e, tgt in ((s1, e1, s2), (ts, ts + s.exposure, s1), (s1, e1, t_star)):
        lr = pn.physics_log_ratio(ev, src_s, src_e, tgt, 0.23, crop)
        tgt_rows = np.full(s.height, t_star) if np.ndim(tgt) == 0 else tgt
        checked = 0
        for px, py in ((5, 7), (20, 10), (43, 35), (30, 20), (10, 30)):
            T0 = tgt_rows[py]
            S, E = np.float32(src_s[py] - T0), np.float32(src_e[py] - T0)
            sel = (x == px) & (y == py) & (t >= min(src_s[py], T0)) & (t <= max(src_e[py], T0))
            taus = list(np.float32(t[sel] - T0).astype(np.float64))
            want = edi_pixel(taus, [1 if q else -1 for q in p[sel]], float(S), float(E), float(np.float32(0.23)))
            np.testing.assert_allclose(lr[py - crop[1], px - crop[0]], want, rtol=1e-6, atol=1e-9)
            checked += int(sel.sum() > 0)
        assert checked >= 3


@pytest.mark.parametrize("log_offset", [0.0, 0.001, 0.05])
def test_torch_log_ratio_applies_as_the_numpy_formula(log_offset):
    """apply_log_ratio_torch (the variant's physics input, differentiable) against apply_log_ratio (the
    C++ formula), at offset 0 and at fitted offsets, with dark, zero and capped pixels."""
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 1, (1, 3, 9, 11)).astype(np.float32)
    img[0, :, 0, :3] = 0.0
    lr = rng.normal(0, 1.5, (1, 1, 9, 11)).astype(np.float32)
    lr[0, 0, 1, :2] = 30.0  # past max_value: capped
    want = pn.apply_log_ratio(img[0], lr[0, 0], 2.2, log_offset=log_offset)
    got = pn.apply_log_ratio_torch(torch.from_numpy(img).double(), torch.from_numpy(lr).double(), 2.2,
                                   log_offset=log_offset)[0].numpy()
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=2e-6)


@needs_cli
def test_physics_numpy_equals_vkunroll_unroll_physics(tmp_path):
    """Same contrast estimate and the same images as the CLI (CPU reference and Vulkan kernel):
    within 2e-5, i.e. the 16-bit PNG quantization (7.6e-6) plus float32 rounding."""
    seq = tmp_path / "sim"
    r = subprocess.run([CLI, "simulate", "--out", seq, "--size", "96x72", "--frames", "3", "--gt-per-frame", "2",
                        "--seed", "5", "--motion", "mixed", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    s = Sequence(str(seq))
    frames = list(range(s.num_frames))
    for extra, backend in (([], "cpu"), ([], "vulkan"), (["--contrast", "0.31", "--gamma", "1"], "vulkan")):
        out = tmp_path / f"out_{backend}_{len(extra)}"
        r = subprocess.run([CLI, "unroll", seq, "--out", out, "--mode", "physics", "--times", "gt", "--no-video",
                            "--bit-depth", "16", "--backend", backend, "--quiet"] + extra, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        summ = json.load(open(out / "summary.json"))
        gamma = 1.0 if extra else pn.meta_gamma(s)
        c, eps = (0.31, 0.0) if extra else pn.estimate_physics(s, frames, gamma)
        assert abs(summ["physics"]["contrast"] - c) < 1e-6 and abs(summ["physics"]["gamma"] - gamma) < 1e-6
        assert abs(summ["physics"]["log_offset"] - eps) < 1e-9, (summ["physics"], eps)
        rows = [l.split(",") for l in open(out / "metrics.csv").read().splitlines()[1:]]
        assert len(rows) == len(s.gt)
        for row in rows:
            k, t = int(row[0]), float(row[1])
            assert pn.frame_for_time(s, frames, t) == k
            # tools/eval/natural_eval.py's metrics are host/metrics.cpp's (RS input vs ground truth: both PNGs)
            gt = read_image(row[4])
            assert abs(natural_eval.psnr(s.frame(k), gt) - float(row[7])) < 1e-4
            assert abs(natural_eval.ssim(s.frame(k), gt) - float(row[8])) < 1e-5
            mine = np.clip(pn.unroll_physics(s, k, t, c, gamma, log_offset=eps), 0, 1)
            cpp = read_image(str(out / row[3]))
            err = float(np.abs(mine - cpp).max())
            assert err <= 2e-5, (backend, extra, t, err)


# ---- the variant -------------------------------------------------------------------------------------
def tiny_variant(seed=1):
    cfg = train.make_config("tiny")
    cfg.physics_input, cfg.gamma = True, 2.2
    net = SelfUnroll(cfg)
    train.init_model(net, seed)
    return net


def random_inputs(cfg, b=2, h=40, w=56, seed=0):
    g = torch.Generator().manual_seed(seed)
    rs = 0.05 + 0.9 * torch.rand(b, 3, h, w, generator=g)
    ev = [torch.randint(0, 3, (b, 2 * cfg.N, h, w), generator=g).float() for _ in range(3)]
    phys = (rs * torch.exp(0.3 * torch.randn(b, 1, h, w, generator=g))).clamp(max=1.4)
    return rs, ev, phys


def test_variant_starts_exactly_at_the_physics_estimate():
    net = tiny_variant()
    rs, ev, phys = random_inputs(net.cfg)
    with torch.no_grad():
        sys_, E, flow, warped, fused, m, out = net(rs, *ev, phys=phys)
    want = phys.clamp(0, 1)
    assert float(E.abs().max()) == 0.0
    assert float((sys_ - want).abs().max()) == 0.0
    assert float((fused - want).abs().max()) < 1e-6
    assert out is not None and float((out - (m * want[:1] + (1 - m) * want[1:])).abs().max()) < 1e-6
    with pytest.raises(ValueError, match="needs phys"):
        net(rs, *ev)
    plain = SelfUnroll(train.make_config("tiny"))
    with pytest.raises(ValueError, match="no physics input"):
        plain(rs, *ev, phys=phys)


def test_lifting_a_trained_model_keeps_its_trunk_and_starts_at_physics():
    src = SelfUnroll(train.make_config("tiny"))
    train.init_model(src, 4)
    with torch.no_grad():
        for p in src.parameters():
            p.add_(0.01 * torch.randn_like(p))  # "trained": not an init any more
    net = train.lift_to_physics(src, 2)
    assert net.cfg.physics_input and net.cfg.gamma == 2.2
    w = net.SFENet1.weight
    n_old = src.SFENet1.weight.shape[1]
    assert torch.equal(w[:, :n_old], src.SFENet1.weight) and float(w[:, n_old:].abs().max()) == 0.0
    assert torch.equal(net.flownet.head.weight, src.flownet.head.weight)
    assert float(net.attfusion_net.pred.bias.abs().max()) == 0.0  # MOA restarts near m = 0.5
    rs, ev, phys = random_inputs(net.cfg, seed=3)
    with torch.no_grad():
        fused = net(rs, *ev, phys=phys, moa=False)[4]
    assert float((fused - phys.clamp(0, 1)).abs().max()) < 1e-6


def test_variant_export_metadata_and_shapes(tmp_path):
    net = tiny_variant()
    path = str(tmp_path / "v.safetensors")
    train.export(net, path, {"data": "test"})
    tensors, md = safetensors_io.load(path)
    assert md["physics_input"] == "true" and md["physics_contrast"] == "estimate" and float(md["gamma"]) == 2.2
    assert tuple(tensors["SFENet1.weight"].shape)[1] == 4 * (3 + 6 * net.cfg.N + 3)
    shapes = infer_config({k: tuple(v.shape) for k, v in tensors.items()})
    assert shapes.physics_input and shapes.N == net.cfg.N
    back = load_model(path)
    rs, ev, phys = random_inputs(net.cfg, b=1)
    with torch.no_grad():
        a, b = net(rs, *ev, phys=phys, moa=False)[4], back(rs, *ev, phys=phys, moa=False)[4]
    assert torch.equal(a, b)
    # the published family: unchanged shapes and no variant keys in its metadata
    pub = SelfUnrollConfig()
    assert "physics_input" not in pub.to_metadata() and "gamma" not in pub.to_metadata()
    assert SelfUnroll(pub).SFENet1.weight.shape[1] == 396
    assert not infer_config({k: tuple(v.shape) for k, v in SelfUnroll(pub).state_dict().items()}).physics_input


def test_event_gate_keeps_physics_where_no_event_is_near():
    """physics_gate = r: fused = clamp(phys) exactly at pixels with no ev1/ev2 event within the
    (2r+1)^2 square, the network's fused result elsewhere; metadata round trip and its errors."""
    net = tiny_variant()
    with torch.no_grad():
        for prm in net.parameters():
            prm.add_(0.05 * torch.randn_like(prm))  # trained: fused is not physics any more
    rs, ev, phys = random_inputs(net.cfg, seed=4)
    for e in ev[:2]:
        e.zero_()
    ev[0][0, 1, 10, 20] = 2.0  # one pixel with events in item 0; ev3 keeps its events (not gated on)
    want = phys.clamp(0, 1)
    with torch.no_grad():
        free = net(rs, *ev, phys=phys, moa=False)[4]
        net.cfg.physics_gate = 1
        gated = net(rs, *ev, phys=phys, moa=False)[4]
    near = torch.zeros_like(gated[:, :1], dtype=torch.bool)
    near[0, 0, 9:12, 19:22] = True
    assert float((free - want).abs().max()) > 1e-3
    assert torch.equal(gated[~near.expand_as(gated)], want[~near.expand_as(want)])
    assert torch.equal(gated[near.expand_as(gated)], free[near.expand_as(free)])
    md = net.cfg.to_metadata()
    assert md["physics_gate"] == "1" and SelfUnrollConfig.from_metadata(md).physics_gate == 1
    assert "physics_gate" not in tiny_variant().cfg.to_metadata()
    for bad in ("-1", "two"):
        with pytest.raises(ValueError, match="physics_gate"):
            SelfUnrollConfig.from_metadata({**md, "physics_gate": bad})
    with pytest.raises(ValueError, match="physics_gate"):
        SelfUnrollConfig.from_metadata({**SelfUnrollConfig().to_metadata(), "physics_gate": "1"})


def test_gate_radii_give_each_item_its_own_radius(tmp_path):
    """forward(gate_radii=[r0, r1, ...]): item i is gated as a model with physics_gate = r_i gates
    it (training at the radius `--gate-radius auto` picks per recording); the radii file's errors."""
    net = tiny_variant()
    with torch.no_grad():
        for prm in net.parameters():
            prm.add_(0.05 * torch.randn_like(prm))
    rs, ev, phys = random_inputs(net.cfg, seed=5)
    for e in ev[:2]:
        e.zero_()
    for b in range(rs.shape[0]):
        ev[0][b, 1, 10, 20] = 2.0  # one event per item: radius 1 and 2 gate different rings
    with torch.no_grad():
        alone = {}
        for r in (1, 2):
            net.cfg.physics_gate = r
            alone[r] = net(rs, *ev, phys=phys, moa=False)[4]
        mixed = net(rs, *ev, phys=phys, moa=False, gate_radii=[2, 1])[4]
    assert not torch.equal(alone[1][0], alone[2][0])
    assert torch.equal(mixed[0], alone[2][0]) and torch.equal(mixed[1], alone[1][1])
    assert train_data.load_gate_radii(None) == {}
    bad = tmp_path / "radii.json"
    bad.write_text('{"/x": {"frame_noise": 0.1}}')
    with pytest.raises(train.DataError, match="radii.json.*radius"):
        train_data.load_gate_radii(str(bad))


def test_learned_confidence_starts_near_the_input_model_and_blends_per_pixel():
    """add_confidence: the same weights plus a 4th fusion_net channel c = hardsigmoid(2.9) = 0.983
    at the start, fused = c * network + (1 - c) * phys per pixel; the gate still keeps physics
    exactly where no event is near; metadata and shapes say it."""
    net = perturbed_variant()
    net.cfg.physics_gate = 1
    rs, ev, phys = random_inputs(net.cfg, seed=4)
    keep = (torch.rand(1, 1, rs.shape[2], rs.shape[3], generator=torch.Generator().manual_seed(2)) < 0.05).float()
    ev = [ev[0] * keep, ev[1] * keep, ev[2]]
    with torch.no_grad():
        base = net(rs, *ev, phys=phys, moa=False)[4]
        lifted = selfunroll_torch.add_confidence(net)
        start = lifted(rs, *ev, phys=phys, moa=False)[4]
        c0 = float(torch.nn.functional.hardsigmoid(torch.tensor(2.9)))
        physc = phys.clamp(0, 1)
        assert float((start - (c0 * base + (1 - c0) * physc)).abs().max()) < 1e-5
        varied = with_varied_confidence(net)
        varied.cfg.physics_gate = -1
        sys_, _, flow, warped = varied(rs, *ev, phys=phys, moa=False)[:4]
        fused4 = varied.fusion_net(torch.cat([sys_, warped, flow, ev[2], rs], 1))
        c = torch.nn.functional.hardsigmoid(fused4[:, 3:4])
        assert float(c.min()) < 0.05 and float(c.max()) > 0.95  # the blend really varies
        want = c * fused4[:, :3] + (1 - c) * physc
        assert float((varied(rs, *ev, phys=phys, moa=False)[4] - want).abs().max()) < 1e-5
        varied.cfg.physics_gate = 1
        gated = varied(rs, *ev, phys=phys, moa=False)[4]
        g = selfunroll_torch.event_gate(ev[0], ev[1], 1).expand_as(gated) > 0
        assert torch.equal(gated[~g], physc[~g]) and int((~g).sum()) > 0
    md = varied.cfg.to_metadata()
    assert md["physics_confidence"] == "true" and SelfUnrollConfig.from_metadata(md).physics_confidence
    assert "physics_confidence" not in net.cfg.to_metadata()
    shapes = {k: tuple(v.shape) for k, v in varied.state_dict().items()}
    assert selfunroll_torch.infer_config(shapes).physics_confidence
    with pytest.raises(ValueError, match="physics_confidence"):
        SelfUnrollConfig.from_metadata({**SelfUnrollConfig().to_metadata(), "physics_confidence": "true"})
    with pytest.raises(ValueError, match="physics-informed"):
        selfunroll_torch.add_confidence(SelfUnroll(SelfUnrollConfig(D=1, C=1, G=4, G0=8, N=2, upnet_width=16)))


def test_event_crops_land_on_events(seq_dir):
    """--event-crops 1: every crop holds events even where they sit in one small patch of the
    sensor (a static scene's mover); uniform crops mostly miss it."""
    s = Sequence(seq_dir)
    t, x, y, p = s.events
    keep = (x >= 50) & (x < 54) & (y >= 36) & (y < 40)
    s._events = (t[keep], x[keep], y[keep], p[keep])
    counts = {}
    for prob in (0.0, 1.0):
        sampler = train_data.Sampler([s], 16, 16, 2, None, random.Random(3), event_crops=prob)
        counts[prob] = sum(sum(float(e.sum()) for e in sampler.draw().ev["g1"][:2]) > 0 for _ in range(12))
    assert counts[1.0] == 12 and counts[0.0] < 8, counts


def test_contrast_jitter_scales_each_samples_physics_input(seq_dir, tmp_path, monkeypatch):
    """--contrast-jitter J: each sample's physics input is the log ratio at its recording's contrast
    times a factor in [1/J, J], drawn per sample; J = 1 draws nothing, so the samples stay as before."""
    s = Sequence(seq_dir)
    cache = str(tmp_path / "contrast.json")
    info = train_data.SeqInfo(s, 1.0, cache)
    scales, make = [], train_data.make_sample

    def recording(*args):
        scales.append(args[11] if len(args) > 11 else 1.0)
        return make(*args)
    monkeypatch.setattr(train_data, "make_sample", recording)
    drawn = {}
    for jitter in (1.0, 1.5):
        sampler = train_data.Sampler([s], 24, 24, 2, None, random.Random(4), supervised=True, physics=True,
                                     contrast_cache=cache, contrast_jitter=jitter)
        drawn[jitter] = [sampler.draw() for _ in range(6)]
    assert scales[:6] == [1.0] * 6
    assert all(1 / 1.5 <= m <= 1.5 for m in scales[6:]) and max(scales[6:]) - min(scales[6:]) > 0.1, scales
    monkeypatch.setattr(train_data, "make_sample", make)
    plain = train_data.Sampler([s], 24, 24, 2, None, random.Random(4), supervised=True, physics=True, contrast_cache=cache)
    assert all(np.array_equal(a.lr["g1"], plain.draw().lr["g1"]) for a in drawn[1.0])
    # a drawn factor reaches the physics input: the log ratio at c * m
    k, crop, t = 0, (4, 6, 24, 24), float(s.gt[1][1])
    smp = make(s, k, crop, t, s.exposure, 2, 1, info, None, True, train_data.SUPERVISED_PASSES, 1.3)
    s1, e1 = s.row_times(k)
    ev = s.events_in(min(s1.min(), t) - 1.0, max(s.row_times(k + 1)[1].max(), t + s.exposure) + 1.0, crop)
    want = pn.physics_log_ratio(ev, s1, e1, np.full(s.height, t), 1.3 * info.contrast(), crop)
    assert np.allclose(smp.lr["g1"][0], want, atol=1e-6) and not np.allclose(smp.lr["g1"][0], want / 1.3, atol=1e-3)
    with pytest.raises(train_data.DataError, match="expected a factor >= 1"):
        train_data.Sampler([s], 24, 24, 2, None, random.Random(4), physics=True, contrast_jitter=0.5)


def test_contrast_jitter_is_refused_without_physics_input_or_with_a_cache(tmp_path, seq_dir):
    r = run_train("--data", seq_dir, "--out", tmp_path / "o", "--config", "tiny", "--crop", "32x32", "--steps-s", "1",
                  "--steps-m", "0", "--contrast-jitter", "1.5")
    assert r.returncode == 1 and "--contrast-jitter 1.5: the model has no physics input" in r.stderr, r.stderr
    r = run_train("--cache", tmp_path / "nowhere", "--out", tmp_path / "o", "--config", "tiny", "--physics-variant",
                  "--contrast-jitter", "1.5")
    assert r.returncode == 2 and "--contrast-jitter applies to samples drawn from --data" in r.stderr, r.stderr
    r = run_train("--data", seq_dir, "--out", tmp_path / "o", "--config", "tiny", "--contrast-jitter", "0.8")
    assert r.returncode == 2 and "--contrast-jitter 0.8: expected a factor >= 1" in r.stderr, r.stderr


def test_converter_knows_the_variant(tmp_path, capsys):
    net = tiny_variant()
    torch.save({"state_dict": {"module." + k: v for k, v in net.state_dict().items()}}, tmp_path / "v.pth")
    cfg, missing, unexpected = convert_checkpoint.convert(str(tmp_path / "v.pth"), str(tmp_path / "v.safetensors"))
    assert cfg.physics_input and not missing and not unexpected
    assert "physics-informed" in capsys.readouterr().out
    _, md = safetensors_io.load(str(tmp_path / "v.safetensors"))
    assert md["physics_input"] == "true" and float(md["gamma"]) == 2.2
    rc = convert_checkpoint.main([str(tmp_path / "v.pth"), str(tmp_path / "g.safetensors"), "--gamma", "1"])
    assert rc == 0 and float(safetensors_io.load(str(tmp_path / "g.safetensors"))[1]["gamma"]) == 1.0


# ---- trainer: cache, device, adaptation -----------------------------------------------------------------
def run_train(*args, timeout=600):
    return subprocess.run([*TRAIN, "--threads", "1", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def test_cache_of_prepared_samples_trains(tmp_path, seq_dir):
    r = run_train("--data", seq_dir, "--out", tmp_path / "o", "--config", "tiny", "--physics-variant", "--crop", "32x32",
                  "--make-cache", tmp_path / "cache", "--cache-samples", "5", "--seed", "3")
    assert r.returncode == 0, r.stdout + r.stderr
    meta = json.load(open(tmp_path / "cache" / "cache.json"))
    assert meta["count"] == 5 and meta["physics"] and meta["bins"] == 2
    cs = train_data.CacheSampler(str(tmp_path / "cache"), random.Random(0), 2, True)
    smp = cs.draw()
    assert smp.rs1.shape == (3, 32, 32) and smp.lr["c1"].shape == (1, 32, 32) and smp.ev["r12"][0].shape == (4, 32, 32)
    r = run_train("--cache", tmp_path / "cache", "--out", tmp_path / "t", "--config", "tiny", "--physics-variant",
                  "--crop", "32x32", "--batch", "2", "--steps-s", "2", "--steps-m", "1", "--print-every", "0")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "[s] step 2/2" in r.stdout and "[m] step 1/1" in r.stdout
    _, md = safetensors_io.load(str(tmp_path / "t" / "model.safetensors"))
    assert md["physics_input"] == "true" and md["training.device"] == "cpu" and "cache" in md["training.data"]
    # a cache for another model is refused with what it holds
    r = run_train("--cache", tmp_path / "cache", "--out", tmp_path / "u", "--config", "tiny", "--steps-s", "1")
    assert r.returncode == 1 and "physics=True" in r.stderr


def test_supervised_cache_holds_two_passes_and_is_refused_for_self_supervision(tmp_path, seq_dir):
    r = run_train("--data", seq_dir, "--out", tmp_path / "o", "--config", "tiny", "--physics-variant", "--crop", "32x32",
                  "--supervised", "--make-cache", tmp_path / "cache", "--cache-samples", "3", "--seed", "3")
    assert r.returncode == 0, r.stdout + r.stderr
    smp = train_data.CacheSampler(str(tmp_path / "cache"), random.Random(0), 2, True, supervised=True).draw()
    assert set(smp.ev) == {"g1", "g2"} and set(smp.lr) == {"g1", "g2"} and smp.gt.shape == (3, 32, 32)
    r = run_train("--cache", tmp_path / "cache", "--out", tmp_path / "t", "--config", "tiny", "--physics-variant",
                  "--crop", "32x32", "--batch", "2", "--steps-s", "1", "--steps-m", "1", "--supervised", "--print-every", "0")
    assert r.returncode == 0 and "[s] step 1/1" in r.stdout and "[m] step 1/1" in r.stdout, r.stdout + r.stderr
    r = run_train("--cache", tmp_path / "cache", "--out", tmp_path / "u", "--config", "tiny", "--physics-variant",
                  "--steps-s", "1")
    assert r.returncode == 1 and "self-supervised losses need all six passes" in r.stderr


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
def test_cuda_device_refused_clearly_without_cuda(tmp_path, seq_dir):
    r = run_train("--data", seq_dir, "--out", tmp_path / "o", "--device", "cuda", "--steps-s", "1")
    assert r.returncode != 0 and "--device cuda: this PyTorch has no CUDA device" in r.stderr


def mean_loss(net, samples):
    with torch.no_grad():
        return float(np.mean([float(train.stage_s_losses(net, [s])["total"]) for s in samples]))


def test_tiny_adaptation_lowers_the_self_supervised_loss(tmp_path, seq_dir):
    """--adapt on one recording without its ground truth (gs/ removed): the loss on fixed samples of
    that recording falls, and the written model is a loadable weights file saying what it is. The
    anchor toward the input model is off (--adapt-anchor 0): it trades some of this loss for staying
    near the input inside frames, and test_train.py tests it."""
    rec = tmp_path / "rec"
    shutil.copytree(seq_dir, rec)
    shutil.rmtree(rec / "gs")  # adaptation must never read ground truth
    base = tiny_variant(seed=5)
    base_path = tmp_path / "base.safetensors"
    train.export(base, str(base_path), {"data": "test"})
    s = Sequence(str(rec))
    info = train_data.SeqInfo(s)
    sampler = train_data.Sampler([s], 32, 32, base.cfg.N, None, random.Random(11), physics=True, model_gamma=2.2)
    sampler.infos[s.folder] = info
    fixed = [sampler.draw() for _ in range(4)]
    before = mean_loss(load_model(str(base_path)), fixed)
    r = run_train("--adapt", rec, "--from", base_path, "--minutes", "5", "--steps-s", "40", "--crop", "32x32",
                  "--batch", "2", "--lr", "2e-3", "--out", tmp_path / "a", "--print-every", "0", "--seed", "2",
                  "--adapt-anchor", "0")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "[s] step 40/40" in r.stdout and " loss " in r.stdout and "[m]" not in r.stdout
    adapted = tmp_path / "a" / "adapted.safetensors"
    net = load_model(str(adapted))
    after = mean_loss(net, fixed)
    assert after < 0.9 * before, (before, after)
    _, md = safetensors_io.load(str(adapted))
    assert md["training.adapt"] == str(rec) and md["physics_input"] == "true"
    r = run_train("--adapt", rec, "--out", tmp_path / "b", "--minutes", "1")
    assert r.returncode != 0 and "--adapt needs --from" in r.stderr


def test_confidence_only_training_moves_the_confidence_row_and_nothing_else(tmp_path, seq_dir):
    """--physics-confidence --confidence-only: fusion_net.pred's 4th row (weights and bias) trains,
    every other weight, the 3 image rows of the same conv included, is exported bit for bit as
    loaded, and stage M has nothing to train; a model without the confidence is refused by name."""
    base = perturbed_variant(seed=7)
    base_path = tmp_path / "base.safetensors"
    train.export(base, str(base_path), {"data": "test"})
    r = run_train("--data", seq_dir, "--from", base_path, "--physics-confidence", "--confidence-only", "--supervised",
                  "--crop", "32x32", "--batch", "2", "--steps-s", "4", "--steps-m", "3", "--lr", "0.05",
                  "--out", tmp_path / "c", "--print-every", "0", "--seed", "2")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "[s] step 4/4" in r.stdout and "[m]" not in r.stdout
    out, md = safetensors_io.load(str(tmp_path / "c" / "model.safetensors"))
    want = selfunroll_torch.add_confidence(load_model(str(base_path))).state_dict()
    for k, v in want.items():
        got = torch.as_tensor(out[k]).float()
        if k.startswith("fusion_net.pred."):
            assert torch.equal(got[:3], v[:3]), k
            assert float((got[3:] - v[3:]).abs().max()) > 1e-4, k  # the confidence row moved
        else:
            assert torch.equal(got, v), k
    assert md["physics_confidence"] == "true" and "confidence alone" in md["training.trained"]
    r = run_train("--data", seq_dir, "--from", base_path, "--confidence-only", "--supervised", "--crop", "32x32",
                  "--steps-s", "1", "--out", tmp_path / "d")
    assert r.returncode == 1 and "--confidence-only" in r.stderr and "--physics-confidence" in r.stderr


def test_gate_radii_file_trains_and_is_checked(tmp_path, seq_dir):
    """--gate-radii FILE: a gated variant trains with each sequence's radius from the file; a file
    without the training sequence, or a model without a gate, is refused naming the file."""
    base = perturbed_variant(seed=8)
    base.cfg.physics_gate = 1
    base_path = tmp_path / "base.safetensors"
    train.export(base, str(base_path), {"data": "test"})
    radii = tmp_path / "radii.json"
    radii.write_text(json.dumps({os.path.abspath(seq_dir): {"radius": 2}}))
    args = ["--data", seq_dir, "--supervised", "--crop", "32x32", "--batch", "2", "--steps-s", "2", "--steps-m", "1",
            "--print-every", "0", "--seed", "2", "--gate-radii", radii]
    r = run_train("--from", base_path, "--out", tmp_path / "g", *args)
    assert r.returncode == 0 and "[s] step 2/2" in r.stdout and "[m] step 1/1" in r.stdout, r.stdout + r.stderr
    assert "--gate-radii" in safetensors_io.load(str(tmp_path / "g" / "model.safetensors"))[1]["training.command"]
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"/elsewhere": {"radius": 1}}))
    r = run_train("--from", base_path, "--out", tmp_path / "h", *args[:-1], other)
    assert r.returncode == 1 and "other.json: no gate radius for 1 training sequences" in r.stderr, r.stderr
    plain = tmp_path / "plain.safetensors"
    train.export(perturbed_variant(seed=8), str(plain), {"data": "test"})
    r = run_train("--from", plain, "--out", tmp_path / "p", *args)
    assert r.returncode == 1 and "the model has no event gate" in r.stderr, r.stderr


# ---- the variant in the C++ CLI ------------------------------------------------------------------------
def perturbed_variant(seed=5):
    net = tiny_variant(seed)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.02 * torch.randn(p.shape, generator=g))  # a trained model, not the init
    return net.eval()


def with_varied_confidence(net, seed=6):
    """`net` with a learned confidence whose channel varies across pixels (c from 0 to 1)."""
    net = selfunroll_torch.add_confidence(net)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        net.fusion_net.pred.weight[3] = 2.0 * torch.randn(net.fusion_net.pred.weight[3].shape, generator=g)
        net.fusion_net.pred.bias[3] = 0.0
    return net.eval()


@needs_cli
@pytest.mark.parametrize("mode,gate,confidence", [("s", -1, False), ("m", -1, False), ("s", 1, False), ("m", 2, False),
                                                  ("s", 1, True), ("m", -1, True)])
def test_variant_in_vkunroll_infer_matches_pytorch(tmp_path, mode, gate, confidence):
    """The exported variant loaded by `vkunroll infer` (Vulkan) gives the mirror's every output within 1e-4,
    with and without the event gate (metadata physics_gate) and the learned confidence."""
    net = perturbed_variant()
    if confidence:
        net = with_varied_confidence(net)
    net.cfg.physics_gate = gate
    path = str(tmp_path / "v.safetensors")
    train.export(net, path, {"data": "test"})
    rs, ev, phys = random_inputs(net.cfg, b=2 if mode == "m" else 1, h=37, w=52, seed=4)
    if gate >= 0:  # sparse ev1/ev2 events, so the gate has pixels on both sides
        keep = (torch.rand(rs.shape[0], 1, 37, 52, generator=torch.Generator().manual_seed(9)) < 0.03).float()
        ev = [ev[0] * keep, ev[1] * keep, ev[2]]
    safetensors_io.save(str(tmp_path / "in.safetensors"), {"rs": rs, "ev1": ev[0], "ev2": ev[1], "ev3": ev[2], "phys": phys})
    r = subprocess.run([CLI, "infer", "--model", path, "--inputs", tmp_path / "in.safetensors", "--out",
                        tmp_path / "out.safetensors", "--mode", mode], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    got, _ = safetensors_io.load(str(tmp_path / "out.safetensors"))
    with torch.no_grad():
        sys_, E, flow, warped, fused, m, out = net(rs, *ev, phys=phys, moa=(mode == "m"))
    want = {"sys": sys_, "E": E, "flow": flow, "warped": warped, "fused": fused}
    if mode == "m":
        want.update(m=m, out=out)
    for k, v in want.items():
        err = float((got[k].float() - v).abs().max())
        assert err <= 1e-4, f"{k}: max abs error {err}"
    assert float(E.abs().max()) > 1e-3  # the correction is not zero: the test sees the network
    if gate >= 0:  # the gate takes physics at some pixels and the network at others
        g = selfunroll_torch.event_gate(ev[0], ev[1], gate).expand_as(fused) > 0
        physc = phys.clamp(0, 1)
        assert bool(torch.equal(fused[~g], physc[~g])) and int((~g).sum()) > 0
        assert float((fused[g] - physc[g]).abs().max()) > 1e-3


@needs_cli
@pytest.mark.parametrize("gamma", [None, "1"])
def test_variant_at_init_unrolls_as_the_physics_unroller(tmp_path, gamma):
    """`unroll --mode s` with the variant at its init (fused = physics) gives `--mode physics`'s images
    at the same physics parameters (the variant's contrast, log offset 0: its physics input is plain
    log, as it was trained), on the simulator's gamma-2.2 frames (no conversion) and read as linear
    (--gamma 1: frames go into the gamma-2.2 model as v^(1/2.2) and come back ^2.2)."""
    seq = tmp_path / "sim"
    r = subprocess.run([CLI, "simulate", "--out", seq, "--size", "96x72", "--frames", "2", "--gt-per-frame", "2",
                        "--seed", "8", "--motion", "pan", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    net = tiny_variant(3)
    model = str(tmp_path / "v.safetensors")
    train.export(net, model, {"data": "test"})
    extra = ["--gamma", gamma] if gamma else []
    outs, given = {}, []
    for mode in ("s", "physics"):
        out = tmp_path / f"out_{mode}"
        cmd = [CLI, "unroll", seq, "--out", out, "--mode", mode, "--times", "gt", "--no-video", "--bit-depth", "16",
               "--quiet"] + extra + (["--model", model] if mode == "s" else given)
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        outs[mode] = out
        if mode == "s":
            phys = json.load(open(out / "summary.json"))["physics"]
            assert phys["log_offset"] == 0.0 and phys["contrast_method"] in ("event_count_fit", "default"), phys
            given = ["--contrast", repr(phys["contrast"])]
    summ = json.load(open(outs["s"] / "summary.json"))
    assert summ["encoding"]["model_gamma"] == 2.2
    assert summ["encoding"]["sequence_gamma"] == (1.0 if gamma else 2.2)
    rows = {m: [l.split(",") for l in open(outs[m] / "metrics.csv").read().splitlines()[1:]] for m in outs}
    assert len(rows["s"]) == len(rows["physics"]) == 4
    worst = 0.0
    for a, b in zip(rows["physics"], rows["s"]):
        assert a[0] == b[0] and a[1] == b[1]  # the same frame and instant
        pa, pb = read_image(str(outs["physics"] / a[3])), read_image(str(outs["s"] / b[3]))
        worst = max(worst, float(np.abs(pa - pb).max()))
    assert worst <= 5e-5, worst  # two 16-bit quantizations (7.6e-6 each) and float32 pow rounding


@needs_cli
def test_gate_radius_is_chosen_said_and_reaches_the_model(tmp_path):
    """`--gate-radius`: auto keeps a clean recording at the model's radius and says why in
    summary.json; a given radius is the one the network runs with (the images change with it);
    a radius for a model without a gate, or a bad value, is refused naming the option."""
    seq = tmp_path / "sim"
    r = subprocess.run([CLI, "simulate", "--out", seq, "--size", "96x72", "--frames", "2", "--gt-per-frame", "2",
                        "--seed", "8", "--motion", "static", "--preset", "clean", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    net = tiny_variant(3)
    selfunroll_torch.random_init_(net, seed=3)  # not the init's fused = physics: the radius shows
    net.cfg.physics_gate = 1
    model = str(tmp_path / "v.safetensors")
    train.export(net, model, {"data": "test"})
    images = {}
    for radius in ("auto", "0", "4"):
        out = tmp_path / f"out_{radius}"
        r = subprocess.run([CLI, "unroll", seq, "--out", out, "--mode", "s", "--times", "gt", "--no-video", "--bit-depth",
                            "16", "--quiet", "--model", model, "--gate-radius", radius], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        phys = json.load(open(out / "summary.json"))["physics"]
        gate = phys["gate_radius"]
        if radius == "auto":
            assert phys["frame_noise"] < 0.01 and phys["isolated_event_fraction"] < 0.05, phys  # the clean preset
            assert gate["radius"] == 1 and "clean recording" in gate["source"], gate
        else:
            assert gate == {"radius": int(radius), "source": "--gate-radius"}, gate
        first = open(out / "metrics.csv").read().splitlines()[1].split(",")
        images[radius] = read_image(str(out / first[3]))
    assert float(np.abs(images["0"] - images["4"]).max()) > 1e-3
    radii = tmp_path / "radii.json"  # tools/train/gate_radii.py (train.py --gate-radii) picks as auto did
    r = subprocess.run([sys.executable, "-m", "tools.train.gate_radii", "--cli", CLI, "--out", radii,
                        "--model-radius", "1", str(seq)], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert train_data.load_gate_radii(str(radii)) == {os.path.abspath(seq): 1}
    plain = tiny_variant(3)  # no gate
    plain_model = str(tmp_path / "p.safetensors")
    train.export(plain, plain_model, {"data": "test"})
    for model_file, radius, says in ((plain_model, "2", "no model with an event gate"), (model, "x", "--gate-radius 'x'")):
        r = subprocess.run([CLI, "unroll", seq, "--out", tmp_path / "bad", "--mode", "s", "--no-video", "--quiet",
                            "--model", model_file, "--gate-radius", radius], capture_output=True, text=True)
        assert r.returncode != 0 and says in r.stderr, r.stderr
