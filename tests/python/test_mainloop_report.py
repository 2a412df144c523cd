"""tools/bench/mainloop_report.py: the static count of a K-stage matches what the tile implies, its
tile table and cost model are the library's (kernels/conv2d_igemm.cpp, the bench's rows of
kernels/igemm.cpp igemm_cost)."""
import json
import os
import re
import tempfile
from pathlib import Path

import pytest

from tools.bench import mainloop_report as mr

ROOT = Path(__file__).resolve().parents[2]


def stage(variant, conv):
    with tempfile.TemporaryDirectory() as tmp:
        return mr.report_row(mr.VARIANTS[variant], mr.CONVS[conv], ROOT / "shaders", Path(tmp), 132)


def test_a_scalar_tile_does_its_fmas_and_loads_per_stage():
    v = mr.VARIANTS["igemm_s"]
    row = stage("igemm_s", "flownet.conv1")
    c, w = row["counts"], row["widths"]
    assert c["fma"] == v.bm * v.bn * v.bk // v.threads()  # today 32 x 64 x 16 / 128 = 256
    assert c["barrier"] == 1
    # A: vec4s of the packed weights; X: one value per gathered element; fragments of TM, TN per step.
    assert w["global_load 128b"] == -(-(v.bk * v.bm // 4) // v.threads())
    assert w["global_load 32b"] == c["x_loads"] == v.x_elements()
    assert w["shared_load 128b"] == v.bk * (v.tm // 4 + v.tn // 4)
    assert c.get("local_load", 0) == 0  # every private array indexed by constants: registers
    assert row["gather"]["elements"] == v.x_elements() and row["gather"]["per_element"] > 1
    assert c["other"] > 0 and row["non_math_per_op"] == pytest.approx(
        (c["other"] + c["global_load"] + c["shared_load"] + c["shared_store"] + c["barrier"]) / c["fma"], abs=0.01)


def test_the_tensor_core_form_counts_its_mmas():
    v = mr.VARIANTS["coopmat NV"]
    row = stage("coopmat NV", "RDB")
    assert row["counts"]["mma"] == v.coopmat["fm"] * v.coopmat["fn"]
    assert row["counts"].get("fma", 0) == 0
    assert row["counts"]["fragment_load"] == v.coopmat["fm"] + v.coopmat["fn"]


def test_the_tiles_are_the_librarys_and_the_mirrors_follow_it():
    variants = mr.load_variants(ROOT)
    assert {"igemm_l", "igemm_m", "igemm_s", "igemm_n"} <= set(variants), "Conv2d::igemm_tile no longer reads"
    assert variants["igemm_m"].threads() == 256
    # coopmat_tile, igemm_kpad, igemm_splits, igemm_cost: the mirror was written against this text.
    changed = {n for n, d in mr.mirrored_digests(ROOT).items() if d != mr.MIRRORED[n]}
    assert not changed, f"kernels/igemm.cpp's {sorted(changed)} changed: update mainloop_report.py's mirror and MIRRORED"


def test_the_cost_mirror_gives_the_benchs_numbers():
    # The rows igemm_cost gave on 2026-12-06, with that day's tiles and K order (lavapipe: no split).
    rows = json.loads((ROOT / "results" / "bench" / "2026-12-06-gpu-convs" / "kernels_fma.json").read_text())
    tiles = {"igemm_l": (128, 128, 8, 8, 8), "igemm_m": (64, 64, 16, 4, 4), "igemm_s": (32, 64, 16, 4, 4),
             "igemm_n": (16, 128, 16, 4, 4)}
    checked = 0
    for r in rows:
        if r["op"] != "conv2d" or r["algo"] not in tiles:
            continue
        conv = mr.Conv(r["name"], r["kernel"], r["stride"], r["cin"], r["cout"], r["h"], r["w"])
        cost = mr.igemm_cost(mr.Variant(r["algo"], "", (), *tiles[r["algo"]]), conv, 1, 4, tap_major=False)
        assert cost["fma"] == pytest.approx(r["model_fma"]), r["shape"]
        assert cost["global_bytes"] == pytest.approx(r["model_global_bytes"]), r["shape"]
        assert cost["shared_bytes"] == pytest.approx(r["model_shared_bytes"]), r["shape"]
        checked += 1
    assert checked >= 12
