"""tools/train/train.py and tools/data/sequence_data.py: the generic-layout reader (PNG 8/16-bit, events h5/txt,
clear errors), the fast event binning against the reference NumPy one, a CI-sized self-supervised
training run whose loss decreases, the time-limited tool run with resume and export, and the
exported weights in `vkunroll infer` against the PyTorch model (needs VKUNROLL_CLI, set by ctest)."""
import json
import os
import re
import random
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest
import torch

from tools.data import event_tensors_numpy as etn
from tools.model import safetensors_io
from tools.train import train
from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig, run_named
from tools.data.sequence_data import DataError, Sequence, read_events, read_image

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

CLI = os.environ.get("VKUNROLL_CLI")
TRAIN = [sys.executable, "-m", "tools.train.train"]  # run from ROOT: tools/ is a package
needs_cli = pytest.mark.skipif(not CLI or not os.path.exists(CLI or ""), reason="VKUNROLL_CLI not set (run through ctest)")


# ---- a small synthetic sequence in the generic layout (no simulator needed) -------------------------
def png_bytes(img: np.ndarray, depth: int, filters=(0,)) -> bytes:
    """img uint8/uint16 [H, W, C] (C = 1 or 3) -> PNG, rows filtered with the given filter types in turn."""
    h, w, c = img.shape
    ctype = {1: 0, 3: 2}[c]
    raw = img.astype(">u2").tobytes() if depth == 16 else img.astype(np.uint8).tobytes()
    stride, bpp = w * c * depth // 8, c * depth // 8
    rows, prev = [], np.zeros(stride, dtype=np.int32)
    for y in range(h):
        line = np.frombuffer(raw[y * stride:(y + 1) * stride], dtype=np.uint8).astype(np.int32)
        f = filters[y % len(filters)]
        left = np.concatenate([np.zeros(bpp, np.int32), line[:-bpp]])
        ul = np.concatenate([np.zeros(bpp, np.int32), prev[:-bpp]])
        if f == 0:
            pred = np.zeros_like(line)
        elif f == 1:
            pred = left
        elif f == 2:
            pred = prev
        elif f == 3:
            pred = (left + prev) >> 1
        else:
            p = left + prev - ul
            pa, pb, pc = abs(p - left), abs(p - prev), abs(p - ul)
            pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, prev, ul))
        rows.append(bytes([f]) + ((line - pred) & 255).astype(np.uint8).tobytes())
        prev = line

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    ihdr = struct.pack(">IIBBBBB", w, h, depth, ctype, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"".join(rows)))
            + chunk(b"IEND", b""))


def scene(t_us, w, h, speed=0.004):
    """A smooth texture translating right at `speed` px/us (linear intensity)."""
    xs = np.arange(w)[None, :] - speed * t_us
    ys = np.arange(h)[:, None]
    base = 0.5 + 0.3 * np.sin(xs * 0.45) * np.cos(ys * 0.3) + 0.1 * np.sin(xs * 0.11 + ys * 0.07)
    return np.stack([base, 0.8 * base + 0.1, 0.6 * base + 0.2], 0).clip(0.05, 1)


def write_sequence(folder, w=64, h=48, frames=3, delay=60.0, exposure=1000.0, period=8000.0, threshold=0.15,
                   events_txt=False, gt_per_frame=2):
    """RS frames integrated over each row's exposure, GS frames at chosen instants, and events from
    log-intensity threshold crossings sampled every 25 us (enough for the training code; the real
    simulator is `vkunroll simulate`)."""
    os.makedirs(os.path.join(folder, "rs"), exist_ok=True)
    os.makedirs(os.path.join(folder, "gs"), exist_ok=True)
    t0s = [1000.0 + k * period for k in range(frames)]
    meta = {"width": w, "height": h, "line_delay_us": delay, "exposure_us": exposure, "readout": "top-down",
            "frames": [], "events": "events.txt" if events_txt else "events.h5", "ground_truth": []}
    for k, t0 in enumerate(t0s):
        img = np.zeros((3, h, w))
        for y in range(h):
            ts = t0 + y * delay + np.linspace(0, exposure, 5)
            img[:, y] = np.mean([scene(t, w, h)[:, y] for t in ts], 0)
        f = f"rs/{k:06d}.png"
        open(os.path.join(folder, f), "wb").write(png_bytes((img.transpose(1, 2, 0) * 255).round(), 8))
        meta["frames"].append({"file": f, "t0_us": t0})
        for j in range(gt_per_frame):
            t = t0 + (j + 0.5) / gt_per_frame * period
            g = f"gs/{k:02d}_{j}.png"
            open(os.path.join(folder, g), "wb").write(png_bytes((scene(t, w, h).transpose(1, 2, 0) * 255).round(), 8))
            meta["ground_truth"].append({"file": g, "t_us": t})
    ref = np.log(scene(0.0, w, h).mean(0))
    ev = []
    for t in np.arange(0.0, t0s[-1] + 2 * period, 25.0):
        cur = np.log(scene(t, w, h).mean(0))
        d = cur - ref
        for pol, mask in ((1, d >= threshold), (0, d <= -threshold)):
            ys, xs = np.nonzero(mask)
            ev += [(t, x, y, pol) for x, y in zip(xs, ys)]
            ref[mask] += threshold if pol else -threshold
    ev = np.array(ev, dtype=np.float64)
    if events_txt:
        np.savetxt(os.path.join(folder, "events.txt"), ev, fmt="%.1f %d %d %d", header="t x y p")
    else:
        import h5py
        with h5py.File(os.path.join(folder, "events.h5"), "w") as f:
            f["events/t"] = ev[:, 0].astype(np.int64)
            f["events/x"] = ev[:, 1].astype(np.uint16)
            f["events/y"] = ev[:, 2].astype(np.uint16)
            f["events/p"] = ev[:, 3].astype(np.int8)
    json.dump(meta, open(os.path.join(folder, "meta.json"), "w"))
    return folder


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    return write_sequence(str(tmp_path_factory.mktemp("seq") / "s0"))


# ---- reader ------------------------------------------------------------------------------------------
def test_png_reader_8_and_16_bit_all_filters(tmp_path):
    rng = np.random.default_rng(3)
    img16 = rng.integers(0, 65536, size=(7, 5, 3)).astype(np.uint16)
    (tmp_path / "c16.png").write_bytes(png_bytes(img16, 16, filters=(0, 1, 2, 3, 4)))
    got = read_image(str(tmp_path / "c16.png"))
    assert got.shape == (3, 7, 5)
    np.testing.assert_array_equal(np.round(got * 65535).astype(np.uint16), img16.transpose(2, 0, 1))
    gray8 = rng.integers(0, 256, size=(6, 4, 1)).astype(np.uint8)
    (tmp_path / "g8.png").write_bytes(png_bytes(gray8, 8, filters=(4, 1)))
    got = read_image(str(tmp_path / "g8.png"))
    assert got.shape == (3, 6, 4)
    for c in range(3):
        np.testing.assert_array_equal(np.round(got[c] * 255), gray8[:, :, 0])
    (tmp_path / "bad.png").write_bytes(b"GIF89a....")
    with pytest.raises(DataError, match="bad.png: not a PNG"):
        read_image(str(tmp_path / "bad.png"))


def test_sequence_reader_and_errors(tmp_path, seq_dir):
    s = Sequence(seq_dir)
    assert (s.width, s.height, s.num_frames, len(s.gt)) == (64, 48, 3, 6)
    start, end = s.row_times(1)
    assert start[0] == 9000.0 and start[47] == 9000.0 + 47 * 60 and end[0] == 10000.0
    assert s.frame(0).shape == (3, 48, 64) and 0 <= s.frame(0).min() and s.frame(0).max() <= 1
    t, x, y, p = s.events
    assert len(t) > 1000 and set(np.unique(p)) == {0, 1}
    # the same events as text give the same arrays
    txt = write_sequence(str(tmp_path / "txt"), frames=2, events_txt=True)
    t2, x2, y2, p2 = read_events(os.path.join(txt, "events.txt"))
    assert len(t2) > 1000 and t2.dtype == np.float64 and set(np.unique(p2)) == {0, 1}
    # errors name the file and what was expected
    meta = json.load(open(os.path.join(seq_dir, "meta.json")))
    bad = tmp_path / "bad"
    bad.mkdir()
    json.dump({k: v for k, v in meta.items() if k != "exposure_us"}, open(bad / "meta.json", "w"))
    with pytest.raises(DataError, match=r"bad/meta.json: field 'exposure_us' missing"):
        Sequence(str(bad))
    (bad / "events.txt").write_text("1 2 3 1\n5 2 3 7\n")
    with pytest.raises(DataError, match=r"events.txt: event 1 has polarity 7"):
        read_events(str(bad / "events.txt"))
    (bad / "events.txt").write_text("9 2 3 1\n5 2 3 1\n")
    with pytest.raises(DataError, match=r"event 1 has t=5.0 before the previous event"):
        read_events(str(bad / "events.txt"))
    json.dump(dict(meta, width=32), open(bad / "meta.json", "w"))
    (bad / "events.h5").symlink_to(os.path.join(seq_dir, "events.h5"))
    with pytest.raises(DataError, match=r"lies outside the 32x48 sensor"):
        Sequence(str(bad)).events


def test_event_tensor_fast_equals_reference():
    rng = np.random.default_rng(11)
    n, W, H = 20000, 37, 29
    t = np.sort(rng.uniform(0, 10000, n))
    x, y, p = rng.integers(0, W, n), rng.integers(0, H, n), rng.integers(0, 2, n)
    start, end = etn.row_times(2000.0, 61.5, 1500.0, H, "bottom-up")
    for a_rows, b_rows in ((np.full(H, 4100.0), start), (np.full(H, 4100.0), end), (start, end + 3000),
                           (end, start), (np.full(H, 7000.0), np.full(H, 7000.0))):
        for crop in ((0, 0, W, H), (5, 3, 16, 12)):
            ref = etn.event_tensor(t, x, y, p, a_rows, b_rows, 5, crop)
            got = etn.event_tensor_fast(t, x, y, p, a_rows, b_rows, 5, crop)
            np.testing.assert_array_equal(got, ref)
    assert ref.sum() == 0  # an empty interval selects nothing


# ---- training ----------------------------------------------------------------------------------------
def tiny_cfg():
    cfg = train.make_config("tiny")
    return cfg


def test_fusion_passthrough_init_starts_at_sys():
    """A fresh model's fusion_net is the identity on its sys input (tools/train/train.py), so S starts at
    E-IC_T's result instead of a random UNet; without the option it is not."""
    torch.manual_seed(0)
    cfg = train.make_config("small")
    rs = 0.05 + 0.9 * torch.rand(1, 3, 64, 96)  # sys = rs + E stays > 0, where LeakyReLU is exact
    ev = [torch.randint(-2, 3, (1, 2 * cfg.N, 64, 96)).float().clamp(min=0) for _ in range(3)]
    for passthrough in (True, False):
        net = SelfUnroll(cfg)
        train.init_model(net, 1, fusion_passthrough=passthrough)
        with torch.no_grad():
            out = net(rs, *ev, moa=False)
        sys_, fused = out[0], out[4]
        err = float((fused - sys_).abs().max())
        if passthrough:
            assert err < 1e-5, err
            assert float((sys_ - rs).abs().max()) < 0.05  # the residual head starts near zero
        else:
            assert err > 0.05, err


def test_self_supervised_losses_decrease_on_a_tiny_crop(seq_dir):
    """A few Adam steps on one fixed batch (32x32 crops) lower the stage-1 loss; stage 2 moves
    only attfusion_net and lowers the dual cycle loss. No ground truth is read."""
    torch.manual_seed(0)
    torch.set_num_threads(1)
    net = SelfUnroll(tiny_cfg())
    # A random fusion_net: the pass-through start (the tool's default) is already near the
    # cycle/temporal optimum of a static crop, so the loss would have little to fall.
    train.init_model(net, 3, fusion_passthrough=False)
    s = Sequence(seq_dir)
    s.gt_image = None  # training must not touch ground truth
    sampler = train.Sampler([s], 32, 32, net.cfg.N, None, random.Random(5))
    batch = [sampler.draw() for _ in range(2)]
    assert all(b.gt is None for b in batch)
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    losses = []
    for _ in range(25):
        L = train.stage_s_losses(net, batch)
        assert set(L) == {"lc", "cc", "tc", "tv", "total"}
        assert abs(float(L["total"]) - float(L["lc"] + L["cc"] + L["tc"] + 0.01 * L["tv"])) < 1e-5
        opt.zero_grad()
        L["total"].backward()
        opt.step()
        losses.append(float(L["total"]))
    assert losses[-1] < 0.7 * losses[0], losses

    before = {k: v.clone() for k, v in net.state_dict().items()}
    for n, p in net.named_parameters():
        p.requires_grad_(n.startswith("attfusion_net."))
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=2e-3)
    m_losses = []
    for _ in range(12):
        L = train.stage_m_losses(net, batch)
        opt.zero_grad()
        L["total"].backward()
        opt.step()
        m_losses.append(float(L["dcc"]))
    assert m_losses[-1] < m_losses[0], m_losses
    after = net.state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed and all(k.startswith("attfusion_net.") for k in changed)


def run_train(*args):
    # one thread: two OpenMP threads on a busy 2-core CI machine are many times slower
    return subprocess.run([*TRAIN, "--threads", "1", *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)


@pytest.fixture(scope="module")
def trained(tmp_path_factory, seq_dir):
    out = tmp_path_factory.mktemp("run")
    r = run_train("--data", seq_dir, "--val", seq_dir, "--out", out / "a", "--config", "tiny", "--crop", "32x32",
                  "--batch", "1", "--steps-s", "4", "--steps-m", "2", "--print-every", "0", "--val-targets", "2",
                  "--ckpt-every", "2", "--seed", "7")
    assert r.returncode == 0, r.stdout + r.stderr
    return out, r.stdout


def test_tool_run_progress_validation_and_metadata(trained):
    out, stdout = trained
    assert "[s] step 4/4" in stdout and "lc " in stdout and "tv " in stdout and "[m] step 2/2" in stdout
    assert "final validation PSNR rs" in stdout and " S " in stdout and " M " in stdout
    tensors, md = safetensors_io.load(str(out / "a" / "model.safetensors"))
    cfg = SelfUnrollConfig.from_metadata(md)
    assert cfg.N == 2 and cfg.moa and md["format"] == "vkunroll-selfunroll" and md["channel_order"] == "rgb"
    for k in ("training.data", "training.losses", "training.steps_s", "training.steps_m", "training.seed",
              "training.command", "training.crop"):
        assert k in md, k
    assert md["training.steps_s"] == "4" and md["training.seed"] == "7" and "Llc" in md["training.losses"]
    assert set(tensors) == set(SelfUnroll(cfg).state_dict())


def test_resume_continues_and_time_limit_stops(trained, seq_dir, tmp_path):
    out, _ = trained
    ck = torch.load(out / "a" / "checkpoint.pt", weights_only=False)
    assert ck["stage"] == "done"
    r = run_train("--data", seq_dir, "--out", tmp_path / "c", "--config", "tiny", "--crop", "32x32", "--batch", "1",
                  "--steps-s", "3", "--steps-m", "0", "--print-every", "0", "--ckpt-every", "1", "--max-minutes", "0.001")
    assert r.returncode == 0, r.stderr
    # the budget (60 ms) ends the stage before its 3 steps (one step is always taken; a second one
    # fits when the first took under 60 ms, as on a quiet machine)
    assert re.search(r"done after [12] steps \(time\)", r.stdout), r.stdout
    # resume a stage-1 checkpoint written at step 1 of 3
    r = run_train("--data", seq_dir, "--out", tmp_path / "d", "--config", "tiny", "--crop", "32x32", "--batch", "1",
                  "--steps-s", "3", "--steps-m", "0", "--print-every", "0", "--ckpt-every", "1", "--stop-after", "1")
    assert r.returncode == 0, r.stderr
    ck = torch.load(tmp_path / "d" / "checkpoint.pt", weights_only=False)
    assert ck["stage"] == "s" and ck["step"] == 1 and "opt" in ck
    r = run_train("--data", seq_dir, "--out", tmp_path / "d", "--resume", tmp_path / "d" / "checkpoint.pt",
                  "--steps-s", "3", "--steps-m", "0", "--print-every", "0", "--crop", "32x32", "--batch", "1")
    assert r.returncode == 0, r.stderr
    assert "resuming" in r.stdout and "[s] step 2/3" in r.stdout and "[s] done after 3 steps" in r.stdout


def test_bad_data_fails_clearly(tmp_path):
    r = run_train("--data", tmp_path / "nothing", "--out", tmp_path / "o", "--steps-s", "1")
    assert r.returncode == 1 and "nothing: not found" in r.stderr


def test_adaptation_returns_the_input_model_when_no_step_improves(trained, seq_dir, tmp_path):
    """lr 0.05 (Adam, 3 steps) makes each step worse: the held-out self-supervised loss never improves, so the export is
    the input model, bit for bit, though the steps changed the weights (checkpoint.pt)."""
    out, _ = trained
    model = out / "a" / "model.safetensors"
    r = run_train("--adapt", seq_dir, "--from", model, "--minutes", "2", "--out", tmp_path / "ad", "--steps-s", "3",
                  "--lr", "0.05", "--constant-lr", "--ckpt-every", "1", "--crop", "32x32", "--batch", "1",
                  "--print-every", "0")  # the default anchor (train.ADAPT_ANCHOR)
    assert r.returncode == 0, r.stdout + r.stderr
    assert " anchor " in r.stdout  # the anchor's term on the progress line (the guard's measure stays stage S's)
    assert "pair 1-2 held out" in r.stdout and "[adapt] step 3: held-out loss" in r.stdout, r.stdout
    assert "exported the input model" in r.stdout, r.stdout
    before, _ = safetensors_io.load(str(model))
    after, md = safetensors_io.load(str(tmp_path / "ad" / "adapted.safetensors"))
    assert set(before) == set(after) and all(torch.equal(before[k], after[k]) for k in before)
    assert md["training.adapt_selected"].startswith("the input model") and md["training.adapt_anchor"] == str(train.ADAPT_ANCHOR)
    # a checkpoint of the run exports the guard's choice (here the input model), not its running weights
    assert train.main(["--export-checkpoint", str(tmp_path / "ad" / "checkpoint.pt"), str(tmp_path / "mid.safetensors")]) == 0
    mid, md = safetensors_io.load(str(tmp_path / "mid.safetensors"))
    assert all(torch.equal(before[k], mid[k]) for k in before) and md["training.adapt_selected"].startswith("the input")
    # the steps did change the model: each held-out loss differs from the input model's, none is lower
    lines = r.stdout.splitlines()
    held = [float(l.split()[-1]) for l in lines if "held-out loss of the input model" in l]
    held += [float(l.split("held-out loss ")[1].split()[0]) for l in lines if l.startswith("[adapt] step")]
    assert len(held) == 4 and all(v != held[0] and not v < held[0] for v in held[1:]), held


def test_adapt_guard_keeps_the_best_step_and_splits_frames(tmp_path):
    """The selection itself: a better step is kept, a worse or NaN one is not; held-out frames."""
    import random as _random
    from tools.train.adapt_guard import AdaptGuard, split_pairs
    assert split_pairs(4) == ([0], [2], "frames 2..3 held out (no training crop uses them)")
    assert split_pairs(10)[:2] == ([0, 1, 2, 3, 4, 5, 6], [8])
    assert split_pairs(2)[:2] == ([0], [0])

    class FakeSampler:
        rng, pairs = _random.Random(1), {}

        def draw(self):
            return self.pairs["s"][0]

    class Seq:
        folder, num_frames = "s", 12

    net = torch.nn.Linear(1, 1, bias=False)
    losses = {"now": 5.0}
    guard = AdaptGuard(Seq(), sampler := FakeSampler(), net, lambda n, part: {"total": torch.tensor(losses["now"])},
                       str(tmp_path), every=1, count=2, log=lambda m: None)
    assert sampler.pairs == {"s": list(range(8))} and guard.samples == [9, 9]
    w0 = net.weight.detach().clone()
    for step, (value, w) in enumerate([(4.0, 1.0), (6.0, 2.0), (float("nan"), 3.0)], 1):
        with torch.no_grad():
            net.weight.fill_(w)
        losses["now"] = value
        guard.check(net, step)
    info = {}
    guard.finish(net, info)
    assert float(net.weight) == 1.0 and guard.best_step == 1 and info["adapt_selected"].startswith("step 1")
    assert float(w0) != 1.0


def test_adapt_anchor_pulls_only_targets_inside_frames(seq_dir):
    """--adapt-anchor: the sampler marks t* inside an exposure span as intra; the anchor is 0 for the
    input model itself, positive once the weights move, and 0 for a batch between frames."""
    import copy
    from tools.train.adapt_guard import IntraAnchor

    class FixedT(random.Random):  # t* at a chosen point of the pair's span
        def uniform(self, a, b):
            return self.at(a, b)

    torch.manual_seed(0)
    net = SelfUnroll(tiny_cfg())
    train.init_model(net, 3, fusion_passthrough=False)
    s = Sequence(seq_dir)
    (a0, a1), (b0, _) = s.frame_span(0), s.frame_span(1)
    assert a1 < b0  # the fixture has a gap between frames
    rng = FixedT(3)
    sampler = train.Sampler([s], 32, 32, net.cfg.N, None, rng)
    sampler.pairs = {s.folder: [0]}
    rng.at = lambda lo, hi: 0.5 * (a0 + a1)
    inside = [sampler.draw() for _ in range(2)]
    rng.at = lambda lo, hi: 0.5 * (a1 + b0)
    between = [sampler.draw() for _ in range(2)]
    assert all(x.intra for x in inside) and not any(x.intra for x in between)
    assert [x.exposing for x in inside + between] == [0, 0, -1, -1]

    anchor = IntraAnchor(copy.deepcopy(net), 2.0, train.run_passes, train.BRANCHES)
    L = train.stage_s_losses(net, inside, anchor=anchor)
    assert float(L["anchor"]) == 0.0
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.05 * torch.randn_like(p))
    for batch, moved in ((inside, True), (between, False), (inside[:1] + between[:1], True)):
        L = train.stage_s_losses(net, batch, anchor=anchor)
        plain = train.stage_s_losses(net, batch)
        assert (float(L["anchor"]) > 1e-4) == moved, float(L["anchor"])
        assert abs(float(L["total"]) - float(plain["total"] + 2.0 * L["anchor"])) < 1e-5
    assert all(not p.requires_grad for p in anchor.ref.parameters())


def test_one_way_latent_consistency_moves_only_the_other_frames_pass():
    """--adapt-lc-one-way: inside an exposure span the exposing frame's pass gets no gradient from Llc,
    the other frame's does; between frames both do; the value is the plain |g1 - g2|."""
    from types import SimpleNamespace
    from tools.train.adapt_guard import one_way_pair
    samples = [SimpleNamespace(exposing=e) for e in (0, 1, -1)]
    g1 = torch.randn(3, 1, 4, 4, requires_grad=True)
    g2 = torch.randn(3, 1, 4, 4, requires_grad=True)
    a, b = one_way_pair(samples, g1, g2)
    loss = (a - b).abs().mean()
    assert abs(float(loss) - float((g1 - g2).abs().mean())) < 1e-7
    loss.backward()
    moved1, moved2 = [[bool(g.grad[i].abs().sum() > 0) for i in range(3)] for g in (g1, g2)]
    assert moved1 == [False, True, True] and moved2 == [True, False, True], (moved1, moved2)


def test_adapt_anchor_options_are_checked(capsys):
    for args, says in ((["--data", "x", "--adapt-anchor", "1"], "--adapt-anchor applies to --adapt only"),
                       (["--adapt", "x", "--from", "m.safetensors", "--minutes", "1", "--adapt-anchor", "-1"],
                        "expected a weight >= 0"),
                       (["--adapt", "x", "--resume", "c.pt", "--minutes", "1"], "--adapt-anchor 0 adapts without it"),
                       (["--data", "x", "--adapt-lc-one-way"], "--adapt-lc-one-way applies to --adapt only")):
        with pytest.raises(SystemExit):
            train.main(args)
        assert says in capsys.readouterr().err, args


def test_heldout_sequences_are_refused_for_data_and_val(tmp_path, seq_dir):
    """A sequence natural_data.py marked held-out (natural.json split 'heldout') is evaluation only."""
    import shutil
    held = tmp_path / "held" / "nat_03001"
    shutil.copytree(seq_dir, held)
    (held / "natural.json").write_text(json.dumps({"split": "heldout", "kind": "camera"}))
    for option in ("--data", "--val"):
        args = ["--data", held.parent] if option == "--data" else ["--data", seq_dir, "--val", held]
        r = run_train(*args, "--out", tmp_path / "o", "--steps-s", "1", "--config", "tiny", "--crop", "32x32")
        assert r.returncode == 1, r.stdout + r.stderr
        assert f"{option} {held}: the sequence is marked held-out" in r.stderr, r.stderr
        assert not (tmp_path / "o" / "checkpoint.pt").exists()
    # a training-split sequence passes the check (the run gets as far as its first step)
    (held / "natural.json").write_text(json.dumps({"split": "train", "kind": "camera"}))
    train.refuse_heldout([str(held.parent)], "--data")
    # the second generator's sequences (split 'validation') serve --val, never --data
    (held / "natural.json").write_text(json.dumps({"split": "validation", "kind": "camera"}))
    train.refuse_heldout([str(held)], "--val")
    with pytest.raises(train.DataError, match="validation-only"):
        train.refuse_heldout([str(held.parent)], "--data")


@needs_cli
@pytest.mark.parametrize("mode", ["s", "m"])
def test_exported_model_in_vkunroll_infer_matches_pytorch(trained, seq_dir, tmp_path, mode):
    out, _ = trained
    model = out / "a" / "model.safetensors"
    tensors, md = safetensors_io.load(str(model))
    net = SelfUnroll(SelfUnrollConfig.from_metadata(md))
    net.load_state_dict(tensors)
    net.eval()
    s = Sequence(seq_dir)
    crop = (3, 5, 40, 30)
    r = train.unroll_pair(net, s, 0, s.gt[1][1], s.exposure, net.cfg.N, crop)
    sample = train.make_sample(s, 0, crop, s.gt[1][1], s.exposure, net.cfg.N)
    pairs = [sample.ev["g1"], sample.ev["g2"]] if mode == "m" else [sample.ev["g1"]]
    imgs = [sample.rs1, sample.rs2] if mode == "m" else [sample.rs1]
    inputs = {"rs": torch.from_numpy(np.stack(imgs))}
    for i, name in enumerate(("ev1", "ev2", "ev3")):
        inputs[name] = torch.from_numpy(np.stack([p[i] for p in pairs]))
    assert float(inputs["ev1"].sum()) > 0  # real events reach the network
    safetensors_io.save(str(tmp_path / "in.safetensors"), inputs)
    res = subprocess.run([CLI, "infer", "--model", model, "--inputs", tmp_path / "in.safetensors",
                          "--out", tmp_path / "out.safetensors", "--mode", mode], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
    got, _ = safetensors_io.load(str(tmp_path / "out.safetensors"))
    want = run_named(net, inputs, mode)
    for k, v in want.items():
        err = (got[k].float() - v).abs().max().item()
        assert err <= 1e-4, f"{k}: max abs error {err}"
    # the training/evaluation path computes the same S/M results as the plain forward, in the
    # model's encoding: the test sequence states no gamma (linear, as unroll --mode physics reads
    # it), the model's metadata says 2.2, so frames go in as v^(1/2.2) and results come back ^2.2
    g = net.cfg.gamma
    assert g == 2.2
    enc = dict(inputs, rs=inputs["rs"] ** (1 / g))
    want_enc = run_named(net, enc, mode)
    assert torch.allclose(r["s1"], want_enc["fused"][0:1].clamp(min=0) ** g, atol=1e-5)
    if mode == "m":
        assert torch.allclose(r["m"], want_enc["out"].clamp(min=0) ** g, atol=1e-5)


def edi_pixel(ts, ps, S, E, c):
    """kernels/physics_unroll.cpp physics_unroll_ref for one pixel (times relative to t*), as written there."""
    f0 = sum(p for t, p in zip(ts, ps) if t <= 0)
    f = sum(p for t, p in zip(ts, ps) if t <= S)
    terms, prev = [], S
    for i in range(len(ts) + 1):
        last = i == len(ts)
        t = E if last else ts[i]
        if not last and t <= S:
            continue
        seg_end = min(t, E)
        if seg_end > prev:
            terms.append(np.log(seg_end - prev) + c * (f - f0))
            prev = seg_end
        if last or t >= E:
            break
        f += ps[i]
    m = max(terms)
    return np.log(E - S) - (m + np.log(sum(np.exp(v - m) for v in terms)))


def test_python_physics_fallback_matches_the_cpp_reference_formula(seq_dir):
    from tools.eval import evaluate
    s = Sequence(seq_dir)
    k, t_star, c, g = 1, s.gt[3][1], 0.2, 2.2
    got = evaluate.physics_edi(s, k, t_star, c, g)
    S_abs, E_abs = s.row_times(k)
    t, x, y, p = s.events
    rs = s.frame(k)
    checked = 0
    for (px, py) in ((3, 4), (20, 10), (40, 30), (63, 47), (10, 40), (33, 21)):
        S, E = S_abs[py] - t_star, E_abs[py] - t_star
        sel = (x == px) & (y == py) & (t - t_star >= min(S, 0)) & (t - t_star <= max(E, 0))
        lr = edi_pixel(list(t[sel] - t_star), [1 if q else -1 for q in p[sel]], S, E, c)
        want = np.power(np.exp(np.log(np.power(rs[:, py, px].astype(np.float64), g)) + lr), 1 / g)
        np.testing.assert_allclose(got[:, py, px], want, rtol=1e-5)
        checked += int(sel.sum() > 0)
    assert checked >= 3  # pixels with events were compared


def test_supervised_comparison_mode_reads_ground_truth(seq_dir):
    """--supervised draws t* at ground-truth instants and uses L1 to them."""
    net = SelfUnroll(tiny_cfg())
    train.init_model(net, 1)
    sampler = train.Sampler([Sequence(seq_dir)], 32, 32, net.cfg.N, None, random.Random(2), supervised=True)
    batch = [sampler.draw() for _ in range(2)]
    assert all(b.gt is not None and b.gt.shape == (3, 32, 32) for b in batch)
    assert all(set(b.ev) == {"g1", "g2"} for b in batch)  # only the passes toward t* are binned
    L = train.stage_s_losses(net, batch, supervised=True)
    assert set(L) == {"sup", "tv", "total"} and float(L["sup"]) > 0
    L = train.stage_m_losses(net, batch, supervised=True)
    assert set(L) == {"sup", "total"}
