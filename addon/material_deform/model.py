"""What the session and the methods share: the error type, the gathered inputs, the cache entry
and the settings accessor. Imports no method and no session, so both can import it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import bridge, core
from .errors import BindError

__all__ = ["BindError", "Entry", "Inputs", "load_core", "settings"]


def settings(obj):
    return obj.material_deform


def load_core():
    """The matdeform module, or BindError with the reason it cannot be loaded."""
    try:
        return core.load()
    except ImportError as exc:
        raise BindError(str(exc)) from exc


@dataclass
class Inputs:
    """Everything a method needs to build its solver, read from Blender and validated.

    Triangles index the full vertex set; ``used``/``tris_c`` are the compacted mesh the solver
    sees (vertices in no triangle dropped). ``extra`` holds what a method gathered itself."""

    arrays: bridge.MeshArrays
    anchor_faces: list  # per anchor: (f_a,) triangle indices
    modes: list  # per anchor: its mode ("POSITION", "ROTATION", ...)
    names: list  # per anchor: its vertex group
    psi: np.ndarray | None  # (P,) stored shear stiffness per polygon; None = never computed
    phi: np.ndarray | None  # (e,) stored bending stiffness per mesh edge; None = from psi
    used: np.ndarray | None = None  # vertices kept after dropping loose ones
    tris_c: np.ndarray | None = None
    region: np.ndarray | None = None  # triangles solved for; None = all (set by a method)
    fp: tuple = ()
    extra: dict = field(default_factory=dict)

    def compact_index(self, vertices) -> np.ndarray:
        """Full-mesh vertex indices -> indices into the compacted mesh."""
        v = np.asarray(vertices, dtype=np.int64)
        if self.used is None:
            return v
        remap = np.full(len(self.arrays.rest), -1, dtype=np.int64)
        remap[self.used] = np.arange(len(self.used))
        return remap[v]

    @property
    def dual(self) -> np.ndarray:
        """(E,2) dual edges of the triangles (computed on first use: only builds need it)."""
        if "dual" not in self.extra:
            md = load_core()
            self.extra["dual"] = np.asarray(md.dual_edges(self.arrays.tris), np.int64).reshape(
                -1, 2
            )
        return self.extra["dual"]

    @property
    def shear(self) -> np.ndarray | None:
        """(m,) shear stiffness per triangle; None = uniform."""
        return None if self.psi is None else self.psi[self.arrays.tri_poly]

    @property
    def bend(self) -> np.ndarray | None:
        """(E,) bending stiffness per dual edge; None = derived from shear by the solver."""
        if self.psi is None or self.phi is None:
            return None
        from .stiffness_map import dual_edge_bend

        a = self.arrays
        return dual_edge_bend(a.tris, self.dual, a.tri_poly, self.psi, a.edge_verts, self.phi)

    @property
    def verts_c(self) -> np.ndarray:
        """(n_c,3) float64 rest positions of the compacted mesh."""
        rest = self.arrays.rest
        return rest if self.used is None else rest[self.used]


@dataclass
class Entry:
    """A built solver and what it was built from (kept in the session's cache, never saved)."""

    method: str
    solver: object
    fp: tuple
    counts: tuple
    rest: np.ndarray  # (n,3) float64, full vertex set
    rest_f32: np.ndarray  # (n,3) float32, the Basis as stored: compared on every update
    used: np.ndarray | None
    n_anchors: int
    last_key: bytes | None = None
    key_pointer: int = 0  # the output shape key this entry writes (renames are followed)
    state: dict = field(default_factory=dict)  # the method's per-object state (warm starts)
    extra: dict = field(default_factory=dict)  # the session's caches (pose inverses)
    warnings: list = field(default_factory=list)  # what Bind reports beside its success
