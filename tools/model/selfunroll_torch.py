"""PyTorch mirror of SelfUnroll-S / -M, written from docs/network.md.

Module and parameter names are the published checkpoints' key names, so
`SelfUnroll(cfg).load_state_dict(checkpoint)` works on a converted or original state_dict.
Used for golden vectors (tools/model/make_golden.py), the converter (tools/model/convert_checkpoint.py),
the model bench and the training code.

    from tools.model.selfunroll_torch import SelfUnroll, SelfUnrollConfig
    net = SelfUnroll(SelfUnrollConfig())            # the published configuration
    sys_, E, flow, warped, fused, m, out = net(rs, ev1, ev2, ev3)   # B = 2 for -M
    net(rs, ev1, ev2, ev3, moa=False)               # SelfUnroll-S: m and out are None

The physics-informed variant (cfg.physics_input, docs/model.md "Physics-informed variant") takes a
fifth input `phys` [B,3,H,W], the physics unroller's estimate of the same target (tools/model/physics_numpy.py):
E-IC_T reads cat(rs, ev1, ev2, ev3, clamp(phys, 0, 1)) and computes sys = clamp(phys, 0, 1) + E.
    net(rs, ev1, ev2, ev3, phys=phys)
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Optional

import torch
import torch.nn as nn
import torch.nn.functional as F


@dataclass
class UnetConfig:
    base: int = 32
    depth: int = 3


@dataclass
class SelfUnrollConfig:
    D: int = 10          # residual dense blocks
    C: int = 5           # convs per block
    G: int = 48          # growth rate
    G0: int = 96         # block width
    N: int = 16          # temporal bins: each event tensor has 2N channels
    upnet_width: int = 256  # UPNet.0 output channels (before depth_to_space(2))
    flownet: UnetConfig = field(default_factory=lambda: UnetConfig(32, 4))
    fusion_net: UnetConfig = field(default_factory=lambda: UnetConfig(32, 3))
    attfusion_net: UnetConfig = field(default_factory=lambda: UnetConfig(32, 3))
    rdb_slope: float = 0.01   # LeakyReLU slope inside the residual dense blocks
    unet_slope: float = 0.1   # LeakyReLU slope inside the UNets
    moa: bool = True          # attfusion_net present (SelfUnroll-M possible)
    channel_order: str = "rgb"
    description: str = ""
    # Physics-informed variant: E-IC_T also reads the physics unroller's estimate and corrects it.
    physics_input: bool = False
    # The intensity encoding the model was trained in (PNG value = linear^(1/gamma)); None: not stated.
    gamma: Optional[float] = None
    # Variant only: the physics estimate's contrast threshold: "estimate" (host/unroll.cpp
    # estimate_contrast on the sequence, as --mode physics) or a number.
    physics_contrast: str = "estimate"
    # Variant only: event gate radius r (-1: none). fused = physics wherever no event of ev1/ev2
    # lies within the (2r+1)^2 square around the pixel (there physics = rs is exact up to noise).
    physics_gate: int = -1
    # Variant only: a learned confidence. fusion_net predicts a 4th channel and
    # fused = c * fusion_net + (1 - c) * phys, c = hardsigmoid(channel 3), before the gate.
    physics_confidence: bool = False

    @property
    def ev_channels(self) -> int:
        return 2 * self.N

    @property
    def eict_inputs(self) -> int:
        """Channels of E-IC_T's input before space_to_depth: rs, ev1, ev2, ev3 (+ phys)."""
        return 3 + 3 * self.ev_channels + (3 if self.physics_input else 0)

    # ---- safetensors metadata (all values are strings) --------------------------------------
    def to_metadata(self) -> Dict[str, str]:
        md = {
            "format": "vkunroll-selfunroll",
            "D": str(self.D), "C": str(self.C), "G": str(self.G), "G0": str(self.G0), "N": str(self.N),
            "upnet_width": str(self.upnet_width),
            "rdb_slope": repr(float(self.rdb_slope)), "unet_slope": repr(float(self.unet_slope)),
            "moa": "true" if self.moa else "false",
            "channel_order": self.channel_order, "description": self.description,
        }
        for name in ("flownet", "fusion_net", "attfusion_net"):
            u = getattr(self, name)
            md[f"{name}.base"] = str(u.base)
            md[f"{name}.depth"] = str(u.depth)
        if self.gamma is not None:
            md["gamma"] = repr(float(self.gamma))
        if self.physics_input:  # absent for the published family: its metadata stays as it was
            md["physics_input"] = "true"
            md["physics_contrast"] = str(self.physics_contrast)
            if self.physics_gate >= 0:
                md["physics_gate"] = str(int(self.physics_gate))
            if self.physics_confidence:
                md["physics_confidence"] = "true"
        return md

    @staticmethod
    def from_metadata(md: Mapping[str, str]) -> "SelfUnrollConfig":
        c = SelfUnrollConfig()
        for k in ("D", "C", "G", "G0", "N", "upnet_width"):
            if k in md:
                setattr(c, k, int(md[k]))
        for k in ("rdb_slope", "unet_slope"):
            if k in md:
                setattr(c, k, float(md[k]))
        if "moa" in md:
            c.moa = md["moa"] == "true"
        c.channel_order = md.get("channel_order", "rgb")
        c.description = md.get("description", "")
        if md.get("physics_input", "false") not in ("true", "false"):
            raise ValueError(f"metadata 'physics_input' = '{md['physics_input']}' (expected true or false)")
        c.physics_input = md.get("physics_input") == "true"
        c.physics_contrast = md.get("physics_contrast", "estimate")
        if "physics_gate" in md:
            try:
                c.physics_gate = int(md["physics_gate"])
            except ValueError:
                c.physics_gate = -2
            if c.physics_gate < 0 or not c.physics_input:
                raise ValueError(f"metadata 'physics_gate' = '{md['physics_gate']}' (expected an integer >= 0, "
                                 "and only with physics_input=true)")
        if md.get("physics_confidence", "false") not in ("true", "false") or (
                md.get("physics_confidence") == "true" and not c.physics_input):
            raise ValueError(f"metadata 'physics_confidence' = '{md['physics_confidence']}' (expected true or false, "
                             "and true only with physics_input=true)")
        c.physics_confidence = md.get("physics_confidence") == "true"
        if "gamma" in md:
            c.gamma = float(md["gamma"])
            if not c.gamma > 0:
                raise ValueError(f"metadata 'gamma' = '{md['gamma']}' (expected a positive number)")
        for name in ("flownet", "fusion_net", "attfusion_net"):
            u = getattr(c, name)
            if f"{name}.base" in md:
                u.base = int(md[f"{name}.base"])
            if f"{name}.depth" in md:
                u.depth = int(md[f"{name}.depth"])
        return c


def infer_config(shapes: Mapping[str, tuple]) -> SelfUnrollConfig:
    """The configuration from tensor shapes (name -> shape); slopes keep the published values."""
    def need(key):
        if key not in shapes:
            raise KeyError(f"cannot infer the configuration: tensor '{key}' is missing")
        return tuple(shapes[key])

    c = SelfUnrollConfig()
    w = need("SFENet1.weight")
    c.G0 = w[0]
    # 4*(3+6N) input channels (published family) or 4*(6+6N) (physics-informed variant: + phys);
    # the two never coincide (3+6N is odd, 6+6N even)
    if w[1] % 4 or (w[1] // 4 - 3) % 6 and (w[1] // 4 - 6) % 6:
        raise ValueError(f"SFENet1.weight has {w[1]} input channels; expected 4*(3+6N) or 4*(6+6N) (physics variant)")
    c.physics_input = (w[1] // 4) % 2 == 0
    c.N = (w[1] // 4 - (6 if c.physics_input else 3)) // 6
    c.D = len({m.group(1) for k in shapes for m in [re.match(r"RDBs\.(\d+)\.LFF\.weight$", k)] if m})
    c.C = len({m.group(1) for k in shapes for m in [re.match(r"RDBs\.0\.convs\.(\d+)\.conv\.0\.weight$", k)] if m})
    c.G = need("RDBs.0.convs.0.conv.0.weight")[0]
    c.upnet_width = need("UPNet.0.weight")[0]
    for name in ("flownet", "fusion_net", "attfusion_net"):
        u = getattr(c, name)
        head = f"{name}.head.weight"
        if head not in shapes:
            if name == "attfusion_net":
                c.moa = False
                continue
            need(head)
        u.base = shapes[head][0]
        u.depth = len({m.group(1) for k in shapes
                       for m in [re.match(rf"{re.escape(name)}\.down_path\.(\d+)\.down\.0\.weight$", k)] if m})
    c.physics_confidence = need("fusion_net.pred.weight")[0] == 4
    return c


# ---- building blocks (Sequential indices reproduce the checkpoint keys) ---------------------

def conv_act(cin, cout, k, s, p, slope):
    # conv, (absent) norm, activation: the conv is element 0
    return nn.Sequential(nn.Conv2d(cin, cout, k, s, p), nn.Identity(), nn.LeakyReLU(slope))


class ResBlock(nn.Module):
    def __init__(self, w, slope):
        super().__init__()
        self.conv = nn.Sequential(conv_act(w, w, 3, 1, 1, slope), nn.Conv2d(w, w, 3, 1, 1))

    def forward(self, x):
        return x + self.conv(x)


class DownBlock(nn.Module):
    def __init__(self, w, wnext, slope):
        super().__init__()
        self.conv1 = ResBlock(w, slope)
        self.conv2 = conv_act(w, w, 1, 1, 0, slope)
        self.down = conv_act(w, wnext, 3, 2, 1, slope)

    def forward(self, x):
        x = self.conv1(x)
        return self.down(x), self.conv2(x)


class UpBlock(nn.Module):
    def __init__(self, wprev, w, slope):
        super().__init__()
        self.deconv = nn.Sequential(nn.ConvTranspose2d(wprev, w, 4, 2, 1), nn.Identity(), nn.LeakyReLU(slope))
        self.conv_skip = conv_act(w, w, 1, 1, 0, slope)
        self.conv1 = conv_act(2 * w, w, 3, 1, 1, slope)
        self.conv2 = ResBlock(w, slope)

    def forward(self, x, skip):
        x = torch.cat([self.deconv(x), self.conv_skip(skip)], 1)
        return self.conv2(self.conv1(x))


def size_adapter_pads(h: int, w: int, multiple: int = 32):
    """(top, bottom, left, right) reflection pads; the odd remainder goes to the bottom/right."""
    dh = -h % multiple
    dw = -w % multiple
    return dh // 2, dh - dh // 2, dw // 2, dw - dw // 2


class Unet(nn.Module):
    def __init__(self, cin, cout, base, depth, slope):
        super().__init__()
        self.depth = depth
        self.head = nn.Conv2d(cin, base, 3, 1, 1)
        self.down_path = nn.ModuleList([DownBlock(base << i, base << (i + 1), slope) for i in range(depth)])
        self.bottom = nn.Sequential(ResBlock(base << depth, slope), ResBlock(base << depth, slope))
        self.up_path = nn.ModuleList([UpBlock(base << (i + 1), base << i, slope) for i in range(depth)])
        self.pred = nn.Conv2d(base, cout, 3, 1, 1)

    def forward(self, x):
        h, w = x.shape[-2:]
        top, bottom, left, right = size_adapter_pads(h, w)
        x = F.pad(x, (left, right, top, bottom), mode="reflect") if (top or bottom or left or right) else x
        x = self.head(x)
        skips = []
        for blk in self.down_path:
            x, s = blk(x)
            skips.append(s)
        x = self.bottom(x)
        for i in range(self.depth - 1, -1, -1):
            x = self.up_path[i](x, skips[i])
        x = self.pred(x)
        return x[:, :, top:top + h, left:left + w]


class RDBConv(nn.Module):
    def __init__(self, cin, g, slope):
        super().__init__()
        self.conv = nn.Sequential(nn.Conv2d(cin, g, 3, 1, 1), nn.LeakyReLU(slope))

    def forward(self, x):
        return torch.cat([x, self.conv(x)], 1)


class RDB(nn.Module):
    def __init__(self, g0, g, c, slope):
        super().__init__()
        self.convs = nn.Sequential(*[RDBConv(g0 + i * g, g, slope) for i in range(c)])
        self.LFF = nn.Conv2d(g0 + c * g, g0, 1, 1, 0)

    def forward(self, x):
        return self.LFF(self.convs(x)) + x


def backward_warp(img: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """Bilinear sample of img at (x + flow_x, y + flow_y), positions clamped to the image
    (= grid_sample(align_corners=True, padding_mode='border')), safe for width/height 1."""
    b, c, h, w = img.shape
    ys = torch.arange(h, dtype=img.dtype, device=img.device).view(1, h, 1)
    xs = torch.arange(w, dtype=img.dtype, device=img.device).view(1, 1, w)
    px = (xs + flow[:, 0]).clamp(0, w - 1)
    py = (ys + flow[:, 1]).clamp(0, h - 1)
    x0 = px.floor()
    y0 = py.floor()
    ax = px - x0
    ay = py - y0
    x0i = x0.long()
    y0i = y0.long()
    x1i = (x0i + 1).clamp(max=w - 1)
    y1i = (y0i + 1).clamp(max=h - 1)
    flat = img.reshape(b, c, h * w)

    def tap(yi, xi):
        idx = (yi * w + xi).reshape(b, 1, h * w).expand(b, c, h * w)
        return flat.gather(2, idx).reshape(b, c, h, w)

    ax = ax.unsqueeze(1)
    ay = ay.unsqueeze(1)
    top = tap(y0i, x0i) * (1 - ax) + tap(y0i, x1i) * ax
    bot = tap(y1i, x0i) * (1 - ax) + tap(y1i, x1i) * ax
    return top * (1 - ay) + bot * ay


def reference_bwarp(img: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """The authors' formulation (grid_sample); divides by zero for width or height 1."""
    b, _, h, w = img.shape
    gx = torch.linspace(-1.0, 1.0, w, dtype=img.dtype).view(1, 1, 1, w).expand(b, -1, h, -1)
    gy = torch.linspace(-1.0, 1.0, h, dtype=img.dtype).view(1, 1, h, 1).expand(b, -1, -1, w)
    f = torch.cat([flow[:, 0:1] / ((w - 1.0) / 2.0), flow[:, 1:2] / ((h - 1.0) / 2.0)], 1)
    g = (torch.cat([gx, gy], 1) + f).permute(0, 2, 3, 1)
    return F.grid_sample(img, g, mode="bilinear", padding_mode="border", align_corners=True)


def event_gate(ev1: torch.Tensor, ev2: torch.Tensor, radius: int) -> torch.Tensor:
    """[B,1,H,W] 1 where an event of ev1 or ev2 (any channel) lies within the (2r+1)^2 square
    around the pixel, else 0: clamp(conv(cat(ev1, ev2), ones[1, 4N, 2r+1, 2r+1], zero padding r), 0, 1)
    (counts are integers >= 0). ev1 and ev2 together hold every event physics uses."""
    x = torch.cat([ev1, ev2], 1)
    k = 2 * radius + 1
    w = torch.ones(1, x.shape[1], k, k, dtype=x.dtype, device=x.device)
    return F.conv2d(x, w, padding=radius).clamp(0.0, 1.0)


def event_gate_items(ev1: torch.Tensor, ev2: torch.Tensor, radii) -> torch.Tensor:
    """event_gate with batch item i at radii[i] (training at the radius `--gate-radius auto` picks
    for each item's recording)."""
    return torch.cat([event_gate(ev1[i:i + 1], ev2[i:i + 1], int(r)) for i, r in enumerate(radii)])


class SelfUnroll(nn.Module):
    def __init__(self, cfg: Optional[SelfUnrollConfig] = None):
        super().__init__()
        cfg = cfg or SelfUnrollConfig()
        self.cfg = cfg
        nev = cfg.ev_channels
        self.SFENet1 = nn.Conv2d(4 * cfg.eict_inputs, cfg.G0, 5, 1, 2)
        self.SFENet2 = nn.Conv2d(cfg.G0, cfg.G0, 3, 1, 1)
        self.RDBs = nn.ModuleList([RDB(cfg.G0, cfg.G, cfg.C, cfg.rdb_slope) for _ in range(cfg.D)])
        self.GFF = nn.Sequential(nn.Conv2d(cfg.D * cfg.G0, cfg.G0, 1, 1, 0), nn.Conv2d(cfg.G0, cfg.G0, 3, 1, 1))
        self.UPNet = nn.Sequential(nn.Conv2d(cfg.G0, cfg.upnet_width, 3, 1, 1), nn.PixelShuffle(2),
                                   nn.Conv2d(cfg.upnet_width // 4, 3, 3, 1, 1))
        s = cfg.unet_slope
        self.flownet = Unet(2 * nev + 3, 2, cfg.flownet.base, cfg.flownet.depth, s)
        self.fusion_net = Unet(3 + 3 + 2 + nev + 3, 4 if cfg.physics_confidence else 3, cfg.fusion_net.base,
                               cfg.fusion_net.depth, s)
        if cfg.moa:
            self.attfusion_net = Unet(3 + 3 + 2 * nev + 2 + 2, 1, cfg.attfusion_net.base, cfg.attfusion_net.depth, s)

    def forward(self, rs, ev1, ev2, ev3, moa: Optional[bool] = None, force_m: Optional[float] = None, phys=None,
                gate_radii=None):
        """Returns (sys, E, flow, warped, fused, m, out); m and out are None for SelfUnroll-S.
        `phys` (physics-informed variant only, [B,3,H,W]): the physics unroller's estimate.
        `gate_radii` (a gated variant): each item's event gate radius instead of cfg.physics_gate.
        `force_m` replaces the blend map by a constant (tests: m = 1 gives S of frame 1).
        An odd height or width (space_to_depth needs even sizes) is handled by padding every
        input by one row/column at the bottom/right (reflection; replication for size 1),
        running the network, and cropping every output back."""
        if moa is None:
            moa = self.cfg.moa and rs.shape[0] == 2
        if (phys is not None) != self.cfg.physics_input:
            raise ValueError("the physics-informed variant needs phys (the physics estimate)" if self.cfg.physics_input
                             else "phys given, but this model has no physics input")
        h, w = rs.shape[-2:]
        if h % 2 or w % 2:
            pads = (0, w % 2, 0, h % 2)
            def even(t):
                mode = "reflect" if (h > 1 or h % 2 == 0) and (w > 1 or w % 2 == 0) else "replicate"
                return None if t is None else F.pad(t, pads, mode=mode)
            res = self.forward(even(rs), even(ev1), even(ev2), even(ev3), moa=moa, force_m=force_m, phys=even(phys),
                               gate_radii=gate_radii)
            return tuple(None if t is None else t[:, :, :h, :w] for t in res)
        if phys is not None:
            phys = phys.clamp(0.0, 1.0)  # the physics output is capped at 1e4, not at 1
        x0 = torch.cat([rs, ev1, ev2, ev3] + ([phys] if phys is not None else []), 1)
        f1 = self.SFENet1(F.pixel_unshuffle(x0, 2))
        x = self.SFENet2(f1)
        outs = []
        for blk in self.RDBs:
            x = blk(x)
            outs.append(x)
        g = self.GFF(torch.cat(outs, 1)) + f1
        E = torch.tanh(self.UPNet(g))
        sys_ = (phys if phys is not None else rs) + E

        flow = 100.0 * torch.tanh(self.flownet(torch.cat([ev1, ev2, rs], 1)))
        warped = backward_warp(rs, flow)
        fused = self.fusion_net(torch.cat([sys_, warped, flow, ev3, rs], 1))
        if phys is not None and self.cfg.physics_confidence:
            c = F.hardsigmoid(fused[:, 3:4])  # = the C++ blend(hardsigmoid(score), a, b)
            fused = c * fused[:, :3] + (1 - c) * phys
        if phys is not None and self.cfg.physics_gate >= 0:
            g = (event_gate(ev1, ev2, self.cfg.physics_gate) if gate_radii is None
                 else event_gate_items(ev1, ev2, gate_radii))
            fused = g * fused + (1 - g) * phys  # = the C++ blend(m, a, b) op
        if not moa:
            return sys_, E, flow, warped, fused, None, None
        if rs.shape[0] != 2:
            raise ValueError(f"SelfUnroll-M needs batch 2 (frames 1 and 2), got {rs.shape[0]}")
        if not hasattr(self, "attfusion_net"):
            raise ValueError("this model has no attfusion_net (MOA) weights: SelfUnroll-S only")
        m, out = self.moa_blend(E[0:1], E[1:2], ev1[0:1], ev1[1:2], flow[0:1], flow[1:2], fused[0:1], fused[1:2],
                                force_m)
        return sys_, E, flow, warped, fused, m, out

    def moa_blend(self, E1, E2, ev1_1, ev1_2, flow1, flow2, fused1, fused2, force_m: Optional[float] = None,
                  grad_leak: float = 0.0):
        """The MOA stage on S results of frames 1 and 2 (any batch: item i of each is one pair);
        returns (m, out). forward() uses it for B = 2; training calls it on batches of pairs.
        `grad_leak` (training only) adds grad_leak * score / 6 to m's gradient and nothing to its
        value: hardsigmoid has zero gradient beyond +-3, where a blend that saturated early stays."""
        score = self.attfusion_net(torch.cat([E1, E2, ev1_1, ev1_2, flow1, flow2], 1))
        m = F.hardsigmoid(score) if force_m is None else torch.full_like(score, float(force_m))
        if grad_leak and force_m is None:
            m = m + grad_leak * (score - score.detach()) / 6.0  # + 0 exactly in the forward pass
        return m, m * fused1 + (1 - m) * fused2


OUTPUT_NAMES = ("sys", "E", "flow", "warped", "fused", "m", "out")


def run_named(net: SelfUnroll, inputs: Mapping[str, torch.Tensor], mode: str = "m") -> Dict[str, torch.Tensor]:
    """Runs on a dict with rs, ev1, ev2, ev3 (+ phys for the variant) and returns the intermediates by name."""
    with torch.no_grad():
        res = net(inputs["rs"], inputs["ev1"], inputs["ev2"], inputs["ev3"], moa=(mode == "m"), phys=inputs.get("phys"))
    return {k: v for k, v in zip(OUTPUT_NAMES, res) if v is not None}


def random_init_(net: nn.Module, seed: int = 0, gain: float = 1.0) -> None:
    """Deterministic weights with activations of order one through the whole network
    (He-style uniform by fan-in; biases small), so parity tests exercise every op."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in net.named_parameters():
            if name.endswith("weight"):
                fan_in = p.shape[1] * p.shape[2] * p.shape[3]
                if ".deconv." in name:  # ConvTranspose2d: [in, out, k, k], each output sums in*k*k/4 taps
                    fan_in = p.shape[0] * p.shape[2] * p.shape[3] / 4
                bound = gain * (3.0 / fan_in) ** 0.5
                p.copy_((torch.rand(p.shape, generator=g) * 2 - 1) * bound)
            else:
                p.copy_((torch.rand(p.shape, generator=g) * 2 - 1) * 0.05)


def config_dict(cfg: SelfUnrollConfig) -> dict:
    return dataclasses.asdict(cfg)


def load_model(path: str) -> SelfUnroll:
    """A SelfUnroll with the weights and configuration of a vkunroll weights file (safetensors)."""
    from tools.model import safetensors_io
    tensors, meta = safetensors_io.load(path)
    shapes = infer_config({k: tuple(v.shape) for k, v in tensors.items()})
    cfg = SelfUnrollConfig.from_metadata(meta) if "D" in meta else shapes
    if "physics_input" not in meta:
        cfg.physics_input = shapes.physics_input
    net = SelfUnroll(cfg)
    net.load_state_dict({k: v.float() for k, v in tensors.items()}, strict=True)
    return net.eval()


def save_model(net: SelfUnroll, path: str, fp16: bool = False) -> None:
    """Writes a vkunroll weights file (what tools/model/convert_checkpoint.py writes) from a mirror."""
    from tools.model import safetensors_io
    dtype = torch.float16 if fp16 else torch.float32
    safetensors_io.save(path, {k: v.detach().to(dtype) for k, v in net.state_dict().items()}, net.cfg.to_metadata())


def add_confidence(net: "SelfUnroll", bias: float = 2.9) -> "SelfUnroll":
    """The variant `net` with a learned confidence: the same weights, and fusion_net.pred's new 4th
    output channel zero but for its bias, so c = hardsigmoid(bias) everywhere (2.9: c = 0.983, near
    the input model's output yet inside hardsigmoid's slope, where c can learn)."""
    if not net.cfg.physics_input:
        raise ValueError("a learned confidence needs the physics-informed variant")
    if net.cfg.physics_confidence:
        return net
    import copy
    cfg = copy.deepcopy(net.cfg)
    cfg.physics_confidence = True
    out = SelfUnroll(cfg)
    sd = net.state_dict()
    w, b = sd["fusion_net.pred.weight"], sd["fusion_net.pred.bias"]
    sd["fusion_net.pred.weight"] = torch.cat([w, torch.zeros_like(w[:1])], 0)
    sd["fusion_net.pred.bias"] = torch.cat([b, torch.full_like(b[:1], bias)], 0)
    out.load_state_dict(sd)
    return out.train(net.training)


def confidence_only(net: "SelfUnroll") -> List[torch.nn.Parameter]:
    """Freeze everything but the learned confidence (fusion_net.pred's 4th output row, weights and
    bias): gradients of the other rows are masked to zero, so Adam leaves them exactly as loaded.
    Returns the two trainable tensors."""
    if not net.cfg.physics_confidence:
        raise ValueError("confidence-only training needs a model with the learned confidence")
    for p in net.parameters():
        p.requires_grad_(False)
    pred = net.fusion_net.pred
    for p in (pred.weight, pred.bias):
        mask = torch.zeros_like(p)
        mask[3:] = 1.0
        p.requires_grad_(True)
        p.register_hook(lambda g, m=mask: g * m.to(g.device))
    return [pred.weight, pred.bias]

