"""Where the edge-based iteration starts: iterations to converge and the final error.

Starts compared (each solve runs to tol 1e-5 of the diagonal, at most 2000 iterations):

- rest, plain: the rest mesh with the anchors already placed (the first step takes the rest
  edge frames as they are, nothing carried);
- rest, fitted (``solve(P)``, the default without vectors): the first step carries the
  anchors' fitted rotations (at most half a turn each);
- previous: warm-started from the previous pose's converged result (the first pose from rest);
  what a live session does, and what a farm frame cannot do;
- material-aware: ``MaterialDeformer`` on the same anchors (uniform stiffness, the anchor
  vertices pinned) for the unwrapped rotations, passed as ``initial``;
- rest, vectors (``solve(P, rotation_vectors=...)``): the first step carries the given
  unwrapped vectors.

Cases: the cat (data/cat-poses, docs/quality.md's six anchors, the anchor vertices pinned at
their pose positions, poses in file order), error = RMS |x - pose| / diagonal; and the twist:
``md.shapes.tube`` (length 10, radius 0.3, 16 x 60), both caps anchored, the top cap turned about
the axis 0..720 degrees in 30-degree steps, error = the largest deviation of a ring's turn from
the linear closed form theta x / L, in degrees; frames solved in order (what "previous" uses).

    python bench/bench_edge_start.py [--stretch 0.3] [--radius 0.3] [--cat-only | --twist-only]

The twist runs at stretch 0.3 and radius 0.3 by default: a softer or thicker tube has no
twisted fixed point that far, nor has this one at stretch 1 past about 600 degrees (docs/edge.md,
"Twists past half a turn").
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import matdeform as md

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_quality import Bench, rms_error  # noqa: E402

TOL, CAP = 1e-5, 2000
STARTS = ("rest, plain", "rest, fitted", "previous", "material-aware", "rest, vectors")


def run_starts(d, mat, frames, error):
    """frames: list of (positions (k,3), transforms for mat, vectors (A,3)). Returns per start:
    (iterations per frame, error per frame, seconds per frame)."""
    out = {}
    rest = d_rest = None
    for name in STARTS:
        its, errs, secs, prev = [], [], [], None
        for i, (pos, mat_args, rv) in enumerate(frames):
            t0 = time.perf_counter()
            kw = {}
            if name == "rest, plain":
                if d_rest is None:
                    d_rest = rest_mesh(d)
                rest = d_rest.copy()
                rest[d.constrained] = pos
                kw["initial"] = rest
            elif name == "previous" and prev is not None:
                kw["initial"] = prev
            elif name == "material-aware":
                x0 = mat(*mat_args)
                x0[d.constrained] = pos
                kw["initial"] = x0
            elif name == "rest, vectors":
                kw["rotation_vectors"] = rv
            x = d.solve(pos, iterations=CAP, tol=TOL, **kw)
            secs.append(time.perf_counter() - t0)
            prev = x
            its.append(d.last_iterations)
            errs.append(error(i, x))
        out[name] = (its, errs, secs)
    return out


def rest_mesh(d):
    """The rest mesh, as the solver returns it for its own rest pose."""
    return d._rest.copy()


def table(title, out, unit):
    print(f"\n{title}")
    print(f"| start | iterations (median, max, total) | error ({unit}): mean, max |")
    print("|---|---:|---:|")
    for name, (its, errs, _secs) in out.items():
        capped = sum(i >= CAP for i in its)
        cap = f", {capped} at the cap" if capped else ""
        print(
            f"| {name} | {int(np.median(its))}, {max(its)}, {sum(its)}{cap} "
            f"| {np.mean(errs):.4g}, {max(errs):.4g} |"
        )


def cat(stretch):
    b = Bench(HERE.parent / "data" / "cat-poses")
    owner = np.full(len(b.rest), -1)
    for a, r in enumerate(b.region_verts):
        owner[r] = np.where(owner[r] < 0, a, owner[r])
    d = md.EdgeDeformer(b.rest, b.faces, b.pinned, stretch=stretch, anchors=owner[b.pinned])
    d._rest = b.rest
    mat = md.MaterialDeformer(b.rest, b.faces, b.region_faces, pinned=b.pinned)
    frames = []
    for p, rots in zip(b.poses, b.rotations, strict=True):
        vec = np.stack([md.transform_log(r)[1] for r in rots])
        pos = p[b.pinned]
        frames.append((pos, (rots, pos, vec), vec))

    def deform(rots, pos, vec):
        return mat.deform(rots, pinned_positions=pos, rotation_vectors=vec)

    out = run_starts(d, deform, frames, lambda i, x: rms_error(x, b.poses[i], b.diag))
    table(f"cat, {len(frames)} poses, stretch {stretch:g}", out, "RMS / diagonal")
    for name, (its, _e, _s) in out.items():
        print(f"  {name}: iterations per pose {its}")


def ring_turns(v, x, n_around, n_along):
    rings = slice(0, (n_along + 1) * n_around)
    rest = np.arctan2(v[rings, 2], v[rings, 1]).reshape(n_along + 1, n_around)
    now = np.arctan2(x[rings, 2], x[rings, 1]).reshape(n_along + 1, n_around)
    return np.unwrap(np.angle(np.exp(1j * (now - rest)).mean(axis=1)))


def twist(stretch, radius, n_around=16, n_along=60):
    v, f = md.shapes.tube(10.0, radius, n_around, n_along)
    lo, hi = md.shapes.end_faces(v, f, fraction=0.01)
    c_lo, c_hi = np.unique(f[lo]), np.unique(f[hi])
    con = np.concatenate([c_lo, c_hi])
    owner = np.repeat([0, 1], [len(c_lo), len(c_hi)])
    d = md.EdgeDeformer(v, f, con, stretch=stretch, anchors=owner)
    d._rest = v
    mat = md.MaterialDeformer(v, f, [lo, hi])
    thetas = np.radians(np.arange(0, 721, 30))
    frames = []
    for t in thetas:
        c, s = np.cos(t), np.sin(t)
        r = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        tr = np.stack([np.eye(4), np.eye(4)])
        tr[1, :3, :3] = r
        rv = np.array([[0.0, 0, 0], [t, 0, 0]])
        pos = v[con].copy()
        pos[owner == 1] = v[c_hi] @ r.T
        frames.append((pos, (tr, rv), rv))
    law = np.linspace(0, 1, n_along + 1)

    def deform(tr, rv):
        return mat.deform(tr, rotation_vectors=rv)

    def error(i, x):
        return float(
            np.degrees(np.abs(ring_turns(v, x, n_around, n_along) - thetas[i] * law).max())
        )

    out = run_starts(d, deform, frames, error)
    title = f"twist 0..720 by 30, tube radius {radius:g}, 16 x {n_along}, stretch {stretch:g}"
    table(title, out, "largest ring deviation, deg")
    for name, (its, errs, secs) in out.items():
        # a whole number of half turns off: the iteration took another branch (unwound)
        bad = [int(round(np.degrees(thetas[i]))) for i, e in enumerate(errs) if e > 90.0]
        print(f"  {name}: iterations {its}")
        ms = np.median(secs) * 1e3
        print(f"    unwound frames (a ring > 90 deg off): {bad}; median {ms:.1f} ms per frame")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--stretch", type=float, default=0.3)
    ap.add_argument("--radius", type=float, default=0.3)
    ap.add_argument("--cat-only", action="store_true")
    ap.add_argument("--twist-only", action="store_true")
    a = ap.parse_args()
    if not a.twist_only:
        cat(1e-4)
    if not a.cat_only:
        twist(a.stretch, a.radius)


if __name__ == "__main__":
    main()
