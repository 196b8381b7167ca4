"""Bulk copies between Blender data and numpy arrays: ``foreach_get`` into a new array, and
the raw-memory route into and out of a shape key's coordinates where ``foreach_*`` goes item by
item (Blender < 4.1). The underscore names are the bridge's own, used by its other modules."""

from __future__ import annotations

import ctypes

import numpy as np


def _get(seq, attr, n, dtype, width=1):
    out = np.empty(n * width, dtype=dtype)
    seq.foreach_get(attr, out)
    return out.reshape(n, width) if width > 1 else out


def _key_array(kb, size: int) -> int:
    """Address of the key block's float[3] array if it is one contiguous block of ``size``
    floats (what Blender < 4.1 keeps), else 0."""
    data = kb.data
    n = len(data)
    if n == 0 or size != 3 * n:
        return 0
    first, last = data[0].as_pointer(), data[n - 1].as_pointer()
    return first if first != 0 and last - first == 12 * (n - 1) else 0


def _raw_copy_into_key(kb, flat) -> bool:
    if flat.size == 0:
        return len(kb.data) == 0
    addr = _key_array(kb, flat.size)
    if addr:
        ctypes.memmove(addr, flat.ctypes.data, flat.nbytes)
    return bool(addr)


def read_key_into(kb, flat) -> None:
    """A key block's coordinates into ``flat`` ((3n,) float32) by the fastest route there is
    (the bulk ``points`` of Blender >= 4.1, raw memory before, else ``data``): live checks."""
    points = getattr(kb, "points", None)
    if points is not None:
        points.foreach_get("co", flat)
    elif not _raw_copy_from_key(kb, flat):
        kb.data.foreach_get("co", flat)


def _raw_copy_from_key(kb, flat) -> bool:
    if flat.size == 0:
        return len(kb.data) == 0
    addr = _key_array(kb, flat.size)
    if addr:
        ctypes.memmove(flat.ctypes.data, addr, flat.nbytes)
    return bool(addr)
