#!/usr/bin/python3
"""Reading the generic sequence layout (docs/sequence-format.md) for training
and evaluation: meta.json, RS/GS PNGs (8/16-bit, gray or color), events.h5 or events.txt; and
the row-aware event tensors of a crop for any source/target timing (tools/data/event_tensors_numpy.py).

    seq = Sequence("data/train/seq_0000")
    img = seq.frame(k)                 # float32 [3, H, W] in [0, 1], channel order rgb
    start, end = seq.row_times(k)      # float64 [H]: exposure start / end of every sensor row
    ev = seq.events_in(t_lo, t_hi, crop)  # (t, x, y, p) inside the time range and the crop

Every error names the file and what was expected.
"""
from __future__ import annotations

import json
import os
import struct
import zlib
from typing import Dict, List, Tuple

import numpy as np

from tools.data import event_tensors_numpy as etn

try:
    from PIL import Image
except ImportError:  # pragma: no cover - Debian's python3-pil is installed with matplotlib
    Image = None


class DataError(ValueError):
    pass


# ---- PNG -----------------------------------------------------------------------------------------
def _png_header(path: str):
    with open(path, "rb") as f:
        head = f.read(33)
    if len(head) < 33 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        raise DataError(f"{path}: not a PNG file")
    w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", head[16:29])
    return w, h, depth, ctype, interlace


def _decode_png16(path: str) -> np.ndarray:
    """16-bit PNG (gray/gray+alpha/RGB/RGBA, not interlaced) -> uint16 [H, W, C]. Pillow 9 reads
    16-bit color as 8-bit, so these are decoded here (zlib + the five PNG row filters)."""
    w, h, depth, ctype, interlace = _png_header(path)
    if interlace:
        raise DataError(f"{path}: interlaced 16-bit PNG is not supported (re-save it without interlacing)")
    channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(ctype)
    if channels is None:
        raise DataError(f"{path}: 16-bit PNG with color type {ctype} (expected gray, gray+alpha, RGB or RGBA)")
    data = open(path, "rb").read()
    pos, idat = 8, []
    while pos + 8 <= len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        if kind == b"IDAT":
            idat.append(data[pos + 8:pos + 8 + n])
        pos += 12 + n
    try:
        raw = np.frombuffer(zlib.decompress(b"".join(idat)), dtype=np.uint8)
    except zlib.error as e:
        raise DataError(f"{path}: corrupt PNG data ({e})") from None
    bpp = 2 * channels
    stride = w * bpp
    if raw.size < h * (stride + 1):
        raise DataError(f"{path}: truncated PNG data ({raw.size} bytes, expected {h * (stride + 1)})")
    rows = raw[:h * (stride + 1)].reshape(h, stride + 1)
    out = np.zeros((h, stride), dtype=np.uint8)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(h):
        ft, line = rows[y, 0], rows[y, 1:].astype(np.int32)
        if ft == 0:
            cur = line
        elif ft == 2:
            cur = (line + prev) & 255
        else:  # Sub, Average, Paeth depend on the reconstructed left neighbour: one pixel at a time
            cur = line.copy()
            for i in range(stride):
                left = cur[i - bpp] if i >= bpp else 0
                if ft == 1:
                    pred = left
                elif ft == 3:
                    pred = (left + prev[i]) >> 1
                elif ft == 4:
                    up, ul = prev[i], (prev[i - bpp] if i >= bpp else 0)
                    p = left + up - ul
                    pa, pb, pc = abs(p - left), abs(p - up), abs(p - ul)
                    pred = left if pa <= pb and pa <= pc else (up if pb <= pc else ul)
                else:
                    raise DataError(f"{path}: row {y} has PNG filter type {ft} (expected 0..4)")
                cur[i] = (cur[i] + pred) & 255
        out[y] = cur
        prev = cur
    return out.view(">u2").astype(np.uint16).reshape(h, w, channels)


def read_image(path: str) -> np.ndarray:
    """A PNG as float32 [3, H, W] in [0, 1], RGB (gray is replicated; alpha is dropped)."""
    if not os.path.isfile(path):
        raise DataError(f"{path}: image file not found")
    _, _, depth, ctype, _ = _png_header(path)
    if depth == 16:
        a = _decode_png16(path).astype(np.float32) / 65535.0
    else:
        if Image is None:
            raise DataError(f"{path}: reading PNGs needs Pillow (Debian package python3-pil)")
        with Image.open(path) as im:
            im = im.convert("RGB") if im.mode not in ("L", "RGB") else im
            a = np.asarray(im, dtype=np.float32) / 255.0
    if a.ndim == 2:
        a = a[:, :, None]
    if a.shape[2] in (2, 4):
        a = a[:, :, :a.shape[2] - 1]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return np.ascontiguousarray(a.transpose(2, 0, 1))


# ---- events ----------------------------------------------------------------------------------------
def read_events(path: str) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t float64 us, x int64, y int64, p int8 in {0,1}) from events.h5 or events.txt."""
    if not os.path.isfile(path):
        raise DataError(f"{path}: event file not found")
    if path.endswith((".h5", ".hdf5")):
        import h5py
        with h5py.File(path, "r") as f:
            for k in ("events/t", "events/x", "events/y", "events/p"):
                if k not in f:
                    raise DataError(f"{path}: dataset '{k}' missing (expected events/t, events/x, events/y, events/p)")
            t = f["events/t"][:].astype(np.float64)
            x = f["events/x"][:].astype(np.int64)
            y = f["events/y"][:].astype(np.int64)
            p = f["events/p"][:].astype(np.int64)
    else:
        try:
            a = np.loadtxt(path, comments="#", ndmin=2, dtype=np.float64)
        except ValueError as e:
            raise DataError(f"{path}: expected lines 't x y p' ({e})") from None
        if a.size == 0:
            a = np.zeros((0, 4))
        if a.shape[1] != 4:
            raise DataError(f"{path}: expected 4 columns 't x y p', found {a.shape[1]}")
        t, x, y, p = a[:, 0], a[:, 1].astype(np.int64), a[:, 2].astype(np.int64), a[:, 3].astype(np.int64)
    if not (len(t) == len(x) == len(y) == len(p)):
        raise DataError(f"{path}: t, x, y, p have different lengths ({len(t)}, {len(x)}, {len(y)}, {len(p)})")
    bad = ~np.isin(p, (-1, 0, 1))
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(f"{path}: event {i} has polarity {p[i]} (expected 1, 0 or -1)")
    if len(t) > 1 and np.any(np.diff(t) < 0):
        i = int(np.argmax(np.diff(t) < 0)) + 1
        raise DataError(f"{path}: event {i} has t={t[i]} before the previous event (t must be non-decreasing)")
    return t, x, y, (p > 0).astype(np.int8)


# ---- a sequence --------------------------------------------------------------------------------------
class Sequence:
    def __init__(self, folder: str, cache_images: bool = True):
        self.folder = folder
        mp = os.path.join(folder, "meta.json")
        if not os.path.isfile(mp):
            raise DataError(f"{mp}: not found (a sequence folder holds meta.json, rs/*.png and events)")
        try:
            meta = json.load(open(mp))
        except json.JSONDecodeError as e:
            raise DataError(f"{mp}: invalid JSON ({e})") from None
        self.meta = meta

        def field(name, kind):
            if name not in meta:
                raise DataError(f"{mp}: field '{name}' missing")
            try:
                return kind(meta[name])
            except (TypeError, ValueError):
                raise DataError(f"{mp}: field '{name}' = {meta[name]!r} is not a {kind.__name__}") from None

        self.width, self.height = field("width", int), field("height", int)
        self.line_delay = field("line_delay_us", float)
        self.exposure = field("exposure_us", float)
        self.readout = meta.get("readout", "top-down")
        if self.readout not in ("top-down", "bottom-up"):
            raise DataError(f"{mp}: readout '{self.readout}' (expected top-down or bottom-up)")
        if self.width < 2 or self.height < 2 or self.exposure <= 0 or self.line_delay < 0:
            raise DataError(f"{mp}: expected width, height >= 2, exposure_us > 0, line_delay_us >= 0")
        frames = meta.get("frames") or []
        if len(frames) < 1:
            raise DataError(f"{mp}: 'frames' is empty")
        self.frame_files = [os.path.join(folder, f["file"]) for f in frames]
        self.frame_t0 = np.array([float(f["t0_us"]) for f in frames], dtype=np.float64)
        if len(self.frame_t0) > 1 and np.any(np.diff(self.frame_t0) <= 0):
            raise DataError(f"{mp}: frame t0_us values must increase")
        self.gt = [(os.path.join(folder, g["file"]), float(g["t_us"])) for g in meta.get("ground_truth") or []]
        self.events_path = os.path.join(folder, field("events", str))
        self._events = None
        self._images: Dict[str, np.ndarray] = {}
        self.cache_images = cache_images

    def __repr__(self):
        return f"Sequence({self.folder}: {len(self.frame_t0)} frames {self.width}x{self.height}, {len(self.gt)} GT)"

    @property
    def num_frames(self) -> int:
        return len(self.frame_t0)

    def row_times(self, k: int) -> Tuple[np.ndarray, np.ndarray]:
        return etn.row_times(self.frame_t0[k], self.line_delay, self.exposure, self.height, self.readout)

    def frame_span(self, k: int) -> Tuple[float, float]:
        """Earliest row start and latest row end of frame k."""
        return self.frame_t0[k], self.frame_t0[k] + (self.height - 1) * self.line_delay + self.exposure

    def _image(self, path: str) -> np.ndarray:
        if path in self._images:
            return self._images[path]
        img = read_image(path)
        if img.shape[1:] != (self.height, self.width):
            raise DataError(f"{path}: image is {img.shape[2]}x{img.shape[1]}, meta.json says {self.width}x{self.height}")
        if self.cache_images:
            self._images[path] = img
        return img

    def frame(self, k: int) -> np.ndarray:
        return self._image(self.frame_files[k])

    def gt_image(self, i: int) -> np.ndarray:
        return self._image(self.gt[i][0])

    @property
    def events(self):
        if self._events is None:
            t, x, y, p = read_events(self.events_path)
            bad = (x < 0) | (x >= self.width) | (y < 0) | (y >= self.height)
            if bad.any():
                i = int(np.argmax(bad))
                raise DataError(f"{self.events_path}: event {i} at ({x[i]}, {y[i]}) lies outside the "
                                f"{self.width}x{self.height} sensor of meta.json ({int(bad.sum())} such events)")
            self._events = (t, x, y, p)
        return self._events

    def events_in(self, t_lo: float, t_hi: float, crop: Tuple[int, int, int, int]):
        t, x, y, p = self.events
        i0, i1 = np.searchsorted(t, t_lo, "left"), np.searchsorted(t, t_hi, "right")
        t, x, y, p = t[i0:i1], x[i0:i1], y[i0:i1], p[i0:i1]
        x0, y0, w, h = crop
        m = (x >= x0) & (x < x0 + w) & (y >= y0) & (y < y0 + h)
        return t[m], x[m], y[m], p[m]


def list_sequences(paths: List[str]) -> List[str]:
    """Sequence folders: each path is one (it has meta.json) or a folder of them."""
    out = []
    for p in paths:
        if os.path.isfile(os.path.join(p, "meta.json")):
            out.append(p)
        elif os.path.isdir(p):
            subs = sorted(os.path.join(p, d) for d in os.listdir(p) if os.path.isfile(os.path.join(p, d, "meta.json")))
            if not subs:
                raise DataError(f"{p}: no meta.json in it or in its subfolders (expected sequence folders)")
            out += subs
        else:
            raise DataError(f"{p}: not found")
    return out


# ---- event tensors for any source -> target timing ------------------------------------------------
def eic_tensors(ev, src_start, src_end, target, target_exposure, bins, crop):
    """ev1/ev2/ev3 [2N, h, w] of one E-IC pass (docs/event_tensors.md, generalized): the
    source image's rows are exposed over [src_start[y], src_end[y]], the output is the image whose
    row y is exposed over [target[y], target[y] + target_exposure). All arrays are float64 per
    full-sensor row; RS2GS uses a constant target, GS2RS a constant source window."""
    tgt_end = target + target_exposure
    return (etn.event_tensor_fast(*ev, target, src_start, bins, crop),
            etn.event_tensor_fast(*ev, target, src_end, bins, crop),
            etn.event_tensor_fast(*ev, target, tgt_end, bins, crop))
