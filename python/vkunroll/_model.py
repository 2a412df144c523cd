"""The SelfUnroll network on raw tensors."""
import os

import numpy as np

from . import _args as A
from . import _vkunroll as _vk
from ._runtime import resolve_context

__all__ = ["Model"]


def _nchw(a, name, channels=None):
    if a is None or isinstance(a, (str, bytes)):
        A.refuse("Model.run", name, a, "a float array [B, C, H, W]", TypeError)
    a = np.asarray(a)
    if a.ndim == 3:
        a = a[None]
    if a.ndim != 4:
        raise ValueError(f"Model.run: {name} must be [B, C, H, W] (or [C, H, W]), got shape {a.shape}")
    if channels is not None and a.shape[1] != channels:
        raise ValueError(f"Model.run: {name} has {a.shape[1]} channels, the model expects {channels}")
    if a.dtype.kind != "f":
        raise ValueError(f"Model.run: {name} has dtype {a.dtype}, expected floats")
    if a.size and not np.isfinite(a).all():
        A.refuse("Model.run", name, "<array with NaN or inf>", "finite values")
    return np.ascontiguousarray(a, dtype=np.float32)


class Model:
    """SelfUnroll-S / -M weights loaded onto a backend. Make one with :meth:`Model.load`."""

    def __init__(self, native):
        self._m = native

    @classmethod
    def load(cls, path, context=None, backend="vulkan", threads=0, precision="fp32", gate_radius=None):
        """Load a safetensors weights file (configuration from its metadata or its shapes).

        ``backend``: "vulkan" (the GPU kernels on ``context``, default :func:`default_context`)
        or "cpu" (the CPU reference backend, fp32, ``threads`` convolution threads, 0: the
        machine's, at most 8). ``precision``: "fp32" (the reference) or "fp16" (vulkan only:
        weights and every buffer in float16, needs 16-bit storage; docs/kernels.md "Precision").
        ``gate_radius``: None (the weights' own) or an integer 0..15, the physics-informed variant's
        event gate radius, as ``vkunroll unroll --gate-radius N`` (and ``unroll(gate_radius=N)``).
        Raises FileNotFoundError for a missing file, ValueError when a tensor is missing or has the
        wrong shape (named), the precision is not available, or a gate radius is out of range or
        given for a model without an event gate.
        """
        fn = "Model.load"
        path = A.existing_path(fn, "path", path)
        threads = A.integer(fn, "threads", threads, 0, 1024)
        precision = A.choice(fn, "precision", precision, ("fp32", "fp16"))
        gate_radius = A.integer(fn, "gate_radius", gate_radius, 0, 15, none=True)
        ctx = resolve_context(context, backend)
        radius = -1 if gate_radius is None else gate_radius
        return cls(_vk._Model(path, ctx, backend, threads, precision, radius))

    @property
    def path(self):
        """The weights file."""
        return self._m.path

    @property
    def config(self):
        """The configuration as a dict: D, C, G, G0, N (= bins), upnet_width, flownet /
        fusion_net / attfusion_net ({"base", "depth"}), slopes, moa (SelfUnroll-M available),
        physics_input (the physics-informed variant), physics_contrast ("estimate" or a number),
        gamma (the encoding the model was trained in, None: unknown), channel_order ("rgb" | "bgr": the image order the weights expect), parameters, summary."""
        return dict(self._m.config)

    @property
    def backend(self):
        """The backend's name ("vulkan" or "cpu")."""
        return self._m.backend

    @property
    def precision(self):
        """The precision the model was loaded in ("fp32" or "fp16")."""
        return self._m.precision

    def run(self, rs, ev1, ev2, ev3, mode="s", precision=None, outputs=None, max_items=0, force_m=None, phys=None):
        """Run the network on raw tensors, exactly as ``vkunroll infer``.

        ``rs`` [B, 3, H, W] float images in the model's channel order (:attr:`config`
        ["channel_order"]); ``ev1``, ``ev2``, ``ev3`` [B, 2N, H, W] event tensors (e.g. from
        :func:`event_tensors_batch`). A 3-dimensional input is one item. ``mode`` "s": B targets
        run independently; "m" (SelfUnroll-M): B = 2K, items 2k and 2k+1 are RS frames 1 and 2
        toward target k. ``precision``: None (the model's, see :meth:`load`) or the one the caller
        expects, "fp32" or "fp16": a run in another precision than the model's is refused.
        ``outputs``: names among sys, E, flow, warped, fused, m, out (default: all of the mode).
        ``max_items``: most batch items run together (0: as many as fit). ``force_m``: replaces
        M's blend map by this constant (m = 1 gives S of frame 1). ``phys`` [B, 3, H, W]: the
        physics unroller's estimate at each target (:func:`physics_unroll`, in the model's
        encoding), needed by the physics-informed variant (:attr:`config` ["physics_input"]) and
        refused by the others.

        Returns a dict of float32 arrays: sys, E, flow, warped, fused [B, ...]; m, out [K, ...] in
        mode m. The GIL is released while the network runs.
        """
        fn = "Model.run"
        mode = A.choice(fn, "mode", mode, ("s", "m"))
        precision = A.choice(fn, "precision", precision, ("fp32", "fp16"), none=True)
        if outputs is not None:
            if isinstance(outputs, (str, bytes)) or not isinstance(outputs, (list, tuple)):
                A.refuse(fn, "outputs", outputs, "a list of output names (sys, E, flow, warped, fused, m, out)", TypeError)
            outputs = [A.choice(fn, "outputs", o, ("sys", "E", "flow", "warped", "fused", "m", "out")) for o in outputs]
        max_items = A.integer(fn, "max_items", max_items, 0, 1 << 20)
        force_m = A.number(fn, "force_m", force_m, 0, 1, none=True, what="a blend value")
        n = self.config["N"]
        arrays = [_nchw(rs, "rs", 3), _nchw(ev1, "ev1", 2 * n), _nchw(ev2, "ev2", 2 * n), _nchw(ev3, "ev3", 2 * n)]
        if phys is not None:
            phys = _nchw(phys, "phys", 3)
        out = self._m.run(*arrays, phys, mode, precision or "", list(outputs or []), max_items,
                          -1.0 if force_m is None else force_m)
        return dict(out)

    def __repr__(self):
        return f"vkunroll.Model({self.path!r}, {self.backend}, {self.config['summary']})"
