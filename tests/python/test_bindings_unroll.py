"""vkunroll.unroll (Python, through UnrollSession frame by frame) equals `vkunroll unroll` on the
same sequence: the GS frames (to the CLI's 8-bit PNG rounding), PSNR/SSIM and the estimated
physics contrast; arrays in give what the sequence folder gives; targets, sessions and progress."""
import csv
import json
import os
import subprocess

import numpy as np
import pytest

import vkunroll
from vkunroll import _vkunroll

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TINY = os.path.join(ROOT, "tests", "data", "selfunroll_tiny.safetensors")
TINY_PHYSICS = os.path.join(ROOT, "tests", "data", "selfunroll_tiny_physics.safetensors")
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    return vkunroll.simulate(tmp_path_factory.mktemp("sim") / "seq", width=96, height=64, frames=3, gt_per_frame=2,
                             seed=3, motion="pan")


@pytest.fixture(scope="module")
def tiny():
    """One session with the tiny model for the module's tests (its set-up paid once)."""
    return vkunroll.UnrollSession(model=TINY)


def cli_unroll(seq, out, *args):
    """The CLI's GS frames (summary.json's gs_frames, read back from its PNGs), metrics.csv, summary."""
    subprocess.run([CLI, "unroll", seq.root, "--out", str(out), "--quiet", *args], check=True, capture_output=True)
    summary = json.load(open(out / "summary.json"))
    gs = summary["gs_frames"]
    frames = [_vkunroll._read_image(str(out / g["file"]), seq.width, seq.height) for g in gs]
    return gs, frames, list(csv.DictReader(open(out / "metrics.csv"))), summary


def assert_same_as_cli(result, cli):
    gs, frames, rows, summary = cli
    rows = [r for r in rows if r["psnr"] != ""]  # metrics.csv has a row per GS frame, ground truth or not
    assert [(t["frame"], float(t["t_us"])) for t in result.targets] == [(g["frame"], g["t_us"]) for g in gs]
    # The CLI's PNGs are the same images rounded to 8 bits.
    assert np.abs(result.frames - np.stack(frames)).max() <= 0.5 / 255 + 1e-6
    with_gt = ~np.isnan(result.metrics["psnr"])
    assert with_gt.sum() == len(rows)
    np.testing.assert_allclose(result.metrics["psnr"][with_gt], [float(r["psnr"]) for r in rows], rtol=0, atol=1e-9)
    np.testing.assert_allclose(result.metrics["ssim"][with_gt], [float(r["ssim"]) for r in rows], rtol=0, atol=1e-6)
    if rows:
        assert result.metrics["mean_psnr"] == pytest.approx(summary["metrics"]["mean_psnr"], abs=1e-9)
        assert result.metrics["rs_mean_psnr"] == pytest.approx(summary["metrics"]["rs_mean_psnr"], abs=1e-9)


def test_physics_equals_cli(seq, tmp_path):
    cli = cli_unroll(seq, tmp_path / "cli", "--times", "gt", "--mode", "physics")
    summary = cli[3]
    result = vkunroll.unroll(seq, times="gt", mode="physics")  # contrast estimated
    assert result.stats["mode"] == summary["mode"] == "physics"
    assert result.stats["contrast"] == pytest.approx(summary["physics"]["contrast"], abs=1e-6)
    assert result.stats["gamma"] == pytest.approx(2.2)
    assert_same_as_cli(result, cli)
    assert len(cli[2]) == 6 and result.metrics["mean_psnr"] > result.metrics["rs_mean_psnr"]


def test_default_model_equals_cli(seq, tmp_path, monkeypatch):
    # No model named, in both: the shipped default, found by one rule (host/unroll/default_model.hpp).
    monkeypatch.delenv("VKUNROLL_MODEL", raising=False)
    cli = cli_unroll(seq, tmp_path / "cli", "--times", "0.25,0.75")
    summary = cli[3]
    assert os.path.basename(summary["model"]["path"]) == "selfunroll_small_physics.safetensors"
    assert summary["model"]["source"] == "default (source tree)" and len(summary["model"]["sha256"]) == 64
    assert os.path.samefile(vkunroll.default_model(), summary["model"]["path"])
    result = vkunroll.unroll(seq, times=[0.25, 0.75])  # every frame: M where a next frame exists, then S
    assert [t["method"] for t in result.targets] == ["m", "m", "m", "m", "s", "s"]
    assert_same_as_cli(result, cli)
    # One job behind both: the same report, each frame decoded once.
    for key in ("mode", "runs", "physics", "reads"):
        assert result.stats[key] == summary[key], key
    assert summary["reads"]["frame_decodes"] == len(seq)
    # VKUNROLL_MODEL names another file for both; a missing one is an error naming it.
    monkeypatch.setenv("VKUNROLL_MODEL", str(tmp_path / "gone.safetensors"))
    with pytest.raises(ValueError, match="VKUNROLL_MODEL=.*gone.safetensors: no such model file"):
        vkunroll.unroll(seq, times=[0.25], frames=[0])
    r = subprocess.run([CLI, "unroll", seq.root, "--out", str(tmp_path / "x"), "--quiet"], capture_output=True, text=True)
    assert r.returncode == 2 and "gone.safetensors: no such model file" in r.stderr, r.stderr


def test_model_equals_cli(seq, tiny, tmp_path):
    cli = cli_unroll(seq, tmp_path / "cli", "--model", TINY, "--times", "0.25,1.5")
    summary = cli[3]
    calls = []
    runs_m = tiny.stats()["runs_m"]
    result = vkunroll.unroll(seq, times=[0.25, 1.5], session=tiny, progress=lambda d, t, i: calls.append((d, t, i["frame"])))
    assert [t["method"] for t in result.targets] == ["m", "m", "m", "m", "s", "s"]  # auto: M where a next frame exists
    assert summary["runs"]["m"] == result.stats["session"]["runs_m"] - runs_m == 4
    assert_same_as_cli(result, cli)
    assert calls == [(2, 6, 0), (4, 6, 1), (6, 6, 2)]


def test_physics_variant_equals_cli(seq, tmp_path):
    """The physics-informed variant (gamma 2.2 in its metadata; the frames said to be linear,
    gamma 1): the frames go in as v^(1/2.2) and come back, the physics input's contrast is
    estimated as the CLI does."""
    cli = cli_unroll(seq, tmp_path / "cli", "--model", TINY_PHYSICS, "--mode", "s", "--times", "gt", "--frames", "0:1",
                     "--gamma", "1")
    summary = cli[3]
    result = vkunroll.unroll(seq, times="gt", mode="s", model=TINY_PHYSICS, frames=[0, 1], gamma=1.0)
    assert summary["physics"]["role"] == "the model's physics input"
    assert result.stats["contrast"] == pytest.approx(summary["physics"]["contrast"], abs=1e-6)
    assert result.stats["gamma"] == pytest.approx(summary["physics"]["gamma"])
    assert summary["encoding"]["sequence_gamma"] == 1 and summary["encoding"]["model_gamma"] == 2.2
    assert result.stats["encoding"]["to_model"] == pytest.approx(1 / 2.2)
    assert_same_as_cli(result, cli)


def test_arrays_equal_the_sequence(seq):
    arrays = {"frames": [seq.frame(k) for k in range(len(seq))], "timing": seq.timings, "events": seq.events(),
              "ground_truth": [(t, seq.ground_truth_image(j)) for j, (t, _) in enumerate(seq.ground_truth)]}
    from_folder = vkunroll.unroll(seq, times="gt", mode="physics", gamma=2.2)
    from_arrays = vkunroll.unroll(arrays, times="gt", mode="physics", gamma=2.2)
    assert from_arrays.stats["contrast"] == from_folder.stats["contrast"]
    np.testing.assert_array_equal(from_arrays.frames, from_folder.frames)
    np.testing.assert_array_equal(from_arrays.metrics["psnr"], from_folder.metrics["psnr"])


def test_targets_sessions_and_errors(seq, tiny):
    session = tiny
    runs_s = session.stats()["runs_s"]
    a = vkunroll.unroll(seq, times=[0, 0.5, 1], mode="s", session=session, frames=[1])
    assert [t["tau"] for t in a.targets] == [0, 0.5, 1]
    assert a.frames.shape == (3, seq.height, seq.width, 3) and a.frames.dtype == np.float32
    assert np.isnan(a.metrics["psnr"]).all() and a.metrics["count"] == 0  # no ground truth at these instants
    t_us = seq.timing(1).target_time(0.5)
    b = vkunroll.unroll(seq, times_us=[t_us], mode="s", session=session)
    assert b.targets[0]["frame"] == 1
    np.testing.assert_array_equal(b.frames[0], a.frames[1])
    assert session.stats()["runs_s"] - runs_s == 4
    one = session.unroll_frame(seq.frame(1), seq.timing(1), seq.frame_events(1), [(t_us, "s")])
    np.testing.assert_array_equal(np.clip(one[0], 0, 1), a.frames[1])  # the frame's span holds the target's events
    with pytest.raises(ValueError, match="outside the recording") as bad_time:
        vkunroll.unroll(seq, times_us=[1e9], session=session, mode="s")
    assert str(bad_time.value).startswith("times_us: ") and "--" not in str(bad_time.value), bad_time.value  # its keyword, not the CLI's flag
    with pytest.raises(ValueError, match="frame 7 does not exist"):
        vkunroll.unroll(seq, frames=[7], session=session, mode="s")
    with pytest.raises(ValueError, match="fp16 needs backend vulkan"):
        vkunroll.UnrollSession(model=TINY, backend="cpu", precision="fp16")
    with pytest.raises(ValueError, match="tile 5"):
        vkunroll.unroll(seq, tile=5, session=session, mode="s")
    with pytest.raises(ValueError, match="gate_radius='wide'"):
        vkunroll.unroll(seq, gate_radius="wide", session=session, mode="s")

    def stop(done, total, info):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        vkunroll.unroll(seq, times=[0.5], mode="physics", contrast=0.2, progress=stop)


def test_contrast_without_a_successor_is_said_as_in_the_cli(seq, tmp_path):
    # The last frame alone: no pair to estimate from, so c is a fixed 0.2, said in stats and notes.
    last = 2  # the fixture has 3 frames
    result = vkunroll.unroll(seq, times=[0.5], mode="physics", frames=[last])
    assert result.stats["contrast"] == pytest.approx(0.2)
    assert "not estimated" in result.stats["contrast_source"] and result.stats["contrast_method"] == "default"
    assert any("fixed default" in w for w in result.stats["warnings"]), result.stats["warnings"]
    summary = cli_unroll(seq, tmp_path / "cli", "--times", "0.5", "--mode", "physics", "--frames", str(last))[3]
    assert summary["physics"]["contrast_source"] == result.stats["contrast_source"]
    assert any("fixed default" in w for w in summary["warnings"])


def test_option_ranges_are_the_clis(seq):
    # One rule in the library for both front ends: a gamma or contrast no sensor has is refused.
    with pytest.raises(ValueError, match=r"gamma=1e\+300: expected a decode gamma in \[0.1, 10\]"):
        vkunroll.unroll(seq, times=[0.5], mode="physics", gamma=1e300)
    with pytest.raises(ValueError, match=r"expected a log-intensity threshold in \(0, 5\]"):
        vkunroll.unroll(seq, times=[0.5], mode="physics", contrast=1e9)


def test_a_profiling_session_reports_each_kernel_per_run(seq):
    """UnrollSession(profile=True): each unroll's stats hold every kernel's GPU time per GS frame of
    that run only (a second run on the warm session is not the sum of both), adding up to its GPU
    time; a plain session's stats have no such table."""
    plain = vkunroll.unroll(seq, times=[0.5], mode="s", frames=[1], session=vkunroll.UnrollSession(model=TINY))
    assert "gpu_ms_per_gs_frame_by_op" not in plain.stats
    session = vkunroll.UnrollSession(model=TINY, profile=True)
    for _ in range(2):
        r = vkunroll.unroll(seq, times=[0.25, 0.75], mode="s", frames=[1], session=session)
        ops = r.stats["gpu_ms_per_gs_frame_by_op"]
        assert ops, "profiled run without kernels"
        assert sum(v["ms"] for v in ops.values()) == pytest.approx(r.stats["gpu_ms_per_gs_frame"], rel=1e-6)
        assert ops["event_tensor_rows_sparse"]["calls"] == pytest.approx(0.5)  # one build for the frame's 2 targets


def test_conv_choice_gpu_equals_cli(seq, tmp_path):
    """conv_choice="gpu" (the GPU kernels' rule on any device) reaches the session as the CLI's
    --conv-choice gpu does: the same frames as the CLI with it; a bad value is named."""
    r = vkunroll.unroll(seq, times=[0.5], mode="s", frames=[1], model=TINY, conv_choice="gpu")
    assert_same_as_cli(r, cli_unroll(seq, tmp_path / "cli", "--times", "0.5", "--mode", "s", "--frames", "1",
                                     "--model", TINY, "--conv-choice", "gpu"))
    with pytest.raises(ValueError, match="conv_choice='fastest'"):
        vkunroll.UnrollSession(model=TINY, conv_choice="fastest")
