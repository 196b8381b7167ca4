"""Minimal Wavefront OBJ reading and writing (positions and faces only)."""

from __future__ import annotations

import os

import numpy as np

from ._validate import as_triangles, as_vertices


def read_obj(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read vertices (n,3) float64 and triangles (m,3) int64 (0-based) from a Wavefront OBJ.

    Fields may be separated by any whitespace (spaces or tabs). Polygons are fan-triangulated;
    'v/t/n', 'v//n' and negative (relative: -1 is the last vertex so far) indices are understood.
    Other records (vt, vn, o, g, s, usemtl, comments) are ignored. Raises ValueError naming the
    file and line for a malformed vertex, a face with fewer than 3 corners, or an index that is
    0 or out of range.
    """
    verts: list[list[float]] = []
    tris: list[tuple[int, int, int]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            tok = line.split("#", 1)[0].split()
            if not tok:
                continue
            where = f"{path}:{lineno}"
            if tok[0] == "v":
                try:
                    verts.append([float(x) for x in tok[1:4]])
                except ValueError:
                    raise ValueError(f"{where}: malformed vertex {line.strip()!r}") from None
                if len(verts[-1]) != 3:
                    raise ValueError(f"{where}: a vertex needs 3 coordinates")
            elif tok[0] == "f":
                idx = []
                for t in tok[1:]:
                    try:
                        i = int(t.split("/")[0])
                    except ValueError:
                        raise ValueError(f"{where}: malformed face index {t!r}") from None
                    j = i - 1 if i > 0 else len(verts) + i
                    if i == 0 or not 0 <= j < len(verts):
                        raise ValueError(
                            f"{where}: face index {i} out of range (1..{len(verts)} or "
                            f"-1..-{len(verts)} here)"
                        )
                    idx.append(j)
                if len(idx) < 3:
                    raise ValueError(f"{where}: a face needs at least 3 corners")
                for j in range(1, len(idx) - 1):
                    tris.append((idx[0], idx[j], idx[j + 1]))
    v = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
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
