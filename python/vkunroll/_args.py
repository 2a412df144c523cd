"""The Python API's argument rules, in one place: every public function checks each keyword's type,
range and units here, once, before any work, and a refusal names the function and the keyword
(``read_events: t_start=1000.7: expected ...``). Nothing is truncated, clamped or guessed: a float
where whole microseconds are meant, an image outside [0, 1], an int64 image, a string where a pair is
meant are refused. ArgumentTypeError (a TypeError and a ValueError) for a wrong type, ValueError for
a wrong value (docs/python.md,
"Arguments"; tests/python/test_python_arguments.py runs the CLI's option property test over every
public function and keyword)."""
import math
import numbers
import os
from fractions import Fraction

import numpy as np

from . import _vkunroll as _vk

MAX_TIME_US = 2 ** 53  # the library's exact-time range (docs/reliability.md)
# The library's format table (host/events/event_formats.hpp): the names (and aliases) format= takes.
EVENT_FORMATS = tuple(n for f in _vk._event_formats() for n in (f["name"], f["alias"]) if n)
WRITABLE_EVENT_FORMATS = tuple(n for f in _vk._event_formats() if f["writable"] for n in (f["name"], f["alias"]) if n)
ON_BAD = ("error", "drop", "sort")
TIME_UNITS = ("s", "ms", "us", "ns")


def _shown(value):
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class ArgumentTypeError(TypeError, ValueError):
    """A keyword of the wrong type: a TypeError, and a ValueError as every bad input of the API is
    (the module's documented rule), so `except ValueError` still catches it."""


def refuse(fn, name, value, expected, exc=ValueError):
    """Raises `exc` naming the function, the keyword and its value (TypeError: ArgumentTypeError)."""
    if exc is TypeError:
        exc = ArgumentTypeError
    raise exc(f"{fn}: {name}={_shown(value)}: expected {expected}")


def _is_bool(v):
    return isinstance(v, (bool, np.bool_))


def _is_int(v):
    return isinstance(v, (int, np.integer)) and not _is_bool(v)


def _is_real(v):
    return isinstance(v, (numbers.Real, np.integer, np.floating)) and not _is_bool(v)


def plain_number(v):
    """The one conversion rule for numbers: a numpy scalar (any integer or floating type, float16 to
    longdouble) is the Python int or float it holds; anything else is returned as it is. Every check
    below reads numbers through it, so np.float32(0.5) is 0.5 wherever 0.5 is accepted."""
    if isinstance(v, np.integer) and not _is_bool(v):
        return int(v)
    if isinstance(v, np.floating):
        return float(v)
    return v


def integer(fn, name, v, lo, hi, none=False):
    """An int (not a bool, not a float) in [lo, hi]."""
    if v is None and none:
        return None
    v = plain_number(v)
    if not _is_int(v):
        refuse(fn, name, v, f"an integer in [{lo}, {hi}]" + (" or None" if none else ""), TypeError)
    if not lo <= v <= hi:
        refuse(fn, name, v, f"an integer in [{lo}, {hi}]")
    return int(v)


def number(fn, name, v, lo=-math.inf, hi=math.inf, lo_open=False, none=False, what="a number"):
    """A finite real number in [lo, hi] ((lo, hi] when lo_open); strings are refused, not parsed."""
    if v is None and none:
        return None
    v = plain_number(v)
    if not _is_real(v):
        refuse(fn, name, v, f"{what} (a finite number, not {type(v).__name__})", TypeError)
    x = float(v)
    inside = (x > lo if lo_open else x >= lo) and x <= hi
    if not math.isfinite(x) or not inside:
        refuse(fn, name, v, f"{what} in {'(' if lo_open else '['}{lo:g}, {hi:g}]")
    return x


def exact_time(fn, name, v, none=False, positive=False, nonnegative=False, what="a time in microseconds",
               limit=MAX_TIME_US, within="+-2^53 us"):
    """A time the library reads exactly: an int, a Fraction, a finite float (numpy scalars included,
    see plain_number) or a string ("73000/259", read by the library's one grammar), within +-limit.
    `what` says what the value is (a time in microseconds; a normalized instant for `times`)."""
    if v is None and none:
        return None
    v = plain_number(v)
    sign = "> 0 " if positive else ">= 0 " if nonnegative else ""
    rule = f"{what} {sign}(int, Fraction, finite float or exact string like '73000/259') within {within}"
    if isinstance(v, str):
        if len(v) > 200:
            refuse(fn, name, v, rule)
        try:
            value = Fraction(_vk._parse_time(v, f"{fn}: {name}"))
        except ValueError as e:
            raise ValueError(f"{fn}: {name}={_shown(v)}: {e}") from None
    elif _is_real(v) or isinstance(v, Fraction):
        if isinstance(v, (float, np.floating)) and not math.isfinite(v):
            refuse(fn, name, v, rule)
        value = Fraction(v)
    else:
        refuse(fn, name, v, rule, TypeError)
    if abs(value) > limit or (positive and value <= 0) or (nonnegative and value < 0):
        refuse(fn, name, v, rule)
    return v


def whole_us(fn, name, v, none=False):
    """Whole microseconds (event times are integers): an int, or a float holding one exactly."""
    if v is None and none:
        return None
    rule = "whole microseconds within +-2^53 (event times are integers; round the bound yourself)"
    v = plain_number(v)
    if isinstance(v, float):
        if not math.isfinite(v) or v != math.floor(v):
            refuse(fn, name, v, rule)
        v = int(v)
    if not _is_int(v):
        refuse(fn, name, v, rule, TypeError)
    if abs(int(v)) > MAX_TIME_US:
        refuse(fn, name, v, rule)
    return int(v)


def choice(fn, name, v, options, none=False):
    """One of `options` (strings)."""
    if v is None and none:
        return None
    listed = ", ".join(repr(o) for o in options) + (" or None" if none else "")
    if not isinstance(v, str):
        refuse(fn, name, v, f"one of {listed}", TypeError)
    if v not in options:
        refuse(fn, name, v, f"one of {listed}")
    return v


def flag(fn, name, v):
    """True or False (not 0/1, not a string)."""
    if not _is_bool(v):
        refuse(fn, name, v, "True or False", TypeError)
    return bool(v)


def text(fn, name, v, none=False, limit=4096):
    """A non-empty string (at most `limit` characters)."""
    if v is None and none:
        return None
    if not isinstance(v, str):
        refuse(fn, name, v, "a string", TypeError)
    if not v or len(v) > limit:
        refuse(fn, name, v, f"a non-empty string of at most {limit} characters")
    return v


def path(fn, name, v):
    """A file or folder path: a non-empty str or os.PathLike."""
    if not isinstance(v, (str, os.PathLike)):
        refuse(fn, name, v, "a path (str or os.PathLike)", TypeError)
    p = os.fspath(v)
    if not isinstance(p, str):
        refuse(fn, name, v, "a text path (not bytes)", TypeError)
    if not p or len(p) > 4096 or "\0" in p:
        refuse(fn, name, v, "a non-empty path of at most 4096 characters")
    return p


def existing_path(fn, name, v):
    """An input path that exists (FileNotFoundError naming the keyword otherwise)."""
    p = path(fn, name, v)
    if not os.path.exists(p):
        raise FileNotFoundError(f"{fn}: {name}={p!r}: no such file or folder")
    return p


class renamed:
    """Within it, a library error that names a CLI option (`--gate-radius 0: ...`) names the keyword
    too (`unroll: gate_radius (--gate-radius): ...`): the checks only the library can make (a gate
    radius for a model without a gate) still name what the caller typed."""

    def __init__(self, fn, keywords):
        self.fn, self.keywords = fn, keywords

    def __enter__(self):
        return self

    def __exit__(self, kind, e, tb):
        if e is None or not isinstance(e, (ValueError, TypeError)):
            return False
        msg = str(e)
        for kw in self.keywords:
            flag = "--" + kw.replace("_", "-")
            if msg.startswith(flag):
                raise type(e)(f"{self.fn}: {kw} ({flag}){msg[len(flag):]}") from None
        return False


def size_pair(fn, name, v, none=False):
    """(width, height): two ints 1..65536 (a string such as '64x48' is refused, not read per character)."""
    if v is None and none:
        return None
    rule = "(width, height), two integers 1 to 65536"
    if isinstance(v, (str, bytes)) or not isinstance(v, (tuple, list, np.ndarray)):
        refuse(fn, name, v, rule, TypeError)
    if len(v) != 2 or not all(_is_int(x) for x in v):
        refuse(fn, name, v, rule, TypeError if len(v) == 2 else ValueError)
    if not all(1 <= int(x) <= 65536 for x in v):
        refuse(fn, name, v, rule)
    return int(v[0]), int(v[1])


def index_list(fn, name, v, none=True):
    """Indices >= 0 (a list, tuple or 1-D integer array), each once."""
    if v is None and none:
        return None
    rule = "a list of frame indices (integers >= 0), each once"
    if isinstance(v, (str, bytes)) or not isinstance(v, (list, tuple, np.ndarray)):
        refuse(fn, name, v, rule, TypeError)
    out = []
    for x in list(v):
        if not _is_int(x):
            refuse(fn, name, v, rule, TypeError)
        if x < 0 or x > 2 ** 31 - 1 or int(x) in out:
            refuse(fn, name, v, rule)
        out.append(int(x))
    return out


def time_list(fn, name, v, positive=False, **kind):
    """One time or a list of them (see exact_time; `kind`: its what, limit and within), at least one.
    A 0-d numpy array is one time."""
    if isinstance(v, np.ndarray) and v.ndim == 0:
        v = v[()]
    values = list(v) if isinstance(v, (list, tuple, np.ndarray)) else [v]
    if not values:
        refuse(fn, name, v, "one time or a non-empty list of times")
    return [exact_time(fn, f"{name}[{i}]" if len(values) > 1 or isinstance(v, (list, tuple, np.ndarray)) else name, x,
                       positive=positive, **kind) for i, x in enumerate(values)]


def image(fn, name, a, gray=True):
    """An image as float32 in [0, 1]: uint8 and uint16 scaled by their full scale, floats as given
    (finite, within [0, 1]); any other dtype is refused, not guessed."""
    if isinstance(a, (str, bytes)) or a is None:
        refuse(fn, name, a, "an image array (H x W or H x W x 3)", TypeError)
    arr = np.asarray(a)
    if arr.ndim < 2 or 0 in arr.shape[:2]:  # an image has at least one pixel, whatever its dtype
        refuse(fn, name, f"<array of shape {arr.shape}>", "an image of H x W (x C) pixels, H and W at least 1")
    if arr.dtype == np.uint8:
        return arr.astype(np.float32) / 255.0
    if arr.dtype == np.uint16:
        return arr.astype(np.float32) / 65535.0
    if arr.dtype.kind != "f":
        refuse(fn, name, f"<{arr.dtype} array>", f"uint8, uint16 or float pixels in [0, 1], not {arr.dtype} "
               "(convert 0..255 integers with .astype(np.uint8), 0..65535 with .astype(np.uint16))", TypeError)
    if arr.size and not np.isfinite(arr).all():
        i = np.unravel_index(int(np.argmax(~np.isfinite(arr))), arr.shape)
        refuse(fn, name, f"<array with {arr[i]} at {tuple(int(x) for x in i)}>", "finite pixels in [0, 1]")
    if arr.size and (arr.min() < 0 or arr.max() > 1):
        bad = (arr < 0) | (arr > 1)
        i = np.unravel_index(int(np.argmax(bad)), arr.shape)
        refuse(fn, name, f"<array with {arr[i]} at {tuple(int(x) for x in i)}>",
               "float pixels in [0, 1] (scale or clip the image yourself; nothing is clamped silently)")
    return arr.astype(np.float32, copy=False)


def row_timing(fn, name, v, rowtiming_type):
    """A vkunroll.RowTiming, or a non-empty list of them."""
    values = list(v) if isinstance(v, (list, tuple)) else [v]
    if not values:
        refuse(fn, name, v, "a vkunroll.RowTiming or a non-empty list of them")
    for i, t in enumerate(values):
        if not isinstance(t, rowtiming_type):
            refuse(fn, f"{name}[{i}]" if isinstance(v, (list, tuple)) else name, t, "a vkunroll.RowTiming", TypeError)
    return values
