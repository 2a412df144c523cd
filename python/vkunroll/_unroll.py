"""The unroll job: GS frames at chosen instants, frame by frame through one UnrollSession."""
import atexit
import json
import logging
import os
import queue
import threading
import weakref
from typing import NamedTuple

import numpy as np

from . import _args as A
from . import _vkunroll as _vk
from ._events import event_fields
from ._model import Model
from ._sequence import Sequence
from ._runtime import _device_arg

__all__ = ["UnrollSession", "UnrollResult", "unroll", "stream"]

_log = logging.getLogger("vkunroll")
NORMALIZED_INSTANT = ("a normalized instant within the frame (0 = the first row's exposure start, 1 = the last row's "
                      "exposure end; not microseconds)")


class UnrollSession:
    """Everything an unroll job holds, built once: device, backend, model, event-tensor builder
    and physics unroller (the library's UnrollSession). Reuse one across :func:`unroll` calls
    (``session=``) to pay the model's set-up once, or call :meth:`unroll_frame` directly.

    ``UnrollSession(model=None, backend="vulkan", device=None, precision="fp32", threads=0, profile=False,
    conv_choice="auto")``:
    ``model`` a weights file or a :class:`Model` (its file is loaded again: the session owns its
    device); None: physics only. ``backend`` "vulkan" or "cpu"; ``device`` an index or name
    substring (None: VKUNROLL_DEVICE, then the best device); ``precision`` "fp32" or "fp16"
    (vulkan only: the network's weights and buffers in float16); ``threads``: CPU backend threads;
    ``profile``: every kernel's GPU time per GS frame in each :func:`unroll` result's ``stats``
    (``gpu_ms_per_gs_frame_by_op``, as ``vkunroll unroll --profile``; Vulkan); ``conv_choice``: the
    conv algorithm per shape, as ``--conv-choice`` (auto, heuristic, cached, measured, retune, or gpu:
    the GPU kernels' rule on any device, lavapipe included).
    """

    def __init__(self, model=None, backend="vulkan", device=None, precision="fp32", threads=0, profile=False,
                 conv_choice="auto"):
        fn = "UnrollSession"
        if isinstance(model, Model):
            model = model.path
        self.model_path = "" if model is None else A.existing_path(fn, "model", model)
        A.choice(fn, "backend", backend, ("vulkan", "cpu"))
        if device is not None and backend == "cpu":
            A.refuse(fn, "device", device, "None with backend='cpu' (a device applies to the vulkan backend)")
        device = _device_arg(fn, device)
        A.choice(fn, "precision", precision, ("fp32", "fp16"))
        A.choice(fn, "conv_choice", conv_choice, CONV_CHOICES)
        self._s = _vk._Session(self.model_path, backend, device, precision, A.integer(fn, "threads", threads, 0, 1024),
                               A.flag(fn, "profile", profile), conv_choice)

    has_model = property(lambda self: self._s.has_model, doc="True when a model was loaded.")
    moa = property(lambda self: self._s.moa, doc="True when the model has MOA weights (SelfUnroll-M).")
    backend = property(lambda self: self._s.backend, doc='"vulkan" or "cpu".')
    device = property(lambda self: self._s.device, doc="The device's name ('cpu' on the CPU backend).")

    def stats(self):
        """What the session did so far: runs per method, tiles, ms per stage, device traffic."""
        return dict(self._s.stats())

    def unroll_frame(self, rs1, timing1, events, targets, rs2=None, timing2=None):
        """GS images of one RS frame: a list of H x W x 3 float32 RGB images, one per target.

        ``rs1``: the frame (H x W x 3 RGB or H x W, float in [0, 1] or uint8 / uint16);
        ``timing1`` its :class:`RowTiming`; ``events``: every target's window (see
        :func:`unroll`); ``targets``: (t_us, method) pairs, method "s", "m" or "physics";
        ``rs2``, ``timing2``: the next frame (needed by "m" targets). Model targets see the frames as
        v^e (e: the exponent into the model's gamma encoding that the last :func:`unroll` on this
        session chose, 1 on a fresh session) and come back as v^(1/e). The GIL is released.
        """
        fn = "UnrollSession.unroll_frame"
        A.row_timing(fn, "timing1", timing1, _vk.RowTiming)
        b = None if rs2 is None else _rgb(rs2, "rs2", fn)
        if rs2 is not None:
            A.row_timing(fn, "timing2", timing2, _vk.RowTiming)
        elif timing2 is not None:
            A.refuse(fn, "timing2", timing2, "None without rs2 (it is the next frame's timing)")
        if isinstance(targets, (str, bytes)) or not isinstance(targets, (list, tuple)) or not targets:
            A.refuse(fn, "targets", targets, "a non-empty list of (t_us, method) pairs", TypeError)
        checked = []
        for i, pair in enumerate(targets):
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                A.refuse(fn, f"targets[{i}]", pair, "a (t_us, method) pair", TypeError)
            checked.append((A.exact_time(fn, f"targets[{i}] t_us", pair[0]),
                            A.choice(fn, f"targets[{i}] method", pair[1], ("s", "m", "physics"))))
        t, x, y, p = event_fields(events)
        a = _rgb(rs1, "rs1", fn)
        return list(self._s.unroll_frame(a, timing1, b, timing2, t, x, y, p, checked))


class UnrollResult(NamedTuple):
    """What :func:`unroll` returns; unpacks as ``frames, metrics, targets, stats``."""
    frames: np.ndarray   #: [T, H, W, 3] float32 RGB in [0, 1], one per target
    metrics: dict        #: PSNR/SSIM per target vs ground truth (NaN without), their means, the RS input's
    targets: list        #: per target: frame, t_us (Fraction), tau, method ("s", "m", "physics"), gt index
    stats: dict          #: mode, notes, ms per GS frame, the session's counters


def _rgb(image, what, fn="unroll"):
    a = A.image(fn, what, image)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"{what}: expected an H x W x 3 (RGB) or H x W image, got shape {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float32)


class _Progress:
    """progress=None: nothing; True: tqdm when installed, else log lines; a callable:
    progress(done, total, info) after every frame. `update` is what the job calls."""

    def __init__(self, progress):
        self.progress, self.bar, self.logged = progress, None, -1

    def update(self, done, total, info):
        if callable(self.progress):
            self.progress(done, total, info)
        elif self.progress:
            self._show(done, total, info)

    def _show(self, done, total, info):
        if self.bar is None:
            try:
                from tqdm import tqdm
                self.bar = tqdm(total=total, desc="unroll", unit="GS frame")
            except ImportError:
                self.bar = False
        if self.bar:
            self.bar.update(done - self.bar.n)
        elif 100 * done // max(total, 1) // 10 != self.logged:
            self.logged = 100 * done // max(total, 1) // 10
            _log.info("unroll: %d/%d GS frames (frame %d)", done, total, info["frame"])

    def close(self):
        if self.bar:
            self.bar.close()


def _times(fn, times, times_us):
    if times_us is not None:
        if not (isinstance(times, float) and times == 0.5):
            A.refuse(fn, "times", times, "its default with times_us (give one of times and times_us)")
        return "us", A.time_list(fn, "times_us", times_us)
    if isinstance(times, str) and times == "gt":
        return "gt", []
    # A normalized instant, a position within its frame (not microseconds), within +-1e6 frame spans (the CLI's rule).
    return "tau", A.time_list(fn, "times", times, what=NORMALIZED_INSTANT, limit=10 ** 6, within="+-1e6 frame spans")


def _job_args(fn, mode, times, times_us, frames, channel_order, contrast, gamma, tile, halo, sparse, sparse_threshold,
              gate_radius, progress):
    """The options unroll and stream share, checked once (the CLI's ranges, named by keyword)."""
    A.choice(fn, "mode", mode, ("auto", "s", "m", "choose", "physics"))
    kind, values = _times(fn, times, times_us)
    frames = A.index_list(fn, "frames", frames)
    if frames == []:
        A.refuse(fn, "frames", frames, "None (all frames) or a non-empty list")
    A.choice(fn, "channel_order", channel_order, ("model", "rgb", "bgr"))
    contrast = A.number(fn, "contrast", contrast, 0, 5, lo_open=True, none=True, what="a log-intensity threshold")
    gamma = A.number(fn, "gamma", gamma, 0.1, 10, none=True, what="a decode gamma")
    tile = A.integer(fn, "tile", tile, 0, 1 << 20)
    halo = A.integer(fn, "halo", halo, -1, 1 << 20)
    A.choice(fn, "sparse", sparse, ("off", "exact", "fast"))
    sparse_threshold = A.number(fn, "sparse_threshold", sparse_threshold, 0, 1e6, what="events per pixel")
    if isinstance(gate_radius, str) and gate_radius not in ("auto", "model"):
        A.refuse(fn, "gate_radius", gate_radius, "'auto', 'model' or an integer 0..15")
    if not isinstance(gate_radius, str):
        A.integer(fn, "gate_radius", gate_radius, 0, 15)
    if progress is not None and not callable(progress) and not isinstance(progress, bool):
        A.refuse(fn, "progress", progress, "None, True/False or a callable progress(done, total, info)", TypeError)
    return dict(mode=mode, kind=kind, values=values, frames=frames or [], channel_order=channel_order,
                contrast=contrast, gamma=gamma, tile=tile, halo=halo, sparse=sparse,
                sparse_threshold=sparse_threshold, gate_radius=str(gate_radius))


def _session_for(fn, session, model, mode, backend, device, precision, conv_choice):
    if session is not None:
        if not isinstance(session, UnrollSession):
            A.refuse(fn, "session", session, "a vkunroll.UnrollSession or None", TypeError)
        for name, value, default in (("model", model, None), ("backend", backend, "vulkan"), ("device", device, None),
                                     ("precision", precision, "fp32"), ("conv_choice", conv_choice, "auto")):
            if value != default:  # the session's own; an option that does not apply is refused
                A.refuse(fn, name, value, f"its default with session= (the session has its own {name})")
        if mode in ("s", "m", "choose") and not session.has_model:
            A.refuse(fn, "mode", mode, "'physics' or 'auto' with a session without a model (mode "
                     f"{mode!r} runs the network: make the session with UnrollSession(model=FILE.safetensors))")
        return session
    if model is None:  # the shipped default, else physics (said), as the CLI
        model = _vk._choose_model(A.choice(fn, "mode", mode, ("auto", "s", "m", "choose", "physics")), "")[0] or None
    elif not isinstance(model, Model):
        model = A.existing_path(fn, "model", model)
    return UnrollSession(model, backend, device, precision, conv_choice=conv_choice)


def unroll(source, times=0.5, mode="auto", model=None, *, times_us=None, frames=None, backend="vulkan", device=None,
           precision="fp32", channel_order="model", contrast=None, gamma=None, tile=0, halo=-1, sparse="exact",
           sparse_threshold=0.05, gate_radius="auto", conv_choice="auto", session=None, progress=None):
    """Unroll RS frames into sharp global-shutter (GS) frames at chosen instants.

    The same job as ``vkunroll unroll``, frame by frame through one :class:`UnrollSession`:
    per frame one read of its image and of the events its targets need, event tensors and the
    network on the device, the GS images back once.

    Parameters:
      source: a :class:`Sequence`, a sequence folder, or arrays: a dict ``{"frames": [...],
        "timing": [RowTiming, ...], "events": array, "ground_truth": [(t_us, image), ...]}``
        (ground truth optional) or the tuple (frames, timing, events[, ground_truth]). Frames are
        H x W x 3 RGB (or gray H x W), float in [0, 1] or uint8 / uint16; events sorted by t.
      times: normalized instants per frame (0 = the first row's exposure start, 1 = the last
        row's exposure end; < 0 or > 1 lies between frames), a number or a list; or "gt": the
        sequence's ground-truth instants (each goes to the frame whose span holds it).
      times_us: absolute instants in microseconds instead (each goes to the frame whose span
        holds it). Times are exact (ints, "73000/259", Fractions) or floats.
      mode: "auto" (SelfUnroll-M where the next frame exists, else S; physics without a model),
        "s", "m", "choose" (S inside the frame's exposure span, M between frames) or "physics"
        (the weight-free event double integral).
      model: a weights file or :class:`Model`; None: the shipped default (:func:`default_model`),
        or physics when none is installed.
      frames: frame indices to unroll (default all).
      backend, device, precision: where the session runs ("vulkan" or "cpu"; precision "fp32" or
        "fp16", vulkan only; see :class:`UnrollSession`); conv_choice: as ``--conv-choice``.
      channel_order: "model" (the weights' metadata), "rgb" or "bgr": the model's input order.
      contrast, gamma: physics contrast threshold (default: estimated from consecutive frames'
        agreement) and the frames' decode gamma (default: the sequence's meta.json, else 1).
      gate_radius: the physics-informed variant's event gate radius: "auto" (2 on a noisy
        recording, as the contrast estimate measures its noise, else the model's), "model" (the
        weights' metadata) or an integer 0..15; as ``--gate-radius``.
      tile, halo, sparse, sparse_threshold: tiled / event-driven sparse execution (docs/tiling.md):
        sparse "exact" (default) skips 32-pixel tiles without events, "fast" also those below
        sparse_threshold events per pixel, "off" runs whole frames (tile 0: untiled if it fits).
      session: an :class:`UnrollSession` to reuse (then model, backend, device, precision are its own).
      progress: None (silent), True (a tqdm bar when tqdm is installed, else log lines on the
        ``vkunroll`` logger), or a callable progress(done, total, info) called after each frame
        (info: {"frame": k}); an exception it raises stops the job.

    Returns an :class:`UnrollResult` (``frames, metrics, targets, stats = unroll(...)``):
    frames [T, H, W, 3] float32 RGB in [0, 1]; metrics: "psnr", "ssim" per target against the
    ground truth at that instant (NaN where there is none), "rs_psnr", "rs_ssim" of the RS
    input, and "count", "mean_psnr", "mean_ssim", "rs_mean_psnr", "rs_mean_ssim"; targets: per
    target frame, t_us, tau, method, gt; stats: mode, notes, contrast / log_offset / gamma /
    contrast_source / contrast_method (mode physics, or the physics-informed variant's input), encoding (the frames' gamma and the exponent
    into the model's encoding), ms per GS frame, and the session's counters.

    Raises ValueError (bad option or input, named as the CLI names it), FileNotFoundError,
    RuntimeError (device failures). The GIL is released while frames are unrolled.
    """
    args = _job_args("unroll", mode, times, times_us, frames, channel_order, contrast, gamma, tile, halo, sparse,
                     sparse_threshold, gate_radius, progress)
    _check_source("unroll", source)
    sess = _session_for("unroll", session, model, mode, backend, device, precision, conv_choice)
    bar = _Progress(progress)
    try:
        with A.renamed("unroll", ["gate_radius", "contrast", "gamma", "tile", "halo", "times", "times_us", "frames"]):
            images, targets, metrics, report = _run(sess, source, args, bar.update)
    finally:
        bar.close()
    stats = json.loads(report)
    if "physics" in stats:  # the physics parameters (of mode physics or of the variant's input), at the top
        stats.update({k: stats["physics"][k] for k in ("contrast", "contrast_source", "contrast_method", "log_offset", "gamma")})
    stats["session"] = sess.stats()
    for n in stats["notes"]:
        _log.info("unroll: %s", n)
    for w in stats["warnings"]:
        _log.warning("unroll: warning: %s", w)
    h, w = (images[0].shape[:2]) if images else (0, 0)
    frames_out = np.stack(images) if images else np.zeros((0, h, w, 3), np.float32)
    return UnrollResult(frames_out, metrics, targets, stats)


def _check_source(fn, source):
    if isinstance(source, (str, os.PathLike)):
        A.existing_path(fn, "source", source)
    elif not isinstance(source, (Sequence, dict, tuple, list)):
        A.refuse(fn, "source", source, "a Sequence, a sequence folder, a dict {frames, timing, events} or a tuple", TypeError)


def _run(sess, source, args, progress):
    """The library's unroll job over a sequence (folder) or arrays."""
    if isinstance(source, (str, os.PathLike)):
        source = Sequence.open(source)
    if isinstance(source, Sequence):
        return _vk._unroll_sequence(sess._s, source._seq, args, progress)
    if isinstance(source, dict):
        missing = [k for k in ("frames", "timing", "events") if k not in source]
        if missing:
            raise ValueError(f"unroll: the source dict lacks {', '.join(missing)} (expected frames, timing, events"
                             "[, ground_truth])")
        source = (source["frames"], source["timing"], source["events"], source.get("ground_truth"))
    if not isinstance(source, (tuple, list)) or len(source) not in (3, 4):
        raise TypeError("unroll: source must be a Sequence, a sequence folder, a dict {frames, timing, events"
                        f"[, ground_truth]}} or a tuple (frames, timing, events[, ground_truth]), got {type(source).__name__}")
    frames, timing, events = source[:3]
    gt = list(source[3] or []) if len(source) == 4 else []
    timings = [timing] if isinstance(timing, _vk.RowTiming) else list(timing)
    t, x, y, p = event_fields(events)
    return _vk._unroll_arrays(sess._s, [_rgb(f, f"frame {k}") for k, f in enumerate(frames)], timings, t, x, y, p,
                              [tt for tt, _ in gt], [_rgb(im, f"ground truth {j}") for j, (_, im) in enumerate(gt)],
                              args, progress)


CONV_CHOICES = ("auto", "heuristic", "cached", "measured", "retune", "gpu")  # as --conv-choice
_LIVE_STREAMS = weakref.WeakSet()


@atexit.register
def _close_live_streams():
    """A stream left open (a loop broken out of without close() or ``with``) is stopped and joined
    before the interpreter goes: its native job never runs on into finalization."""
    for s in list(_LIVE_STREAMS):
        s.close()


class _Stream:
    """The iterator :func:`stream` returns; ``report`` is the job's report once it is exhausted.
    Once exhausted (or closed) every ``next()`` raises StopIteration again, at once."""

    def __init__(self, sess, seq, args, events, idle_s, max_events):
        self.report, self._q, self._stop, self._error = None, queue.Queue(maxsize=4), threading.Event(), None
        self._done = False
        self._next_lock = threading.Lock()  # next() from several threads: served one at a time, never a hang

        def on_frame(item):
            while not self._stop.is_set():  # back-pressure: the job waits for a slow consumer
                try:
                    return self._q.put(item, timeout=0.05)
                except queue.Full:
                    pass
            raise RuntimeError("stream: closed by the caller")

        def job():
            try:
                self.report = json.loads(_vk._stream_sequence(sess._s, seq._seq, args, events, float(idle_s), int(max_events),
                                                              on_frame, self._stop.is_set))
            except BaseException as e:  # handed to the consumer
                self._error = e
            finally:
                self._q.put(None)

        self._thread = threading.Thread(target=job, daemon=True)
        self._thread.start()
        _LIVE_STREAMS.add(self)

    def __iter__(self):
        return self

    def __next__(self):
        """The next frame's dict. An iterator shared by threads is serialized: each frame goes to one
        caller, and once the job ends every caller gets StopIteration (the end is seen once, by
        the lock's holder, and remembered)."""
        with self._next_lock:
            return self._next_locked()

    def _next_locked(self):
        if self._done:
            raise StopIteration
        item = self._q.get()
        if item is None:
            self._done = True
            self._thread.join()
            _LIVE_STREAMS.discard(self)
            if self._error is not None and not self._stop.is_set():
                raise self._error
            for w in (self.report or {}).get("warnings", []):
                _log.warning("stream: warning: %s", w)
            raise StopIteration
        if item.get("events_window") == "partial":
            _log.warning("stream: frame %d: the stream ended inside its event window; its GS frames were computed "
                         "from part of its events", item["frame"])
        item["images"] = [np.asarray(im) for im in item["images"]]
        return item

    def close(self):
        """Stops the job (the frame in work finishes) and waits for it. Idempotent."""
        self._stop.set()
        while self._thread.is_alive():
            try:
                self._q.get(timeout=0.05)
            except queue.Empty:
                pass
        self._thread.join()
        self._done = True
        try:  # a next() waiting in another thread wakes and ends (the drain above may have taken the end)
            self._q.put_nowait(None)
        except queue.Full:
            pass
        _LIVE_STREAMS.discard(self)

    def __del__(self):
        if getattr(self, "_thread", None) is not None and self._thread.is_alive():
            self.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def stream(source, events="-", times=0.5, mode="auto", model=None, *, times_us=None, frames=None, contrast=None,
           gamma=None, idle_s=10.0, max_events=1 << 24, on_bad="error", session=None, backend="vulkan", device=None,
           precision="fp32", channel_order="model", tile=0, halo=-1, sparse="exact", sparse_threshold=0.05,
           gate_radius="auto", conv_choice="auto"):
    """Unrolls a live recording as ``vkunroll unroll --follow`` does (docs/follow.md), yielding
    each RS frame's GS frames as soon as they are computed.

    ``source``: the live sequence folder (meta.json lists the frames to come; their images appear
    in it); ``events``: an EVT 3.0 stream (a pipe, a growing file, "-" for stdin). ``idle_s``,
    ``max_events``: as ``--follow-idle-s``, ``--follow-max-events``; the rest as :func:`unroll`.
    Yields dicts ``{"frame", "images": [H x W x 3 float32 RGB], "targets", "done", "total"}``.
    The iterator's ``close()`` (or leaving a ``with`` block) stops the job; ``report`` holds the
    job's report with ``follow`` (status complete or stopped, latency) after the last frame.
    """
    fn = "stream"
    args = _job_args(fn, mode, times, times_us, frames, channel_order, contrast, gamma, tile, halo, sparse,
                     sparse_threshold, gate_radius, None)
    if isinstance(source, Sequence):
        source = source.root
    source = A.existing_path(fn, "source", source)
    events = "-" if events == "-" else A.existing_path(fn, "events", events)
    if not idle_s == 0:  # 0: wait for ever; else at least the reader's poll (the CLI's --follow-idle-s rule)
        idle_s = A.number(fn, "idle_s", idle_s, 0.1, 1e6, what="seconds (0: wait for ever)")
    idle_s = A.number(fn, "idle_s", idle_s, 0, 1e6, what="seconds (0: wait for ever)")
    max_events = A.integer(fn, "max_events", max_events, 1024, 1 << 34)
    on_bad = A.choice(fn, "on_bad", on_bad, ("error", "drop"))
    sess = _session_for(fn, session, model, mode, backend, device, precision, conv_choice)
    seq = Sequence.open(source, check_frame_sizes=False, on_bad=on_bad,
                        events_file="/dev/stdin" if events == "-" else events)
    return _Stream(sess, seq, args, events, idle_s, max_events)
