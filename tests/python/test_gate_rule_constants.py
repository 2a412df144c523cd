"""`vkunroll unroll --gate-radius auto` and tools/eval/natural_eval.py --gate auto apply one rule: the
evaluation tool's copy of the constants equals the CLI's (host/unroll/unroll_plan.hpp), and its rule
picks as the CLI's does on both sides of each threshold."""
import os
import re

from tools.eval import natural_eval

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def header_constants():
    text = open(os.path.join(ROOT, "host", "unroll", "unroll_plan.hpp")).read()
    doubles = re.search(r"constexpr double kCleanFrameNoise = ([0-9.e-]+), kCleanIsolatedEvents = ([0-9.e-]+);", text)
    radius = re.search(r"constexpr int kNoisyGateRadius = (\d+);", text)
    assert doubles and radius, "unroll_plan.hpp no longer declares the gate rule's constants as this test reads them"
    return float(doubles.group(1)), float(doubles.group(2)), int(radius.group(1))


def test_the_evaluation_tool_uses_the_clis_constants():
    frame_noise, isolated, radius = header_constants()
    assert (natural_eval.CLEAN_FRAME_NOISE, natural_eval.CLEAN_ISOLATED_EVENTS, natural_eval.NOISY_GATE_RADIUS) == \
        (frame_noise, isolated, radius)


def test_the_rule_picks_on_each_side_of_the_thresholds():
    frame_noise, isolated, radius = header_constants()
    clean = {"frame_noise": frame_noise / 2, "isolated_event_fraction": isolated / 2}
    assert natural_eval.auto_gate_radius(clean, 1) == 1
    assert natural_eval.auto_gate_radius(dict(clean, frame_noise=frame_noise), 1) == radius
    assert natural_eval.auto_gate_radius(dict(clean, isolated_event_fraction=isolated), 1) == radius
    assert natural_eval.auto_gate_radius(dict(clean, isolated_event_fraction=isolated), radius + 1) == radius + 1
    assert natural_eval.auto_gate_radius({"frame_noise": -1.0, "isolated_event_fraction": 0.5}, 1) == 1  # not measured
