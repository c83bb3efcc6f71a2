"""Memory and number-range limits shared by the readers and the broadcasting predictions.

* :func:`available_memory` — bytes this process may still allocate (``/proc/meminfo``'s
  ``MemAvailable``, lowered to a cgroup's limit);
* :func:`check_broadcast` — the shape of a broadcast of named inputs, refused *before* any
  allocation when the arrays it would create do not fit the available memory (one error naming
  each parameter and its length), or when the shapes do not broadcast (naming the parameters, not
  numpy's "operands could not be broadcast");
* :func:`as_float_array` — a parameter as float64, with a message naming it for strings, ``None``
  and other non-numbers;
* :func:`release_free_memory` — the C heap's free pages handed back to the operating system
  (glibc's ``malloc_trim``), after a phase that made many small arrays.

The disk engine's reading rule (``dem.io``) uses :func:`available_memory` too.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import math
import os
import sys

import numpy as np

__all__ = ["available_memory", "check_broadcast", "as_float_array", "release_free_memory", "MEMORY_FRACTION"]

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


def _malloc_trim():
    """glibc's ``malloc_trim`` (a ctypes function), or None (not Linux, or another C library)."""
    if not sys.platform.startswith("linux"):
        return None
    return _libc_trim()


@functools.lru_cache(maxsize=1)
def _libc_trim():
    """The C library's ``malloc_trim``, looked up once (``find_library`` runs ``ldconfig``), or None."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


def release_free_memory() -> bool:
    """Hand the C heap's free pages back to the operating system: glibc's ``malloc_trim(0)``.

    numpy's arrays below glibc's mmap threshold (128 KiB, raised up to 32 MiB once such blocks
    are freed) live on the heap; once freed, their pages stay in the process's resident set as
    long as a live block sits above them. A phase that makes many small arrays (the dual bound's
    statics: one dense operator per unit and seed) thus leaves resident memory nothing uses:
    measured 0.43 GiB of 4.2 at 3.2e5 spheres (issue 26, docs/results/spheres.md). Returns True
    where it ran (Linux with glibc), False elsewhere (nothing done; other allocators return
    memory their own way). Costs a walk over the heap's free lists (milliseconds)."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
