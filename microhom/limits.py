"""Memory and number-range limits shared by the readers and the broadcasting predictions.

* :func:`available_memory` — bytes this process may still allocate (``/proc/meminfo``'s
  ``MemAvailable``, lowered to a cgroup's limit);
* :func:`check_broadcast` — the shape of a broadcast of named inputs, refused *before* any
  allocation when the arrays it would create do not fit the available memory (one error naming
  each parameter and its length), or when the shapes do not broadcast (naming the parameters, not
  numpy's "operands could not be broadcast");
* :func:`as_float_array` — a parameter as float64, with a message naming it for strings, ``None``
  and other non-numbers.

The disk engine's reading rule (``dem.io``) uses :func:`available_memory` too.
"""
from __future__ import annotations

import math
import os

import numpy as np

__all__ = ["available_memory", "check_broadcast", "as_float_array", "MEMORY_FRACTION"]

#: A broadcast may take at most this fraction of :func:`available_memory`.
MEMORY_FRACTION = 0.5


def available_memory() -> int:
    """Bytes of memory this process may still allocate: ``MemAvailable`` of ``/proc/meminfo``,
    lowered to the cgroup's ``memory.max - memory.current`` when a container sets a limit; the
    free physical pages (``os.sysconf``) where ``/proc`` is missing; 2**62 when nothing tells."""
    avail = None
    try:
        with open("/proc/meminfo", "rb") as f:
            for line in f:
                if line.startswith(b"MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = 2 ** 62
    try:
        with open("/sys/fs/cgroup/memory.max", "rb") as f:
            cap = f.read().strip()
        with open("/sys/fs/cgroup/memory.current", "rb") as f:
            used = int(f.read().strip())
        if cap != b"max":
            avail = min(avail, max(int(cap) - used, 0))
    except (OSError, ValueError):
        pass
    return int(avail)


def as_float_array(name, value, *, unit="") -> np.ndarray:
    """``value`` as a float64 array; ValueError naming ``name`` for text, ``None``, complex
    numbers and other non-numbers (never numpy's "could not convert string to float")."""
    if value is None:
        raise ValueError(f"{name} must be a number or an array of numbers{unit}, got None")
    if isinstance(value, (str, bytes)):
        raise ValueError(f"{name} must be a number or an array of numbers{unit}, got the text "
                         f"{value!r} (convert it with float() first)")
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError):  # ragged nested lists
        raise ValueError(f"{name} must be a number or a regular array of numbers{unit}; got a "
                         f"{type(value).__name__} that is not a regular array") from None
    if arr.dtype.kind in "iufb":
        return arr.astype(np.float64, copy=False)
    if arr.dtype.kind == "c":
        raise ValueError(f"{name} must be real{unit}; got a complex value")
    try:
        return np.asarray(value, dtype=np.float64)
    except (ValueError, TypeError):
        raise ValueError(f"{name} must be a number or an array of numbers{unit}; got "
                         f"{type(value).__name__} holding non-numbers") from None


def check_broadcast(named, *, bytes_per_element, what="the result") -> tuple:
    """Broadcast shape of the arrays in ``named`` (dict name -> array), checked before allocating.

    ``bytes_per_element``: bytes the caller allocates per element of the broadcast shape (all its
    outputs and temporaries). Raises ValueError naming the parameters and their shapes when the
    shapes do not broadcast, and MemoryError naming each non-scalar parameter's size, the element
    count and the memory it would take when that exceeds ``MEMORY_FRACTION`` of
    :func:`available_memory`.
    """
    shapes = {k: np.shape(v) for k, v in named.items()}
    try:
        shape = np.broadcast_shapes(*shapes.values())
    except ValueError:
        listed = ", ".join(f"{k} {s}" for k, s in shapes.items() if s)
        raise ValueError(f"the array parameters have shapes that do not broadcast together: "
                         f"{listed} (each axis must have equal lengths or length 1)") from None
    count = math.prod(shape)
    need = count * bytes_per_element
    allowed = int(MEMORY_FRACTION * available_memory())
    if need > allowed:
        listed = ", ".join(f"{k} {s}" for k, s in shapes.items() if s)
        raise MemoryError(f"{what} would have {count:,} entries (shape {shape} from {listed}) "
                          f"and take about {need / 1e9:.3g} GB, more than the {allowed / 1e9:.3g} "
                          f"GB allowed ({MEMORY_FRACTION:g} of the memory available): give fewer "
                          f"values")
    return shape
