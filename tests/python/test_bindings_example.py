"""docs/python.md's worked example runs as written (its one ```python block, executed from the
repository root), and its results hold: the real recording's event count, event tensors with
events in them, the by-hand model run equal to the unroll job's frame, and both the default model
and the physics unroller beating the RS input at the ground-truth instants."""
import os
import re

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def example_code():
    text = open(os.path.join(ROOT, "docs", "python.md")).read()
    section = text.split("## Worked example", 1)[1]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the worked example is one python block"
    return blocks[0]


def test_worked_example(monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    ns = {}
    exec(compile(example_code(), "docs/python.md (worked example)", "exec"), ns)
    printed = capsys.readouterr().out
    assert printed.startswith("111954 events, aedat4, 320x240")
    assert len(ns["events"]) == 111954
    ev1, ev2, ev3 = ns["ev1"], ns["ev2"], ns["ev3"]
    assert ev1.shape == (8, 120, 160) and min(ev1.sum(), ev2.sum(), ev3.sum()) > 0
    learned, physics = ns["learned"], ns["physics"]
    np.testing.assert_array_equal(ns["by_hand"], ns["own"].frames[0])
    assert ns["own"].stats["physics"]["gate_radius"]["radius"] == 1  # the weights' own
    assert learned.targets[0]["gt"] == 0 and learned.targets[0]["method"] == "s"
    assert learned.metrics["count"] == physics.metrics["count"] == 4
    assert learned.metrics["mean_psnr"] > learned.metrics["rs_mean_psnr"] + 1
    assert physics.metrics["mean_psnr"] > physics.metrics["rs_mean_psnr"] + 1
    print(printed)
