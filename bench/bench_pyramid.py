"""Pyramid coordinates: the timing, convergence and invariance targets in one table.

    python bench/bench_pyramid.py                  # the target table (two threads)
    python bench/bench_pyramid.py --repeats 1 --sizes "cat 5k" "cat 14k"
    python bench/bench_pyramid.py --plot docs/images/pyramid_convergence.png

Meshes (all from data/cat-poses, nine poses with the same connectivity):
  * cat 5k: the reference cat decimated to ~5k faces (fast-simplification, QEM; benchmark only:
    pip install fast-simplification), 9 control vertices (4 feet, head tip, tail tip, three
    along the back) moved to their positions in each pose (as the paper's walking camel);
  * cat 14k: the quality protocol of bench_quality.py, every anchor-region vertex a control at
    its pose position;
  * cat 58k: the cat and its poses midpoint-subdivided once, the same protocol.

Every pose is solved with the library's defaults (L-BFGS, then Newton's method, from the start
built from the controls, tol 1e-6), the median of --repeats runs per pose. The table shows per
mesh the slowest pose and its time against the target, whether every pose converged, the
residual (the largest last Newton step over the poses, as a fraction of the diagonal: the
stopping rule's quantity), and for the slowest pose the largest difference (fraction of the
diagonal) to the same solve on a randomly relabelled mesh and with one thread. For cat 14k a
second table gives the quality protocol's error per pose against Blender's Laplacian Deform
(docs/quality.md).

Timings are wall-clock medians on whatever machine runs this; the lead's figures come from an
idle machine. numpy's own BLAS threads are limited to one (they spin after each call and take a
core from the solver; the solver's own BLAS is serial).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: see the docstring

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from bench_quality import Bench, anchor_points, rms_error  # noqa: E402

import matdeform as md  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data" / "cat-poses"
TARGET_MS = {"cat 5k": 50.0, "cat 14k": 200.0, "cat 58k": 1000.0}
# Blender's Laplacian Deform on the quality protocol (docs/quality.md), per pose, and the
# uniform material-aware solve's mean: the quality targets.
LAPLACIAN = [0.0546, 0.0398, 0.0346, 0.1101, 0.0833, 0.0494, 0.0943, 0.0614, 0.0783]
UNIFORM_MEAN = 0.0569


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
    return "cat 5k", vd, fd, ctrl, targets, None


def meshes(b: Bench, sizes):
    """(name, vertices, faces, controls, [target per pose], [true pose] or None)."""
    out = []
    if "cat 5k" in sizes:
        try:
            import fast_simplification
        except ImportError:
            print("cat 5k skipped: pip install fast-simplification to decimate the cat")
        else:
            out.append(decimated(b, fast_simplification))
    if "cat 14k" in sizes:
        out.append(("cat 14k", b.rest, b.faces, b.pinned, [p[b.pinned] for p in b.poses], b.poses))
    if "cat 58k" in sizes:
        vs, fs, ps = subdivide(b.rest, b.faces, b.poses)
        diag = np.linalg.norm(vs.max(0) - vs.min(0))
        inside = np.zeros(len(vs), bool)
        for c in [b.rest[i] for i in b.points.values()]:
            inside |= np.linalg.norm(vs - c, axis=1) <= 0.025 * diag
        pinned = np.flatnonzero(inside)
        out.append(("cat 58k", vs, fs, pinned, [p[pinned] for p in ps], None))
    return out


def relabelled(v, f, ctrl, seed=5):
    """A random vertex numbering, face order and corner rotation: (v2, f2, ctrl2, perm) with
    v2 = v[perm]."""
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(v))
    inv = np.argsort(perm)
    f2 = np.roll(inv[f][rng.permutation(len(f))], 1, axis=1)
    return v[perm], f2, inv[ctrl], perm


def run(name, v, f, ctrl, targets, poses_idx, repeats, invariance):
    t0 = time.perf_counter()
    d = md.PyramidDeformer(v, f, ctrl)
    build = time.perf_counter() - t0
    per = []
    for h in poses_idx:
        ts = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            X = d.deform(targets[h])
            ts.append(time.perf_counter() - t0)
        per.append(
            {
                "pose": h + 1,
                "ms": statistics.median(ts) * 1e3,
                "converged": d.last_converged,
                "step": d.last_step,
                "iterations": d.last_iterations,
                "factorizations": d.last_factorizations,
                "lbfgs": d.last_lbfgs_iterations,
                "X": X,
            }
        )
    slow = max(per, key=lambda r: r["ms"])
    out = {
        "name": name,
        "faces": len(f),
        "free": d.num_free,
        "controls": len(ctrl),
        "build": build,
        "per": per,
        "slow": slow,
    }
    if invariance:
        h = slow["pose"] - 1
        v2, f2, c2, perm = relabelled(v, f, ctrl)
        X2 = md.PyramidDeformer(v2, f2, c2).deform(targets[h])
        out["relabel"] = float(np.abs(X2 - slow["X"][perm]).max() / d.diagonal)
        before = md.num_threads()
        md.set_num_threads(1)
        try:
            X1 = d.deform(targets[h])
        finally:
            md.set_num_threads(before)
        out["threads"] = float(np.abs(X1 - slow["X"]).max() / d.diagonal)
    return out


def plot(b: Bench, path: Path, old: Path) -> None:
    """The cat (14k, quality-protocol controls), Newton's method against the old Gauss-Seidel +
    Anderson sweeps, whose curves are read from `old` (bench/pyramid_old_sweeps.npz, measured
    once with the last build that had them, commit 56382a7, two threads). Left, pose 1 (where
    the sweeps converge): distance to each method's own converged result against time. Right,
    pose 7 (where they stall): the stopping rule's quantity against time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.load(old)
    d = md.PyramidDeformer(b.rest, b.faces, b.pinned)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    # pose 1: distance after a budget of iterations, against the time that budget takes
    tgt = b.poses[0][b.pinned]
    ref = d.deform(tgt, tol=1e-11)
    times, dist = [], []
    for it in range(1, 40):
        ts = []
        for _ in range(3):
            t0 = time.perf_counter()
            X = d.deform(tgt, iterations=it, tol=1e-11)
            ts.append(time.perf_counter() - t0)
        times.append(statistics.median(ts))
        dist.append(max(np.abs(X - ref).max() / d.diagonal, 1e-16))
        if d.last_converged:
            break
    ax[0].loglog(z["seconds"], z["distance"], "o-", ms=3, label="old: Gauss-Seidel + Anderson")
    ax[0].loglog(
        times, dist, "s-", ms=3, label="L-BFGS, then Newton (one point per Newton iteration)"
    )
    ax[0].set_xlabel("seconds")
    ax[0].set_ylabel("max |x - x*| / diagonal")
    ax[0].set_title("pose 1: distance to each method's own result")
    ax[0].legend(fontsize=8)
    # pose 7: the stopping rule's quantity per iteration, against time
    tgt = b.poses[6][b.pinned]
    stamps = []
    t0 = time.perf_counter()
    d.deform(
        tgt, progress=lambda i, s: stamps.append((time.perf_counter() - t0, s)), progress_seconds=0
    )
    ax[1].loglog(z["seconds7"], z["moves7"], lw=1, label="old sweeps: move per sweep")
    ax[1].loglog(
        [t for t, _ in stamps],
        [max(s, 1e-16) for _, s in stamps],
        "s-",
        ms=3,
        label="L-BFGS, then Newton: step per iteration",
    )
    ax[1].axhline(1e-6, color="0.5", ls=":", lw=1)
    ax[1].set_xlabel("seconds")
    ax[1].set_ylabel("largest vertex move / diagonal")
    ax[1].set_title("pose 7: the stopping rule's quantity (dotted: tol 1e-6)")
    ax[1].legend(fontsize=8)
    fig.suptitle(
        f"Pyramid coordinates on the cat (14k faces, 1502 controls), {md.num_threads()} threads"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, nargs="*", default=[2])
    ap.add_argument("--poses", type=int, nargs="*", default=list(range(1, 10)))
    ap.add_argument("--sizes", nargs="*", default=list(TARGET_MS))
    ap.add_argument("--no-invariance", action="store_true", help="skip the relabelling runs")
    ap.add_argument("--plot", type=Path, help="write the convergence plot (matplotlib)")
    ap.add_argument(
        "--old",
        type=Path,
        default=Path(__file__).with_name("pyramid_old_sweeps.npz"),
        help="the old sweeps' measured curve for the plot",
    )
    args = ap.parse_args()
    b = Bench(args.data)
    if args.plot:
        md.set_num_threads(args.threads[0])
        plot(b, args.plot, args.old)
        return
    idx = [p - 1 for p in args.poses]
    sets = meshes(b, args.sizes)
    for th in args.threads:
        md.set_num_threads(th)
        print(
            f"\n*{platform.machine()}, {os.cpu_count()} cores, {md.num_threads()} solver "
            f"thread(s), load average {os.getloadavg()[0]:.2f}, poses {args.poses}, median of "
            f"{args.repeats} runs per pose*\n"
        )
        print(
            "| mesh | faces | free vertices | controls | slowest pose | time (ms) | target "
            "| converged | residual (last step / diag) | L-BFGS iterations | Newton iterations "
            "| factorisations | relabelled / 1 thread (of diag) | build (s) |"
        )
        print("|---|---:|---:|---:|---:|---:|---|---|---:|---|---|---:|---|---:|")
        quality = None
        for name, v, f, ctrl, targets, truth in sets:
            r = run(name, v, f, ctrl, targets, idx, args.repeats, not args.no_invariance)
            s, per = r["slow"], r["per"]
            conv = sum(p["converged"] for p in per)
            ok = "met" if s["ms"] <= TARGET_MS[name] else "MISSED"
            its = [p["iterations"] for p in per]
            lb = [p["lbfgs"] for p in per]
            inv = "-" if args.no_invariance else f"{r['relabel']:.1e} / {r['threads']:.1e}"
            print(
                f"| {name} | {r['faces']} | {r['free']} | {r['controls']} | {s['pose']} | "
                f"{s['ms']:.0f} | <= {TARGET_MS[name]:g} ms: {ok} | "
                f"{'yes' if conv == len(per) else 'NO'} ({conv}/{len(per)}) | "
                f"{max(p['step'] for p in per):.1e} | {min(lb)}-{max(lb)} | "
                f"{min(its)}-{max(its)} | "
                f"{max(p['factorizations'] for p in per)} | {inv} | {r['build']:.2f} |",
                flush=True,
            )
            if truth is not None:
                quality = [
                    (p["pose"], rms_error(p["X"], truth[p["pose"] - 1], b.diag)) for p in per
                ]

        if quality:
            print("\ncat 14k, quality protocol (error to the real pose / diagonal, RMS):\n")
            print("| pose | pyramid | Laplacian Deform | below it |")
            print("|---:|---:|---:|---|")
            for pose, e in quality:
                lap = LAPLACIAN[pose - 1]
                print(f"| {pose} | {e:.4f} | {lap:.4f} | {'yes' if e < lap else 'NO'} |")
            mean = float(np.mean([e for _, e in quality]))
            print(
                f"| mean | {mean:.4f} | {np.mean(LAPLACIAN):.4f} | target <= {UNIFORM_MEAN}: "
                f"{'met' if mean <= UNIFORM_MEAN else 'MISSED'} |"
            )


if __name__ == "__main__":
    main()
