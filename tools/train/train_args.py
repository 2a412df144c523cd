"""The command line of tools/train/train.py: its options (build_parser) and their combined rules
(check_args), kept apart from the training code."""
import argparse
from typing import Tuple

import torch


def parse_size(s: str) -> Tuple[int, int]:
    try:
        w, h = s.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{s}': expected WIDTHxHEIGHT, e.g. 64x64") from None


def add_data_generation_options(ap):
    """--make-data: simulated sequences."""
    g = ap.add_argument_group("data generation")
    g.add_argument("--make-data", metavar="DIR", help="simulate --sequences sequences into DIR and exit")
    g.add_argument("--sequences", type=int, default=16)
    g.add_argument("--seed-base", type=int, default=1000)
    g.add_argument("--size", default="240x180", help="simulated sensor size [240x180]")
    g.add_argument("--frames", type=int, default=8)
    g.add_argument("--gt-per-frame", type=int, default=4)
    g.add_argument("--speeds", default="1", help="comma-separated motion speed factors, cycled [1]")
    g.add_argument("--cli", help="vkunroll executable [env VKUNROLL_CLI or build/vkunroll]")
    g.add_argument("--sim-arg", action="append", default=[], help="extra argument for vkunroll simulate (repeatable)")


def add_training_options(ap, presets):
    """The data, the model and the schedule."""
    g = ap.add_argument_group("training")
    g.add_argument("--data", nargs="+", help="sequence folders, or folders of them (generic layout)")
    g.add_argument("--val", nargs="*", default=[], help="held-out sequences with ground truth, for validation PSNR")
    g.add_argument("--out", default="runs/train", help="folder for checkpoint.pt and model.safetensors")
    g.add_argument("--export", help="weights file to write at the end [OUT/model.safetensors]")
    g.add_argument("--config", choices=sorted(presets), default="small")
    g.add_argument("--bins", type=int, help="N temporal bins (overrides the configuration's)")
    g.add_argument("--description", default="")
    g.add_argument("--init", help="start from these weights (a checkpoint.pt)")
    g.add_argument("--resume", help="continue a checkpoint.pt (stage, step, optimizer, sampler state)")
    g.add_argument("--steps-s", type=int, default=2000, help="stage 1 steps (SelfUnroll-S)")
    g.add_argument("--steps-m", type=int, default=400, help="stage 2 steps (MOA alone)")
    g.add_argument("--max-minutes", type=float, help="time budget of both stages (the cosine schedule follows it)")
    g.add_argument("--crop", type=parse_size, default=(64, 64))
    g.add_argument("--batch", type=int, default=2)
    g.add_argument("--lr", type=float, default=1e-3)
    g.add_argument("--target-exposure-us", type=float, help="GS target exposure (ev3 window) [the RS exposure]")
    g.add_argument("--seed", type=int, default=1)
    g.add_argument("--no-fusion-passthrough", action="store_true",
                   help="initialise fusion_net randomly instead of as the identity on its sys input")
    g.add_argument("--threads", default="2", help="torch threads, or 'auto': re-measure 1 vs 2 every 200 steps "
                   "(2 OpenMP threads on an oversubscribed machine can be many times slower than 1) [2]")
    g.add_argument("--supervised", action="store_true", help="L1 to the ground truth of simulated sequences "
                   "(t* at their GT instants) instead of the self-supervised losses")
    g.add_argument("--print-every", type=float, default=10.0, help="seconds between progress lines")
    g.add_argument("--ckpt-every", type=int, default=100)
    g.add_argument("--rescan-every", type=int, default=0,
                   help="every this many steps, add sequences that appeared in --data folders (data still being made)")
    g.add_argument("--stop-after", type=int, default=0, help="stop (with a checkpoint) after this many steps")
    g.add_argument("--val-every", type=int, default=0)
    g.add_argument("--val-targets", type=int, default=8)
    g.add_argument("--val-crop", type=parse_size, default=None)
    return g


def add_training_setting_options(g):
    """The training group's other options: the device, the variant and the sampling."""
    g.add_argument("--device", default="cpu", help="torch device: cpu, cuda, cuda:1, ... [cpu]")
    g.add_argument("--chunk-minutes", type=float, default=0,
                   help="stop (with a checkpoint) after this many minutes of this session; --resume continues")
    g.add_argument("--physics-variant", action="store_true",
                   help="the physics-informed variant (E-IC_T corrects the physics estimate; docs/model.md)")
    g.add_argument("--gamma", type=float, help="intensity encoding the model works in (metadata 'gamma') [2.2]")
    g.add_argument("--data-gamma", type=float, default=1.0,
                   help="encoding gamma of sequences whose meta.json states none (as unroll --mode physics) [1]")
    g.add_argument("--from", dest="from_model", metavar="MODEL.safetensors",
                   help="start from this weights file (with --physics-variant: lifted to the variant)")
    g.add_argument("--constant-lr", action="store_true", help="no warm-up or cosine decay")
    g.add_argument("--physics-gate", type=int, metavar="R",
                   help="variant: fused = physics wherever no event lies within the (2R+1)^2 square (metadata physics_gate)")
    g.add_argument("--physics-confidence", action="store_true", help="with a variant --from: add the learned "
                   "confidence (fused = c * fusion_net + (1 - c) * phys; metadata physics_confidence)")
    g.add_argument("--confidence-only", action="store_true", help="train the learned confidence alone (stage S; "
                   "every other weight stays as loaded)")
    g.add_argument("--reset-moa", action="store_true",
                   help="with --from: restart attfusion_net.pred near m = 0.5 (a saturated MOA cannot learn)")
    g.add_argument("--event-crops", type=float, default=0.0, metavar="P",
                   help="with probability P a crop is centred on a random event of its frame pair (else uniform) [0]")
    g.add_argument("--contrast-jitter", type=float, default=1.0, metavar="J",
                   help="physics variant: each sample's physics input at its recording's contrast times a factor "
                   "drawn log-uniformly in [1/J, J] (a model that tolerates a misestimated contrast) [1: none]")


def add_adaptation_and_cache_options(ap, adapt_anchor):
    """--adapt, the sample cache and --export-checkpoint."""
    g = ap.add_argument_group("adaptation to one recording (self-supervised; ground truth is never read)")
    g.add_argument("--adapt", metavar="SEQUENCE", help="fine-tune --from on this recording alone (stage S), "
                   "for --minutes; writes OUT/adapted.safetensors (or --export)")
    g.add_argument("--minutes", type=float, help="with --adapt: the time budget (= --max-minutes)")
    g.add_argument("--adapt-anchor", type=float, metavar="W", help="with --adapt: W x the mean |output - the input "
                   f"model's| for targets inside an exposure span joins the loss (between frames: free) [{adapt_anchor}; 0: off]")
    g.add_argument("--adapt-lc-one-way", action="store_true", help="with --adapt: inside an exposure span, "
                   "the latent consistency pulls the other frame's pass toward the exposing frame's, not both ways")
    g = ap.add_argument_group("sample cache (data prepared in advance, e.g. for a short GPU slot)")
    g.add_argument("--make-cache", metavar="DIR", help="draw --cache-samples samples from --data into DIR and exit")
    g.add_argument("--cache-samples", type=int, default=2048)
    g.add_argument("--cache", metavar="DIR", help="train on the samples of a cache instead of --data")
    g.add_argument("--gate-radii", metavar="FILE", help="gated variant: each --data sequence's event gate radius "
                   "(tools/train/gate_radii.py: what `unroll --gate-radius auto` picks there) instead of the model's")
    g = ap.add_argument_group("export only")
    g.add_argument("--export-checkpoint", nargs=2, metavar=("CKPT", "OUT"))


def build_parser(doc: str, presets, adapt_anchor: float) -> argparse.ArgumentParser:
    """The options; `doc`: train.py's docstring (description and epilog)."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[1], formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=doc.split("\n", 2)[2])
    add_data_generation_options(ap)
    add_training_setting_options(add_training_options(ap, presets))
    add_adaptation_and_cache_options(ap, adapt_anchor)
    return ap


def check_args(ap: argparse.ArgumentParser, a, adapt_anchor: float) -> None:
    """The options' combined rules (ap.error names the option); settles --adapt's budget and anchor."""
    if a.adapt:
        if not a.from_model and not a.resume:
            ap.error("--adapt needs --from MODEL.safetensors (the model to fine-tune)")
        if a.minutes is None and a.max_minutes is None:
            ap.error("--adapt needs --minutes M")
        a.max_minutes = a.minutes if a.minutes is not None else a.max_minutes
        if a.supervised:
            ap.error("--adapt uses the self-supervised losses only")
        a.adapt_anchor = adapt_anchor if a.adapt_anchor is None else a.adapt_anchor
        if a.adapt_anchor < 0 or (a.adapt_anchor and not a.from_model):
            ap.error(f"--adapt-anchor {a.adapt_anchor:g}: expected a weight >= 0 and --from (the input model it "
                     "pulls toward; --adapt-anchor 0 adapts without it)")
    elif a.adapt_anchor is not None or a.adapt_lc_one_way:
        ap.error(f"--adapt-{'anchor' if a.adapt_anchor is not None else 'lc-one-way'} applies to --adapt only")
    elif not a.data and not a.resume and not a.cache:
        ap.error("--data is required (or --cache / --adapt / --make-data / --export-checkpoint)")
    elif a.resume and not a.data and not a.cache:
        ap.error("--resume needs the same --data (or --cache) as the run it continues")
    if a.physics_gate is not None and (a.physics_gate < 0 or not (a.physics_variant or a.from_model)):
        ap.error("--physics-gate R needs R >= 0 and the physics variant (--physics-variant or a variant --from)")
    if a.physics_confidence and not a.from_model:
        ap.error("--physics-confidence needs a physics-variant --from model")
    if not 0.0 <= a.event_crops <= 1.0:
        ap.error(f"--event-crops {a.event_crops}: expected a probability in [0, 1]")
    if a.make_cache and a.cache:
        ap.error("--make-cache draws from --data, not from --cache")
    if not a.contrast_jitter >= 1.0:
        ap.error(f"--contrast-jitter {a.contrast_jitter}: expected a factor >= 1")
    if a.contrast_jitter > 1.0 and (a.cache or a.make_cache):
        ap.error("--contrast-jitter applies to samples drawn from --data, not to a cache")
    if a.gate_radii and (a.cache or a.make_cache):
        ap.error("--gate-radii applies to samples drawn from --data, not to a cache")
    if a.device.startswith("cuda") and not torch.cuda.is_available():
        ap.error(f"--device {a.device}: this PyTorch has no CUDA device")
