"""Pyramid coordinates: time to converge and sweeps per second at three sizes.

Meshes (all from data/cat-poses, poses with the same connectivity):
  * cat 5k: the reference cat decimated to ~5k faces (fast-simplification, QEM), 9 control
    vertices (4 feet, head tip, tail tip, and three along the back) moved to their positions in
    each of the nine cat poses (as the paper's walking camel: 9 control vertices);
  * cat 14k: the quality protocol of bench_quality.py, every anchor-region vertex a control at
    its pose position;
  * cat 58k: the cat and its poses midpoint-subdivided once, the same protocol.

For each mesh and pose: deform(tol=1e-5) from the default start is timed (median of --repeats
runs), and its result compared with a tight reference (tol 1e-12) to show how far the stopping
rule leaves it from the fixed point. Sweeps per second come from fixed 50-sweep runs.

    python bench/bench_pyramid.py [--repeats 3] [--threads 1 2] [--poses 1 2 ...] [--plot PNG]
                                  [--stretch on|off] [--addon]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
from bench_quality import Bench, anchor_points

import matdeform as md

DATA = Path(__file__).resolve().parents[1] / "data" / "cat-poses"
TARGET_MS = {"cat 5k": 50.0, "cat 14k": 200.0, "cat 58k": 1000.0}
TOL = 1e-5


def subdivide(v: np.ndarray, f: np.ndarray, poses: list[np.ndarray]):
    """Midpoint subdivision (1 -> 4 triangles), applied to the rest mesh and every pose."""
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    m = len(f)
    mid = len(v) + inv.reshape(3, m).T  # (m,3): midpoints of edges 01, 12, 20
    a, b, c = f.T
    ab, bc, ca = mid.T
    f2 = np.concatenate(
        [np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
    )

    def lift(x):
        return np.vstack([x, 0.5 * (x[uniq[:, 0]] + x[uniq[:, 1]])])

    return lift(v), f2, [lift(p) for p in poses]


def nine_controls(v: np.ndarray) -> np.ndarray:
    """4 feet, head and tail tips (bench_quality's points) and the top of the back at 1/4, 1/2
    and 3/4 of the body length."""
    pts = list(anchor_points(v).values())
    up = 1
    axis = max((0, 2), key=lambda a: np.ptp(v[:, a]))
    lo, hi = v[:, axis].min(), v[:, axis].max()
    for t in (0.25, 0.5, 0.75):
        x = lo + t * (hi - lo)
        band = np.flatnonzero(np.abs(v[:, axis] - x) < 0.02 * (hi - lo))
        pts.append(int(band[v[band, up].argmax()]))
    return np.array(pts)


def meshes(b: Bench):
    """(name, vertices, faces, controls, [target per pose]) for the three sizes. The 5k mesh
    needs fast-simplification (pip install fast-simplification; benchmark only)."""
    out = []
    try:
        import fast_simplification
    except ImportError:
        print("cat 5k skipped: pip install fast-simplification to decimate the cat")
        fast_simplification = None
    if fast_simplification is not None:
        out.append(decimated(b, fast_simplification))
    out.append(("cat 14k", b.rest, b.faces, b.pinned, [p[b.pinned] for p in b.poses]))
    vs, fs, ps = subdivide(b.rest, b.faces, b.poses)
    diag = np.linalg.norm(vs.max(0) - vs.min(0))
    centres = [b.rest[i] for i in b.points.values()]
    inside = np.zeros(len(vs), bool)
    for c in centres:
        inside |= np.linalg.norm(vs - c, axis=1) <= 0.025 * diag
    pinned = np.flatnonzero(inside)
    out.append(("cat 58k", vs, fs, pinned, [p[pinned] for p in ps]))
    return out


def decimated(b: Bench, fast_simplification):
    """The cat decimated to ~5k faces (QEM) with 9 controls following their nearest cat vertex."""
    vd, fd = fast_simplification.simplify(
        b.rest.astype(np.float32),
        b.faces.astype(np.int32),
        target_reduction=1 - 5000 / len(b.faces),
    )
    vd = vd.astype(np.float64)
    fd = fd.astype(np.int64)
    ctrl = nine_controls(vd)
    # each control follows the nearest vertex of the full cat, keeping its small offset
    near = np.array([np.linalg.norm(b.rest - vd[c], axis=1).argmin() for c in ctrl])
    targets = [p[near] + (vd[ctrl] - b.rest[near]) for p in b.poses]
    return "cat 5k", vd, fd, ctrl, targets


def rms(x, y, diag):
    return float(np.sqrt(np.mean(np.sum((x - y) ** 2, axis=1))) / diag)


def run(name, v, f, ctrl, targets, poses_idx, repeats, poses_full=None, stretch=True):
    t0 = time.perf_counter()
    d = md.PyramidDeformer(v, f, ctrl)
    pre = time.perf_counter() - t0
    times, sweeps, gaps = [], [], []
    for h in poses_idx:
        tgt = targets[h]
        ref = d.deform(tgt, tol=1e-12, stretch=stretch)
        ts = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            X = d.deform(tgt, tol=TOL, stretch=stretch)
            ts.append(time.perf_counter() - t0)
        times.append(statistics.median(ts))
        sweeps.append(d.last_iterations)
        gaps.append(float(np.abs(X - ref).max() / d.diagonal))
    # sweeps per second: fixed 50-sweep runs, default settings and plain sweeps
    tgt = targets[poses_idx[0]]
    per = {}
    for label, kw in (("anderson 20", {}), ("plain", {"anderson": 0})):
        ts = []
        for _ in range(max(3, repeats)):
            t0 = time.perf_counter()
            d.deform(tgt, iterations=50, tol=0, stretch=stretch, **kw)
            ts.append(time.perf_counter() - t0)
        per[label] = 50 / statistics.median(ts)
    # one live update of the add-on: its default budget (30 sweeps), warm-started from the last
    x = d.deform(tgt, iterations=30, stretch=stretch)
    ts = []
    for _ in range(max(3, repeats)):
        t0 = time.perf_counter()
        x = d.deform(tgt, iterations=30, initial=x, stretch=stretch)
        ts.append(time.perf_counter() - t0)
    per["live update (30 sweeps) ms"] = statistics.median(ts) * 1e3
    return {
        "name": name,
        "faces": len(f),
        "vertices": len(v),
        "controls": len(ctrl),
        "precompute_s": pre,
        "median_ms": statistics.median(times) * 1e3,
        "max_ms": max(times) * 1e3,
        "sweeps": int(statistics.median(sweeps)),
        "gap": statistics.median(gaps),
        "sps": per,
    }


def plot_moves(b: Bench, path: Path) -> None:
    """Move per sweep on the cat (pose 1): the paper's sweeps, with stretch off, accelerated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = md.PyramidDeformer(b.rest, b.faces, b.pinned)
    tgt = b.poses[0][b.pinned]
    # each setting against the fixed point of its own equations (stretch changes them)
    refs = {s: d.deform(tgt, tol=1e-13, stretch=s) for s in (True, False)}
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for label, kw in (
        ("Gauss-Seidel (paper), stretch", {"anderson": 0}),
        ("Gauss-Seidel (paper), no stretch", {"anderson": 0, "stretch": False}),
        ("Jacobi + Anderson 20, stretch", {"method": "jacobi"}),
        ("Gauss-Seidel + Anderson 20, stretch (default)", {}),
    ):
        d.deform(tgt, iterations=1500, tol=1e-13, record_moves=True, **kw)
        ax[0].semilogy(d.last_moves, label=label, lw=1)
        its = [25, 50, 100, 200, 400, 800, 1500]
        ref = refs[kw.get("stretch", True)]
        errs = [
            np.abs(d.deform(tgt, iterations=i, tol=0, **kw) - ref).max() / d.diagonal for i in its
        ]
        ax[1].loglog(its, errs, "o-", label=label, ms=3)
    ax[0].axhline(TOL, color="0.5", ls=":", lw=1)
    ax[0].set_xlabel("sweep")
    ax[0].set_ylabel("largest move / diagonal")
    ax[0].set_title("move per sweep (the stopping rule's quantity)")
    ax[1].set_xlabel("sweeps")
    ax[1].set_ylabel("max |x - x*| / diagonal")
    ax[1].set_title("distance to the fixed point x* (default settings, tol 1e-13)")
    ax[1].legend(fontsize=7)
    fig.suptitle("Pyramid coordinates on the cat (14k faces, pose 1, quality-protocol controls)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def addon_table(sets, idx, repeats) -> None:
    """What the add-on's settings give: sweeps to tol 1e-5 (at most its 20000-sweep allowance)
    with stretch off and on, the converge time, and one live update (30 sweeps, warm start)."""
    print(
        "| mesh | stretch | sweeps to tol 1e-5 per pose | converge median (ms) "
        "| live update, 30 sweeps (ms) |"
    )
    print("|---|---|---|---:|---:|")
    for name, v, f, ctrl, targets in sets:
        d = md.PyramidDeformer(v, f, ctrl)
        for st in (False, True):
            sweeps, ts, live = [], [], []
            for h in idx:
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    x = d.deform(targets[h], tol=TOL, stretch=st, iterations=20000)
                    ts.append(time.perf_counter() - t0)
                n = d.last_iterations
                sweeps.append(str(n) if d.last_move < TOL else f">{n}")
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    x = d.deform(targets[h], iterations=30, initial=x, stretch=st)
                    live.append(time.perf_counter() - t0)
            print(
                f"| {name} | {'on' if st else 'off'} | {' / '.join(sweeps)} | "
                f"{statistics.median(ts) * 1e3:.0f} | {statistics.median(live) * 1e3:.1f} |",
                flush=True,
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, nargs="*", default=[1, 2])
    ap.add_argument("--poses", type=int, nargs="*", default=list(range(1, 10)))
    ap.add_argument("--sizes", nargs="*", default=list(TARGET_MS))
    ap.add_argument("--plot", type=Path, help="write the convergence plot (matplotlib)")
    ap.add_argument(
        "--stretch",
        choices=("on", "off"),
        default="on",
        help="on: the default of the library and the add-on; off: unscaled weights",
    )
    ap.add_argument(
        "--addon", action="store_true", help="the add-on's table: stretch off/on, live update"
    )
    args = ap.parse_args()
    stretch = args.stretch == "on"
    b = Bench(args.data)
    if args.plot:
        plot_moves(b, args.plot)
        return
    idx = [p - 1 for p in args.poses]
    sets = [m for m in meshes(b) if m[0] in args.sizes]
    for th in args.threads:
        md.set_num_threads(th)
        print(
            f"\n*{platform.machine()}, {os.cpu_count()} cores, {md.num_threads()} solver "
            f"thread(s), load average {os.getloadavg()[0]:.2f}, poses {args.poses}, "
            f"median of {args.repeats} runs per pose, stretch {args.stretch}*"
        )
        if args.addon:
            addon_table(sets, idx, args.repeats)
            continue
        print(
            "| mesh | faces | controls | precompute (s) | sweeps to tol 1e-5 | converge median "
            "(ms) | slowest pose (ms) | gap to fixed point | sweeps/s (Anderson 20) "
            "| sweeps/s (plain) | live update, 30 sweeps (ms) | target |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
        for name, v, f, ctrl, targets in sets:
            r = run(name, v, f, ctrl, targets, idx, args.repeats, stretch=stretch)
            tgt = TARGET_MS[name]
            ok = "met" if r["median_ms"] <= tgt else "MISSED"
            print(
                f"| {name} | {r['faces']} | {r['controls']} | {r['precompute_s']:.3f} | "
                f"{r['sweeps']} | {r['median_ms']:.0f} | {r['max_ms']:.0f} | {r['gap']:.1e} | "
                f"{r['sps']['anderson 20']:.0f} | {r['sps']['plain']:.0f} | "
                f"{r['sps']['live update (30 sweeps) ms']:.0f} | <= {tgt:g} ms: {ok} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
