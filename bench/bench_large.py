"""Large meshes (~1M faces) through the numpy API: bind time and memory, first and later calls.

Each mesh runs in its own interpreter so peak RSS belongs to that mesh alone:

    python bench/bench_large.py [--faces 1000000] [--repeats 10] [--threads N]

Meshes: a closed tube of ~--faces triangles, and the cat subdivided 3 times (4^3 x 14410 =
922k faces; an organic mesh with the vertex order of a real model). Anchors: 6 regions of the
cat (feet, head, tail) or both tube ends; transforms are freely rotated, scaled float32
matrices, as an add-on sends them. Reported per mesh (seconds unless noted):

    bind        MaterialDeformer(...) (validation, weights, factorisation of the 4x4 system)
      weights   md.harmonic_weights alone (Eq. 1, part of bind)
    first 4x4   the first deform() with (k,4,4)
    4x4         median of the next --repeats calls (ms)
    4x4 exact   the same poses re-orthonormalised in float64 (exact similarities) (ms)
    first 3x3   the first deform() with (k,3,3): factors the rotation-only system on demand
    3x3         median of the next --repeats calls (ms)
    RSS         resident set after loading the mesh, after bind, after the (k,3,3) calls, and
                the peak (MiB)

Every time is also taken as process CPU time ("cpu" columns): on a shared machine the wall
time of a one-thread run is inflated by other jobs, its CPU time much less.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CAT = HERE.parent / "data" / "cat-poses"


def rss_mib() -> tuple[float, float]:
    """(current, peak) resident set of this process in MiB, from /proc."""
    cur = peak = 0.0
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                cur = int(line.split()[1]) / 1024
            elif line.startswith("VmHWM:"):
                peak = int(line.split()[1]) / 1024
    return cur, peak


def subdivide(v, f):
    """Split every triangle into four at its edge midpoints (shared midpoints, same order)."""
    e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    mid = len(v) + inv.reshape(-1, 3)  # midpoint of edges (0,1), (1,2), (2,0)
    v2 = np.vstack([v, 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])])
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    f2 = np.concatenate(
        [np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
    )
    return v2, f2


def mesh(name, faces):
    from matdeform import shapes

    if name == "tube":
        v, f = shapes.tube_with_faces(faces)
        lo, hi = shapes.end_faces(v, f, fraction=0.01)
        return v, f, [lo, hi]
    v, f = np.load(CAT / "reference.npy"), np.load(CAT / "faces.npy")
    anchor_ids = cat_anchor_vertices(v)
    for _ in range(3):
        v, f = subdivide(v, f)
    # Anchors: faces inside balls around the six extreme points of the reference cat.
    diag = np.linalg.norm(np.ptp(v, axis=0))
    anchors = []
    for p in anchor_ids:
        inside = np.linalg.norm(v - v[p], axis=1) < 0.025 * diag
        anchors.append(np.flatnonzero(inside[f].all(axis=1)))
    return v, f, anchors


def cat_anchor_vertices(v):
    """Four feet (lowest points per quadrant), head tip (max z), tail tip (min z); y is up."""
    out = []
    low = v[:, 1] < np.percentile(v[:, 1], 5)
    for sx in (1, -1):
        for sz in (1, -1):
            cand = np.flatnonzero(low & (np.sign(v[:, 0]) == sx) & (np.sign(v[:, 2]) == sz))
            if cand.size:
                out.append(int(cand[np.argmin(v[cand, 1])]))
    out += [int(np.argmax(v[:, 2])), int(np.argmin(v[:, 2]))]
    return out


def poses(k, count, seed=0):
    """(count, k, 4, 4) float32: free rotations up to pi, uniform scale 0.8-1.25, moves."""
    import matdeform as md

    rng = np.random.default_rng(seed)
    out = np.tile(np.eye(4, dtype=np.float32), (count, k, 1, 1))
    for p in range(count):
        for a in range(1, k):
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            t = rng.uniform(0, np.pi)
            R = md.transform_exp(np.zeros((3, 3)), t * axis)
            out[p, a, :3, :3] = rng.uniform(0.8, 1.25) * R
            out[p, a, :3, 3] = rng.normal(scale=0.2, size=3)
    return out


class Clock:
    """Wall and process-CPU seconds of a block."""

    def __enter__(self):
        self.w, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall, self.cpu = time.perf_counter() - self.w, time.process_time() - self.c


def run_one(name, faces, repeats, threads):
    import matdeform as md

    if threads:
        md.set_num_threads(threads)
    v, f, anchors = mesh(name, faces)
    loaded = rss_mib()[0]
    with Clock() as bind:
        d = md.MaterialDeformer(v, f, anchors)
    bound = rss_mib()[0]
    with Clock() as weights:
        md.harmonic_weights(f, anchors)
    T = poses(len(anchors), repeats + 1)
    row = dict(mesh=name, faces=len(f), vertices=len(v), anchors=len(anchors))
    row.update({"bind": bind.wall, "bind cpu": bind.cpu})
    row.update({"weights": weights.wall, "weights cpu": weights.cpu})
    for mode, tr in (("4x4", T), ("3x3", T[:, :, :3, :3])):
        with Clock() as first:
            d.deform(tr[0])
        row[f"first {mode}"], row[f"first {mode} cpu"] = first.wall, first.cpu
        times = []
        for p in range(1, len(tr)):
            with Clock() as c:
                d.deform(tr[p])
            times.append((c.wall, c.cpu))
        row[mode] = statistics.median(t[0] for t in times) * 1e3
        row[f"{mode} cpu"] = statistics.median(t[1] for t in times) * 1e3
    # The same poses as exact similarities in float64: float32 rounding leaves a deviatoric
    # log-stretch of ~1e-7, which the blend does not take for a similarity (tolerance 1e-12),
    # so every face goes through the general path.
    exact = T.astype(np.float64)
    for p in exact:
        for a in range(len(p)):
            U, S, Vt = np.linalg.svd(p[a, :3, :3])
            p[a, :3, :3] = S.mean() * U @ Vt
    times = []
    for p in range(1, len(exact)):
        with Clock() as c:
            d.deform(exact[p])
        times.append((c.wall, c.cpu))
    row["4x4 exact"] = statistics.median(t[0] for t in times) * 1e3
    row["4x4 exact cpu"] = statistics.median(t[1] for t in times) * 1e3
    row["rss loaded"], row["rss bound"] = loaded, bound
    row["rss 3x3"], row["rss peak"] = rss_mib()
    row["threads"] = md.num_threads()
    row["load"] = os.getloadavg()[0]
    print(json.dumps(row))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--faces", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--runs", type=int, default=1, help="runs per mesh; medians reported")
    ap.add_argument("--one", nargs=1, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        run_one(args.one[0], args.faces, args.repeats, args.threads)
        return
    names = ["tube", "cat x64"]
    rows = []
    for name in names:
        runs = []
        for _ in range(args.runs):
            cmd = [sys.executable, __file__, "--one", name, "--faces", str(args.faces)]
            cmd += ["--repeats", str(args.repeats), "--threads", str(args.threads)]
            out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
            runs.append(json.loads(out.strip().splitlines()[-1]))
        row = {k: runs[0][k] for k in ("mesh", "faces", "vertices", "anchors", "threads")}
        for k in runs[0]:
            if k not in row:
                row[k] = statistics.median(r[k] for r in runs)
        rows.append(row)
    print("Times as wall (process CPU); medians over runs.")
    print(
        "| mesh | faces | threads | bind (s) | of which weights (s) | first 4x4 (s) | 4x4 (ms) "
        "| 4x4 exact (ms) "
        "| first 3x3 (s) | 3x3 (ms) | RSS loaded / bound / 3x3 / peak (MiB) | load |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|")

    def t(r, k, fmt):
        return f"{r[k]:{fmt}} ({r[k + ' cpu']:{fmt}})"

    for r in rows:
        print(
            f"| {r['mesh']} | {r['faces']} | {r['threads']} | {t(r, 'bind', '.2f')} | "
            f"{t(r, 'weights', '.2f')} | {t(r, 'first 4x4', '.3f')} | {t(r, '4x4', '.0f')} | "
            f"{t(r, '4x4 exact', '.0f')} | "
            f"{t(r, 'first 3x3', '.2f')} | {t(r, '3x3', '.0f')} | {r['rss loaded']:.0f} / "
            f"{r['rss bound']:.0f} / {r['rss 3x3']:.0f} / {r['rss peak']:.0f} | {r['load']:.1f} |"
        )


if __name__ == "__main__":
    main()
