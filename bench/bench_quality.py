"""Held-out pose reconstruction on the cat: how much does learned stiffness help?

For each of the 9 cat poses, stiffness is learned from the other 8 only (never from the pose
being reconstructed). Six anchors sit at the four feet, the tip of the head and the tip of the
tail of the reference mesh; each anchor is the set of vertices within 2.5% of the bounding-box
diagonal of its extreme point, its faces those with all three vertices in the set. Every anchor
gets the best-fit (Kabsch) rotation of its region rest -> pose, and all anchor vertices are
pinned to their pose positions. The reference mesh is deformed and compared with the true pose:

    error = RMS over all vertices of |x - x_pose| / bounding-box diagonal of the reference

Rows: uniform stiffness, learned isotropic, learned anisotropic (when MaterialDeformer accepts
(E,3) bend), the edge-based method (md.EdgeDeformer: the anchor vertices pinned at their pose
positions, no rotations given), pyramid coordinates (md.PyramidDeformer: the anchor vertices as
controls at their pose positions, no stiffness, no rotations), Blender's Laplacian Deform with
the same pinned vertices, and pose-space manipulation (PoseSpaceDeformer: the other 8 poses are
the examples, the six anchor regions the translational handles, every anchor vertex at its pose
position), with and without multiresolution.

    python bench/bench_quality.py [--data DIR] [--no-blender] [--explore] [--pose-space-only]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

import matdeform as md

HERE = Path(__file__).resolve().parent
RADIUS = 0.025  # anchor region radius, fraction of the bounding-box diagonal
UP = 1  # the cat OBJs are y-up


# ----------------------------------------------------------------------------- anchors


def anchor_points(v: np.ndarray) -> dict[str, int]:
    """Vertex index of each extreme point: 4 feet, head tip, tail tip.

    Body axis = the longer horizontal bounding-box side. Feet: among the lowest 10% (in height)
    of the vertices, split front/back at the middle of their body-axis extent and left/right at
    their mean lateral coordinate; each quadrant's lowest vertex. Head/tail: the two extreme
    vertices along the body axis; the tail is the thin end (fewer vertices in the last 15%).
    """
    lo, hi = v.min(0), v.max(0)
    horizontal = [a for a in range(3) if a != UP]
    axis = max(horizontal, key=lambda a: hi[a] - lo[a])
    side = next(a for a in horizontal if a != axis)
    low = np.flatnonzero(v[:, UP] < lo[UP] + 0.1 * (hi[UP] - lo[UP]))
    mid_axis = 0.5 * (v[low, axis].min() + v[low, axis].max())
    mid_side = v[low, side].mean()
    a_min, a_max = int(v[:, axis].argmin()), int(v[:, axis].argmax())
    length = hi[axis] - lo[axis]
    mass_min = np.sum(v[:, axis] < lo[axis] + 0.15 * length)
    mass_max = np.sum(v[:, axis] > hi[axis] - 0.15 * length)
    head, tail = (a_max, a_min) if mass_max > mass_min else (a_min, a_max)
    # Facing +axis with y up, the left side is +side when (side, up, axis) is right-handed.
    left_sign = 1.0 if np.cross(np.eye(3)[side], np.eye(3)[UP]) @ np.eye(3)[axis] > 0 else -1.0
    front_sign = 1.0 if v[head, axis] > v[tail, axis] else -1.0
    out = {}
    for fb, fs in (("front", 1.0), ("back", -1.0)):
        for lr, ls in (("left", 1.0), ("right", -1.0)):
            q = low[
                (front_sign * fs * (v[low, axis] - mid_axis) > 0)
                & (left_sign * ls * (v[low, side] - mid_side) > 0)
            ]
            out[f"{fb}-{lr} foot"] = int(q[v[q, UP].argmin()])
    out["head tip"] = head
    out["tail tip"] = tail
    return out


def anchor_regions(v: np.ndarray, f: np.ndarray, points: dict[str, int]):
    """Per anchor: vertex indices within RADIUS * diag of its point, and faces inside them."""
    diag = np.linalg.norm(v.max(0) - v.min(0))
    verts, faces = [], []
    for i in points.values():
        r = np.flatnonzero(np.linalg.norm(v - v[i], axis=1) <= RADIUS * diag)
        inside = np.zeros(len(v), bool)
        inside[r] = True
        verts.append(r)
        faces.append(np.flatnonzero(inside[f].all(1)).astype(np.int32))
    return verts, faces


def kabsch(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rotation R (3,3) minimising sum |R (p - mean p) - (q - mean q)|^2 (p, q: (k,3))."""
    h = (p - p.mean(0)).T @ (q - q.mean(0))
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


# ----------------------------------------------------------------------------- methods


Stiffness = Callable[[list[np.ndarray]], tuple[np.ndarray | None, np.ndarray | None]]


def rms_error(x: np.ndarray, target: np.ndarray, diag: float) -> float:
    return float(np.sqrt(np.mean(np.sum((x - target) ** 2, axis=1))) / diag)


class Bench:
    def __init__(self, data: Path):
        self.rest, self.faces = np.load(data / "reference.npy"), np.load(data / "faces.npy")
        self.poses = list(np.load(data / "poses.npy"))
        self.diag = float(np.linalg.norm(self.rest.max(0) - self.rest.min(0)))
        self.points = anchor_points(self.rest)
        self.region_verts, self.region_faces = anchor_regions(self.rest, self.faces, self.points)
        self.pinned = np.unique(np.concatenate(self.region_verts))
        self.rotations = [
            np.stack([kabsch(self.rest[r], p[r]) for r in self.region_verts]) for p in self.poses
        ]

    def train(self, h: int) -> list[np.ndarray]:
        """All poses except the held-out one."""
        return [p for s, p in enumerate(self.poses) if s != h]

    def reconstruct(self, h: int, shear, bend) -> np.ndarray:
        d = md.MaterialDeformer(
            self.rest, self.faces, self.region_faces, shear=shear, bend=bend, pinned=self.pinned
        )
        return d.deform(self.rotations[h], pinned_positions=self.poses[h][self.pinned])

    def run(self, stiffness: Stiffness) -> list[float]:
        errs = []
        for h in range(len(self.poses)):
            shear, bend = stiffness(self.train(h))
            x = self.reconstruct(h, shear, bend)
            errs.append(rms_error(x, self.poses[h], self.diag))
        return errs

    def pyramid(self) -> list[float]:
        """Pyramid coordinates: the anchor vertices as controls at their pose positions, the
        library's defaults (Newton's method to tol 1e-6; every pose converges, an exception
        otherwise)."""
        d = md.PyramidDeformer(self.rest, self.faces, self.pinned)
        errs = []
        for p in self.poses:
            x = d.deform(p[self.pinned])
            if not d.last_converged:
                raise RuntimeError("pyramid coordinates: a pose did not converge")
            errs.append(rms_error(x, p, self.diag))
        return errs

    def pose_space(self, **kw) -> list[float]:
        """Held-out error of PoseSpaceDeformer per pose: examples = the other 8 poses."""
        errs = []
        for h in range(len(self.poses)):
            d = md.PoseSpaceDeformer(self.rest, self.faces, self.train(h), self.region_verts, **kw)
            x = d.deform([self.poses[h][r] for r in self.region_verts])
            errs.append(rms_error(x, self.poses[h], self.diag))
        return errs

    def laplacian(self, iterations: int = 1) -> tuple[list[float], float] | None:
        """Blender's Laplacian Deform for all poses; None if blender is not installed."""
        blender = shutil.which("blender")
        if blender is None:
            return None
        # Blender embeds its own Python; a pyenv/venv Python on PATH or PYTHON* variables make
        # it pick the wrong standard library.
        env = {k: v for k, v in os.environ.items() if not k.startswith(("PYENV", "PYTHON"))}
        env.pop("VIRTUAL_ENV", None)
        env["PATH"] = os.pathsep.join(
            p for p in env["PATH"].split(os.pathsep) if ".pyenv" not in p and ".venv" not in p
        )
        with tempfile.TemporaryDirectory() as tmp:
            src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
            targets = np.stack([p[self.pinned] for p in self.poses])
            np.savez(
                src,
                rest=self.rest,
                faces=self.faces,
                anchors=self.pinned,
                targets=targets,
                iterations=iterations,
            )
            cmd = [
                blender,
                "-b",
                "--factory-startup",
                "--python",
                str(HERE / "blender_laplacian.py"),
                "--",
                str(src),
                str(dst),
            ]
            r = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if r.returncode != 0 or not dst.exists():
                sys.stderr.write(r.stdout[-2000:] + r.stderr[-2000:])
                raise RuntimeError("blender Laplacian Deform run failed")
            out = np.load(dst)["deformed"]
        errs = [rms_error(x, p, self.diag) for x, p in zip(out, self.poses, strict=True)]
        # Blender's anchors are soft: report how far they end up from their targets.
        slip = max(
            float(np.abs(x[self.pinned] - p[self.pinned]).max())
            for x, p in zip(out, self.poses, strict=True)
        )
        return errs, slip / self.diag


def supports_anisotropic(b: Bench) -> bool:
    """Whether MaterialDeformer accepts per-axis (E,3) bending."""
    e = len(md.dual_edges(b.faces))
    try:
        md.MaterialDeformer(b.rest, b.faces, b.region_faces, bend=np.ones((e, 3)), pinned=b.pinned)
    except (ValueError, TypeError, RuntimeError):
        return False
    return True


# ----------------------------------------------------------------------------- learning variants


def uniform(_train):
    return None, None


def learned(anisotropic: bool = False, **kw) -> Stiffness:
    def f(train):
        bend, shear = md.learn_stiffness(
            BENCH.rest, BENCH.faces, train, anisotropic=anisotropic, **kw
        )
        return shear, bend

    return f


BENCH: Bench  # set in main(); the variant closures read it


def plot_anchors(b: Bench, path: Path) -> None:
    """Side and top views of the reference cat with the anchor regions highlighted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, (i, j, title) in zip(axes, [(2, 1, "side (z, y)"), (2, 0, "top (z, x)")], strict=True):
        ax.scatter(b.rest[:, i], b.rest[:, j], s=0.2, c="0.7")
        for (name, v), r in zip(b.points.items(), b.region_verts, strict=True):
            ax.scatter(b.rest[r, i], b.rest[r, j], s=1.5, label=name)
            ax.annotate(name, (b.rest[v, i], b.rest[v, j]), fontsize=8)
        ax.set_aspect("equal")
        ax.set_title(title)
    axes[0].legend(markerscale=6, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"  wrote {path}")


def fmt_row(name: str, errs: list[float], note: str = "") -> str:
    cells = " | ".join(f"{e:.4f}" for e in errs)
    return f"| {name} | {np.mean(errs):.4f} | {cells} |{(' ' + note) if note else ''}"


def main() -> None:
    global BENCH
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "data" / "cat-poses",
    )
    ap.add_argument("--no-blender", action="store_true")
    ap.add_argument("--explore", action="store_true", help="also run the learning variants")
    ap.add_argument("--plot", type=Path, help="write a PNG of the anchor regions (matplotlib)")
    ap.add_argument("--pose-space-only", action="store_true", help="only the pose-space rows")
    args = ap.parse_args()

    b = BENCH = Bench(args.data)
    print(f"cat: {len(b.rest)} vertices, {len(b.faces)} faces, diag {b.diag:.4f}")
    for (name, i), r, fs in zip(b.points.items(), b.region_verts, b.region_faces, strict=True):
        print(
            f"  anchor {name:16s} vertex {i:5d} at {np.round(b.rest[i], 3)}: "
            f"{len(r)} vertices, {len(fs)} faces"
        )
    print(f"  {len(b.pinned)} pinned vertices")
    if args.plot:
        plot_anchors(b, args.plot)

    header = "| method | mean | " + " | ".join(f"pose {k}" for k in range(1, 10)) + " |"
    print(header)
    print("|" + "---|" * 11)
    print(fmt_row("pose space, 8 examples", b.pose_space()), flush=True)
    print(fmt_row("pose space, 8 examples, coarse 1000 faces", b.pose_space(coarse=1000)))
    if args.pose_space_only:
        if args.explore:
            explore_pose_space(b)
        return
    print(fmt_row("uniform stiffness", b.run(uniform)))
    print(fmt_row("learned isotropic (paper)", b.run(learned())))
    print(fmt_row("learned isotropic (smoothing 30, eps 0.001)", b.run(learned(**TUNED))))
    name = "learned, region-level bending (region 2000, clamp 5%)"
    print(fmt_row(name, b.run(learned(**REGION))))
    if supports_anisotropic(b):
        for frame in ("rest", "world"):
            for label, kw in (("paper map", {}), ("smoothing 30, eps 0.001", TUNED)):
                name = f"learned anisotropic, {frame} axes ({label})"
                print(fmt_row(name, b.run(learned(True, frame=frame, **kw))))
    else:
        print("| learned anisotropic | pending: MaterialDeformer does not accept (E,3) bend yet |")
    for row in edge_rows(b):
        print(row)
    if hasattr(md, "PyramidDeformer"):
        print(fmt_row("pyramid coordinates (no stiffness; Newton, defaults)", b.pyramid()))
    if not args.no_blender:
        lap = b.laplacian()
        if lap is None:
            print("| Blender Laplacian Deform | skipped: blender not found |")
        else:
            errs, slip = lap
            print(fmt_row("Blender Laplacian Deform", errs, f"(max anchor slip {slip:.4f})"))
    if args.explore:
        explore(b)
        explore_edge(b)
        explore_pose_space(b)


def edge_errors(
    b: Bench, stretch: float, bend: float, iterations: int, tol: float = 1e-5, relaxation=1.0
):
    """Edge-based method (issue 13): only the anchor vertices are pinned at their pose
    positions (no rotations); each pose is solved from the rest mesh. Returns (errors,
    iterations used per pose)."""
    d = md.EdgeDeformer(b.rest, b.faces, b.pinned, stretch=stretch, bend=bend)
    errs, its = [], []
    for p in b.poses:
        x = d.solve(p[b.pinned], iterations=iterations, tol=tol, relaxation=relaxation)
        errs.append(rms_error(x, p, b.diag))
        its.append(d.last_iterations)
    return errs, its


def edge_rows(b: Bench) -> list[str]:
    """The edge-based rows of the main table, at the solver's defaults (stretch 1e-4, bend 1)."""
    rows = []
    variants = (
        ("to convergence (tol 1e-5, <= 2000 it.)", 2000, 1.0),
        ("15 iterations", 15, 1.0),
        ("relaxation 0.8, to convergence", 2000, 0.8),
    )
    for label, iterations, w in variants:
        errs, its = edge_errors(b, 1e-4, 1.0, iterations, relaxation=w)
        note = ""
        if iterations > 15:
            capped = sum(i >= iterations for i in its)
            note = f"(iterations: median {int(np.median(its))}, {capped} poses at the cap)"
        rows.append(fmt_row(f"edge-based, stretch 1e-4, bend 1, {label}", errs, note))
    return rows


def explore_edge(b: Bench) -> None:
    """Edge-based method over stretch (lambda) with bend 1: chosen on the test poses, so the
    best row is optimistic."""
    print("\nedge-based, stretch sweep (bend 1, tol 1e-5, <= 2000 iterations):")
    print("| variant | mean | " + " | ".join(f"pose {k}" for k in range(1, 10)) + " |")
    print("|" + "---|" * 11)
    for lam in (0.0, 1e-4, 1e-3, 1e-2, 1e-1):
        errs, its = edge_errors(b, lam, 1.0, 2000)
        print(fmt_row(f"stretch {lam:g}", errs, f"(iterations {its})"), flush=True)


def explore_pose_space(b: Bench) -> None:
    """Pose-space variants (docs/pose_space.md): each departs from the defaults in one option."""
    print("\npose-space variants (held-out error per pose, mean over the 9 poses):")
    print("| variant | mean | " + " | ".join(f"pose {k}" for k in range(1, 10)) + " |")
    print("|" + "---|" * 11)
    variants = {
        "handle positions only in the pose (orientation_weight 0)": dict(orientation_weight=0.0),
        "orientation_weight 0.3": dict(orientation_weight=0.3),
        "orientation_weight 3": dict(orientation_weight=3.0),
        "all dual edges weigh 1 (reliability_angle inf)": dict(reliability_angle=np.inf),
        "reliability_angle 0.2": dict(reliability_angle=0.2),
        "reliability_angle 1.0": dict(reliability_angle=1.0),
        "geodesic step 1 (3 Gauss-Newton steps)": dict(
            rotation_energy="geodesic", rotation_iterations=3
        ),
        "chordal step 1 converged (300 CG iterations)": dict(rotation_iterations=300),
        "no handle rotations in step 1": dict(handle_rotations=False),
        "convex weights": dict(convex_weights=True),
        "weight smoothing 0.05": dict(weight_regularization=0.05),
        "position_weight 10": dict(position_weight=10.0),
        "position_weight 1e4": dict(position_weight=1e4),
        "coarse 500 faces": dict(coarse=500),
        "coarse 2000 faces": dict(coarse=2000),
        "coarse 4000 faces": dict(coarse=4000),
    }
    for name, kw in variants.items():
        print(fmt_row(name, b.pose_space(**kw)), flush=True)


# Defaults of learn_stiffness are the paper's recipe. TUNED is the best variant explore() found
# on these same 9 folds (so its number is optimistic; explore() also reports an honest nested
# selection). See docs/quality.md.
TUNED: dict = dict(smoothing=30, eps=0.001)
# Bending from the region-level rotation spread (md.rotation_spread). Also picked on these folds,
# but the nested selection in explore() picks exactly this setting in every fold.
REGION: dict = dict(region=2000, smoothing=30, clamp_percent=5.0)


def explore(b: Bench) -> None:
    """Learning variants, each strictly held-out (the reconstructed pose is never used).

    Per-pose distortions are computed once with md.learn_distortions on single poses; their max
    over the 8 training poses is exactly what learn_distortions returns for the set.
    """
    pairs = md.dual_edges(b.faces)
    per_pose = [md.learn_distortions(b.rest, b.faces, [p]) for p in b.poses]
    pb = np.stack([x[0] for x in per_pose])  # (9,E)
    ps = np.stack([x[1] for x in per_pose])  # (9,m)
    n_poses = len(b.poses)
    aggregates = {
        "max": lambda x: x.max(0),
        "mean": lambda x: x.mean(0),
        "rms": lambda x: np.sqrt((x**2).mean(0)),
        "2nd largest": lambda x: np.sort(x, 0)[-2],
    }

    def distortions(excluded, agg="max", smoothing=0):
        keep = [s for s in range(n_poses) if s not in excluded]
        bd, sd = aggregates[agg](pb[keep]), aggregates[agg](ps[keep])
        return md.smooth_distortions(b.faces, bd, sd, smoothing) if smoothing else (bd, sd)

    def inverse(d, delta, clamp=1.0):
        top = np.percentile(d, 100 - clamp)
        return delta / (np.minimum(d, top) / top + delta)

    def mapped(agg="max", smoothing=0, bend=True, shear=True, **kw):
        """Variant: (held-out pose, excluded set) -> (shear, bend) with the library map."""

        def f(excluded):
            bd, sd = distortions(excluded, agg, smoothing)
            sb = md.stiffness_from_distortion(bd, **kw) if bend else np.ones_like(bd)
            ss = md.stiffness_from_distortion(sd, **kw) if shear else np.ones_like(sd)
            return ss, sb

        return f

    def held_out(f):
        return [rms_error(b.reconstruct(h, *f({h})), b.poses[h], b.diag) for h in range(n_poses)]

    # Diagnostic only (hand-painted, not learned): everything soft in bending in the torso.
    c = b.rest[b.faces].mean(1)
    lo, hi = b.rest.min(0), b.rest.max(0)
    rel = (c - lo) / (hi - lo)
    torso = (rel[:, 1] > 0.44) & (rel[:, 2] > 0.32) & (rel[:, 2] < 0.84)
    torso_bend = np.where(torso[pairs[:, 0]] & torso[pairs[:, 1]], 0.01, 1.0)

    variants = {
        "paper: linear, eps 0.01, clamp 1%": mapped(),
        "bend from learned shear (psi_i+psi_j)/2": lambda ex: (mapped()(ex)[0], None),
        "bend learned, shear uniform": mapped(shear=False),
        "shear learned, bend uniform": mapped(bend=False),
    }
    for eps in (0.001, 0.05, 0.2):
        variants[f"eps {eps}"] = mapped(eps=eps)
    for clamp in (0.0, 2.0, 5.0, 10.0, 20.0):
        variants[f"clamp {clamp:g}%"] = mapped(clamp_percent=clamp)
    for a in (3.0, 10.0, 30.0):
        variants[f"exponential falloff, sharpness {a:g}"] = mapped(sharpness=a)
    for delta in (0.01, 0.03, 0.1):
        variants[f"inverse map delta/(u+delta), delta {delta:g}"] = lambda ex, delta=delta: tuple(
            inverse(d, delta) for d in distortions(ex)[::-1]
        )
    for agg in ("mean", "rms", "2nd largest"):
        variants[f"aggregate {agg} over poses, clamp 5%"] = mapped(agg, clamp_percent=5.0)
    for k in (3, 10, 30, 100, 300):
        variants[f"smoothing {k}, clamp 1%"] = mapped(smoothing=k)
        variants[f"smoothing {k}, clamp 5%"] = mapped(smoothing=k, clamp_percent=5.0)
    variants["smoothing 30, clamp 1%, eps 0.001"] = mapped(smoothing=30, eps=0.001)
    variants["diagnostic, NOT learned: bend 0.01 in a hand-picked torso box"] = lambda ex: (
        None,
        torso_bend,
    )

    print("\nexploration (held-out error per pose, mean over the 9 poses):")
    print("| variant | mean | " + " | ".join(f"pose {k}" for k in range(1, 10)) + " |")
    print("|" + "---|" * 11)
    for name, f in variants.items():
        print(fmt_row(name, held_out(f)), flush=True)

    # Honest model selection: for each held-out pose h, pick the candidate with the lowest
    # leave-one-out error on the 8 training poses (stiffness learned from the other 7), then
    # learn from all 8 with it and reconstruct h. inner[(h, s)]: error on s learned without h, s.
    candidates = {
        f"smoothing {k}, clamp {c:g}%": mapped(smoothing=k, clamp_percent=c)
        for k in (0, 10, 30, 100)
        for c in (1.0, 5.0)
    }
    inner = {
        name: {
            (h, s): rms_error(b.reconstruct(s, *f({h, s})), b.poses[s], b.diag)
            for h in range(n_poses)
            for s in range(n_poses)
            if s != h
        }
        for name, f in candidates.items()
    }
    errs, picks = [], []
    for h in range(n_poses):
        train = [s for s in range(n_poses) if s != h]
        score = {name: np.mean([tab[(h, s)] for s in train]) for name, tab in inner.items()}
        best = min(score, key=score.get)
        picks.append(best)
        errs.append(rms_error(b.reconstruct(h, *candidates[best]({h})), b.poses[h], b.diag))
    print(fmt_row("nested leave-one-out selection of smoothing x clamp", errs))
    print("  picked per pose: " + "; ".join(f"{k + 1}: {p}" for k, p in enumerate(picks)))
    explore_region(b, pb, ps)


def explore_region(b: Bench, pb: np.ndarray, ps: np.ndarray) -> None:
    """Region-level bending (learn_stiffness(region=k)): per-pose rotation spreads are computed
    once per k (column s depends on pose s only) and their max taken over the training poses,
    which is exactly what learn_stiffness does with the training set."""
    pairs = md.dual_edges(b.faces)
    n_poses = len(b.poses)
    ks = (300, 1000, 2000, 4000, 8000)
    spread = {k: md.rotation_spread(b.rest, b.faces, b.poses, k) for k in ks}  # (m, 9) each

    def region(k, clamp, eps=0.01, smoothing=30):
        def f(excluded):
            keep = [s for s in range(n_poses) if s not in excluded]
            fd = spread[k][:, keep].max(1)
            bd = 0.5 * (fd[pairs[:, 0]] + fd[pairs[:, 1]])
            sd = ps[keep].max(0)
            if smoothing:
                sd = md.smooth_distortions(b.faces, pb[keep].max(0), sd, smoothing)[1]
            kw = dict(eps=eps, clamp_percent=clamp)
            return md.stiffness_from_distortion(sd, **kw), md.stiffness_from_distortion(bd, **kw)

        return f

    def err(f, test, excluded):
        return rms_error(b.reconstruct(test, *f(excluded)), b.poses[test], b.diag)

    print("\nregion-level bending (rotation spread over k passes; shear smoothing 30, eps 0.01):")
    print("| variant | mean | " + " | ".join(f"pose {k}" for k in range(1, 10)) + " |")
    print("|" + "---|" * 11)
    candidates = {f"region {k}, clamp {c:g}%": region(k, c) for k in ks for c in (1.0, 5.0)}
    outer = {}
    for name, f in candidates.items():
        outer[name] = [err(f, h, {h}) for h in range(n_poses)]
        print(fmt_row(name, outer[name]), flush=True)
    for name, f in {
        "region 2000, clamp 5%, eps 0.001": region(2000, 5.0, eps=0.001),
        "region 2000, clamp 5%, shear not smoothed": region(2000, 5.0, smoothing=0),
    }.items():
        print(fmt_row(name, [err(f, h, {h}) for h in range(n_poses)]), flush=True)
    # Nested: pick k x clamp by leave-one-out on the 8 training poses, then apply to h.
    errs, picks = [], []
    for h in range(n_poses):
        train = [s for s in range(n_poses) if s != h]
        score = {
            name: np.mean([err(f, s, {h, s}) for s in train]) for name, f in candidates.items()
        }
        best = min(score, key=score.get)
        picks.append(best)
        errs.append(outer[best][h])
    print(fmt_row("nested leave-one-out selection of region x clamp", errs))
    print("  picked per pose: " + "; ".join(f"{k + 1}: {p}" for k, p in enumerate(picks)))


if __name__ == "__main__":
    main()
