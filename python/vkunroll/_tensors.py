"""Row-aware event tensors and the weight-free physics unroller."""
import numpy as np

from . import _args as A
from . import _vkunroll as _vk
from ._events import event_fields
from ._runtime import resolve_context

__all__ = ["event_tensors", "event_tensors_batch", "physics_unroll", "image_float", "psnr", "ssim"]


def _sensor(x, y, timing, sensor_size, fn="event_tensors", name="sensor_size"):
    """The sensor's (width, height) from `sensor_size`, given as the keyword `name` (physics_unroll:
    the image rs's size), checked against the timing and the events; errors name that keyword."""
    height = timing.height
    if sensor_size is None:
        if not x.size:
            A.refuse(fn, name, None, "(width, height) when there are no events to infer the width from")
        width = int(x.max()) + 1
    else:
        width, h = A.size_pair(fn, name, sensor_size)
        if h != height:
            A.refuse(fn, name, sensor_size, f"a height of the timing's {height} rows (timing.height), not {h}")
        if x.size and int(x.max()) >= width:
            i = int(np.argmax(x >= width))
            raise ValueError(f"events: x[{i}] = {x[i]} is outside the sensor width {width}")
    if y.size and int(y.max()) >= height:
        i = int(np.argmax(y >= height))
        raise ValueError(f"events: y[{i}] = {y[i]} is outside the {height} sensor rows")
    return width, height


def event_tensors_batch(events, timing, t_us, bins=16, target_exposure_us=None, *, crop=None, sensor_size=None,
                        backend="vulkan", context=None):
    """ev1, ev2, ev3 of many (frame, target) pairs: three float32 arrays [P, 2N, h, w].

    ``timing``: one :class:`RowTiming` for every target, or a list with one per target (pairs
    of different frames). ``t_us``: the targets t* (exact: ints, strings "73000/259",
    Fractions, or floats). Otherwise as :func:`event_tensors`; pair i is (timing[i], t_us[i]).
    """
    fn = "event_tensors"
    targets = A.time_list(fn, "t_us", t_us)
    timings = A.row_timing(fn, "timing", timing, _vk.RowTiming)
    if not isinstance(timing, (list, tuple)):
        timings = timings * len(targets)
    if len(timings) != len(targets):
        A.refuse(fn, "timing", timing, f"one RowTiming, or one per target ({len(targets)})")
    bins = A.integer(fn, "bins", bins, 1, 4096)
    target_exposure_us = A.exact_time(fn, "target_exposure_us", target_exposure_us, none=True, positive=True)
    if crop is not None:
        if isinstance(crop, (str, bytes)) or not isinstance(crop, (list, tuple, np.ndarray)) or len(crop) != 4:
            A.refuse(fn, "crop", crop, "(x0, y0, width, height), four integers", TypeError)
        crop = [A.integer(fn, "crop", c, 0, 65536) for c in crop]
    A.choice(fn, "backend", backend, ("vulkan", "cpu"))
    t, x, y, p = event_fields(events)
    if t.size > 1 and np.any(np.diff(t) < 0):
        i = int(np.argmax(np.diff(t) < 0)) + 1
        A.refuse(fn, "events", f"<t[{i}] = {t[i]} < t[{i - 1}] = {t[i - 1]}>", "events sorted by t")
    width, height = _sensor(x, y, timings[0], sensor_size)
    ctx = resolve_context(context, backend)
    ev1, ev2, ev3, _considered = _vk._event_tensors(ctx, t, x, y, p, width, height, timings, targets,
                                                    target_exposure_us, int(bins), list(crop) if crop else [])
    return ev1, ev2, ev3


def event_tensors(events, timing, t_us, bins=16, target_exposure_us=None, *, crop=None, sensor_size=None,
                  backend="vulkan", context=None):
    """The row-aware event tensors ev1, ev2, ev3 of one RS frame and target instant t*.

    Each is a float32 array [2N, h, w] (N = ``bins``; channel 2k + 1 counts positive and 2k
    negative signed events of bin k). For sensor row y: ev1 bins the events between t* and the
    row's exposure start, ev2 between t* and its exposure end, ev3 between t* and
    t* + ``target_exposure_us`` (default: the frame's exposure); an event's sign flips when it lies
    before t* (SelfUnroll, section 4 of the network reference). Exact: times are rationals.

    Parameters:
      events: any event array with t, x, y, p (tonic, expelliarmus, Metavision, vkunroll).
      timing: the frame's :class:`RowTiming` (its height is the sensor's).
      t_us: the target t* in microseconds (exact: int, str "73000/259", Fraction; or float).
      crop: (x0, y0, width, height) of the sensor; rows keep their full-sensor times.
      sensor_size: (width, height); default width max(x) + 1 — pass it for a camera's full width.
      backend: "vulkan" (the GPU builder, on ``context`` or the default one) or "cpu" (the exact
        CPU reference). Both give the same counts.

    Returns (ev1, ev2, ev3). Equal to ``vkunroll voxelize`` and tools/data/event_tensors_numpy.py.
    """
    ev1, ev2, ev3 = event_tensors_batch(events, timing, [t_us], bins, target_exposure_us, crop=crop,
                                        sensor_size=sensor_size, backend=backend, context=context)
    return ev1[0], ev2[0], ev3[0]


def image_float(image, what="image"):
    """An image as float32 in [0, 1]: uint8 / uint16 scaled by their full scale, floats as given
    (within [0, 1]); other dtypes and out-of-range floats are refused (_args.image)."""
    fn, _, name = what.rpartition(": ")
    return A.image(fn or "image", name or what, image)


def _metric_images(fn, a, b):
    a, b = A.image(fn, "a", a), A.image(fn, "b", b)
    if a.shape != b.shape:
        A.refuse(fn, "b", f"<array of shape {b.shape}>", f"an image of a's shape {a.shape}")
    return a, b


def psnr(a, b):
    """PSNR in dB of two images of one shape (float in [0, 1], uint8 or uint16); inf when equal."""
    return _vk.psnr(*_metric_images("psnr", a, b))


def ssim(a, b):
    """SSIM (Gaussian window, as the paper's evaluation) of two images of one shape."""
    return _vk.ssim(*_metric_images("ssim", a, b))


def physics_unroll(rs, events, timing, t_us, contrast=0.2, gamma=1.0, *, log_offset=0.0, backend="vulkan", context=None):
    """The weight-free physics unroller: the RS image at instant t* from the events (EDI).

    Per pixel, I(t*) = I_rs * T / integral over the row's exposure [S_y, E_y] of
    exp(c * E(t* -> s)) ds, E the pixel's signed event count from t* to s and c the contrast
    threshold; evaluated in the log domain (no overflow with thousands of events; black pixels
    stay 0). The image is decoded with x ** gamma before and encoded after. ``log_offset``
    (eps >= 0): the events measure log(lin + eps); the ratio applies to lin + eps.

    ``rs``: H x W or H x W x C image (float in [0, 1], or uint8 / uint16). ``events``: any event
    array; ``timing``: the frame's :class:`RowTiming`; ``t_us``: t* (exact). ``backend``
    "vulkan" (GPU; a pixel with more events than the kernel's loop limit runs on the CPU
    reference, logged) or "cpu". Returns float32 of ``rs``'s shape (not clipped to [0, 1]).
    """
    fn = "physics_unroll"
    img = A.image(fn, "rs", rs)
    if img.ndim not in (2, 3):
        raise ValueError(f"physics_unroll: rs must be H x W or H x W x C, got shape {img.shape}")
    A.row_timing(fn, "timing", timing, _vk.RowTiming)
    if isinstance(timing, (list, tuple)):
        A.refuse(fn, "timing", timing, "one vkunroll.RowTiming (the frame's)", TypeError)
    t_us = A.exact_time(fn, "t_us", t_us)
    # Ranges a real sensor can have (the CLI's --contrast and --gamma rules).
    contrast = A.number(fn, "contrast", contrast, 0, 5, lo_open=True, what="a log-intensity threshold")
    gamma = A.number(fn, "gamma", gamma, 0.1, 10, what="a decode gamma")
    log_offset = A.number(fn, "log_offset", log_offset, 0, 1e6, what="a log offset")
    A.choice(fn, "backend", backend, ("vulkan", "cpu"))
    planes = img[None] if img.ndim == 2 else np.moveaxis(img, 2, 0)
    t, x, y, p = event_fields(events)
    if t.size > 1 and np.any(np.diff(t) < 0):  # as event_tensors: the double integral needs time order
        i = int(np.argmax(np.diff(t) < 0)) + 1
        A.refuse(fn, "events", f"<t[{i}] = {t[i]} < t[{i - 1}] = {t[i - 1]}>", "events sorted by t")
    _sensor(x, y, timing, (planes.shape[2], planes.shape[1]), fn, name="rs")
    out = _vk._physics_unroll(resolve_context(context, backend), np.ascontiguousarray(planes), t, x, y, p, timing,
                              t_us, contrast, gamma, log_offset)
    return out[0] if img.ndim == 2 else np.ascontiguousarray(np.moveaxis(out, 0, 2))
