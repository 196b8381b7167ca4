"""Minimal Wavefront OBJ reading and writing (positions and faces only)."""

from __future__ import annotations

import os

import numpy as np

from ._validate import as_triangles, as_vertices


def read_obj(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read vertices (n,3) float64 and triangles (m,3) int64 (0-based).

    Polygons are fan-triangulated; texture/normal indices ('v/t/n') and negative (relative)
    indices are understood.
    """
    verts: list[list[float]] = []
    tris: list[tuple[int, int, int]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = []
                for tok in line.split()[1:]:
                    i = int(tok.split("/")[0])
                    idx.append(i - 1 if i > 0 else len(verts) + i)
                for j in range(1, len(idx) - 1):
                    tris.append((idx[0], idx[j], idx[j + 1]))
    v = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"{path}: face index out of range")
    if not np.isfinite(v).all():
        raise ValueError(
            f"{path}: vertex {int(np.flatnonzero(~np.isfinite(v).all(1))[0])} is not finite"
        )
    return v, f


def write_obj(path: str | os.PathLike, vertices, faces) -> None:
    """Write (n,3) vertices and (m,3) 0-based triangles as an OBJ file."""
    v = as_vertices(vertices)
    f = as_triangles(faces, num_vertices=len(v))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# written by matdeform\n")
        np.savetxt(fh, v, fmt="v %.9g %.9g %.9g")
        np.savetxt(fh, f + 1, fmt="f %d %d %d")
