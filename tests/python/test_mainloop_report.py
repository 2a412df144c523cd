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
    assert c["fma"] == v.bm * v.bn * v.bk // v.threads()  # 32 x 64 x 16 / 128 = 256
    assert c["barrier"] == 1
    # A: vec4s of the packed weights; X: one value per gathered element; fragments of TM, TN per step.
    assert w["global_load 128b"] == -(-(v.bk * v.bm // 4) // v.threads())
    assert w["global_load 32b"] == c["x_loads"] == v.x_elements() == 8
    assert w["shared_load 128b"] == v.bk * (v.tm // 4 + v.tn // 4)
    assert c.get("local_load", 0) == 0  # every private array indexed by constants: registers
    assert row["gather"]["elements"] == 8 and row["gather"]["per_element"] > 1
    assert c["other"] > 0 and row["non_math_per_op"] == pytest.approx(
        (c["other"] + c["global_load"] + c["shared_load"] + c["shared_store"] + c["barrier"]) / c["fma"], abs=0.01)


def test_the_tensor_core_form_counts_its_mmas():
    v = mr.VARIANTS["coopmat NV"]
    row = stage("coopmat NV", "RDB")
    assert row["counts"]["mma"] == v.coopmat["fm"] * v.coopmat["fn"]
    assert row["counts"].get("fma", 0) == 0
    assert row["counts"]["fragment_load"] == v.coopmat["fm"] + v.coopmat["fn"]


def test_the_tile_table_is_the_librarys():
    text = (ROOT / "kernels" / "conv2d_igemm.cpp").read_text()
    tiles = dict(re.findall(r"case ConvAlgo::(igemm_\w): return \{([\d, ]+)\};", text))
    assert set(tiles) == {"igemm_l", "igemm_m", "igemm_s", "igemm_n"}, "conv2d_igemm.cpp's tiles moved"
    for name, values in tiles.items():
        v = mr.VARIANTS[name]
        assert [int(x) for x in values.split(",")] == [v.bm, v.bn, v.bk, v.tm, v.tn], name


def test_the_cost_mirror_gives_the_benchs_numbers():
    rows = json.loads((ROOT / "results" / "bench" / "2026-12-06-gpu-convs" / "kernels_fma.json").read_text())
    checked = 0
    for r in rows:
        if r["op"] != "conv2d" or r["algo"] not in mr.VARIANTS:
            continue
        conv = mr.Conv(r["name"], r["kernel"], r["stride"], r["cin"], r["cout"], r["h"], r["w"])
        cost = mr.igemm_cost(mr.VARIANTS[r["algo"]], conv, 1, 4)  # lavapipe: no split
        assert cost["fma"] == pytest.approx(r["model_fma"]), r["shape"]
        assert cost["global_bytes"] == pytest.approx(r["model_global_bytes"]), r["shape"]
        assert cost["shared_bytes"] == pytest.approx(r["model_shared_bytes"]), r["shape"]
        checked += 1
    assert checked >= 12
