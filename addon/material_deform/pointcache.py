"""The .pc2 point cache format (no bpy): what Blender's Mesh Cache modifier reads.

Layout (little-endian): ``char[12] "POINTCACHE2\\0"``, ``int32 version = 1``, ``int32 points``,
``float32 start frame``, ``float32 sample rate`` (frames between samples), ``int32 samples``,
then ``samples * points * 3`` float32 coordinates, sample after sample.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct

import numpy as np

MAGIC = b"POINTCACHE2\0"
_HEAD = struct.Struct("<12siiffi")


def temp_name(path: str, suffix: str = "") -> str:
    """A temporary file next to ``path`` that no other writer (process or farm node) uses."""
    return f"{_temp_prefix(path)}{os.getpid()}{suffix}"


def _temp_prefix(path: str) -> str:
    # host and process in the name: writers on several farm nodes never share a temp file, and
    # one left by a killed process of this host can be told apart from a running writer's
    return f"{path}.tmp-{socket.gethostname()}-"


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # POSIX only: signal 0 checks, on Windows os.kill would terminate
    except ProcessLookupError:
        return False
    except OSError:
        return True  # someone else's process: alive
    return True


def remove_stale_temps(path: str) -> list[str]:
    """Remove the temporary files of ``path`` left by writers of this host that no longer run
    (a bake or farm task killed mid-write), which would keep a full disk full. Returns them.
    Temp files of other hosts and of running processes stay; on Windows nothing is removed."""
    if os.name != "posix":
        return []
    folder, prefix = os.path.split(_temp_prefix(path))
    removed = []
    for name in os.listdir(folder or "."):
        pid = name[len(prefix) :]
        if name.startswith(prefix) and pid.isdigit() and not _running(int(pid)):
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(folder, name))
                removed.append(name)
    return removed


class PC2Writer:
    """Write ``samples`` frames of ``points`` positions to ``path`` atomically: the frames go
    to a temporary file next to it, renamed over ``path`` only when every frame was written
    (an error or an interrupted bake leaves an existing cache as it was, and no temporary
    file; those of killed writers go when the next writer of ``path`` starts)."""

    def __init__(self, path: str, points: int, samples: int, start: float, rate: float = 1.0):
        if points <= 0 or samples <= 0:
            raise ValueError("points and samples: must be > 0")
        self.path, self.points, self.samples = path, int(points), int(samples)
        remove_stale_temps(path)
        self.tmp = temp_name(path)
        self.written = 0
        try:
            self._f = open(self.tmp, "wb")  # noqa: SIM115 (closed in close / __exit__)
        except OSError as exc:  # name the cache, not the temporary file next to it
            raise OSError(exc.errno, exc.strerror, path) from None
        try:
            self._f.write(
                _HEAD.pack(MAGIC, 1, self.points, float(start), float(rate), self.samples)
            )
        except BaseException:
            self.abort()
            raise

    def add(self, positions) -> None:
        """positions: (points,3) for the next frame."""
        p = np.ascontiguousarray(positions, dtype="<f4")
        if p.shape != (self.points, 3):
            raise ValueError(f"positions: expected ({self.points}, 3), got {p.shape}")
        if self.written >= self.samples:
            raise ValueError(f"positions: all {self.samples} samples already written")
        self._f.write(p.tobytes())
        self.written += 1

    def close(self) -> None:
        if self.written != self.samples:
            self.abort()
            raise ValueError(f"only {self.written} of {self.samples} samples were written")
        try:
            self._f.close()  # flushes: a full disk fails here too
            os.replace(self.tmp, self.path)
        except BaseException as exc:
            self.abort()
            if isinstance(exc, OSError):  # name the cache, not the temporary file
                raise OSError(exc.errno, exc.strerror, self.path) from None
            raise

    def abort(self) -> None:
        """Drop the temporary file (the cache at ``path`` stays as it was), even when closing it
        fails as a full disk makes it fail."""
        with contextlib.suppress(OSError):
            self._f.close()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.tmp)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, _exc, _tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False


def read_pc2(path: str) -> tuple[float, float, np.ndarray]:
    """(start frame, sample rate, positions (samples, points, 3) float32)."""
    with open(path, "rb") as f:
        head = f.read(_HEAD.size)
        if len(head) != _HEAD.size:
            raise ValueError(f"{path}: too short for a .pc2 header")
        magic, _version, points, start, rate, samples = _HEAD.unpack(head)
        if magic != MAGIC:
            raise ValueError(f"{path}: not a .pc2 file")
        data = np.frombuffer(f.read(), dtype="<f4")
    if data.size != samples * points * 3:
        raise ValueError(
            f"{path}: holds {data.size} floats, the header says {samples * points * 3}"
        )
    return start, rate, data.reshape(samples, points, 3)
