"""Recordings: RS frames with their row timing, events, optional ground truth."""
import json
import math
import os

import numpy as np

from . import _args as A
from . import _vkunroll as _vk
from ._events import _structured, event_fields

__all__ = ["Sequence", "simulate"]


def _encode_image(image, what, bit_depth=None, name="frames"):
    """uint8 / uint16 H x W (x 1 or 3) as given; float in [0, 1] -> 8 or 16 bits (default 16); a
    float outside [0, 1] or another dtype is refused (_args.image), never clipped."""
    if isinstance(image, (str, bytes)) or image is None:
        A.refuse("Sequence.create", name, image, "an image array", TypeError)
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
        raise ValueError(f"{what}: expected an H x W or H x W x 3 image, got shape {a.shape}")
    if a.dtype == np.uint8 or a.dtype == np.uint16:
        if bit_depth is not None and {8: np.uint8, 16: np.uint16}[bit_depth] != a.dtype:
            raise ValueError(f"{what}: {a.dtype} pixels but bit_depth={bit_depth}")
        return np.ascontiguousarray(a)
    a = A.image("Sequence.create", f"{name} ({what})", a)
    bits = 16 if bit_depth is None else bit_depth
    full = 65535.0 if bits == 16 else 255.0
    return np.ascontiguousarray(np.round(a * full).astype(np.uint16 if bits == 16 else np.uint8))


class Sequence:
    """A recording: RS frames with their row timing, the event stream, optional ground truth.

    Open one with :meth:`Sequence.open` (the generic layout of sequence-format.md, Gev-RS,
    Gev-RS-Real, DRE, Fastec-RS), write one with :meth:`Sequence.create`, or simulate one with
    :func:`simulate`. ``len(seq)`` is the number of frames.

    Attributes: ``root``, ``layout``, ``width``, ``height``, ``sensor_size`` (width, height),
    ``timings`` (one :class:`RowTiming` per frame), ``frame_files``, ``ground_truth`` (list of
    (t_us Fraction, file)), ``event_files``, ``notes`` (how the timing was derived).
    """

    def __init__(self, native):
        self._seq = native

    @classmethod
    def open(cls, path, layout="auto", **options):
        """Load a sequence folder.

        ``layout``: "auto" (detected), "generic", "gev-rs", "gev-rs-real", "dre", "fastec".
        Options (None keeps the layout's value): ``line_delay_us``, ``exposure_us``, ``readout``,
        ``t0s_us`` (one per frame), ``frame_period_us`` (Gev-RS-Real), ``gev_half_row`` (Gev-RS),
        ``fastec_frame_step_gs``, ``events_file`` (replaces the layout's), ``events_topic`` (a ROS
        bag's event topic, over meta.json's ``events_topic``), ``on_bad``
        ("error", "drop", "sort"), ``check_frame_sizes``. Times are exact (ints, floats, strings
        like "73000/259", Fractions).

        Raises FileNotFoundError for a missing folder or file, ValueError for a malformed one.
        """
        fn = "Sequence.open"
        path = A.existing_path(fn, "path", path)
        A.choice(fn, "layout", layout, ("auto", "generic", "gev-rs", "gev-rs-real", "dre", "fastec"))
        checks = {"line_delay_us": lambda n, v: A.exact_time(fn, n, v, none=True),
                  "exposure_us": lambda n, v: A.exact_time(fn, n, v, none=True, positive=True),
                  "frame_period_us": lambda n, v: A.exact_time(fn, n, v, none=True, positive=True),
                  "readout": lambda n, v: A.choice(fn, n, v, ("top-down", "bottom-up"), none=True),
                  "t0s_us": lambda n, v: None if v is None else A.time_list(fn, n, v),
                  "gev_half_row": lambda n, v: A.flag(fn, n, v),
                  "fastec_frame_step_gs": lambda n, v: A.integer(fn, n, v, 1, 1 << 20, none=True),
                  "events_file": lambda n, v: None if v is None else A.existing_path(fn, n, v),
                  "events_topic": lambda n, v: A.text(fn, n, v, none=True),
                  "on_bad": lambda n, v: A.choice(fn, n, v, A.ON_BAD, none=True),
                  "check_frame_sizes": lambda n, v: A.flag(fn, n, v)}
        for name, value in options.items():
            if name not in checks:
                A.refuse(fn, name, value, f"a known option ({', '.join(sorted(checks))})", TypeError)
            checked = checks[name](name, value)
            if name in ("events_file",) and checked is not None:
                options[name] = checked
        options["layout"] = layout
        return cls(_vk._load_sequence(path, options))

    @classmethod
    def create(cls, path, frames, events, timing, ground_truth=None, sensor_size=None, events_format="h5",
               bit_depth=None, source=None, *, overwrite=False):
        """Write a recording in the generic layout and return it opened.

        ``frames``: a list of images (or an array [K, H, W(, 3)]): uint8 or uint16 as stored, or
        float in [0, 1] (stored as 16-bit PNG, or ``bit_depth`` 8); RGB channel order.
        ``events``: any event array with t, x, y, p (see :func:`convert_events`), t
        non-decreasing. ``timing``: one :class:`RowTiming` per frame (all with the same line
        delay and readout), or a single RowTiming for a one-frame sequence.
        ``ground_truth``: optional list of (t_us, image) pairs, sharp GS images at instant t_us.
        ``sensor_size``: (width, height), default the frames' size. ``events_format``: "h5" or
        "txt". ``source``: a JSON-serializable dict stored as meta.json's ``source``.

        ``overwrite``: replace an existing, non-empty ``path`` (only a folder vkunroll wrote: its
        manifest lists everything in it); without it such a folder is refused.

        The folder is written under a staging name, loaded back with the loader's schema and only
        then renamed into place: a failed call leaves nothing under ``path``.
        """
        fn = "Sequence.create"
        path = A.path(fn, "path", path)
        bit_depth = None if bit_depth is None else A.integer(fn, "bit_depth", bit_depth, 8, 16)
        if bit_depth not in (None, 8, 16):
            A.refuse(fn, "bit_depth", bit_depth, "8, 16 or None")
        A.choice(fn, "events_format", events_format, ("h5", "txt"))
        sensor_size = A.size_pair(fn, "sensor_size", sensor_size, none=True)
        overwrite = A.flag(fn, "overwrite", overwrite)
        if source is not None and not isinstance(source, dict):
            A.refuse(fn, "source", source, "a dict (stored as meta.json's source) or None", TypeError)
        if isinstance(frames, (str, bytes)) or not isinstance(frames, (list, tuple, np.ndarray)):
            A.refuse(fn, "frames", frames, "a list of images or an array [K, H, W(, 3)]", TypeError)
        frames = list(frames)
        if not frames:
            A.refuse(fn, "frames", frames, "at least one frame")
        encoded = [_encode_image(f, f"frame {k}", bit_depth) for k, f in enumerate(frames)]
        timings = A.row_timing(fn, "timing", timing, _vk.RowTiming)
        if sensor_size is None:
            sensor_size = (encoded[0].shape[1], encoded[0].shape[0])
        gt_times, gt_images = [], []
        if ground_truth is not None and not isinstance(ground_truth, (list, tuple)):
            A.refuse(fn, "ground_truth", ground_truth, "a list of (t_us, image) pairs", TypeError)
        for g, pair in enumerate(ground_truth or []):
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                A.refuse(fn, f"ground_truth[{g}]", pair, "a (t_us, image) pair", TypeError)
            gt_times.append(A.exact_time(fn, f"ground_truth[{g}] t_us", pair[0]))
            gt_images.append(_encode_image(pair[1], f"ground truth {g}", bit_depth, "ground_truth"))
        try:
            source_json = "" if source is None else json.dumps(source, allow_nan=False)
        except (TypeError, ValueError) as e:
            A.refuse(fn, "source", source, f"a JSON-serializable dict ({e})", TypeError)
        t, x, y, p = event_fields(events)
        _vk._write_sequence(path, int(sensor_size[0]), int(sensor_size[1]), encoded, timings, gt_times, gt_images,
                            t, x, y, p, events_format, source_json, overwrite)
        return cls.open(path, layout="generic")

    # ---- what the recording holds --------------------------------------------------------------
    root = property(lambda self: self._seq.root, doc="The sequence folder.")
    layout = property(lambda self: self._seq.layout, doc='"generic", "gev-rs", ...')
    width = property(lambda self: self._seq.width, doc="Sensor width in pixels.")
    height = property(lambda self: self._seq.height, doc="Sensor height in pixels.")
    sensor_size = property(lambda self: (self._seq.width, self._seq.height), doc="(width, height).")
    timings = property(lambda self: list(self._seq.timings), doc="One RowTiming per frame.")
    frame_files = property(lambda self: list(self._seq.frame_images), doc="The RS frames' image files.")
    event_files = property(lambda self: list(self._seq.event_files), doc="The event file(s).")
    notes = property(lambda self: list(self._seq.notes), doc="How the timing was derived.")
    ground_truth = property(lambda self: list(self._seq.ground_truth),
                            doc="Ground-truth GS frames: a list of (t_us Fraction, image file).")

    def __len__(self):
        return len(self._seq.frame_images)

    def __repr__(self):
        return (f"vkunroll.Sequence({self.root!r}, layout={self.layout!r}, {self.width}x{self.height}, "
                f"{len(self)} frames, {len(self.ground_truth)} ground truth)")

    def timing(self, k):
        """The :class:`RowTiming` of frame ``k`` (negative: from the end)."""
        return self.timings[self._index(k)]

    def frame(self, k):
        """RS frame ``k`` as an H x W x 3 float32 RGB image in [0, 1] (gray frames repeated)."""
        return _vk._read_image(self.frame_files[self._index(k)], self.width, self.height)

    def ground_truth_image(self, j):
        """Ground-truth image ``j`` (see :attr:`ground_truth`) as H x W x 3 float32 RGB in [0, 1]."""
        gt = self.ground_truth
        A.integer("Sequence.ground_truth_image", "j", j, -(2 ** 31), 2 ** 31 - 1)
        if not 0 <= j < len(gt):
            raise IndexError(f"Sequence.ground_truth_image: j={j}: the sequence has {len(gt)} ground-truth image(s)")
        return _vk._read_image(gt[j][1], self.width, self.height)

    def events(self, t_start=None, t_end=None, dtype=None):
        """The events with t_start <= t < t_end (integer microseconds; None: open end), read
        through the file's index where it has one, as a structured array (:data:`EVENT_DTYPE`
        or ``dtype``). Bounds are whole microseconds: a fractional one is refused, not rounded."""
        t_start = A.whole_us("Sequence.events", "t_start", t_start, none=True)
        t_end = A.whole_us("Sequence.events", "t_end", t_end, none=True)
        if t_start is not None and t_end is not None and t_end < t_start:
            A.refuse("Sequence.events", "t_end", t_end, f"a time >= t_start={t_start}")
        lo = -(2 ** 62) if t_start is None else t_start
        hi = 2 ** 62 if t_end is None else t_end
        (t, x, y, p, _, _), _info = self._seq.read_events(lo, hi)
        return _structured(t, x, y, p, dtype)

    def frame_events(self, k, dtype=None):
        """The events of frame ``k``'s exposure span [first row's start, last row's end]."""
        tm = self.timing(k)
        return self.events(math.floor(tm.first_start_us), math.ceil(tm.last_end_us) + 1, dtype)

    def event_totals(self):
        """What every event read of this sequence so far decoded, each record counted once however
        many windows covered it: reads, delivered (summed over reads), records, valid, dropped
        (and by reason), reordered, empty_files, and a one-line summary."""
        return dict(self._seq.event_totals())

    def meta_gamma(self):
        """The frames' encoding gamma a generic sequence records (source.settings.gamma, as the
        simulator writes it, or source.gamma); 1.0 otherwise."""
        return self._seq.meta_gamma()

    def _index(self, k):
        n = len(self)
        A.integer("Sequence", "k", k, -(2 ** 31), 2 ** 31 - 1)
        if not -n <= k < n:
            raise IndexError(f"Sequence: k={k}: the sequence has {n} frames (k from {-n} to {n - 1})")
        return k % n


def simulate(path, preset="realistic", seed=1, *, overwrite=False, **settings):
    """Simulate a recording (the same as ``vkunroll simulate``) and return it as a :class:`Sequence`.

    A scene (moving camera, sprites, optional flicker) is rendered into rolling-shutter frames
    integrated row by row over their exposure, sharp global-shutter ground truth at chosen
    instants, and a DVS event stream (ESIM/v2e-style), written in the generic layout under
    ``path``. ``preset``: "clean", "realistic", "noisy" (event and frame noise). Settings (the
    SimulationConfig names; see docs/simulator.md): width, height, frames, fps, line_delay_us,
    exposure_us, readout, lead_in_us, gt_per_frame, motion ("static", "pan", "accelerate",
    "rotate", "zoom", "shake", "mixed"), texture, sprites, speed_scale, flicker_amplitude,
    flicker_hz, supersample, gamma, bit_depth, color, events_format ("h5", "txt", "both"),
    c_on, c_off, sigma, refractory_us, leak_hz, shot_hz, cutoff_hz, eps, full_well_e, read_noise,
    step_fraction, dt_min_us, dt_max_us. Deterministic for a given seed. ``overwrite``: replace an
    existing ``path`` that vkunroll wrote (as ``vkunroll simulate --overwrite``).
    """
    path = A.path("simulate", "path", path)
    A.choice("simulate", "preset", preset, ("clean", "realistic", "noisy"))
    seed = A.integer("simulate", "seed", seed, 0, 2 ** 64 - 1)
    overwrite = A.flag("simulate", "overwrite", overwrite)
    ints = {"width": (2, 8192), "height": (2, 8192), "frames": (1, 100000), "gt_per_frame": (0, 10000),
            "sprites": (0, 1000), "supersample": (1, 64), "bit_depth": (8, 16)}
    for name, value in settings.items():
        if name in ints:
            A.integer("simulate", name, value, *ints[name])
        elif isinstance(value, str):
            A.text("simulate", name, value)
        elif isinstance(value, (bool, np.bool_)):
            pass
        else:
            A.number("simulate", name, value, -1e15, 1e15)
    with A.renamed("simulate", list(settings)):
        _vk._simulate(path, preset, seed, settings, overwrite)
    return Sequence.open(path, layout="generic")
