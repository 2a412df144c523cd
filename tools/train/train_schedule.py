"""How a training run spends its time (tools/train/train.py): the torch thread count, fixed or chosen by
timing, and the learning-rate schedule."""
import math

import numpy as np
import torch


class ThreadChooser:
    """Fixed torch thread count, or 'auto': every `period` steps, time `probe` steps with 1 thread
    and up to `probe` with 2 (cut short when the first is clearly slower) and keep the faster:
    the machine's load changes during a long run, and 2 OpenMP threads on an oversubscribed
    machine can be many times slower than 1."""

    def __init__(self, spec: str, period: int = 300, probe: int = 3):
        self.auto = spec == "auto"
        self.n = 2 if self.auto else int(spec)
        self.period, self.probe = period, probe
        self.times = {1: [], 2: []}
        self.trial = None
        self.next_probe = 0
        torch.set_num_threads(self.n)

    def before_step(self, step: int) -> None:
        if not self.auto:
            return
        if self.trial is None and step >= self.next_probe:
            self.trial, self.times = 1, {1: [], 2: []}
        if self.trial == 1 and len(self.times[1]) >= self.probe:
            self.trial = 2
        if self.trial == 2:
            t1 = float(np.median(self.times[1]))
            t2 = self.times[2]
            if len(t2) >= self.probe or (t2 and t2[0] > 1.5 * t1):
                t2m = float(np.median(t2))
                self.n = 1 if t1 < t2m else 2
                print(f"threads: 1 -> {t1:.2f} s/step, 2 -> {t2m:.2f} s/step: using {self.n}", flush=True)
                self.trial, self.next_probe = None, step + self.period
        torch.set_num_threads(self.trial or self.n)

    def after_step(self, seconds: float) -> None:
        if self.trial is not None:
            self.times[self.trial].append(seconds)


def cosine_lr(lr0: float, progress: float, warmup: float = 0.02) -> float:
    if progress < warmup:
        return lr0 * max(progress / warmup, 0.05)
    return lr0 * 0.5 * (1 + math.cos(math.pi * min(1.0, progress)))
