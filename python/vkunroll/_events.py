"""Events as numpy structured arrays: reading, writing, and the dtypes other libraries use."""
import logging
import os
from collections import namedtuple

import numpy as np

from . import _args as A
from . import _vkunroll as _vk

__all__ = ["EVENT_DTYPE", "TONIC_DTYPE", "EXPELLIARMUS_DTYPE", "METAVISION_DTYPE", "EVENT_FORMATS", "read_events",
           "write_events", "convert_events", "detect_event_format"]

_log = logging.getLogger("vkunroll")

#: vkunroll's own layout: t int64 microseconds, x and y uint16, p int8 (+1 on, -1 off).
EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
#: tonic's ``events_struct`` (tonic.io): x, y int16, t int64, p bool.
TONIC_DTYPE = np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "?")])
#: expelliarmus' arrays: t int64, x, y int16, p uint8 (0 / 1).
EXPELLIARMUS_DTYPE = np.dtype([("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1")])
#: Metavision's EventCD: x, y uint16, p int16 (0 / 1), t int64, 16-byte records.
METAVISION_DTYPE = np.dtype({"names": ["x", "y", "p", "t"], "formats": ["<u2", "<u2", "<i2", "<i8"],
                             "offsets": [0, 2, 4, 8], "itemsize": 16})

#: One row a format vkunroll reads, from the library's table (host/events/event_formats.hpp): name (what
#: ``format=`` takes), alias (also taken), what, extensions, signature, streamed, reader (its source
#: file), writable (:func:`write_events` takes it), fuzzer.
EventFormat = namedtuple("EventFormat", ["name", "alias", "what", "extensions", "signature", "streamed", "reader",
                                         "writable", "fuzzer"])
EVENT_FORMATS = tuple(EventFormat(**row) for row in _vk._event_formats())

_ALIASES = {"t": ("t", "ts", "timestamp"), "x": ("x",), "y": ("y",), "p": ("p", "pol", "polarity")}


def _field(events, name):
    names = events.dtype.names if isinstance(events, np.ndarray) else tuple(events.keys())
    for alias in _ALIASES[name]:
        if names is not None and alias in names:
            return np.asarray(events[alias])
    raise ValueError(f"events: no field {name!r} (fields: {', '.join(names or ())}); expected t, x, y, p")


def event_fields(events):
    """(t int64, x uint16, y uint16, p int8 +1/-1) contiguous arrays of any event array.

    Accepts a structured array or a dict with fields t, x, y, p in any order (tonic,
    expelliarmus, Metavision, vkunroll), t integer microseconds (or floats holding integers), x
    and y non-negative integers below 65536, p bool or numbers (p > 0 is on, anything else off:
    1/0, 1/-1 and True/False all work). Raises ValueError naming the field and the event.
    """
    if isinstance(events, str) or events is None:
        raise TypeError(f"events: expected a numpy structured array or a dict of arrays, got {type(events).__name__}")
    if isinstance(events, np.ndarray) and events.dtype.names is None:
        raise ValueError(f"events: expected a structured array with fields t, x, y, p, got a plain {events.dtype} array")
    if not isinstance(events, (np.ndarray, dict)):
        raise TypeError(f"events: expected a numpy structured array or a dict of arrays, got {type(events).__name__}")
    t, x, y, p = (_field(events, k) for k in "txyp")
    n = t.shape[0] if t.ndim == 1 else -1
    for name, a in zip("txyp", (t, x, y, p)):
        if a.ndim != 1 or a.shape[0] != n:
            raise ValueError(f"events: field {name!r} has shape {a.shape}, expected ({n},) like field 't'")
    if t.dtype.kind == "f":
        bad = ~np.isfinite(t) | (t != np.round(t))
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"events: t[{i}] = {t[i]!r} is not an integer number of microseconds "
                             "(convert seconds with t * 1e6 and round)")
    elif t.dtype.kind not in "iu":
        raise ValueError(f"events: field 't' has dtype {t.dtype}, expected integer microseconds")
    for name, a in (("x", x), ("y", y)):
        if a.dtype.kind not in "iu":
            raise ValueError(f"events: field {name!r} has dtype {a.dtype}, expected integer pixel coordinates")
        bad = (a < 0) | (a > 65535)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"events: {name}[{i}] = {a[i]} is outside 0..65535")
    if p.dtype.kind not in "biuf":
        raise ValueError(f"events: field 'p' has dtype {p.dtype}, expected bool or numbers")
    if p.dtype.kind == "f" and not np.isfinite(p).all():
        i = int(np.argmax(~np.isfinite(p)))
        raise ValueError(f"events: p[{i}] = {p[i]!r} is not a polarity (the file readers refuse it too)")
    pol = np.where(p > 0, 1, -1).astype(np.int8)
    return (np.ascontiguousarray(t, dtype=np.int64), np.ascontiguousarray(x, dtype=np.uint16),
            np.ascontiguousarray(y, dtype=np.uint16), pol)


def _structured(t, x, y, p, dtype=None, p_off=None):
    if dtype is not None:
        try:
            dtype = np.dtype(dtype)
        except (TypeError, ValueError):
            A.refuse("events", "dtype", dtype, "a numpy structured dtype with fields t, x, y, p", TypeError)
    dtype = EVENT_DTYPE if dtype is None else dtype
    if dtype.names is None or not all(k in dtype.names for k in "txyp"):
        A.refuse("events", "dtype", dtype, "a structured dtype with fields t, x, y, p")
    out = np.empty(t.shape[0], dtype=dtype)
    for name, a in (("t", t), ("x", x), ("y", y)):
        kind = dtype[name]
        if kind.kind in "iu" and a.size:
            info = np.iinfo(kind)
            if a.max() > info.max or a.min() < info.min:
                raise ValueError(f"events: field {name!r} does not fit dtype {kind} (values {a.min()}..{a.max()})")
        out[name] = a
    pk = dtype["p"]
    on = p > 0
    if pk.kind == "b":
        out["p"] = on
    else:
        if p_off is None:
            p_off = -1 if dtype == EVENT_DTYPE else 0
        if pk.kind == "u" and p_off < 0:
            raise ValueError(f"p_off={p_off}: dtype {pk} of field 'p' is unsigned")
        out["p"] = np.where(on, 1, p_off)
    return out


def convert_events(events, dtype=EVENT_DTYPE, p_off=None):
    """The events in another dtype (tonic's, expelliarmus', Metavision's or any with t, x, y, p).

    ``p`` becomes True/False for a bool field, else 1 for on and ``p_off`` for off (default -1
    for :data:`EVENT_DTYPE`, 0 for every other dtype, the convention of tonic, expelliarmus and
    Metavision). Raises ValueError when a value does not fit the target field.
    """
    p_off = A.integer("convert_events", "p_off", p_off, -128, 127, none=True)
    return _structured(*event_fields(events), dtype=dtype, p_off=p_off)


def detect_event_format(path):
    """The format :func:`read_events` would read ``path`` as: a name of :data:`EVENT_FORMATS` (from
    the file's signature, then its extension)."""
    return _vk._detect_event_format(A.existing_path("detect_event_format", "path", path))


def read_events(path, t_start=None, t_end=None, format=None, on_bad="error", *, dtype=None, sensor_size=None,
                columns=None, time_unit=None, array_time_unit=None, topic=None, return_info=False):
    """Read an event file into a numpy structured array.

    Formats: every row of :data:`EVENT_FORMATS` (text/CSV, HDF5 with the vkunroll, Gev-RS, DRE,
    DSEC and v2e layouts, NumPy .npy/.npz, Prophesee, AEDAT, ROS 1 bags), detected from the file,
    or ``format`` = a row's name or alias.

    Parameters:
      t_start, t_end: read only events with t_start <= t < t_end (integer microseconds; None:
        open end). Indexed formats seek instead of reading everything.
      on_bad: "error" (default) raises ValueError naming the file, record and rule at the first
        bad record; "drop" drops and counts bad records; "sort" keeps out-of-order records and
        sorts by t.
      dtype: the result's dtype (default :data:`EVENT_DTYPE`: t int64 us, x, y uint16, p int8
        +1/-1); e.g. :data:`TONIC_DTYPE`, :data:`EXPELLIARMUS_DTYPE`, :data:`METAVISION_DTYPE`.
      sensor_size: (width, height) when the file lacks it, or to override it.
      columns: text column order, a permutation of "txyp" ('_' skips a column).
      time_unit: text time unit "s", "ms", "us", "ns" (default: detected).
      array_time_unit: unit of float time arrays in .npy/.npz/.h5 (default "us").
      topic: ROS bags: the event topic (default: the bag's only topic of an event type,
        dvs_msgs/EventArray, prophesee_event_msgs/EventArray or event_camera_msgs/EventPacket).
      return_info: also return a dict: format, sensor_size, records, kept, dropped counts,
        ignored record kinds, notes and a one-paragraph summary.

    Raises FileNotFoundError (missing file), ValueError (bad record, bad option), with the
    reader's message.
    """
    fn = "read_events"
    path = A.existing_path(fn, "path", path)
    t_start, t_end = A.whole_us(fn, "t_start", t_start, none=True), A.whole_us(fn, "t_end", t_end, none=True)
    if t_start is not None and t_end is not None and t_end < t_start:
        A.refuse(fn, "t_end", t_end, f"a time >= t_start={t_start}")
    format = A.choice(fn, "format", format, A.EVENT_FORMATS, none=True)
    on_bad = A.choice(fn, "on_bad", on_bad, A.ON_BAD)
    width, height = A.size_pair(fn, "sensor_size", sensor_size, none=True) or (0, 0)
    columns = A.text(fn, "columns", columns, none=True)
    time_unit = A.choice(fn, "time_unit", time_unit, A.TIME_UNITS, none=True)
    array_time_unit = A.choice(fn, "array_time_unit", array_time_unit, A.TIME_UNITS, none=True)
    topic = A.text(fn, "topic", topic, none=True)
    return_info = A.flag(fn, "return_info", return_info)
    (t, x, y, p, w, h), info = _vk._read_events(path, t_start, t_end, format or "", on_bad, width, height, columns or "",
                                                time_unit or "", array_time_unit or "", topic or "")
    info = dict(info)
    info["sensor_size"] = (w, h)
    if info["dropped"] or info["sorted"]:
        _log.warning("%s", info["summary"])
    else:
        _log.debug("%s", info["summary"])
    events = _structured(t, x, y, p, dtype)
    return (events, info) if return_info else events


def write_events(path, events, sensor_size=None, format=None, *, overwrite=False):
    """Write events in the project's layouts: HDF5 (.h5: events/{t,x,y,p}, t int64 us, x/y
    uint16, p int8 1/0, width/height attributes) or text (.txt/.csv: "t x y p" lines).

    ``events``: any structured array with t, x, y, p (see :func:`convert_events`), t
    non-decreasing. ``sensor_size`` = (width, height) (default: max x + 1, max y + 1).
    ``format``: a writable row of :data:`EVENT_FORMATS`, "h5" or "txt" (default: from the extension).
    Read back with :func:`read_events`.
    ``overwrite``: replace an existing file (only one vkunroll wrote); without it an existing
    ``path`` is refused. The file is written under a temporary name and renamed when complete.
    Raises ValueError naming the event that breaks a rule.
    """
    path = A.path("write_events", "path", path)
    sensor_size = A.size_pair("write_events", "sensor_size", sensor_size, none=True)
    format = A.choice("write_events", "format", format, A.WRITABLE_EVENT_FORMATS, none=True)
    overwrite = A.flag("write_events", "overwrite", overwrite)
    t, x, y, p = event_fields(events)
    if sensor_size is None:
        if not x.size:
            A.refuse("write_events", "sensor_size", None, "(width, height) when there are no events to infer it from")
        sensor_size = (int(x.max()) + 1, int(y.max()) + 1)
    if format is None:
        ext = os.path.splitext(path)[1].lower()
        format = next((f.name for f in EVENT_FORMATS if f.writable and ext in f.extensions), None)
        if format is None:
            exts = " ".join(e for f in EVENT_FORMATS if f.writable for e in f.extensions)
            raise ValueError(f"{path}: cannot tell the event format from the extension '{ext}' (use one of {exts}, "
                             "or format=)")
    _vk._write_events(path, t, x, y, p, int(sensor_size[0]), int(sensor_size[1]), format, overwrite)
