"""Pose-space deformation timing: precompute (constructor) and per-edit deform() time.

Cases (issue 15): a 17k-face tube with 10 examples, with and without multiresolution (coarse
1000 faces), and a 140k-face tube with a 1k-face coarse mesh; optionally the cat (14k faces,
8 example poses, six anchor regions as handles). Edits look like Blender use: four
anchors (both ends, two in between) follow Empties whose float32 4x4 matrices are best-fit rigid
motions (sometimes scaled) of the anchor regions of random in-between poses, freely rotated as a
whole. Reports medians over repeated edits; per-step medians from ``d.last_stats``.

    python bench/bench_pose_space.py [--repeats 30] [--threads 1] [--refactor]
        [--cases 17k 17k-multires 140k-multires cat cat-multires]

Peak memory of a bind (and one deform()) at single resolution and with ``coarse`` faces, each
case in a child process of its own (its peak resident set size, ru_maxrss, with the inputs'
share before the bind):

    python bench/bench_pose_space.py --cases --memory 1000000 [--coarse 1000]
"""

from __future__ import annotations

import argparse
import os

# The edits are made with numpy's SVD; an OpenBLAS thread pool left spinning after it would take
# a core from the timed deform() calls. (Set before numpy is imported.)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import platform  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import matdeform as md  # noqa: E402
from matdeform import shapes  # noqa: E402

TARGETS_MS = {"17k": 60.0, "17k-multires": 10.0, "140k-multires": 20.0}


def rot(axis, angle):
    """(3,3) turn by angle (rad) about axis: the library's exp of the axis-angle vector."""
    a = np.asarray(axis, float)
    return md.transform_exp(np.zeros((3, 3)), angle * a / np.linalg.norm(a))


def example_poses(v, count, seed=0):
    """count example shapes of a tube along x: bends in random planes, twists and bulges."""
    rng = np.random.default_rng(seed)
    length = v[:, 0].max()
    out = []
    for k in range(count):
        x = v[:, 0] / length
        bend = rng.uniform(-1.6, 1.6)
        plane = rng.uniform(0, 2 * np.pi)
        twist = rng.uniform(-2.0, 2.0)
        bulge = rng.uniform(0.0, 0.5) if k % 3 == 0 else 0.0
        # local frame: bend the axis in `plane`, twist about it, bulge in the middle
        p = v.copy()
        s = 1 + bulge * np.exp(-(((x - 0.5) / 0.12) ** 2))
        p[:, 1:] *= s[:, None]
        t = twist * x
        c, sn = np.cos(t), np.sin(t)
        y, z = p[:, 1].copy(), p[:, 2].copy()
        p[:, 1], p[:, 2] = c * y - sn * z, sn * y + c * z
        R = rot([1, 0, 0], plane)
        q = p @ R  # rotate the bend plane to xy
        if abs(bend) > 1e-9:
            rho = length / bend
            a = q[:, 0] / rho
            rr = rho - q[:, 1]
            q[:, 0], q[:, 1] = rr * np.sin(a), rho - rr * np.cos(a)
        out.append(q @ R.T)
    return np.stack(out)


def best_fit(p, q):
    """Rigid (3,4) [R|t] minimising |R p + t - q|."""
    pc, qc = p.mean(0), q.mean(0)
    u, _, vt = np.linalg.svd((p - pc).T @ (q - qc))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1, 1, d]) @ u.T
    return R, qc - R @ pc


def edits(v, examples, handles, count, seed=1):
    """Handle positions of `count` edits from Empty-like float32 matrices: best-fit rigid
    motions of the handle regions of shapes between (and a little beyond) two examples."""
    rng = np.random.default_rng(seed)
    p = len(examples)
    out = []
    for _ in range(count):
        a, b = rng.choice(p, 2, replace=False)
        t = rng.uniform(-0.2, 1.2)
        shape = (1 - t) * examples[a] + t * examples[b]
        G = rot(rng.normal(size=3), rng.uniform(0, np.pi))
        shape = shape @ G.T + rng.normal(scale=0.5, size=3)
        hp = []
        for h in handles:
            R, tr = best_fit(v[h], shape[h])
            M = np.eye(4, dtype=np.float32)
            s = rng.choice([1.0, 1.0, 1.0, rng.uniform(0.9, 1.1)])  # sometimes scaled
            M[:3, :3] = s * R
            M[:3, 3] = tr
            hp.append((v[h] @ M[:3, :3].T.astype(np.float64)) + M[:3, 3].astype(np.float64))
        out.append(hp)
    return out


def tube_case(faces_target):
    v, f = shapes.tube_with_faces(faces_target, aspect=8.0)
    x = v[:, 0] / v[:, 0].max()
    handles = [np.flatnonzero(np.abs(x - c) < 0.012) for c in (0.0, 0.33, 0.66, 1.0)]
    return v, f, handles


CAT = Path(__file__).resolve().parents[1] / "data" / "cat-poses"


def cat_case():
    """The cat: 8 poses as examples, the ninth's anchor regions (bench_quality) as handles."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_quality import Bench

    b = Bench(CAT)
    return b.rest, b.faces, np.stack(b.poses[1:]), b.region_verts


def measure(name, v, f, examples, handles, repeats, coarse):
    t0 = time.perf_counter()
    d = md.PoseSpaceDeformer(v, f, examples, handles, coarse=coarse, orientation_weight=1.0)
    pre = time.perf_counter() - t0
    seq = edits(v, examples, handles, repeats + 3)
    times, steps = [], []
    for k, hp in enumerate(seq):
        t0 = time.perf_counter()
        X = d.deform(hp)
        dt = time.perf_counter() - t0
        assert np.isfinite(X).all()
        if k >= 3:
            times.append(dt)
            steps.append(d.last_stats)
    med = {k: statistics.median(s[k] for s in steps) for k in steps[0]}
    return {
        "name": name,
        "faces": len(f),
        "coarse": len(d.coarse_faces) if coarse else None,
        "examples": len(examples),
        "precompute_s": pre,
        "median_ms": statistics.median(times) * 1e3,
        "best_ms": min(times) * 1e3,
        "steps": med,
    }


def refactor_ms(faces, repeats=3):
    """What the paper's per-edit step would cost: factoring the 3m x 3m chordal rotation system
    (3x3 blocks D per dual edge; random small rotations, one face held) with SuperLU via scipy
    (no sparse Cholesky in scipy; CHOLMOD is in the same range, see docs/pose_space.md)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    pairs = md.dual_edges(faces)
    m = len(faces)
    rng = np.random.default_rng(0)
    rows, cols, vals = [], [], []
    diag = np.full(3 * m, 1e-9)
    diag[:3] = 1e3
    for a, b in pairs:
        D = rot(rng.normal(size=3), rng.normal(scale=0.1))
        for c in range(3):
            diag[3 * a + c] += 1
            diag[3 * b + c] += 1
        for r in range(3):
            for c in range(3):
                rows += [3 * b + r, 3 * a + c]
                cols += [3 * a + c, 3 * b + r]
                vals += [-D[c, r], -D[c, r]]
    A = sp.csc_matrix((vals, (rows, cols)), shape=(3 * m, 3 * m)) + sp.diags(diag)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        splu(A.tocsc(), permc_spec="COLAMD")
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def memory_child(faces, coarse):
    """In a child process: peak RSS (MB) before and after a bind plus one deform(), bind time."""
    v, f, handles = tube_case(faces)
    ex = example_poses(v, 10)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    d = md.PoseSpaceDeformer(v, f, ex, handles, coarse=coarse)
    bind = time.perf_counter() - t0
    X = d.deform(edits(v, ex, handles, 1)[0])
    assert np.isfinite(X).all()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"MEMORY {len(f)} {len(d.coarse_faces) if coarse else 0} {before:.0f} {peak:.0f} {bind:.2f}"
    )


def memory_table(faces, coarse, threads):
    print("| faces | coarse | inputs (MB) | peak RSS (MB) | bind (s) |")
    print("|---:|---:|---:|---:|---:|")
    for c in (None, coarse):
        cmd = [sys.executable, __file__, "--child-memory", str(faces), str(c or 0)]
        if threads:
            cmd += ["--threads", str(threads)]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
        nf, nc, before, peak, bind = out.split("MEMORY")[-1].split()
        print(f"| {nf} | {nc if c else '-'} | {before} | {peak} | {bind} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--examples", type=int, default=10)
    ap.add_argument("--cases", nargs="*", default=["17k", "17k-multires", "140k-multires"])
    ap.add_argument(
        "--refactor", action="store_true", help="also time a per-edit factorisation (scipy)"
    )
    ap.add_argument("--memory", type=int, metavar="FACES", help="peak memory of a bind, per case")
    ap.add_argument("--coarse", type=int, default=1000, help="coarse faces of --memory")
    ap.add_argument("--child-memory", nargs=2, type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.threads:
        md.set_num_threads(args.threads)
    if args.child_memory:
        memory_child(args.child_memory[0], args.child_memory[1] or None)
        return
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"*{platform.machine()}, {os.cpu_count()} cores, {md.num_threads()} solver thread(s), "
        f"load average {load:.2f}*"
    )
    if args.cases:
        print(
            "| case | faces | coarse | examples | precompute (s) | deform() median (ms) "
            "| best (ms) | weights / blend / rotations / positions / fit / transfer (ms, medians) "
            "| CG its | target |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---|---|---|")
    for case in args.cases:
        coarse = 1000 if case.endswith("multires") else None
        if case.startswith("cat"):
            v, f, ex, handles = cat_case()
        else:
            v, f, handles = tube_case(17_000 if case.startswith("17k") else 140_000)
            ex = example_poses(v, args.examples)
        r = measure(case, v, f, ex, handles, args.repeats, coarse)
        s = r["steps"]
        parts = " / ".join(
            f"{s[k]:.2f}"
            for k in (
                "ms_weights",
                "ms_blend",
                "ms_rotations",
                "ms_positions",
                "ms_fit",
                "ms_transfer",
            )
        )
        tgt = TARGETS_MS.get(case)
        met = (
            "" if tgt is None else f"<= {tgt:g} ms: {'met' if r['median_ms'] <= tgt else 'NOT met'}"
        )
        print(
            f"| {case} | {r['faces']} | {r['coarse'] or '-'} | {r['examples']} | "
            f"{r['precompute_s']:.2f} | {r['median_ms']:.2f} | {r['best_ms']:.2f} | {parts} | "
            f"{s['iterations_first']:.0f}+{s['iterations_second']:.0f} | {met} |",
            flush=True,
        )
    if args.memory:
        memory_table(args.memory, args.coarse, args.threads)
    if args.refactor:
        for faces in (1000, 17_000):
            _, f, _ = tube_case(faces)
            print(
                f"per-edit factorisation of the chordal rotation system, {len(f)} faces: "
                f"{refactor_ms(f):.1f} ms (SuperLU, best of 3)",
                flush=True,
            )


if __name__ == "__main__":
    main()
