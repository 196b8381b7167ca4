"""Speed of stiffness learning: 10 poses of a ~44k-face mesh (the paper: 9.5 s for its camel).

The mesh is three side-by-side copies of the cat (43,230 faces); the 10 poses are the nine
cat poses plus a rigidly moved copy of pose 1, applied to all three copies. Reports the median
wall time of repeated ``learn_stiffness`` calls (input validation included).

    python bench/bench_learn.py [--data data/cat-poses] [--repeat 9]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import matdeform as md


def tile(v: np.ndarray, f: np.ndarray, copies: int, step: float) -> tuple[np.ndarray, np.ndarray]:
    """`copies` disjoint copies of (v, f) shifted by `step` along x."""
    vs = [v + [c * step, 0.0, 0.0] for c in range(copies)]
    fs = [f + c * len(v) for c in range(copies)]
    return np.concatenate(vs), np.concatenate(fs).astype(np.int32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "data" / "cat-poses",
    )
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--copies", type=int, default=3)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="core thread counts")
    args = ap.parse_args()

    v0, f0 = np.load(args.data / "reference.npy"), np.load(args.data / "faces.npy")
    poses0 = list(np.load(args.data / "poses.npy"))
    c, s = np.cos(0.7), np.sin(0.7)
    turn = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    poses0.append(poses0[0] @ turn.T + [0.1, 0.2, 0.3])
    step = 2.0 * np.ptp(v0[:, 0]) + 1.0
    v, f = tile(v0, f0, args.copies, step)
    poses = np.stack([tile(p, f0, args.copies, step)[0] for p in poses0])
    print(
        f"mesh: {len(v)} vertices, {len(f)} faces, {len(md.dual_edges(f))} dual edges; "
        f"{len(poses)} poses; OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, "
        f"cpus={os.cpu_count()}"
    )

    for threads in args.threads:
        md.set_num_threads(threads)
        for aniso in (False, True):
            md.learn_stiffness(v, f, poses, anisotropic=aniso)  # warm-up
            times = []
            for _ in range(args.repeat):
                t = time.perf_counter()
                md.learn_stiffness(v, f, poses, anisotropic=aniso)
                times.append(time.perf_counter() - t)
            label = "anisotropic" if aniso else "isotropic"
            print(
                f"threads {threads}  learn_stiffness {label:12s} median {np.median(times):.3f} s"
                f"  min {min(times):.3f} s  max {max(times):.3f} s  ({args.repeat} runs)"
            )


if __name__ == "__main__":
    main()
