"""Seeded fuzz of every public function of matdeform (issue 11, "keep it found").

Case i of seed s is a function of (s, i) alone: a random mesh (soup, partial grid, tube or fan;
randomly scaled, moved and relabelled), random arguments (anchors, stiffness, pinned vertices,
regions, transforms, poses, ...) and, for about a quarter of the cases, one hostile mutation
(NaN, negative or out-of-range index, wrong shape or dtype, extreme scale, overlapping anchors,
det <= 0, ...). A case passes when the call either returns finite numbers or raises ValueError,
and, for meshes that are not soups, when a random relabelling of vertices, faces and corners
gives the same result, permuted back (positions to 1e-9 of the bounding-box diagonal).

Worker protocol (tests/python/test_fuzz.py drives it in subprocesses, so a crash is counted):
    python tests/python/fuzz.py SEED START COUNT
prints "start i function" before case i and one JSON line {"i", "function", "status", "detail"}
after it.
Statuses: ok, rejected (ValueError), and the failures error, nan, permutation.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile

import numpy as np
from conftest import rotation
from permutation import Relabelling, grid

import matdeform as md
from matdeform import shapes

FUNCTIONS = [
    "MaterialDeformer",
    "harmonic_weights",
    "dual_edges",
    "face_components",
    "faces_inside",
    "boundary_and_nonmanifold_edges",
    "bend_from_shear",
    "bend_from_vertex",
    "shear_from_vertex",
    "deformation_gradients",
    "learn_distortions",
    "learn_stiffness",
    "rotation_spread",
    "smooth_distortions",
    "stiffness_from_distortion",
    "transform_log",
    "transform_exp",
    "polar_decompose",
    "blend_transforms",
    "obj_round_trip",
    "set_num_threads",
    "PyramidDeformer",
]
# Checked for relabelling on soups too: they only count and sort.
TOPOLOGY = {"dual_edges", "face_components", "faces_inside", "boundary_and_nonmanifold_edges"}
# Solvers get more cases: they have the most arguments.
WEIGHTS = np.array([6, 2] + [1] * (len(FUNCTIONS) - 2), dtype=float)
WEIGHTS[FUNCTIONS.index("PyramidDeformer")] = 4


class Failure(Exception):
    def __init__(self, status, detail):
        super().__init__(detail)
        self.status, self.detail = status, detail


# ---- random inputs -------------------------------------------------------------------------


def random_rotation(rng, max_angle=np.pi):
    a = rng.normal(size=3)
    return rotation(a / np.linalg.norm(a), rng.uniform(0, max_angle))


def random_mesh(rng):
    """(kind, vertices, faces): not relabelled yet."""
    kind = rng.choice(["soup", "grid", "tube", "fan"], p=[0.3, 0.35, 0.2, 0.15])
    if kind == "soup":
        n = int(rng.integers(3, 25))
        v = rng.normal(size=(n, 3))
        if rng.random() < 0.2:  # coincident vertices
            v[rng.integers(0, n, n // 3)] = v[0]
        f = rng.integers(0, n, (int(rng.integers(1, 30)), 3))
        if rng.random() < 0.7:  # mostly proper triangles
            f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
            if len(f) == 0:
                f = np.array([[0, 1, 2]])
    elif kind == "grid":
        v, f = grid(int(rng.integers(1, 8)), int(rng.integers(1, 8)))
        v[:, 2] = rng.normal(scale=0.2, size=len(v))
        keep = rng.random(len(f)) < rng.uniform(0.5, 1.0)
        keep[rng.integers(0, len(f))] = True
        f = f[keep]
    elif kind == "tube":
        v, f = shapes.tube(
            length=rng.uniform(1, 6),
            radius=rng.uniform(0.2, 1.5),
            n_around=int(rng.integers(3, 9)),
            n_along=int(rng.integers(1, 7)),
        )
    else:
        c = int(rng.integers(1, 8))
        step = min(1.5, 5.2 / c)
        a = step * np.arange(c + 1)
        v = np.vstack([[0, 0, 0.3], np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)])
        f = np.stack([np.zeros(c, int), np.arange(1, c + 1), np.arange(2, c + 2)], 1)
    scale = 10.0 ** rng.uniform(-3, 3)
    v = (v @ random_rotation(rng).T) * scale + rng.normal(scale=scale, size=3)
    return str(kind), v, np.asarray(f, dtype=np.int64)


def disjoint_face_sets(rng, m, k, max_size=4):
    order = rng.permutation(m)
    sizes = rng.integers(1, max_size + 1, k)
    out, at = [], 0
    for s in sizes:
        if at >= m:
            break
        out.append(order[at : at + s])
        at += s
    return out


def random_transforms(rng, k, diag, affine=True):
    T = np.tile(np.eye(4), (k, 1, 1))
    for a in range(k):
        S = np.eye(3) * 10.0 ** rng.uniform(-0.5, 0.5)
        if rng.random() < 0.3:  # non-uniform stretch
            S = np.diag(10.0 ** rng.uniform(-0.5, 0.5, 3))
        T[a, :3, :3] = S @ random_rotation(rng, 3.5)
        T[a, :3, 3] = rng.normal(scale=diag, size=3)
    return T if affine else T[:, :3, :3].copy()


def random_stiffness(rng, size):
    lo = 10.0 ** -rng.uniform(0, 3)
    return rng.uniform(lo, 1.0, size)


# ---- hostile mutations ---------------------------------------------------------------------

MUTATIONS = [
    "nan_vertex",
    "negative_index",
    "big_index",
    "float_faces",
    "flat_faces",
    "tiny_mesh",
    "huge_mesh",
    "argument",
]


def mutate_mesh(rng, what, v, f):
    v, f = v.copy(), f.copy()
    if what == "nan_vertex":
        v[rng.integers(0, len(v)), rng.integers(0, 3)] = rng.choice([np.nan, np.inf, -np.inf])
    elif what == "negative_index":
        f[rng.integers(0, len(f)), rng.integers(0, 3)] = -int(rng.integers(1, 2**31 - 1))
    elif what == "big_index":
        f[rng.integers(0, len(f)), rng.integers(0, 3)] = int(rng.integers(len(v), 2**31 - 1))
    elif what == "float_faces":
        f = f.astype(float) + 0.5
    elif what == "flat_faces":
        f = f[:, :2]
    elif what == "tiny_mesh":
        v = v * 1e-60
    elif what == "huge_mesh":
        v = v * 1e60
    return v, f


# ---- checks --------------------------------------------------------------------------------


def finite(name, *arrays):
    for a in arrays:
        a = np.asarray(a)
        if a.dtype.kind in "fc" and not np.isfinite(a).all():
            raise Failure("nan", f"{name}: non-finite output")


def close(name, a, b, tol):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        raise Failure("permutation", f"{name}: shape {a.shape} vs {b.shape} after relabelling")
    err = float(np.abs(a - b).max()) if a.size else 0.0
    if not err <= tol:
        raise Failure("permutation", f"{name}: differs by {err:.3g} (tol {tol:.3g})")


def same_partition(name, a, b):
    """Labels a (original order) and b (permuted back) define the same partition."""
    first = {}
    ca = np.array([first.setdefault(x, len(first)) for x in a])
    first = {}
    cb = np.array([first.setdefault(x, len(first)) for x in b])
    if not np.array_equal(ca, cb):
        raise Failure("permutation", f"{name}: components change under relabelling")


def edge_set(edges, vertex_map=None):
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if vertex_map is not None:
        e = vertex_map[e]
    return {tuple(sorted(x)) for x in e.tolist()}


# ---- one case ------------------------------------------------------------------------------


def case_function(seed: int, i: int):
    """(rng, function name) of case i: the rng continues into the case's inputs."""
    rng = np.random.default_rng([seed, i])
    return rng, FUNCTIONS[rng.choice(len(FUNCTIONS), p=WEIGHTS / WEIGHTS.sum())]


def run_case(seed: int, i: int) -> dict:
    rng, fn = case_function(seed, i)
    kind, v, f = random_mesh(rng)
    mutation = rng.choice(MUTATIONS) if rng.random() < 0.25 else None
    if mutation is not None and mutation != "argument":
        v, f = mutate_mesh(rng, mutation, v, f)
    # Relabelling checks: every function on unmutated meshes; the solvers not on soups, whose
    # near-degenerate faces make the result depend on round-off (and folded face pairs make
    # the hinge vertices of bend_from_vertex order-dependent, as documented).
    perm = mutation is None and kind != "soup"
    topology = mutation is None
    try:
        CASES[fn](rng, v, f, mutation == "argument", perm if fn not in TOPOLOGY else topology, kind)
    except ValueError as e:
        return {"function": fn, "status": "rejected", "detail": str(e)[:200]}
    except Failure as e:
        return {"function": fn, "status": e.status, "detail": e.detail}
    except Exception as e:  # noqa: BLE001 - any other exception is a finding
        return {"function": fn, "status": "error", "detail": f"{type(e).__name__}: {e}"[:300]}
    return {"function": fn, "status": "ok", "detail": kind}


def relabel_for(rng, v, f):
    return Relabelling(v, f, np.random.default_rng(rng.integers(2**32)))


def case_deformer(rng, v, f, hostile, perm, kind):
    n, m = len(v), len(f)
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if n else 1.0
    k = int(rng.integers(1, 4))
    anchors = disjoint_face_sets(rng, max(m, 1), k)
    kw = {}
    if rng.random() < 0.7:
        kw["shear"] = random_stiffness(rng, m)
    e = len(md.dual_edges(f)) if f.ndim == 2 and f.shape[-1] == 3 and f.dtype.kind == "i" else 0
    b = str(rng.choice(["none", "edge", "vertex", "edge3", "vertex3"]))
    if b.startswith("vertex") and n == e:
        b = b.replace("vertex", "edge")  # (E,) wins when E == n (documented)
    if b != "none":
        rows = e if b.startswith("edge") else n
        kw["bend"] = random_stiffness(rng, (rows, 3) if b.endswith("3") else rows)
    if rng.random() < 0.3:
        kw["pinned"] = rng.permutation(n)[: int(rng.integers(0, 4))]
    if rng.random() < 0.3:
        extra = rng.permutation(m)[: int(rng.integers(1, m + 1))]
        kw["region"] = np.unique(np.concatenate([extra, *anchors]))
    if rng.random() < 0.2:
        kw["axes"] = random_rotation(rng)
    affine = rng.random() < 0.6
    T = random_transforms(rng, len(anchors), diag, affine)
    pp = None
    if kw.get("pinned") is not None and rng.random() < 0.5:
        pp = v[kw["pinned"]] + rng.normal(scale=0.1 * diag, size=(len(kw["pinned"]), 3))
    if hostile:
        what = rng.choice(
            ["overlap", "empty", "det", "nan_T", "count", "shear0", "ratio", "pp_nan", "roi"]
        )
        if what == "overlap" and m:
            anchors = anchors + [anchors[0][:1]]
            T = random_transforms(rng, len(anchors), diag, affine)
        elif what == "empty":
            anchors = anchors + [np.zeros(0, int)]
        elif what == "det":
            T[0, :3, :3] = T[0, :3, :3] @ np.diag([1, 1, -1])
        elif what == "nan_T":
            T[0, 0, 0] = np.nan
        elif what == "count":
            T = T[:-1] if len(T) > 1 else np.concatenate([T, T])
        elif what == "shear0":
            kw["shear"] = np.zeros(m)
        elif what == "ratio":
            kw["shear"] = np.ones(m)
            kw["shear"][0] = 1e-15
        elif what == "pp_nan":
            kw["pinned"] = np.array([0])
            pp = np.full((1, 3), np.nan)
        elif what == "roi":
            kw["region"] = np.setdiff1d(np.arange(m), anchors[0])
    d = md.MaterialDeformer(v, f, anchors, **kw)
    X = d.deform(T, pp)
    finite("deform", X, d.weights, d.face_transforms, d.axis_weights(2))
    if X.shape != (n, 3):
        raise Failure("error", f"deform: shape {X.shape}")
    if not perm:
        return
    r = relabel_for(rng, v, f)
    kw2 = dict(kw)
    if "shear" in kw:
        kw2["shear"] = r.per_face(kw["shear"])
    if "bend" in kw:
        kw2["bend"] = (
            r.per_dual_edge(kw["bend"]) if b.startswith("edge") else r.per_vertex(kw["bend"])
        )
    if "pinned" in kw:
        kw2["pinned"] = r.vertex_ids(kw["pinned"])
    if "region" in kw:
        kw2["region"] = r.face_ids(kw["region"])
    d2 = md.MaterialDeformer(r.vertices, r.faces, r.anchors(anchors), **kw2)
    close("deform", r.to_original(d2.deform(T, pp)), X, 1e-9 * max(diag, 1e-300))
    close("weights", r.faces_to_original(d2.weights), d.weights, 1e-9)


def case_harmonic_weights(rng, v, f, hostile, perm, kind):
    m = len(f)
    anchors = disjoint_face_sets(rng, max(m, 1), int(rng.integers(1, 4)))
    e = len(md.dual_edges(f))
    bend = random_stiffness(rng, e) if rng.random() < 0.7 else None
    if hostile:
        bend = -np.ones(e) if rng.random() < 0.5 else np.full(e + 1, 1.0)
    W = md.harmonic_weights(f, anchors, bend)
    finite("harmonic_weights", W)
    if perm:
        r = relabel_for(rng, v, f)
        b2 = None if bend is None else r.per_dual_edge(bend)
        W2 = md.harmonic_weights(r.faces, r.anchors(anchors), b2)
        close("harmonic_weights", r.faces_to_original(W2), W, 1e-9)


def case_dual_edges(rng, v, f, hostile, perm, kind):
    pairs, shared = md.dual_edges(f, return_shared=True)
    if pairs.size and (pairs.min() < 0 or pairs.max() >= len(f)):
        raise Failure("error", "dual_edges: pair out of range")
    if perm:
        r = relabel_for(rng, v, f)
        p2 = md.dual_edges(r.faces)
        if edge_set(pairs, r.face) != edge_set(p2):
            raise Failure("permutation", "dual_edges: pairs change under relabelling")


def case_face_components(rng, v, f, hostile, perm, kind):
    labels, count = md.face_components(f)
    if len(labels) and (labels.min() < 0 or labels.max() >= count):
        raise Failure("error", "face_components: label out of range")
    if perm:
        r = relabel_for(rng, v, f)
        labels2, count2 = md.face_components(r.faces)
        if count2 != count:
            raise Failure("permutation", "face_components: count changes")
        same_partition("face_components", labels, r.faces_to_original(labels2))


def case_faces_inside(rng, v, f, hostile, perm, kind):
    ids = rng.permutation(max(len(v), 1))[: int(rng.integers(0, len(v) + 1))]
    if hostile:
        ids = np.append(ids, -int(rng.integers(1, 100)))
    inside = md.faces_inside(f, ids)
    if perm:
        r = relabel_for(rng, v, f)
        inside2 = md.faces_inside(r.faces, r.vertex_ids(ids))
        if set(r.face[inside].tolist()) != set(inside2.tolist()):
            raise Failure("permutation", "faces_inside changes under relabelling")


def case_boundary(rng, v, f, hostile, perm, kind):
    b, nm = md.boundary_and_nonmanifold_edges(f)
    if perm:
        r = relabel_for(rng, v, f)
        b2, nm2 = md.boundary_and_nonmanifold_edges(r.faces)
        if edge_set(b, r.vertex) != edge_set(b2) or edge_set(nm, r.vertex) != edge_set(nm2):
            raise Failure("permutation", "boundary edges change under relabelling")


def case_bend_from_shear(rng, v, f, hostile, perm, kind):
    shear = random_stiffness(rng, len(f))
    if hostile:
        shear = np.append(shear, 1.0)
    phi = md.bend_from_shear(f, shear)
    finite("bend_from_shear", phi)
    if perm:
        r = relabel_for(rng, v, f)
        close(
            "bend_from_shear",
            r.dual_edges_to_original(md.bend_from_shear(r.faces, r.per_face(shear))),
            phi,
            1e-12,
        )


def case_bend_from_vertex(rng, v, f, hostile, perm, kind):
    s = random_stiffness(rng, len(v))
    if hostile:
        s = s[:-1]
    phi = md.bend_from_vertex(f, s)
    finite("bend_from_vertex", phi)
    if perm:
        r = relabel_for(rng, v, f)
        phi2 = md.bend_from_vertex(r.faces, r.per_vertex(s))
        close("bend_from_vertex", r.dual_edges_to_original(phi2), phi, 1e-12)


def case_shear_from_vertex(rng, v, f, hostile, perm, kind):
    s = random_stiffness(rng, len(v))
    if hostile:
        s = np.where(rng.random(len(s)) < 0.5, np.nan, s)
    psi = md.shear_from_vertex(f, s)
    finite("shear_from_vertex", psi)
    if perm:
        r = relabel_for(rng, v, f)
        psi2 = md.shear_from_vertex(r.faces, r.per_vertex(s))
        close("shear_from_vertex", r.faces_to_original(psi2), psi, 1e-12)


def random_poses(rng, v, count):
    out = []
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if len(v) else 1.0
    for _ in range(count):
        p = v @ random_rotation(rng).T + rng.normal(scale=diag, size=3)
        out.append(p + rng.normal(scale=0.05 * diag, size=v.shape))
    return out


def case_deformation_gradients(rng, v, f, hostile, perm, kind):
    (w,) = random_poses(rng, v, 1)
    if hostile:
        w = w[:-1]
    T = md.deformation_gradients(v, w, f)
    finite("deformation_gradients", T)
    if perm:
        r = relabel_for(rng, v, f)
        T2 = md.deformation_gradients(r.vertices, r.per_vertex(w), r.faces)
        close("deformation_gradients", r.faces_to_original(T2), T, 1e-8 * max(1, np.abs(T).max()))


def case_learn(rng, v, f, hostile, perm, kind, which):
    poses = random_poses(rng, v, int(rng.integers(1, 4)))
    if hostile:
        poses[0] = poses[0][:, :2]
    aniso = bool(rng.random() < 0.4)
    if which == "distortions":
        frame = str(rng.choice(["rest", "world"]))
        out = md.learn_distortions(v, f, poses, anisotropic=aniso, frame=frame)
    else:
        region = int(rng.integers(0, 3)) if not aniso else 0
        kw = dict(anisotropic=aniso, smoothing=int(rng.integers(0, 3)), region=region)
        out = md.learn_stiffness(v, f, poses, **kw)
    finite(which, *out)
    if not perm:
        return
    r = relabel_for(rng, v, f)
    p2 = [r.per_vertex(p) for p in poses]
    if which == "distortions":
        b = md.learn_distortions(r.vertices, r.faces, p2, anisotropic=aniso, frame=frame)
        close("learn_distortions bend", r.dual_edges_to_original(b[0]), out[0], 1e-8)
        close("learn_distortions shear", r.faces_to_original(b[1]), out[1], 1e-8)
    else:
        b = md.learn_stiffness(r.vertices, r.faces, p2, **kw)
        # The map divides by a percentile of the distortions: a looser tolerance.
        close("learn_stiffness bend", r.dual_edges_to_original(b[0]), out[0], 1e-6)
        close("learn_stiffness shear", r.faces_to_original(b[1]), out[1], 1e-6)


def case_learn_distortions(rng, v, f, hostile, perm, kind):
    case_learn(rng, v, f, hostile, perm, kind, "distortions")


def case_learn_stiffness(rng, v, f, hostile, perm, kind):
    case_learn(rng, v, f, hostile, perm, kind, "stiffness")


def case_rotation_spread(rng, v, f, hostile, perm, kind):
    poses = random_poses(rng, v, int(rng.integers(1, 4)))
    passes = int(rng.integers(0, 4))
    if hostile:
        passes = -1
    s = md.rotation_spread(v, f, poses, passes)
    finite("rotation_spread", s)
    if perm:
        r = relabel_for(rng, v, f)
        s2 = md.rotation_spread(r.vertices, r.faces, [r.per_vertex(p) for p in poses], passes)
        close("rotation_spread", r.faces_to_original(s2), s, 1e-8)


def case_smooth(rng, v, f, hostile, perm, kind):
    e = len(md.dual_edges(f))
    bend = rng.uniform(0, 1, (e, int(rng.integers(1, 4))))
    shear = rng.uniform(0, 1, len(f))
    if hostile:
        bend[..., 0] = np.nan
    passes = int(rng.integers(0, 4))
    b, s = md.smooth_distortions(f, bend, shear, passes)
    finite("smooth_distortions", b, s)
    if perm:
        r = relabel_for(rng, v, f)
        b2, s2 = md.smooth_distortions(r.faces, r.per_dual_edge(bend), r.per_face(shear), passes)
        close("smooth_distortions bend", r.dual_edges_to_original(b2), b, 1e-12)
        close("smooth_distortions shear", r.faces_to_original(s2), s, 1e-12)


def case_stiffness_from_distortion(rng, v, f, hostile, perm, kind):
    d = rng.exponential(10.0 ** rng.uniform(-14, 2), (int(rng.integers(0, 50)), 2))
    eps = float(10.0 ** -rng.uniform(0, 4))
    clamp = float(rng.uniform(0, 10))
    sharp = float(rng.uniform(0, 10)) if rng.random() < 0.5 else 0.0
    if hostile:
        eps, clamp, sharp = rng.choice(
            [(-1.0, clamp, sharp), (eps, 150.0, sharp), (eps, clamp, np.nan)]
        )
    s = md.stiffness_from_distortion(d, eps=eps, clamp_percent=clamp, sharpness=sharp)
    finite("stiffness_from_distortion", s)
    if s.size and (s.min() < eps - 1e-12 or s.max() > 1 + 1e-12):
        raise Failure("error", "stiffness_from_distortion: outside [eps, 1]")


def random_matrix(rng):
    kind = rng.choice(["rotation", "similarity", "general", "huge", "singular", "negative", "4x4"])
    if kind == "rotation":
        return random_rotation(rng)
    if kind == "similarity":
        return 10.0 ** rng.uniform(-3, 3) * random_rotation(rng)
    if kind == "general":
        return rng.normal(size=(3, 3))
    if kind == "huge":
        return np.diag(10.0 ** rng.uniform(-320, 320, 3)) @ random_rotation(rng)
    if kind == "singular":
        return np.outer(rng.normal(size=3), rng.normal(size=3))
    if kind == "negative":
        return random_rotation(rng) @ np.diag([1, 1, -1])
    return np.eye(4)


def case_transform_log(rng, v, f, hostile, perm, kind):
    L, w = md.transform_log(random_matrix(rng))
    finite("transform_log", L, w)


def case_transform_exp(rng, v, f, hostile, perm, kind):
    L = rng.normal(scale=10.0 ** rng.uniform(-2, 3.2), size=(3, 3))
    if rng.random() < 0.5:
        L = (L + L.T) / 2
    M = md.transform_exp(L, rng.normal(scale=10.0 ** rng.uniform(-3, 2), size=3))
    finite("transform_exp", M)


def case_polar(rng, v, f, hostile, perm, kind):
    S, R = md.polar_decompose(random_matrix(rng))
    finite("polar_decompose", S, R)


def case_blend(rng, v, f, hostile, perm, kind):
    k = int(rng.integers(1, 4))
    T = random_transforms(rng, k, 1.0, affine=False)
    if rng.random() < 0.3:  # hostile matrices among them
        T[0] = random_matrix(rng)[:3, :3]
    W = rng.normal(scale=10.0 ** rng.uniform(-1, 3), size=(int(rng.integers(0, 20)), k))
    out = md.blend_transforms(T, W)
    finite("blend_transforms", out)


def case_obj(rng, v, f, hostile, perm, kind):
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "m.obj")
        md.write_obj(path, v, f)
        v2, f2 = md.read_obj(path)
    finite("read_obj", v2)


def case_threads(rng, v, f, hostile, perm, kind):
    before = md.num_threads()
    try:
        md.set_num_threads(rng.choice([-1, 0, 1, 2, 3]).item())
        if md.num_threads() < 1:
            raise Failure("error", "num_threads below 1")
    finally:
        md.set_num_threads(before)


def case_pyramid(rng, v, f, hostile, perm, kind):
    """Controls: a few random vertices, or a random ball of them; targets: their rest places
    moved by a random similarity and noise. Every numeric argument of deform() is drawn, and a
    hostile case breaks one of them (or the positions' scale)."""
    n = len(v)
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if n else 1.0
    if rng.random() < 0.5:
        ctrl = rng.permutation(n)[: int(rng.integers(1, min(n, 6) + 1))]
    else:
        centre = v[rng.integers(0, n)] if n else np.zeros(3)
        near = np.argsort(np.linalg.norm(v - centre, axis=1))
        ctrl = np.sort(near[: int(rng.integers(1, max(2, n // 3) + 1))])
    R = random_rotation(rng) * 10.0 ** rng.uniform(-0.3, 0.3)
    target = v[ctrl] @ R.T + rng.normal(scale=diag, size=3)
    target = target + rng.normal(scale=rng.choice([0.0, 0.05, 0.3]) * diag, size=target.shape)
    kw = {
        "iterations": [None, 0, 1, 5, int(rng.integers(0, 200))][int(rng.integers(0, 5))],
        "tol": float(10.0 ** rng.uniform(-10, -2)),
        "scale_weight": float(rng.choice([0.0, 0.003, 10.0 ** rng.uniform(-4, 2)])),
    }
    if rng.random() < 0.3:
        kw["initial"] = v * 10.0 ** rng.uniform(-1, 1) + rng.normal(scale=0.1 * diag, size=v.shape)
    if hostile:
        what = rng.choice(["iterations", "tol", "scale_weight", "initial", "target", "control"])
        if what == "iterations":
            kw["iterations"] = rng.choice([-1, 2**31, 2**40, 1.5, "x"]).item()
        elif what == "tol":
            kw["tol"] = rng.choice([-1e-6, np.nan, np.inf, "x"]).item()
        elif what == "scale_weight":
            kw["scale_weight"] = rng.choice([-1.0, np.nan, 1e300, "x"]).item()
        elif what == "initial":
            kw["initial"] = rng.choice([1e200, np.nan, -1]).item() * (v if n else np.zeros((0, 3)))
        elif what == "target":
            target = target * rng.choice([1e200, np.inf, np.nan]).item()
        else:
            ctrl = np.concatenate([ctrl, ctrl[:1]])
            target = np.vstack([target, target[:1]])
    d = md.PyramidDeformer(v, f, ctrl)
    X = d.deform(target, **kw)
    finite("PyramidDeformer.deform", X, d.last_energy)
    if X.shape != (n, 3):
        raise Failure("error", f"deform: shape {X.shape}")
    # Relabelling: when converged from the start deform() builds, and when the controls pin the
    # pose (one or two controls, or controls on a line, leave the turn about them free: a family
    # of minima, docs/pyramid.md). Converged means within ~tol^2 of the minimum.
    p = v[ctrl] - v[ctrl].mean(0)
    pinned = len(ctrl) >= 3 and np.linalg.svd(p, compute_uv=False)[1] > 1e-6 * diag
    if not perm or not pinned or not d.last_converged or "initial" in kw:
        return
    r = relabel_for(rng, v, f)
    d2 = md.PyramidDeformer(r.vertices, r.faces, r.vertex_ids(ctrl))
    X2 = d2.deform(target, **kw)
    if d2.last_converged:
        tol = max(1e-9, 10 * kw["tol"] ** 2) * max(diag, 1e-300)
        close("PyramidDeformer.deform", r.to_original(X2), X, tol)


CASES = {
    "MaterialDeformer": case_deformer,
    "harmonic_weights": case_harmonic_weights,
    "dual_edges": case_dual_edges,
    "face_components": case_face_components,
    "faces_inside": case_faces_inside,
    "boundary_and_nonmanifold_edges": case_boundary,
    "bend_from_shear": case_bend_from_shear,
    "bend_from_vertex": case_bend_from_vertex,
    "shear_from_vertex": case_shear_from_vertex,
    "deformation_gradients": case_deformation_gradients,
    "learn_distortions": case_learn_distortions,
    "learn_stiffness": case_learn_stiffness,
    "rotation_spread": case_rotation_spread,
    "smooth_distortions": case_smooth,
    "stiffness_from_distortion": case_stiffness_from_distortion,
    "transform_log": case_transform_log,
    "transform_exp": case_transform_exp,
    "polar_decompose": case_polar,
    "blend_transforms": case_blend,
    "obj_round_trip": case_obj,
    "set_num_threads": case_threads,
    "PyramidDeformer": case_pyramid,
}
assert set(CASES) == set(FUNCTIONS)


def main(argv):
    seed, start, count = (int(x) for x in argv[1:4])
    crash_at = int(os.environ.get("MD_FUZZ_CRASH_AT", "-1"))  # tests the harness
    for i in range(start, start + count):
        print(f"start {i} {case_function(seed, i)[1]}", flush=True)
        if i == crash_at:
            os.abort()
        print(json.dumps({"i": i, **run_case(seed, i)}), flush=True)


if __name__ == "__main__":
    main(sys.argv)
