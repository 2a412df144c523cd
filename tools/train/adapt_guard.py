"""Adaptation that never hurts (tools/train/train.py --adapt): the recording's last frames are held out of
the training crops, a fixed set of crops from them measures the self-supervised loss of the model,
and the export is the checkpoint with the lowest such loss, the input model itself when no step
beats it. Ground truth is never read: the loss is stage S's (Llc + Lcc + Ltc + 0.01 Ltv)."""
import os
import random
from typing import Callable, List, Optional, Tuple

import torch

from tools.data.sequence_data import Sequence

VAL_SEED = 7919  # the held-out crops' own RNG: the same crops for every evaluation and on --resume


def split_pairs(num_frames: int) -> Tuple[List[int], List[int], str]:
    """(training pairs k, held-out pairs k, how) of a recording's frame pairs (k, k+1). From 4 frames
    on, the last max(2, F // 4) frames are held out whole: no training pair touches them. With 3
    frames the last pair is held out (it shares frame 1 with the training pair); with 2 the one
    pair serves both (the held-out crops are then only other crops of the same frames)."""
    pairs = list(range(num_frames - 1))
    if num_frames >= 4:
        first_held = num_frames - max(2, num_frames // 4)
        return [k for k in pairs if k + 1 < first_held], [k for k in pairs if k >= first_held], \
            f"frames {first_held}..{num_frames - 1} held out (no training crop uses them)"
    if num_frames == 3:
        return [0], [1], "pair 1-2 held out (it shares frame 1 with the training pair 0-1)"
    return pairs, pairs, "a 2-frame recording: the held-out crops come from the same pair as the training ones"


class AdaptGuard:
    """Keeps the best model by held-out self-supervised loss. `loss_fn(net, samples)` is train.py's
    stage_s_losses; `sampler` is the adaptation's train_data.Sampler (its pairs get restricted)."""

    def __init__(self, seq: Sequence, sampler, net: torch.nn.Module, loss_fn: Callable, out: str,
                 every: int, count: int = 8, batch: int = 2, resumed: bool = False, log=print):
        train_pairs, held_pairs, self.how = split_pairs(seq.num_frames)
        self.loss_fn, self.every, self.batch, self.log = loss_fn, max(1, every), max(1, batch), log
        self.path = os.path.join(out, "adapt_best.pt")
        # the held-out crops: drawn once, from the held-out pairs, with their own RNG
        saved_rng, saved_pairs = sampler.rng, sampler.pairs
        sampler.rng, sampler.pairs = random.Random(VAL_SEED), {seq.folder: held_pairs}
        self.samples = [sampler.draw() for _ in range(count)]
        sampler.rng, sampler.pairs = saved_rng, {seq.folder: train_pairs}
        del saved_pairs
        if resumed and os.path.isfile(self.path):
            best = torch.load(self.path, map_location="cpu", weights_only=False)
            self.best_loss, self.best_step, self.input_loss = best["loss"], best["step"], best["input_loss"]
        else:  # a fresh run: the input model is the one to beat
            self.input_loss = self.best_loss = self.loss(net)
            self.best_step = 0
            self._save(net)
        log(f"[adapt] {self.how}; held-out loss of the input model {self.input_loss:.5f}")

    def loss(self, net: torch.nn.Module) -> float:
        was_training = net.training
        net.eval()
        total = 0.0
        with torch.no_grad():
            for i in range(0, len(self.samples), self.batch):
                part = self.samples[i:i + self.batch]
                total += float(self.loss_fn(net, part)["total"]) * len(part)
        net.train(was_training)
        return total / len(self.samples)

    def check(self, net: torch.nn.Module, step: int, last: bool = False) -> Optional[float]:
        """Evaluates every `every` steps and at the `last`; a strictly lower (finite) loss becomes the best."""
        if step % self.every and not last:
            return None
        v = self.loss(net)
        if v == v and v < self.best_loss:  # NaN never wins
            self.best_loss, self.best_step = v, step
            self._save(net)
        self.log(f"[adapt] step {step}: held-out loss {v:.5f} (best {self.best_loss:.5f} at step {self.best_step})")
        return v

    def finish(self, net: torch.nn.Module, info: dict) -> None:
        """Loads the best weights into `net` and says in `info` which they are."""
        weights, what = selected_so_far(os.path.dirname(self.path))
        net.load_state_dict(weights)
        info.update({"adapt_selected": what, "adapt_holdout": self.how})
        self.log(f"[adapt] exported {what}")

    def _save(self, net: torch.nn.Module) -> None:
        tmp = self.path + ".tmp"
        torch.save({"model": {k: v.detach().cpu().clone() for k, v in net.state_dict().items()},
                    "loss": self.best_loss, "step": self.best_step, "input_loss": self.input_loss}, tmp)
        os.replace(tmp, self.path)


def selected_so_far(out: str) -> Optional[Tuple[dict, str]]:
    """(weights, what they are) of the guard's choice in OUT/adapt_best.pt, also of a run still under way
    (train.py --export-checkpoint of an adaptation checkpoint exports these); None without the file."""
    path = os.path.join(out, "adapt_best.pt")
    if not os.path.isfile(path):
        return None
    best = torch.load(path, map_location="cpu", weights_only=False)
    if best["step"] == 0:
        return best["model"], f"the input model: no step lowered the held-out loss {best['input_loss']:.5f}"
    return best["model"], f"step {best['step']}: held-out loss {best['loss']:.5f} (input model {best['input_loss']:.5f})"


class IntraAnchor:
    """`--adapt-anchor W`: adaptation's pull toward the input model inside frames. For each sample
    whose t* lies inside an exposure span (Sample.intra), W x the mean |output - input model's output|
    of the g1 and g2 passes (sys, warped, fused) joins the stage S loss; samples between frames are
    free. Why: on the second generator's validation suite the self-supervised losses gained between
    frames and lost inside them (docs/journal/training.md). `reference` is the input model, never trained."""

    def __init__(self, reference: torch.nn.Module, weight: float, run_passes: Callable, branches):
        if not weight > 0:
            raise ValueError(f"--adapt-anchor {weight}: expected a weight > 0")
        self.ref, self.weight, self.run_passes, self.branches = reference.eval(), weight, run_passes, branches
        for p in self.ref.parameters():
            p.requires_grad_(False)

    def __call__(self, samples, rs1: torch.Tensor, rs2: torch.Tensor, g1: dict, g2: dict) -> torch.Tensor:
        idx = [i for i, s in enumerate(samples) if s.intra]  # the input model runs on these alone
        if not idx:
            return torch.zeros((), device=rs1.device)
        n = len(idx)
        with torch.no_grad():
            ref = self.run_passes(self.ref, torch.cat([rs1[idx], rs2[idx]]), [samples[i] for i in idx], ("g1", "g2"),
                                  rs1.device)
        total = torch.zeros((), device=rs1.device)
        for b in self.branches:
            for out, r in ((g1[b][idx], ref[b][:n]), (g2[b][idx], ref[b][n:])):
                total = total + (out - r).abs().mean()
        return total


def one_way_pair(samples, g1: torch.Tensor, g2: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
    """`--adapt-lc-one-way`: the latent consistency |g1 - g2| of a sample whose t* lies inside an exposure
    span teaches one way. The pass from the frame exposing t* integrates events over at most one readout
    and is the teacher (no gradient from this term); the pass from the other frame is pulled toward it.
    Between frames both move, as in the paper. The loss value is unchanged, so the guard's measure is too."""
    def mask(frame):
        return torch.tensor([s.exposing == frame for s in samples], device=g1.device).view(-1, 1, 1, 1)
    return torch.where(mask(0), g1.detach(), g1), torch.where(mask(1), g2.detach(), g2)
