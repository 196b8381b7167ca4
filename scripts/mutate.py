"""Mutation runner: does the test suite catch the bugs it is meant to catch?

Each entry of MUTATIONS is one small, realistic bug: an exact piece of source text and what it
becomes. For each, the runner applies it to a scratch copy of the working tree, rebuilds the
C++ tests and the Python extension there, runs the C++ suite and then the Python suite (both
stop at the first failure), restores the file and prints a table: caught (by which test) or
not caught. A test that cannot fail is a defect, so every mutation here must be caught.

Not part of CI (a few minutes per mutation on 2 cores). Run it after changing a solver or its
tests; every new solver mode adds its own mutations to the list (docs/testing.md).

    .venv/bin/python scripts/mutate.py                # all mutations, table at the end
    .venv/bin/python scripts/mutate.py --only W3,B5   # some of them
    .venv/bin/python scripts/mutate.py --list         # the list, nothing run

The scratch copy lives in /tmp (--scratch) and is kept between runs, so later runs rebuild only
what changed. Blender suites are not run (too slow); a mutation the numpy-level suites miss is
a missing test there too.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutation:
    id: str
    file: str  # relative to the repository root
    old: str  # must occur exactly once in the file
    new: str
    what: str


M = Mutation
MUTATIONS = [
    # Issue 18's audit: the seven the suite let through.
    M(
        "W3",
        "native/src/stiffness.cpp",
        "phi(e) = 0.5 * (shear(pairs(e, 0)) + shear(pairs(e, 1)));",
        "phi(e) = 0.5 * (shear(pairs(e, 0)) + shear(pairs(e, 0)));",
        "bend_from_shear uses face f twice",
    ),
    M(
        "B3",
        "native/src/deformer.cpp",
        "mean_weights_ = (axis_weights_[0] + axis_weights_[1] + axis_weights_[2]) / 3.0;",
        "mean_weights_ = axis_weights_[0];",
        "anisotropic `weights` returns axis 0, not the mean of the axes",
    ),
    M(
        "B5",
        "native/src/transforms.cpp",
        "    sum.similarity = sum.similarity && logs[a].similarity;\n",
        "",
        "a non-similarity anchor blend is flagged as a similarity",
    ),
    M(
        "R3",
        "native/src/deformer.cpp",
        "      p /= static_cast<double>(e - b);\n",
        "",
        "a vertex shared by two anchors takes the sum of their transforms, not the mean",
    ),
    M(
        "L1",
        "native/src/learn.cpp",
        ": log_difference(logs[i], logs[j]);",
        ": Eigen::Vector3d(logs[j] - logs[i]);",
        "world-frame learning skips the closest log near pi",
    ),
    M(
        "L2",
        "native/src/learn.cpp",
        "if (!valid[i] || !valid[j]) continue;",
        "if (!valid[i]) continue;",
        "a dual edge to a face collapsed in the pose is not skipped",
    ),
    M(
        "L4",
        "native/src/learn.cpp",
        "squaredNorm() / (w * w));",
        "squaredNorm() / w);",
        "rotation_spread divides by w, not w^2",
    ),
    # More of the same kinds, one per code path the suite should reach.
    M(
        "L5",
        "native/src/learn.cpp",
        "std::max(out.bend(e, 0), (Q[i] - Q[j]).squaredNorm());",
        "std::max(out.bend(e, 0), (Q[i] - Eigen::Matrix3d::Identity()).squaredNorm());",
        "isotropic learning measures each face's own rotation, not the one between the faces",
    ),
    M(
        "V1",
        "native/src/stiffness.cpp",
        "(s(faces(f, 0)) + s(faces(f, 1)) + s(faces(f, 2))) / 3.0;",
        "(s(faces(f, 0)) + s(faces(f, 1)) + s(faces(f, 1))) / 3.0;",
        "shear_from_vertex reads a face's second vertex twice",
    ),
    M(
        "B6",
        "native/src/transforms.cpp",
        "    sum.similarity = all_similar;\n",
        "    sum.similarity = true;\n",
        "the anisotropic blend flags a stretched anchor as a similarity",
    ),
    M(
        "AX1",
        "native/src/transforms.cpp",
        "C.col(a) = axes.transpose() * logs[static_cast<size_t>(a)].rotation;",
        "C.col(a) = logs[static_cast<size_t>(a)].rotation;",
        "the anisotropic blend reads the rotation logs in mesh axes, not the given axes",
    ),
    M(
        "RG1",
        "native/src/deformer.cpp",
        "if (outside_use[sub_vertices_[s]]) boundary_.push_back(static_cast<int>(s));",
        "if (outside_use[sub_vertices_[s]] && s == 0) boundary_.push_back(static_cast<int>(s));",
        "a region's boundary vertices are not held at rest (all but the first)",
    ),
    M(
        "H1",
        "native/src/weights.cpp",
        "couplings.push_back({ug, anchor_of[f], w});",
        "couplings.push_back({ug, anchor_of[f], 0.0 * w});",
        "harmonic weights drop the boundary term of an anchor face numbered before its neighbour",
    ),
    M(
        "UF1",
        "native/src/mesh.cpp",
        "  b = find(b);\n",
        "",
        "union-find links a stale root (the issue-11 bug: parts cut off for some vertex orders)",
    ),
    M(
        "SC1",
        "native/src/sparse_cholesky.cpp",
        "sched.jobs.emplace_back(first[r], r + 1);",
        "sched.jobs.emplace_back(first[r], r);",
        "parallel substitution leaves each subtree's root out (only the threaded path)",
    ),
    M(
        "SC2",
        "native/src/sparse_cholesky.cpp",
        "y[sched.slot_row[q]] += sl[q];",
        "y[sched.slot_row[q]] -= sl[q];",
        "parallel substitution subtracts the subtrees' updates of the top separators twice over",
    ),
    M(
        "SC3",
        "native/src/sparse_cholesky.cpp",
        "const double* tc = tri + static_cast<size_t>(c) * (c - 1) / 2;",
        "const double* tc = tri + static_cast<size_t>(c) * (c + 1) / 2;",
        "backward substitution reads the supernode triangle's next row (packed offset)",
    ),
    M(
        "P1",
        "native/src/pyramid_energy.cpp",
        "coef[0] = 2.0 / (s0 * (1 + kappa));",
        "coef[0] = 2.0 / s0;",
        "pyramid Hessian: the scale term forgets the size weight kappa",
    ),
    M(
        "P2",
        "native/src/pyramid_energy.cpp",
        "coef[i + 1] = std::abs(g) > floor ? 2.0 * fit.scale / g : 0.0;",
        "coef[i + 1] = std::abs(g) > floor ? 2.0 / g : 0.0;",
        "pyramid Hessian: the rotation terms forget the pyramid's scale",
    ),
    M(
        "P5",
        "native/src/pyramid_energy.cpp",
        "coef[j] = std::min(lam, 2.0);",
        "coef[j] = lam;",
        "the positive semidefinite pyramid Hessian is not clamped (indefinite far from rest)",
    ),
    M(
        "P7",
        "native/src/pyramid_deformer.cpp",
        "s += 2.0 * (x - f.centre - f.scale * (f.R * Vec3(p[0], p[1], p[2])));",
        "s += 2.0 * (x - f.centre - f.R * Vec3(p[0], p[1], p[2]));",
        "pyramid gradient: the fitted scale is left out (rigid targets)",
    ),
    # Session 13: the anchor vertices' transforms looked up at construction.
    M(
        "D1",
        "native/src/deformer.cpp",
        "const bool follow = has_translation && &rep == follow_.get();",
        "const bool follow = &rep == follow_.get();",
        "pinned anchor vertices follow their anchor's linear part with 3x3 transforms too",
    ),
    M(
        "D2",
        "native/src/deformer.cpp",
        "range = {av_offsets_[j], av_offsets_[j + 1]};",
        "range = {av_offsets_[j], av_offsets_[j] + 1};",
        "a vertex shared by two anchors follows only the first",
    ),
    M(
        "D3",
        "native/src/deformer.cpp",
        "if (!std::binary_search(boundary_.begin(), boundary_.end(), v) &&\n        it != ",
        "if (it != ",
        "a region-boundary vertex of an anchor face follows the anchor instead of staying at rest",
    ),
    # Session 10: the blend's weight reads and lane fallbacks, the pyramid's in-place sweeps.
    M(
        "T1",
        "native/src/transforms.cpp",
        "if (any_lane(t2 > kSeriesMaxT2)) {",
        "if (false && any_lane(t2 > kSeriesMaxT2)) {",
        "blended angles beyond the Rodrigues series' range keep the series",
    ),
    M(
        "T2",
        "native/src/transforms.cpp",
        "if (any_lane(s * s > 490000.0)) {",
        "if (false && any_lane(s * s > 490000.0)) {",
        "the vector exp's 2^n is used beyond its exponent range",
    ),
    M(
        "T3",
        "native/src/transforms.cpp",
        "(W)[static_cast<size_t>(f0 + 2) * (k) + (a)]",
        "(W)[static_cast<size_t>(f0 + 1) * (k) + (a)]",
        "a full face group's third face takes the second face's weights",
    ),
    M(
        "P8",
        "native/src/pyramid_start.cpp",
        "    for (int i = 0; i < u; ++i) field.row(S.field_vertex[static_cast<size_t>(i)]) = "
        "sol.row(i);",
        "",
        "the start's rotation field is not interpolated (the overall fit everywhere)",
    ),
    # Session 11: the quaternion rotation fit the pyramid's followers use.
    M(
        "T4",
        "native/src/transforms.cpp",
        "{{sxx + syy + szz, syz - szy,",
        "{{sxx + syy + szz, szy - syz,",
        "Horn's matrix gets one antisymmetric entry with the wrong sign",
    ),
    M(
        "T5",
        "native/src/transforms.cpp",
        "for (const double below : {1e-3, 1e-5}) {",
        "for (const double below : {1e-300}) {",
        "the rotation fit never refines a root found near a small eigenvalue gap",
    ),
    M(
        "T6",
        "native/src/transforms.cpp",
        "constexpr double kRefuse = 1e-6;",
        "constexpr double kRefuse = 1e-9;",
        "the rotation fit accepts eigenvalue gaps too small for its Newton root",
    ),
    M(
        "T7",
        "native/src/transforms.cpp",
        "const Vec4m fast = (qn > 1e-3 * cube)",
        "const Vec4m fast = (qn > 1e-9 * cube)",
        "the four-lane rotation fit keeps unrefined roots near small eigenvalue gaps",
    ),
    M(
        "T8",
        "native/src/transforms.cpp",
        "H[0].data()[e], H[1].data()[e], H[2].data()[e], H[3].data()[e]",
        "H[0].data()[e], H[1].data()[e], H[1].data()[e], H[3].data()[e]",
        "the four-lane rotation fit reads the second matrix into the third lane",
    ),
    M(
        "T9",
        "native/src/transforms.cpp",
        "(qn > 1e-3 * cube) & (qn < Vec4d{inf, inf, inf, inf})",
        "(qn > 1e-3 * cube) & (qn > -Vec4d{inf, inf, inf, inf})",
        "the four-lane rotation fit accepts an adjugate whose squared norm overflowed (R = 0)",
    ),
    M(
        "P4",
        "native/src/pyramid_coordinates.cpp",
        "weight[i] = w / length[i];",
        "weight[i] = w;",
        "mean-value weights without the 1/l_i factor",
    ),
    M(
        "P10",
        "native/src/pyramid_deformer.cpp",
        "const double Et = S.fit_all(trial.data(), kappa, false);\n"
        "        if (std::isfinite(Et) && Et <= E + 1e-4 * alpha * slope + noise) {",
        "const double Et = S.fit_all(trial.data(), kappa, false);\n"
        "        if (std::isfinite(Et)) {",
        "pyramid Newton: every step is accepted, also one that raises the energy",
    ),
    M(
        "P11",
        "native/src/pyramid_deformer.cpp",
        "      if (!S.moving[static_cast<size_t>(v)]) X.row(v) = S.placement.rest.row(v);",
        "",
        "a warm start moves a part no control reaches away from rest",
    ),
    # The pyramid's L-BFGS phase before Newton's method.
    M(
        "Q5",
        "native/src/pyramid_deformer.cpp",
        "if (!(v.dot(Ap) < 0)) return false;",
        "return false;",
        "saddles: no step along negative curvature (the iterate leaves by round-off)",
    ),
    M(
        "Q1",
        "native/src/pyramid_deformer.cpp",
        "          Et = S.fit_all(trial.data(), kappa, &S.trial_fits);\n"
        "          if (std::isfinite(Et) && Et <= E + 1e-4 * alpha * slope + noise) {",
        "          Et = S.fit_all(trial.data(), kappa, &S.trial_fits);\n"
        "          if (std::isfinite(Et)) {",
        "pyramid L-BFGS: every step is accepted, also one that raises the energy",
    ),
    M(
        "Q2",
        "native/src/pyramid_deformer.cpp",
        "d += (a_hist[i] - b) * hs[i];",
        "d += (b - a_hist[i]) * hs[i];",
        "pyramid L-BFGS: the two-loop recursion's second loop corrects the wrong way",
    ),
    M(
        "Q3",
        "native/src/pyramid_deformer.cpp",
        "tri.emplace_back(I, J, 2.0 * ((I == J ? 1.0 : 0.0) - 1.0 / M));",
        "tri.emplace_back(I, J, 2.0 * ((I == J ? 1.0 : 0.0) - 0.5 / M));",
        "pyramid L-BFGS: the constant matrix's off-diagonal coupling is halved",
    ),
    M(
        "Q4",
        "native/src/pyramid_deformer.cpp",
        "        if (sy > 1e-12 * alpha * d.norm() * q.norm()) {",
        "        if (false && sy > 1e-12 * alpha * d.norm() * q.norm()) {",
        "pyramid L-BFGS keeps no correction pairs (the local-global step alone)",
    ),
    M(
        "Q6",
        "native/src/pyramid_deformer.cpp",
        "        if (pairs > 0) d *= gamma;",
        "",
        "pyramid L-BFGS: the initial inverse Hessian C^-1 is not scaled by gamma",
    ),
    M(
        "Q7",
        "native/src/pyramid_deformer.cpp",
        "          hcy[i] = S.cg_new - S.cg;",
        "          hcy[i] = S.cg_new;",
        "pyramid L-BFGS: C^-1 y kept as C^-1 g_new (the two-loop's C^-1 q is wrong)",
    ),
    M(
        "Q8",
        "native/src/pyramid_deformer.cpp",
        "    if (tight && step <= limit) {",
        "    if (newton && step <= limit) {",
        "pyramid Newton: the stopping rule trusts a step solved only to 1e-3",
    ),
    M(
        "Q9",
        "native/src/pyramid_deformer.cpp",
        "const double eta = tight ? kTightEta : newton ? kLooseEta : 1e-2;",
        "const double eta = newton ? kLooseEta : 1e-2;",
        "pyramid Newton: every Newton step is solved only to 1e-3, the last ones too",
    ),
    M(
        "Q10",
        "native/src/pyramid_deformer.cpp",
        "        exact = false;\n        --last_iterations_;\n        continue;\n",
        "        exact = false;\n",
        "pyramid Newton: a rejected exact step spends the iteration (a live chain can stall)",
    ),
    M(
        "RP1",
        "native/src/reposition.cpp",
        "y -= k * p[a.nfix];",
        "y -= k * p[0];",
        "repositioning: a pinned vertex's y coupling reads its x coordinate",
    ),
    # Edge-based iterative deformation (edge_deformer.cpp).
    M(
        "E1",
        "native/src/edge_deformer.cpp",
        "const Vec4d am = one - al, bm = be - one;",
        "const Vec4d am = one - al, bm = one - be;",
        "estimation kernel: D_sig^T scatters the wrong sign onto the fourth vertex m",
    ),
    M(
        "E2",
        "native/src/edge_deformer.cpp",
        "        fv -= fv.dot(u) * u;\n",
        "",
        "anisotropy keeps the normal part of the direction field (Eq. 13 uses the tangential one)",
    ),
    M(
        "E3",
        "native/src/edge_deformer.cpp",
        "load_soa(a.P, t.m, &xm, &ym, &zm);",
        "load_soa(a.P, t.l, &xm, &ym, &zm);",
        "estimation kernel reads vertex l where it means m (the bending normal collapses)",
    ),
    M(
        "E4",
        "native/src/edge_deformer.cpp",
        "(!used[v] || !root_fixed[sets.find(v)])",
        "(!used[v])",
        "a part (through edges) without a constrained vertex is left free, not passive",
    ),
    M(
        "E5",
        "native/src/edge_deformer.cpp",
        "0.5 * options.gravity(1), 0.5 * options.gravity(2),",
        "0.5 * options.gravity(2), 0.5 * options.gravity(2),",
        "gravity: the y component of g reads its z component",
    ),
    M(
        "E6",
        "native/src/edge_deformer.cpp",
        "std::fill(d.acc[p].begin(), d.acc[p].begin() + 4 * static_cast<size_t>(nf), 0.0);",
        "",
        "parallel estimation: a later part's accumulator keeps the last iteration (threaded)",
    ),
    M(
        "E7",
        "native/src/edge_deformer.cpp",
        "next[r] = w == 1.0 ? Y[r] : cur[r] + w * dv;",
        "next[r] = w == 1.0 ? Y[r] : cur[r] + dv;",
        "relaxation: the step is not scaled by w",
    ),
    M(
        "E8",
        "native/src/edge_deformer.cpp",
        "if (rho < 1.0) error = move * rho / (1.0 - rho);",
        "error = move;",
        "stopping rule: a small last move taken for a small distance to the fixed point",
    ),
    # Pose-space manipulation (native/src/pose_space_*.cpp).
    M(
        "S1",
        "native/src/pose_space_encoding.cpp",
        "rotation_log(R[ldual(e, 0)].transpose() * R[ldual(e, 1)]).transpose();",
        "rotation_log(R[ldual(e, 1)].transpose() * R[ldual(e, 0)]).transpose();",
        "examples' relative rotations encoded the wrong way round (b to a)",
    ),
    M(
        "S2",
        "native/src/pose_space_interpolation.cpp",
        "phi(l) = den > 0.0 ? (p0 - pl).dot(2.0 * x - pl - p0) / den : 0.0;",
        "phi(l) = den > 0.0 ? (p0 - pl).dot(2.0 * x - pl - p0) : 0.0;",
        "pose weights evaluate phi(r) = r^2 while the system was solved for phi(r) = r",
    ),
    M(
        "S3",
        "native/src/pose_space_multires.cpp",
        "  return M * d;\n",
        "  return d;\n",
        "multiresolution: detail vectors are not rotated with their coarse neighbours",
    ),
    M(
        "S4",
        "native/src/pose_space_encoding.cpp",
        "pack_sym(R[i].transpose() * T[i], &stretch(i, 6 * k));",
        "pack_sym(T[i] * R[i].transpose(), &stretch(i, 6 * k));",
        "examples' stretch taken as the left polar factor (world frame), not the rest frame",
    ),
    M(
        "S5",
        "native/src/pose_space_rotations.cpp",
        "acc += (adj_[k] & 1 ? lw_[l] : -lw_[l]) * d_[l];",
        "acc += (adj_[k] & 1 ? -lw_[l] : lw_[l]) * d_[l];",
        "geodesic Gauss-Newton: the link residual enters with the wrong sign at both ends",
    ),
    M(
        "S6",
        "native/src/pose_space_interpolation.cpp",
        "    w = w.cwiseMax(0.0);\n",
        "",
        "convex pose weights are not clipped at zero",
    ),
    M(
        "S7",
        "native/src/pose_space_rotations.cpp",
        "(*face_turns)[f] - phi_[f]",
        "(*face_turns)[f]",
        "turns: a handle face's residual keeps its start's branch after the steps taken",
    ),
    M(
        "S8",
        "native/src/pose_space_rotations.cpp",
        "const bool pair_branch = pair_turns && G;",
        "const bool pair_branch = false;",
        "turns: the joints' rotation vectors are ignored (principal logs)",
    ),
    M(
        "S9",
        "native/src/pose_space_deformer.cpp",
        "    if (err <= tolerance) return;\n",
        "    if (err <= 10 * tolerance) return;\n",
        "turns: rotation vectors 10x farther from their rotation are accepted",
    ),
    # Turns past half a turn: rotation vectors and their unwrapping.
    M(
        "TW1",
        "native/src/deformer.cpp",
        "(*logs)[a].rotation = v.row(static_cast<Eigen::Index>(a));",
        "(*logs)[a].rotation = rotation_log(rotation_exp(v.row(static_cast<Eigen::Index>(a))));",
        "given rotation vectors are re-wrapped to the principal branch",
    ),
    M(
        "TW2",
        "native/src/transforms.cpp",
        "if (!(err <= kRotationVectorTolerance)) {",
        "if (!(err <= 100 * kRotationVectorTolerance)) {",
        "rotation vectors 100x farther from their anchor's rotation are accepted",
    ),
    M(
        "TW3",
        "native/src/deformer.cpp",
        "rotation_exp((*logs)[a].rotation),",
        "rotation_exp((*logs)[0].rotation),",
        "every rotation vector is checked against anchor 0's rotation",
    ),
    M(
        "PT1",
        "native/src/pyramid_start.cpp",
        "const bool logs = rotation_vectors != nullptr && !S.rot.empty();",
        "const bool logs = false;",
        "the pyramid start ignores the given rotation vectors (quaternions: principal turns)",
    ),
    M(
        "PT2",
        "native/src/pyramid_start.cpp",
        "const Vec3 r = rotation_log_near(R, near / static_cast<double>(cl.size()));",
        "const Vec3 r = rotation_log(R);",
        "a control cluster blends the principal log of its rotation, not the given branch",
    ),
    M(
        "TW4",
        "native/src/transforms.cpp",
        "best = (theta + kTwoPi * std::round((u.dot(near) - theta) / kTwoPi)) * u;",
        "best = (theta + kTwoPi * std::floor((u.dot(near) - theta) / kTwoPi)) * u;",
        "unwrapping picks the whole turns below the previous vector, not the nearest",
    ),
    M(
        "TW5",
        "native/src/transforms.cpp",
        "if (theta <= kRotationVectorTolerance && len >= 0.5 * kTwoPi) {",
        "if (false) {",
        "at a whole turn the identity's noisy axis replaces the previous vector's",
    ),
    M(
        "TW6",
        "native/src/transforms.cpp",
        "return (((t - k * kTwoPiHi) - k * kTwoPiMid) - k * kTwoPiLo) / t;",
        "return ((t - k * kTwoPiHi) - k * kTwoPiLo) / t;",
        "whole turns are taken out with 2 pi rounded to float (off by 1.7e-7 rad per turn)",
    ),
    M(
        "TW7",
        "src/matdeform/deformer.py",
        "return self._core.deform(t, pp, rv)",
        "return self._core.deform(t, pp, None)",
        "the numpy API drops rotation_vectors (float64 result)",
    ),
]


def run(cmd, cwd, timeout, env=None):
    """(status, output): status 0 ok, None timed out, else the exit code."""
    try:
        p = subprocess.run(
            cmd,
            cwd=cwd,
            env=env,
            timeout=timeout,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
        )
    except subprocess.TimeoutExpired as e:
        out = e.stdout.decode(errors="replace") if isinstance(e.stdout, bytes) else e.stdout
        return None, out or ""
    return p.returncode, p.stdout


class Scratch:
    """A copy of the working tree with its own build, kept between runs."""

    def __init__(self, base: Path, jobs: int):
        self.base = base
        self.repo = base / "repo"
        self.build = self.repo / "build" / "mutate"
        self.jobs = jobs
        self.python = ROOT / ".venv" / "bin" / "python"
        self.env = dict(os.environ, PYTHONPATH=str(self.repo / "src"))
        self.env.pop("MD_FUZZ_N", None)

    def sync(self):
        """Copy the tracked and untracked (not ignored) files; only changed ones, so that the
        build stays incremental. Files gone from the working tree go here too."""
        out = subprocess.run(
            ["git", "ls-files", "-z", "-co", "--exclude-standard"],
            cwd=ROOT,
            check=True,
            capture_output=True,
        ).stdout.decode()
        wanted = set()
        for rel in filter(None, out.split("\0")):
            src = ROOT / rel
            if src.is_symlink() or not src.is_file():
                continue
            wanted.add(rel)
            dst = self.repo / rel
            if dst.is_file() and dst.read_bytes() == src.read_bytes():
                continue
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, dst)  # a fresh mtime: ninja sees the change
            shutil.copymode(src, dst)
        for top, dirs, files in os.walk(self.repo):
            if Path(top) == self.repo:
                dirs[:] = [d for d in dirs if d != "build"]
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            for name in files:
                path = Path(top) / name
                if path.relative_to(self.repo).as_posix() not in wanted:
                    path.unlink()  # gone from the tree, or the extension link (made anew)

    def configure(self):
        if (self.build / "build.ninja").exists():
            return
        pybind = subprocess.run(
            [str(self.python), "-c", "import pybind11; print(pybind11.get_cmake_dir())"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
        cmd = [
            str(ROOT / ".venv" / "bin" / "cmake"),
            "-S",
            str(self.repo),
            "-B",
            str(self.build),
            "-G",
            "Ninja",
            f"-DCMAKE_MAKE_PROGRAM={ROOT / '.venv' / 'bin' / 'ninja'}",
            "-DCMAKE_BUILD_TYPE=Release",
            "-DMATDEFORM_BUILD_TESTS=ON",
            "-DMATDEFORM_BUILD_PYTHON=ON",
            f"-DPython_EXECUTABLE={self.python}",
            f"-Dpybind11_DIR={pybind}",
        ]
        status, out = run(cmd, self.repo, 600)
        if status != 0:
            sys.exit(f"configure failed:\n{out[-3000:]}")

    def make(self) -> tuple[bool, str]:
        cmd = [str(ROOT / ".venv" / "bin" / "cmake"), "--build", str(self.build)]
        cmd += ["-j", str(self.jobs), "--target", "matdeform_tests", "_core"]
        status, out = run(cmd, self.repo, 3600)
        if status != 0:
            return False, out
        # The freshly built extension, where `import matdeform` from src/ finds it.
        (so,) = (self.build / "native" / "python").glob("_core*.so")
        link = self.repo / "src" / "matdeform" / so.name
        if not link.is_symlink():
            link.symlink_to(so)
        return True, out

    def test(self, suites) -> tuple[str, str]:
        """('passed', '') or ('caught', first failing test) or ('caught', 'timeout ...')."""
        if "cpp" in suites:
            exe = self.build / "tests" / "cpp" / "matdeform_tests"
            status, out = run([str(exe), "--gtest_fail_fast", "--gtest_brief=1"], self.build, 900)
            if status is None:
                return "caught", "C++ suite timed out (a hang)"
            if status != 0:
                m = re.search(r"\[  FAILED  \] (\S+)", out)
                return "caught", f"C++ {m.group(1) if m else f'exit {status}'}"
        if "python" in suites:
            cmd = [str(self.python), "-m", "pytest", "-x", "-q", "-rf", "-p", "no:cacheprovider"]
            status, out = run(cmd + ["tests/python"], self.repo, 1800, self.env)
            if status is None:
                return "caught", "Python suite timed out (a hang)"
            if status != 0:
                m = re.search(r"^FAILED (\S+)", out, re.M) or re.search(r"^ERROR (\S+)", out, re.M)
                return "caught", m.group(1) if m else f"pytest exit {status}: {out[-500:]}"
        return "passed", ""

    def check_import(self):
        code = "import matdeform; print(matdeform.__file__)"
        status, out = run([str(self.python), "-c", code], self.base, 60, self.env)
        if status != 0 or not out.strip().startswith(str(self.repo)):
            sys.exit(f"the scratch copy's matdeform is not the one imported: {out}")


def apply(m: Mutation, repo: Path) -> str | None:
    """Mutates the file in the scratch copy; returns its original text, None if stale."""
    path = repo / m.file
    text = path.read_text()
    if text.count(m.old) != 1:
        return None
    path.write_text(text.replace(m.old, m.new))
    return text


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", help="comma-separated mutation ids")
    ap.add_argument("--list", action="store_true", help="print the mutations and exit")
    ap.add_argument("--suites", default="cpp,python", help="cpp, python or both (default)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scratch", default=f"/tmp/matdeform-mutate-{ROOT.name}")
    ap.add_argument("--no-baseline", action="store_true", help="skip the unmutated run")
    args = ap.parse_args()
    chosen = MUTATIONS
    if args.only:
        ids = args.only.split(",")
        unknown = set(ids) - {m.id for m in MUTATIONS}
        if unknown:
            sys.exit(f"unknown mutation ids: {sorted(unknown)}")
        chosen = [m for m in MUTATIONS if m.id in ids]
    if args.list:
        for m in chosen:
            print(f"{m.id:4} {m.file}: {m.what}")
        return 0
    suites = set(args.suites.split(","))

    s = Scratch(Path(args.scratch), args.jobs)
    s.repo.mkdir(parents=True, exist_ok=True)
    print(f"scratch copy: {s.repo}", flush=True)
    s.sync()
    s.configure()
    ok, out = s.make()
    if not ok:
        sys.exit(f"the unmutated tree does not build:\n{out[-3000:]}")
    s.check_import()
    if not args.no_baseline:
        t0 = time.monotonic()
        status, detail = s.test(suites)
        if status != "passed":
            sys.exit(f"the unmutated tree fails its tests ({detail}); fix that first")
        print(f"baseline: all tests pass ({time.monotonic() - t0:.0f} s)", flush=True)

    rows = []
    for m in chosen:
        t0 = time.monotonic()
        original = apply(m, s.repo)
        if original is None:
            rows.append((m, "stale", "the source text is gone: update the mutation", 0.0))
            print(f"{m.id}: stale", flush=True)
            continue
        try:
            ok, out = s.make()
            if not ok:
                status, detail = "build failed", out.strip().splitlines()[-1][:120]
            else:
                status, detail = s.test(suites)
                status = "not caught" if status == "passed" else status
        finally:
            (s.repo / m.file).write_text(original)
        dt = time.monotonic() - t0
        rows.append((m, status, detail, dt))
        print(f"{m.id}: {status} {detail} ({dt:.0f} s)", flush=True)
    s.make()  # leave the scratch build unmutated

    print("\n| id | mutation | file | result | first failing test |")
    print("|---|---|---|---|---|")
    for m, status, detail, _ in rows:
        print(f"| {m.id} | {m.what} | `{Path(m.file).name}` | {status} | {detail} |")
    missed = [m.id for m, status, _, _ in rows if status != "caught"]
    tail = f"; not: {', '.join(missed)}" if missed else ""
    print(f"\n{len(rows) - len(missed)} of {len(rows)} caught{tail}")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
