"""Mesh topology: dual edges (pairs of faces sharing a mesh edge)."""

from __future__ import annotations

import numpy as np

from . import _core
from ._validate import as_int_array, as_triangles


def dual_edges(faces, return_shared: bool = False):
    """Pairs of faces that share a mesh edge.

    faces: (m,3) int triangles.
    Returns pairs (E,2) int64 with f < g, sorted lexicographically: the order `bend` uses. An
    edge shared by more than two faces (non-manifold) yields every pair of its faces. With
    return_shared, also returns shared (E,2): the two vertices of the mesh edge each pair shares.
    """
    f = as_triangles(faces)
    pairs, shared = _core.dual_edges(f)
    pairs = pairs.astype(np.int64)
    if return_shared:
        return pairs, shared.astype(np.int64)
    return pairs


def boundary_and_nonmanifold_edges(faces) -> tuple[np.ndarray, np.ndarray]:
    """Mesh edges used by exactly one face, and by more than two. Each (K,2) int64, a < b."""
    f = as_triangles(faces)
    e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq[counts == 1].astype(np.int64), uniq[counts > 2].astype(np.int64)


def faces_inside(faces, vertex_ids) -> np.ndarray:
    """Indices of the faces (m,3) whose three vertices all lie in vertex_ids. Returns (K,) int64.

    Turns a vertex selection (a vertex group, a ball around a point) into anchor or region faces.
    """
    f = as_triangles(faces)
    ids = as_int_array(np.asarray(vertex_ids).ravel(), "vertex_ids", 1)
    if ids.size and ids.min() < 0:
        raise ValueError(f"vertex_ids: indices must be >= 0, got {ids.min()}")
    inside = np.zeros(int(f.max()) + 1 if f.size else 0, dtype=bool)
    inside[ids[ids < inside.size]] = True  # larger ids are in no face
    return np.flatnonzero(inside[f].all(axis=1)).astype(np.int64)


def face_components(faces) -> tuple[np.ndarray, int]:
    """Connected components of the faces (m,3) through shared edges.

    Returns (labels (m,) int64 in [0, count), count). Each component is deformed on its own; a
    component without an anchor keeps its rest shape.
    """
    f = as_triangles(faces)
    pairs, _ = _core.dual_edges(f)
    labels, count = _core.face_components(f.shape[0], pairs)
    return labels.astype(np.int64), int(count)


def mesh_edges(faces) -> np.ndarray:
    """Undirected edges (E,2) int64 of the faces (m,3): a < b, unique, sorted lexicographically.

    The order of per-edge arrays such as ``EdgeDeformer(edge_weight=...)``.
    """
    f = as_triangles(faces)
    return _core.mesh_edges(f).astype(np.int64)
