"""Input checks shared by the public API. Each raises ValueError naming the argument."""

from __future__ import annotations

import math
import numbers

import numpy as np


def _fail(name: str, msg: str) -> ValueError:
    return ValueError(f"{name}: {msg}")


def as_vertices(x, name: str = "vertices", rows: int | None = None) -> np.ndarray:
    """(n,3) finite float64, C-contiguous."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise _fail(name, f"expected a float array of shape (n,3) ({e})") from None
    if a.ndim != 2 or a.shape[1] != 3:
        raise _fail(name, f"expected shape (n,3), got {a.shape}")
    if rows is not None and a.shape[0] != rows:
        raise _fail(name, f"expected shape ({rows},3), got {a.shape}")
    if not np.isfinite(a).all():
        raise _fail(name, "contains NaN or infinity")
    return np.ascontiguousarray(a)


# The core's limits (native/include/matdeform/mesh.hpp, stiffness.hpp), checked here first for a
# message in the caller's terms.
MIN_MESH_SIZE, MAX_MESH_SIZE = 1e-50, 1e50
MAX_STIFFNESS_RATIO = 1e12


def as_mesh_vertices(x, name: str = "vertices") -> np.ndarray:
    """as_vertices, and a bounding box whose largest extent lies in [1e-50, 1e50]."""
    v = as_vertices(x, name)
    if len(v):
        size = float(np.ptp(v, axis=0).max())
        if size == 0.0:
            raise _fail(name, "all vertices coincide")
        if not MIN_MESH_SIZE <= size <= MAX_MESH_SIZE:
            raise _fail(
                name,
                f"the mesh is {size:.3g} across; expected {MIN_MESH_SIZE:g} to {MAX_MESH_SIZE:g}: "
                "rescale the mesh (only its shape matters)",
            )
    return v


def check_stiffness_ratio(a: np.ndarray, name: str) -> None:
    """a > 0: max/min at most 1e12, beyond which the factorisations lose every digit."""
    if a.size and a.max() > MAX_STIFFNESS_RATIO * a.min():
        raise _fail(
            name,
            f"stiffness ratio max/min = {a.max() / a.min():.3g} is above 1e12; raise the smallest "
            "values (only ratios matter)",
        )


# The largest count or index the core's 32-bit ints hold.
MAX_INT = 2**31 - 1


def as_real(
    x,
    name: str,
    lo: float,
    hi: float = math.inf,
    lo_open: bool = False,
    hi_open: bool = False,
    allow_inf: bool = False,
) -> float:
    """A real number (Python or numpy, not bool or str) in [lo, hi], each end open on request;
    finite unless allow_inf (then +inf passes when hi is inf)."""
    lo_s = f"({lo:g}" if lo_open else f"[{lo:g}"
    hi_s = (
        ("inf]" if allow_inf else "inf)")
        if hi == math.inf
        else f"{hi:g}" + (")" if hi_open else "]")
    )
    what = f"a {'' if allow_inf else 'finite '}value in {lo_s}, {hi_s}"
    if isinstance(x, bool) or not isinstance(x, numbers.Real):
        raise _fail(name, f"expected {what}, got {type(x).__name__} {x!r}")
    v = float(x)
    ok = (
        (math.isfinite(v) or (allow_inf and v == math.inf and hi == math.inf))
        and (v > lo if lo_open else v >= lo)
        and (v < hi if hi_open else v <= hi)
    )
    if not ok:
        raise _fail(name, f"expected {what}, got {v!r}")
    return v


def as_count(x, name: str, lo: int = 0, hi: int = MAX_INT) -> int:
    """An integer (Python or numpy, not bool) in [lo, hi]; hi defaults to what a C int holds."""
    if isinstance(x, bool) or not isinstance(x, numbers.Integral):
        raise _fail(name, f"expected an integer in [{lo}, {hi}], got {type(x).__name__} {x!r}")
    if not lo <= int(x) <= hi:
        raise _fail(name, f"expected an integer in [{lo}, {hi}], got {int(x)}")
    return int(x)


def as_bool(x, name: str) -> bool:
    """True or False (numpy's too); anything else, even truthy, is refused."""
    if not isinstance(x, (bool, np.bool_)):
        raise _fail(name, f"expected True or False, got {type(x).__name__} {x!r}")
    return bool(x)


def as_float_array(x, name: str) -> np.ndarray:
    """float64 array of any shape (shape and value checks are the caller's)."""
    try:
        return np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise _fail(name, f"expected a float array ({e})") from None


def as_int_array(x, name: str, ndim: int) -> np.ndarray:
    a = np.asarray(x)
    if a.dtype == object or not (np.issubdtype(a.dtype, np.integer) or a.size == 0):
        raise _fail(name, f"expected an integer array, got dtype {a.dtype}")
    if a.ndim != ndim:
        raise _fail(name, f"expected a {ndim}-d integer array, got shape {a.shape}")
    if a.size and (a.max() > np.iinfo(np.int32).max or a.min() < np.iinfo(np.int32).min):
        raise _fail(name, "indices do not fit in 32 bits")
    return np.ascontiguousarray(a, dtype=np.int32)


def as_triangles(x, name: str = "faces", num_vertices: int | None = None) -> np.ndarray:
    """(m,3) int32 vertex indices >= 0 (and < num_vertices when given); m may be 0."""
    f = as_int_array(x, name, 2)
    if f.shape[1] != 3:
        raise _fail(name, f"expected triangles of shape (m,3), got {f.shape}")
    if f.size and f.min() < 0:
        raise _fail(name, f"indices must be >= 0, got {f.min()}")
    if f.size and num_vertices is not None and f.max() >= num_vertices:
        raise _fail(name, f"indices must lie in [0, {num_vertices}), got [{f.min()}, {f.max()}]")
    return f


def as_faces(x, num_vertices: int, name: str = "faces") -> np.ndarray:
    """(m,3) int32 triangles with indices in [0, num_vertices) and no repeated corner."""
    f = as_triangles(x, name, num_vertices)
    if f.shape[0] == 0:
        raise _fail(name, "expected at least one triangle, got shape (0,3)")
    bad = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    if bad.any():
        raise _fail(name, f"face {int(np.flatnonzero(bad)[0])} repeats a vertex")
    return f


def as_index_set(x, upper: int, name: str) -> np.ndarray:
    """1-d unique indices in [0, upper), order kept."""
    a = as_int_array(x, name, 1)
    if a.size and (a.min() < 0 or a.max() >= upper):
        raise _fail(name, f"indices must lie in [0, {upper}), got [{a.min()}, {a.max()}]")
    if np.unique(a).size != a.size:
        raise _fail(name, "indices must be unique")
    return a


def as_anchors(anchors, num_faces: int, name: str = "anchors") -> list[np.ndarray]:
    """List of k non-empty, disjoint face index arrays."""
    if isinstance(anchors, np.ndarray) and anchors.dtype != object:
        anchors = list(anchors) if anchors.ndim == 2 else [anchors]
    try:
        items = list(anchors)
    except TypeError:
        raise _fail(name, "expected a list of k integer arrays of face indices") from None
    if not items:
        raise _fail(name, "expected at least one anchor")
    out = []
    owner = np.full(num_faces, -1, dtype=np.int64)
    for a, item in enumerate(items):
        idx = as_index_set(np.atleast_1d(np.asarray(item)), num_faces, f"{name}[{a}]")
        if idx.size == 0:
            raise _fail(f"{name}[{a}]", "anchor has no faces")
        clash = owner[idx] >= 0
        if clash.any():
            other = int(owner[idx[clash][0]])
            raise _fail(name, f"anchors {other} and {a} overlap (face {int(idx[clash][0])})")
        owner[idx] = a
        out.append(idx)
    return out


def as_stiffness(x, size: int, name: str, solved: bool = False) -> np.ndarray:
    """(size,) finite float64 > 0; with solved (a field a solver factors), max/min <= 1e12."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(name, f"expected a float array of shape ({size},)") from None
    if a.shape != (size,):
        raise _fail(name, f"expected shape ({size},), got {a.shape}")
    if not np.isfinite(a).all():
        raise _fail(name, "contains NaN or infinity")
    if (a <= 0).any():
        raise _fail(name, f"stiffness must be > 0 (min is {a.min()})")
    if solved:
        check_stiffness_ratio(a, name)
    return np.ascontiguousarray(a)


# Levi-Civita symbol: det(a) = eps_ijk a_0i a_1j a_2k.
_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0


def _det3(a: np.ndarray) -> np.ndarray:
    """Determinants of (k,3,3) matrices as triple products. Not np.linalg.det: deform() is
    called per live update, and any LAPACK call makes the OpenBLAS bundled with PyPI numpy keep
    a thread spinning on a core for as long as calls keep coming, taking it from the solver.
    One einsum: 2.5x faster than cross products built by fancy indexing (6 vs 16 us for k = 6)."""
    # Rows 2, 1, 0 in that order: like a0 . (a1 x a2), a tiny row scales the products before
    # a huge one can overflow them.
    return np.einsum("ijk,nk,nj,ni->n", _EPS, a[:, 2], a[:, 1], a[:, 0], optimize=False)


_AFFINE_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def as_transforms(x, count: int, name: str = "transforms") -> np.ndarray:
    """(count,3,3) or (count,4,4) finite, linear part with det > 0, affine bottom row."""
    try:
        t = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(name, f"expected shape ({count},3,3) or ({count},4,4)") from None
    if t.ndim != 3 or t.shape[1:] not in ((3, 3), (4, 4)) or t.shape[0] != count:
        raise _fail(name, f"expected shape ({count},3,3) or ({count},4,4), got {t.shape}")
    if not np.isfinite(t).all():
        raise _fail(name, "contains NaN or infinity")
    det = _det3(t[:, :3, :3])
    if not (det > 0).all():  # NaN too: a determinant that overflowed
        a = int(np.flatnonzero(~(det > 0))[0])
        raise _fail(name, f"transform {a} has det {det[a]:.3g}; rotation and scale need det > 0")
    # abs/max rather than np.allclose: the same test (t is finite here) in 2 us instead of 13,
    # on a path that runs once per live update
    if t.shape[1] == 4 and np.abs(t[:, 3, :] - _AFFINE_ROW).max() > 1e-12:
        raise _fail(name, "4x4 transforms must be affine (bottom row 0 0 0 1)")
    return np.ascontiguousarray(t)


def as_rotation_vectors(x, count: int, name: str = "rotation_vectors") -> np.ndarray:
    """(count,3) finite float64 axis * angle vectors (radians, any length), C-contiguous."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(name, f"expected a float array of shape ({count},3)") from None
    if a.shape != (count, 3):
        raise _fail(name, f"expected shape ({count},3), one vector per anchor, got {a.shape}")
    if not np.isfinite(a).all():
        raise _fail(name, "contains NaN or infinity")
    return np.ascontiguousarray(a)
