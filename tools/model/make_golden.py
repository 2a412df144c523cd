#!/usr/bin/python3
"""Writes the golden fixtures of the model parity tests (tests/data/selfunroll_*.safetensors).

A tiny SelfUnroll (D=2, C=2, G=8, G0=16, N=4, UPNet width 32, UNets flownet 4/4, fusion_net 4/3,
attfusion_net 8/2 (base/depth)) with fixed-seed weights rounded to fp16 (stored as F16, exact),
inputs with fp16-exact values, and every intermediate of the PyTorch mirror in fp32:

  selfunroll_tiny.safetensors        weights + configuration metadata
  selfunroll_golden_m_64x48.safetensors  rs, ev1, ev2, ev3 (B=2) + sys, E, flow, warped, fused, m, out
  selfunroll_golden_s_64x48.safetensors  batch item 0 of the above, run as SelfUnroll-S (no m, out)
  selfunroll_golden_m_37x29.safetensors  odd size, SelfUnroll-M

and, with --physics only, the physics-informed variant (docs/model.md) of the same tiny network
(SFENet1 with 4*(6+6N) inputs), for the C++ side's parity tests once it knows the variant:

  selfunroll_tiny_physics.safetensors             weights + metadata (physics_input=true, gamma=2.2)
  selfunroll_golden_physics_m_64x48.safetensors   rs, ev1, ev2, ev3, phys (B=2; phys up to 1.5, so the
                                                   graph's clamp to [0, 1] is exercised) + every output
  selfunroll_golden_physics_s_64x48.safetensors   item 0 as SelfUnroll-S
  selfunroll_golden_physics_m_37x29.safetensors   odd size

Usage: /usr/bin/python3 -m tools.model.make_golden [OUT_DIR] [--physics]   (default tests/data)
"""
import argparse
import os

import torch

from tools.model import safetensors_io
from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig, UnetConfig, random_init_, run_named

SEED = 20240611


def tiny_config() -> SelfUnrollConfig:
    return SelfUnrollConfig(D=2, C=2, G=8, G0=16, N=4, upnet_width=32,
                            flownet=UnetConfig(4, 4), fusion_net=UnetConfig(4, 3), attfusion_net=UnetConfig(8, 2),
                            description="vkunroll golden fixture: tiny random SelfUnroll")


def tiny_model(physics: bool = False) -> SelfUnroll:
    cfg = tiny_config()
    if physics:
        cfg.physics_input, cfg.gamma = True, 2.2
        cfg.description = "vkunroll golden fixture: tiny random SelfUnroll, physics-informed variant"
    net = SelfUnroll(cfg).eval()
    random_init_(net, seed=SEED)
    with torch.no_grad():
        # flows of a few pixels (not saturated at +-100) so the warp interpolates inside the image
        net.flownet.pred.weight.mul_(0.03)
        net.flownet.pred.bias.zero_()
        net.UPNet[2].weight.mul_(0.2)        # E mostly inside tanh's linear range
        net.attfusion_net.pred.weight.mul_(5.0)  # blend maps that span [0, 1] and clamp somewhere
        for p in net.parameters():
            p.copy_(p.half().float())
    return net


def make_inputs(b: int, h: int, w: int, n: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    rs = torch.rand(b, 3, h, w, generator=g).half().float()

    def events():
        counts = torch.randint(0, 4, (b, 2 * n, h, w), generator=g).float()
        return counts * (torch.rand(b, 2 * n, h, w, generator=g) < 0.25).float()

    d = {"rs": rs, "ev1": events(), "ev2": events(), "ev3": events()}
    return d


def with_phys(inputs, seed: int):
    """A physics estimate near rs (the log ratio of a few events), partly above 1 (clamped)."""
    g = torch.Generator().manual_seed(seed)
    rs = inputs["rs"]
    phys = rs * torch.exp(0.4 * torch.randn(rs.shape[0], 1, *rs.shape[2:], generator=g))
    return dict(inputs, phys=phys.clamp(max=1.5).half().float())


def fixture(net, inputs, mode):
    outs = run_named(net, inputs, mode)
    d = {k: v.half() for k, v in inputs.items()}  # fp16-exact values: stored compactly
    d.update({k: v.float() for k, v in outs.items()})
    return d


def physics_fixtures(out_dir):
    torch.manual_seed(SEED)
    net = tiny_model(physics=True)
    safetensors_io.save(os.path.join(out_dir, "selfunroll_tiny_physics.safetensors"),
                        {k: v.half() for k, v in net.state_dict().items()}, net.cfg.to_metadata())
    model = {"model": "selfunroll_tiny_physics.safetensors"}
    m_in = with_phys(make_inputs(2, 48, 64, net.cfg.N, SEED + 1), SEED + 3)
    safetensors_io.save(os.path.join(out_dir, "selfunroll_golden_physics_m_64x48.safetensors"), fixture(net, m_in, "m"),
                        {"mode": "m", **model})
    s_in = {k: v[0:1] for k, v in m_in.items()}
    safetensors_io.save(os.path.join(out_dir, "selfunroll_golden_physics_s_64x48.safetensors"), fixture(net, s_in, "s"),
                        {"mode": "s", **model})
    o_in = with_phys(make_inputs(2, 29, 37, net.cfg.N, SEED + 2), SEED + 4)
    safetensors_io.save(os.path.join(out_dir, "selfunroll_golden_physics_m_37x29.safetensors"), fixture(net, o_in, "m"),
                        {"mode": "m", **model})


def main():
    parser = argparse.ArgumentParser(description="Writes the golden fixtures of the model parity tests.")
    parser.add_argument("out_dir", nargs="?", default=os.path.join(os.path.dirname(__file__), "..", "..", "tests", "data"),
                        help="where the fixtures go (default: tests/data)")
    parser.add_argument("--physics", action="store_true", help="only the physics-informed variant's fixtures")
    opts = parser.parse_args()
    out_dir = opts.out_dir
    os.makedirs(out_dir, exist_ok=True)
    if opts.physics:
        physics_fixtures(out_dir)
        for name in sorted(os.listdir(out_dir)):
            if name.startswith("selfunroll_") and "physics" in name:
                print(f"{name}: {os.path.getsize(os.path.join(out_dir, name))} bytes")
        return
    torch.manual_seed(SEED)
    net = tiny_model()
    cfg = net.cfg
    safetensors_io.save(os.path.join(out_dir, "selfunroll_tiny.safetensors"),
                        {k: v.half() for k, v in net.state_dict().items()}, cfg.to_metadata())
    m_in = make_inputs(2, 48, 64, cfg.N, SEED + 1)
    safetensors_io.save(os.path.join(out_dir, "selfunroll_golden_m_64x48.safetensors"), fixture(net, m_in, "m"),
                        {"mode": "m", "model": "selfunroll_tiny.safetensors"})
    s_in = {k: v[0:1] for k, v in m_in.items()}
    safetensors_io.save(os.path.join(out_dir, "selfunroll_golden_s_64x48.safetensors"), fixture(net, s_in, "s"),
                        {"mode": "s", "model": "selfunroll_tiny.safetensors"})
    o_in = make_inputs(2, 29, 37, cfg.N, SEED + 2)
    safetensors_io.save(os.path.join(out_dir, "selfunroll_golden_m_37x29.safetensors"), fixture(net, o_in, "m"),
                        {"mode": "m", "model": "selfunroll_tiny.safetensors"})
    for name in sorted(os.listdir(out_dir)):
        if name.startswith("selfunroll_"):
            print(f"{name}: {os.path.getsize(os.path.join(out_dir, name))} bytes")


if __name__ == "__main__":
    main()
