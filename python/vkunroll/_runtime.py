"""Devices and the device context."""
import threading

from . import _args as A
from . import _vkunroll as _vk

__all__ = ["devices", "Context", "default_context"]


def _device_arg(fn, device):
    """None (VKUNROLL_DEVICE, else the best device), an index >= 0, or a name substring / uuid:UUID."""
    if device is None:
        return ""
    if isinstance(device, str):
        return A.text(fn, "device", device, limit=256)
    return str(A.integer(fn, "device", device, 0, 1 << 16))


def devices(validation=False):
    """Every Vulkan device the loader sees, as a list of dicts.

    Each dict has ``index``, ``name``, ``type`` ("discrete", "integrated", "virtual", "cpu",
    "other"), ``api_version`` ("1.3.230"), ``driver``, ``driver_info``, ``subgroup_size``, ``fp16``
    (16-bit arithmetic and storage both supported), ``shader_float16``, ``storage_buffer_16bit``,
    ``timestamps``, ``device_local_bytes``, ``limits`` (a dict: ``max_storage_buffer_range``,
    ``max_shared_memory``, ``max_workgroup_invocations``, ...) and ``default`` (True for the device
    a ``Context()`` opens: the VKUNROLL_DEVICE environment variable, else discrete > integrated >
    virtual > cpu). No device is opened.

    Raises RuntimeError when no Vulkan driver is installed (the message says how to install
    Mesa's lavapipe).
    """
    return _vk._devices(A.flag("devices", "validation", validation))


class Context:
    """An opened Vulkan device, shared by the objects that run on it.

    ``Context(device=None, validation=False)``: ``device`` is an index or a case-insensitive
    substring of the name (see :func:`devices`); None picks VKUNROLL_DEVICE, else the best device.
    ``validation=True`` enables VK_LAYER_KHRONOS_validation (its messages go to the ``vkunroll``
    logger as warnings; they are also listed by :meth:`validation_messages`).

    Pass it to :meth:`Model.load`, :func:`event_tensors` and :func:`physics_unroll`; without one,
    they use :func:`default_context`. Work from several Python threads on one context is
    serialized (the GIL is released meanwhile).

    Raises RuntimeError when the device cannot be opened, ValueError when ``device`` matches none.
    """

    def __init__(self, device=None, validation=False):
        device = _device_arg("Context", device)
        self._ctx = _vk._Context(device, A.flag("Context", "validation", validation))

    @property
    def device(self):
        """The opened device as a dict (the fields of :func:`devices`)."""
        return self._ctx.info

    @property
    def name(self):
        """The device's name, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)"."""
        return self._ctx.info["name"]

    @property
    def validation(self):
        """True when the validation layer is on."""
        return self._ctx.validation

    def validation_messages(self):
        """The validation layer's messages since the context was made (list of str)."""
        return list(self._ctx.validation_messages())

    def traffic(self):
        """Host <-> device bytes and submissions through this context so far (a dict)."""
        return dict(self._ctx.traffic())

    def __repr__(self):
        return f"vkunroll.Context({self.name!r})"


_default = None
_default_lock = threading.Lock()


def default_context():
    """The process's shared :class:`Context` (made on first use with ``Context()``)."""
    global _default
    with _default_lock:
        if _default is None:
            _default = Context()
        return _default


def resolve_context(context, backend="vulkan"):
    """The internal context handle for `backend` ("vulkan": `context` or the default; "cpu": None)."""
    if not isinstance(backend, str):
        raise TypeError(f"backend={backend!r}: expected 'vulkan' or 'cpu'")
    if backend == "cpu":
        if context is not None:  # an option that does not apply is refused, never ignored
            raise ValueError("context: a vkunroll.Context applies to backend='vulkan', not 'cpu'")
        return None
    if backend != "vulkan":
        raise ValueError(f"backend={backend!r}: expected 'vulkan' or 'cpu'")
    if context is None:
        context = default_context()
    if not isinstance(context, Context):
        raise TypeError(f"context: expected a vkunroll.Context, got {type(context).__name__}")
    return context._ctx
