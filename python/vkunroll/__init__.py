"""vkunroll: rolling-shutter images + event streams -> global-shutter video (SelfUnroll) on any
Vulkan GPU, from Python. numpy in, numpy out.

    import vkunroll
    vkunroll.devices()                                       # the Vulkan devices
    ev = vkunroll.read_events("recording.raw")               # t, x, y, p structured array
    timing = vkunroll.RowTiming(260, 0, 100, 3000)           # height, t0, line delay, exposure (us)
    ev1, ev2, ev3 = vkunroll.event_tensors(ev, timing, t_us=15000, bins=16)
    model = vkunroll.Model.load("checkpoint.safetensors")    # e.g. tools/model/convert_checkpoint.py's output
    out = model.run(rs, ev1, ev2, ev3, mode="s")             # dict of float32 arrays
    frames, metrics, targets, stats = vkunroll.unroll(vkunroll.Sequence.open("seq"), times="gt")
    # ... with the shipped default model (vkunroll.default_model()); model="FILE" for another

Errors are ValueError (bad input), FileNotFoundError (missing files) and RuntimeError (device
failures), with the library's messages. Long GPU work releases the GIL. The library's messages
(the chosen device, validation, notes) go to the ``vkunroll`` logger. See docs/python.md.
"""
from . import _vkunroll
from ._events import (EVENT_DTYPE, EVENT_FORMATS, EXPELLIARMUS_DTYPE, METAVISION_DTYPE, TONIC_DTYPE, convert_events,
                      detect_event_format, read_events, write_events)
from ._model import Model
from ._runtime import Context, default_context, devices
from ._sequence import Sequence, simulate
from ._tensors import event_tensors, event_tensors_batch, physics_unroll, psnr, ssim
from ._unroll import UnrollResult, UnrollSession, stream, unroll
from ._vkunroll import RowTiming, default_model

__version__ = _vkunroll.__version__

__all__ = [
    "devices", "Context", "default_context",
    "EVENT_DTYPE", "TONIC_DTYPE", "EXPELLIARMUS_DTYPE", "METAVISION_DTYPE", "EVENT_FORMATS",
    "read_events", "write_events", "convert_events", "detect_event_format",
    "Sequence", "simulate", "RowTiming",
    "event_tensors", "event_tensors_batch", "physics_unroll",
    "Model", "UnrollSession", "UnrollResult", "unroll", "stream", "default_model", "psnr", "ssim",
]
