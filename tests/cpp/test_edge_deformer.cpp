// Edge-based iterative deformation (EdgeDeformer): fixed points, the alpha/beta rule, rigid
// motions, composition of iterations, the single factorisation, kernels and bad input.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <complex>
#include <limits>
#include <set>
#include <stdexcept>
#include <utility>

#include "matdeform/edge_deformer.hpp"
#include "matdeform/mesh.hpp"
#include "matdeform/threads.hpp"
#include "simd.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

namespace {

// Grid with ridges and valleys (z = 0.6 sin x cos y) and alternating diagonals.
void bumpy_grid(int nx, int ny, Vertices* V, Faces* F) {
  meshes::make_grid(nx, ny, V, F);
  for (Eigen::Index v = 0; v < V->rows(); ++v) {
    (*V)(v, 2) = 0.6 * std::sin(1.1 * (*V)(v, 0)) * std::cos(0.8 * (*V)(v, 1));
  }
  for (Eigen::Index f = 0; f < F->rows(); f += 2) {
    const int a = (*F)(f, 0), b = (*F)(f, 1), d = (*F)(f, 2), c = (*F)(f + 1, 2);
    if ((f / 2) % 3 == 0) {  // flip this square's diagonal: a b c / b d c
      F->row(f) << a, b, c;
      F->row(f + 1) << b, d, c;
    }
  }
}

// Open tube along x: (nx+1) rings of na vertices, radius r, length len.
void tube(int nx, int na, double r, double len, Vertices* V, Faces* F) {
  V->resize((nx + 1) * na, 3);
  for (int i = 0; i <= nx; ++i) {
    for (int k = 0; k < na; ++k) {
      const double t = 2.0 * M_PI * k / na;
      V->row(i * na + k) << len * i / nx, r * std::cos(t), r * std::sin(t);
    }
  }
  F->resize(2 * nx * na, 3);
  int f = 0;
  for (int i = 0; i < nx; ++i) {
    for (int k = 0; k < na; ++k) {
      const int a = i * na + k, b = i * na + (k + 1) % na, c = a + na, d = b + na;
      F->row(f++) << a, b, d;
      F->row(f++) << a, d, c;
    }
  }
}

std::vector<int> corners(int nx, int ny) {
  const int w = nx + 1;
  return {0, nx, w * ny, w * ny + nx};
}

Vertices rows_of(const Vertices& X, const std::vector<int>& idx) {
  Vertices out(static_cast<Eigen::Index>(idx.size()), 3);
  for (size_t k = 0; k < idx.size(); ++k) out.row(static_cast<Eigen::Index>(k)) = X.row(idx[k]);
  return out;
}

double max_diff(const Vertices& a, const Vertices& b) { return (a - b).cwiseAbs().maxCoeff(); }

EdgeSolveOptions iterations(int k, double tol = 0.0) {
  EdgeSolveOptions o;
  o.iterations = k;
  o.tol = tol;
  return o;
}

}  // namespace

TEST(MeshEdges, GridHasEulerCountSortedUniqueEdges) {
  Vertices V;
  Faces F;
  meshes::make_grid(4, 3, &V, &F);
  const IndexPairs E = mesh_edges(F);
  // A disc: V - E + F = 1.
  EXPECT_EQ(E.rows(), V.rows() + F.rows() - 1);
  std::set<std::pair<int, int>> seen;
  for (Eigen::Index e = 0; e < E.rows(); ++e) {
    EXPECT_LT(E(e, 0), E(e, 1));
    if (e > 0) {
      EXPECT_LT(std::make_pair(E(e - 1, 0), E(e - 1, 1)), std::make_pair(E(e, 0), E(e, 1)));
    }
    seen.insert({E(e, 0), E(e, 1)});
  }
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = F(f, k), b = F(f, (k + 1) % 3);
      EXPECT_TRUE(seen.count({std::min(a, b), std::max(a, b)}));
    }
  }
}

TEST(EdgeDeformer, RestConstraintsGiveTheRestMeshForAnyMaterial) {
  Vertices V;
  Faces F;
  bumpy_grid(9, 7, &V, &F);
  const std::vector<int> c = corners(9, 7);
  // The mesh bends both ways: some rest sigma point along the edge normal, some against it. An
  // unsigned |sigma_0| n target (Eq. 10 read literally) would flip the valleys.
  {
    EdgeDeformer probe(V, F, c);
    int up = 0, down = 0;
    for (Eigen::Index e = 0; e < probe.edges().rows(); ++e) {
      if (probe.opposite()(e, 0) < 0) continue;
      const int a = probe.edges()(e, 0), b = probe.edges()(e, 1);
      const int l = probe.opposite()(e, 0), m = probe.opposite()(e, 1);
      const double al = probe.bend_coefficients()(e, 0), be = probe.bend_coefficients()(e, 1);
      const Eigen::Vector3d s =
          (al * V.row(a) + (1 - al) * V.row(b) - be * V.row(l) - (1 - be) * V.row(m)).transpose();
      // The face normals' sum is along (x_b - x_a) x (x_l - x_m) up to the sign of the winding.
      const Eigen::Vector3d n =
          (V.row(b) - V.row(a)).transpose().cross((V.row(l) - V.row(m)).transpose());
      const double side =
          s.dot(n) * ((V.row(l) - V.row(a)).transpose().cross((V.row(b) - V.row(a)).transpose()))
                         .dot(Eigen::Vector3d::UnitZ());
      if (side > 1e-9) ++up;
      if (side < -1e-9) ++down;
    }
    ASSERT_GT(up, 10);
    ASSERT_GT(down, 10);
  }
  for (double stretch : {0.0, 1e-3, 2.0}) {
    for (double bend : {0.3, 1.0}) {
      EdgeDeformerOptions o;
      o.stretch = stretch;
      o.bend = bend;
      EdgeDeformer d(V, F, c, o);
      for (double p : {0.0, 0.4, 1.0}) {
        EdgeSolveOptions s = iterations(6);
        s.p_stretch = p;
        s.p_bend = 1.0 - 0.5 * p;
        const Vertices X = d.solve(rows_of(V, c), s);
        EXPECT_LT(max_diff(X, V), 1e-12 * d.diagonal()) << stretch << " " << bend << " " << p;
        EXPECT_EQ(d.last_iterations(), 6);
      }
    }
  }
}

TEST(EdgeDeformer, AlphaBetaMakeSigmaParallelToTheNormalWhenPossible) {
  // Two triangles (0 2 1), (0 1 3) over the unit square with the hinge 0-1 on the diagonal.
  // Flat: the diagonals cross at their middles and sigma vanishes. Lifted corner 1: by the
  // x <-> y symmetry beta stays 1/2, and sigma must be exactly along the edge normal.
  for (double lift : {0.0, 0.3}) {
    Vertices V(4, 3);
    V << 0, 0, 0, 1, 1, lift, 1, 0, 0, 0, 1, 0;
    Faces F(2, 3);
    F << 0, 2, 1, 0, 1, 3;
    EdgeDeformer d(V, F, {0, 1, 2, 3});
    const IndexPairs& E = d.edges();
    int hinge = -1;
    for (Eigen::Index e = 0; e < E.rows(); ++e) {
      if (E(e, 0) == 0 && E(e, 1) == 1) {
        hinge = static_cast<int>(e);
      } else {
        EXPECT_EQ(d.opposite()(e, 0), -1);  // boundary edges: no sigma term
      }
    }
    ASSERT_GE(hinge, 0);
    const double a = d.bend_coefficients()(hinge, 0), b = d.bend_coefficients()(hinge, 1);
    const int l = d.opposite()(hinge, 0), m = d.opposite()(hinge, 1);
    const Eigen::Vector3d s =
        (a * V.row(0) + (1 - a) * V.row(1) - b * V.row(l) - (1 - b) * V.row(m)).transpose();
    const Eigen::Vector3d n =
        ((V.row(1) - V.row(0)).transpose().cross((V.row(2) - V.row(0)).transpose()) +
         (V.row(0) - V.row(1)).transpose().cross((V.row(3) - V.row(1)).transpose()))
            .normalized();
    EXPECT_NEAR(b, 0.5, 1e-9);
    if (lift == 0.0) {
      EXPECT_NEAR(a, 0.5, 1e-9);
      EXPECT_LT(s.norm(), 1e-9);
    } else {
      EXPECT_GT(a, 0.0);
      EXPECT_LT(a, 1.0);
      EXPECT_GT(s.norm(), 0.05);
      EXPECT_LT(s.cross(n).norm(), 1e-9);
    }
  }
}

TEST(EdgeDeformer, AlphaBetaAreTheBoxConstrainedLeastSquaresMinimiser) {
  // A skewed hinge whose projected segments do not cross: alpha, beta clamp to the box, and
  // must minimise the tangential part of sigma over [0,1]^2 (checked by brute force).
  Vertices V(4, 3);
  V << 0, 0, 0, 1, 0, 0, 2.2, 0.7, 0.1, 1.9, -0.9, 0.4;
  Faces F(2, 3);
  F << 0, 1, 2, 1, 0, 3;
  EdgeDeformer d(V, F, {0, 1, 2, 3});
  const IndexPairs& E = d.edges();
  int hinge = -1;
  for (Eigen::Index e = 0; e < E.rows(); ++e)
    if (E(e, 0) == 0 && E(e, 1) == 1) hinge = static_cast<int>(e);
  ASSERT_GE(hinge, 0);
  ASSERT_EQ(d.opposite()(hinge, 0), 2);
  const Eigen::Vector3d xi = V.row(0), xj = V.row(1), xl = V.row(2), xm = V.row(3);
  const Eigen::Vector3d n = ((xj - xi).cross(xl - xi) + (xi - xj).cross(xm - xj)).normalized();
  auto tangential = [&](double a, double b) {
    const Eigen::Vector3d s = a * xi + (1 - a) * xj - b * xl - (1 - b) * xm;
    return (s - s.dot(n) * n).norm();
  };
  double best = std::numeric_limits<double>::infinity();
  for (int p = 0; p <= 1000; ++p)
    for (int q = 0; q <= 1000; ++q) best = std::min(best, tangential(p / 1000.0, q / 1000.0));
  const double a = d.bend_coefficients()(hinge, 0), b = d.bend_coefficients()(hinge, 1);
  EXPECT_GE(a, 0.0);
  EXPECT_LE(a, 1.0);
  EXPECT_GE(b, 0.0);
  EXPECT_LE(b, 1.0);
  EXPECT_TRUE(a == 0.0 || a == 1.0 || b == 0.0 || b == 1.0) << a << " " << b;
  EXPECT_GT(best, 0.05);  // really no exact solution in the box
  EXPECT_LE(tangential(a, b), best + 1e-9);
}

TEST(EdgeDeformer, RigidlyMovedConstraintsConvergeToTheMovedRestMesh) {
  Vertices V;
  Faces F;
  tube(14, 10, 0.6, 4.0, &V, &F);
  std::vector<int> c;
  for (int k = 0; k < 10; ++k) {  // both end rings
    c.push_back(k);
    c.push_back(static_cast<int>(V.rows()) - 1 - k);
  }
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::RowVector3d t(1.0, -2.0, 0.5);
  const Vertices moved = (V * R.transpose()).rowwise() + t;
  for (double stretch : {0.0, 0.1}) {
    EdgeDeformerOptions o;
    o.stretch = stretch;
    EdgeDeformer d(V, F, c, o);
    // From rest the end rings' fitted rotation carries every edge: the first step is the
    // rigid motion up to round-off, the next ones only confirm it.
    Vertices X = d.solve(rows_of(moved, c), iterations(5000, 1e-14));
    EXPECT_LT(max_diff(X, moved), 1e-11 * d.diagonal()) << stretch;
    EXPECT_LE(d.last_iterations(), 3);
    // From a bent start with the rings in place nothing is carried: the iteration finds it.
    Vertices bent = moved;
    for (Eigen::Index v = 0; v < V.rows(); ++v) bent(v, 1) += 0.1 * std::sin(3.0 * V(v, 0));
    for (int k : c) bent.row(k) = moved.row(k);
    X = d.solve(rows_of(moved, c), iterations(5000, 1e-14), &bent);
    EXPECT_LT(max_diff(X, moved), 1e-9 * d.diagonal()) << stretch;
    EXPECT_LT(d.last_iterations(), 5000);
    EXPECT_GT(d.last_iterations(), 5);  // not solved by one linear step
  }
}

// Base ring fixed, tip ring turned about the axis: the middle ring turns by half the tip, the
// short way. From rest the plain first step shears the turn in and pushes rings through the
// axis (the tube then settles a half turn the wrong way); the carried first step does not.
TEST(EdgeDeformer, TwistedTubeTurnsItsMiddleByHalfTheTip) {
  Vertices V;
  Faces F;
  tube(40, 16, 1.0, 16.0, &V, &F);
  std::vector<int> c;
  for (int k = 0; k < 16; ++k) c.push_back(k);
  for (int k = 0; k < 16; ++k) c.push_back(40 * 16 + k);
  struct Case {
    double stretch, relaxation, tip_degrees;
  };
  for (const Case& t : {Case{1e-4, 1.0, 120.0}, Case{1e-2, 0.8, 170.0}, Case{1e-4, 1.0, -175.0}}) {
    EdgeDeformerOptions o;
    o.stretch = t.stretch;
    EdgeDeformer d(V, F, c, o);
    const Eigen::Matrix3d R =
        Eigen::AngleAxisd(t.tip_degrees * M_PI / 180.0, Eigen::Vector3d::UnitX())
            .toRotationMatrix();
    Vertices pos = rows_of(V, c);
    for (int k = 16; k < 32; ++k) pos.row(k) = pos.row(k) * R.transpose();
    EdgeSolveOptions s = iterations(3000, 1e-9);
    s.relaxation = t.relaxation;
    const Vertices X = d.solve(pos, s);
    EXPECT_LT(d.last_iterations(), 3000);
    std::complex<double> turn = 0.0;
    for (int k = 0; k < 16; ++k) {
      const int v = 20 * 16 + k;
      turn += std::complex<double>(X(v, 1), X(v, 2)) / std::complex<double>(V(v, 1), V(v, 2));
    }
    EXPECT_NEAR(std::arg(turn) * 180.0 / M_PI, t.tip_degrees / 2, 0.01) << t.tip_degrees;
  }
}

TEST(EdgeDeformer, IterationsComposeAndToleranceStops) {
  Vertices V;
  Faces F;
  bumpy_grid(8, 8, &V, &F);
  std::vector<int> c = corners(8, 8);
  c.push_back(40);
  Vertices pos = rows_of(V, c);
  pos(4, 2) += 3.0;
  EdgeDeformerOptions o;
  o.stretch = 0.05;
  EdgeDeformer d(V, F, c, o);
  EdgeSolveOptions s = iterations(10);
  s.gravity << 0.01, 0.0, -0.02;
  s.p_stretch = 0.7;
  const Vertices all = d.solve(pos, s);
  EXPECT_EQ(d.last_iterations(), 10);
  s.iterations = 4;
  const Vertices half = d.solve(pos, s);
  s.iterations = 6;
  const Vertices rest_of = d.solve(pos, s, &half);
  EXPECT_LT(max_diff(all, rest_of), 1e-14 * d.diagonal());
  EXPECT_GT(max_diff(all, half), 1e-3);

  // tol: stops once the largest move is below tol * diagonal, and reports that move.
  s.iterations = 1000;
  s.tol = 1e-4;
  const Vertices X = d.solve(pos, s);
  EXPECT_LT(d.last_iterations(), 1000);
  EXPECT_LT(d.last_move(), 1e-4);
  const double reported = d.last_move();
  s.iterations = 1;
  s.tol = 0.0;
  const Vertices Y = d.solve(pos, s, &X);
  // one more iteration moves by about the last reported move (the iteration contracts)
  EXPECT_LT(max_diff(X, Y), 1.0001 * reported * d.diagonal() + 1e-15);
}

TEST(EdgeDeformer, ZeroResponseKeepsTheIterate) {
  Vertices V;
  Faces F;
  bumpy_grid(7, 6, &V, &F);
  const std::vector<int> c = {0, 5, 17, 30};
  Vertices X = V;
  for (Eigen::Index v = 0; v < X.rows(); ++v) {
    X.row(v) += Eigen::RowVector3d(std::sin(3.0 * v), std::cos(2.0 * v), 0.5 * std::sin(v));
  }
  EdgeDeformerOptions o;
  o.stretch = 0.3;
  EdgeDeformer d(V, F, c, o);
  EdgeSolveOptions s = iterations(3);
  s.p_stretch = 0.0;
  s.p_bend = 0.0;
  const Vertices Y = d.solve(rows_of(X, c), s, &X);
  EXPECT_LT(max_diff(X, Y), 1e-11 * d.diagonal());
  // the same with p = 1 does move: the test above is not trivially satisfied
  s.p_stretch = s.p_bend = 1.0;
  EXPECT_GT(max_diff(X, d.solve(rows_of(X, c), s, &X)), 0.1);
}

TEST(EdgeDeformer, FactorsOnceInTheConstructorOnly) {
  Vertices V;
  Faces F;
  bumpy_grid(10, 10, &V, &F);
  const std::vector<int> c = corners(10, 10);
  const long long before = EdgeDeformer::process_factorizations();
  EdgeDeformer d(V, F, c);
  EXPECT_EQ(EdgeDeformer::process_factorizations(), before + 1);
  EXPECT_EQ(d.factorizations(), 1);
  Vertices pos = rows_of(V, c);
  for (int k = 0; k < 5; ++k) {
    EdgeSolveOptions s = iterations(3);
    s.p_stretch = 0.2 * k;
    s.p_bend = 1.0 - 0.2 * k;
    s.gravity << 0, 0, -0.1 * k;
    pos(0, 0) -= 0.5;
    d.solve(pos, s);
  }
  EXPECT_EQ(EdgeDeformer::process_factorizations(), before + 1);
}

TEST(EdgeDeformer, PartsWithoutConstraintsAndLooseVerticesArePassive) {
  Vertices A, B;
  Faces FA, FB;
  meshes::make_grid(4, 4, &A, &FA);
  meshes::make_grid(3, 3, &B, &FB);
  Vertices V(A.rows() + B.rows() + 1, 3);
  V << A, (B.rowwise() + Eigen::RowVector3d(10, 0, 0)), Eigen::RowVector3d(-5, -5, -5);
  Faces F(FA.rows() + FB.rows(), 3);
  F << FA, (FB.array() + static_cast<int>(A.rows())).matrix();
  const std::vector<int> c = corners(4, 4);
  EdgeDeformerOptions o;
  o.stretch = 0.1;
  EdgeDeformer d(V, F, c, o);
  EXPECT_EQ(d.num_free(), A.rows() - 4);
  Vertices init = V;
  init.bottomRows(B.rows() + 1).array() += 0.25;
  Vertices pos = rows_of(V, c);
  pos(3, 2) = 2.0;
  EdgeSolveOptions s = iterations(4);
  s.gravity << 0, 0, -1;
  const Vertices X = d.solve(pos, s, &init);
  // at rest bit for bit, whatever the start holds: the rule for every method
  EXPECT_EQ(max_diff(X.bottomRows(B.rows() + 1), V.bottomRows(B.rows() + 1)), 0.0);
  EXPECT_GT(max_diff(X.topRows(A.rows()), V.topRows(A.rows())), 0.1);
}

TEST(EdgeDeformer, NonManifoldEdgeHasNoBendTerm) {
  // Three triangles on the edge (0, 1) plus one ordinary neighbour pair.
  Vertices V(6, 3);
  V << 0, 0, 0, 1, 0, 0, 0.5, 1, 0, 0.5, -1, 0, 0.5, 0, 1, 1.5, 1, 0.2;
  Faces F(4, 3);
  F << 0, 1, 2, 1, 0, 3, 0, 1, 4, 1, 5, 2;
  EdgeDeformerOptions o;
  o.stretch = 1.0;
  EdgeDeformer d(V, F, {0, 3, 4, 5}, o);
  for (Eigen::Index e = 0; e < d.edges().rows(); ++e) {
    const bool hinge12 = d.edges()(e, 0) == 1 && d.edges()(e, 1) == 2;
    EXPECT_EQ(d.opposite()(e, 0) >= 0, hinge12) << d.edges()(e, 0) << "-" << d.edges()(e, 1);
  }
  const Vertices X = d.solve(rows_of(V, {0, 3, 4, 5}), iterations(3));
  EXPECT_LT(max_diff(X, V), 1e-12);
}

TEST(EdgeDeformer, AnisotropyFollowsTheTangentialField) {
  Vertices V;
  Faces F;
  meshes::make_grid(3, 3, &V, &F);
  EdgeDeformerOptions o;
  // along x, plus a normal component that must not matter
  o.direction = Vertices::Zero(V.rows(), 3);
  o.direction.col(0).setConstant(1.0);
  o.direction.col(2).setConstant(5.0);
  o.direction.row(0).setZero();  // f_0 + f_1 still along x
  EdgeDeformer d(V, F, corners(3, 3), o);
  for (Eigen::Index e = 0; e < d.edges().rows(); ++e) {
    const Eigen::Vector3d r = (V.row(d.edges()(e, 1)) - V.row(d.edges()(e, 0))).transpose();
    EXPECT_NEAR(d.anisotropy()(e), std::abs(r.normalized().x()), 1e-12);
  }
  // a field that cancels on an edge leaves it isotropic
  o.direction.setZero();
  o.direction.row(0) << 1, 0, 0;
  o.direction.row(1) << -1, 0, 0;
  EdgeDeformer z(V, F, corners(3, 3), o);
  for (Eigen::Index e = 0; e < z.edges().rows(); ++e) {
    if (z.edges()(e, 0) == 0 && z.edges()(e, 1) == 1) {
      EXPECT_EQ(z.anisotropy()(e), 1.0);
    }
  }
}

TEST(EdgeDeformer, ThreadsAndBaselineKernelsAgree) {
  Vertices V;
  Faces F;
  bumpy_grid(90, 90, &V, &F);  // large enough for the parallel paths
  EdgeDeformerOptions o;
  o.stretch = 1e-3;
  EdgeSolveOptions s = iterations(3);
  s.p_bend = 0.8;
  const int threads = num_threads();
  auto check = [&](const std::vector<int>& c, const Vertices& pos) {
    set_num_threads(1);
    EdgeDeformer d(V, F, c, o);
    const Vertices serial = d.solve(pos, s);
    set_num_threads(2);
    const Vertices parallel = d.solve(pos, s);
    set_num_threads(threads);
    EXPECT_GT(max_diff(serial, V), 5.0);
    EXPECT_LT(max_diff(serial, parallel), 1e-12 * d.diagonal());
    if (cpu_has_avx2_fma()) {
      const bool before = set_avx2_kernels_enabled(false);
      const Vertices base = d.solve(pos, s);
      set_avx2_kernels_enabled(before);
      EXPECT_LT(max_diff(serial, base), 1e-10 * d.diagonal());
    }
  };
  const int centre = 45 * 91 + 45;
  std::vector<int> c = corners(90, 90);
  c.push_back(centre);
  Vertices pos = rows_of(V, c);
  pos(4, 2) += 20.0;
  check(c, pos);
  // The carried first step: a turned anchor (the centre vertex and its ring).
  c.pop_back();
  for (int dv : {0, -1, 1, -91, 91, -92, 92, -90, 90}) c.push_back(centre + dv);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(1.2, Eigen::Vector3d(0.3, 1, 0.2).normalized()).toRotationMatrix();
  pos = rows_of(V, c);
  for (Eigen::Index k = 4; k < pos.rows(); ++k) {
    pos.row(k) = (pos.row(k) - V.row(centre)) * R.transpose() + V.row(centre);
    pos(k, 2) += 10.0;
  }
  check(c, pos);
}

TEST(EdgeDeformer, BadInputThrowsAndChangesNothing) {
  Vertices V;
  Faces F;
  meshes::make_grid(4, 4, &V, &F);
  const std::vector<int> c = corners(4, 4);
  auto make = [&](const std::vector<int>& cc, EdgeDeformerOptions o) {
    EdgeDeformer d(V, F, cc, o);
  };
  EdgeDeformerOptions ok;
  EXPECT_THROW(make({}, ok), std::invalid_argument);
  EXPECT_THROW(make({0, 25}, ok), std::invalid_argument);
  EXPECT_THROW(make({0, -1}, ok), std::invalid_argument);
  EXPECT_THROW(make({0, 3, 0}, ok), std::invalid_argument);
  EdgeDeformerOptions o = ok;
  o.stretch = -1e-3;
  EXPECT_THROW(make(c, o), std::invalid_argument);
  o = ok;
  o.stretch = std::nan("");
  EXPECT_THROW(make(c, o), std::invalid_argument);
  o = ok;
  o.bend = 0.0;
  EXPECT_THROW(make(c, o), std::invalid_argument);
  o = ok;
  o.edge_weight = Eigen::VectorXd::Ones(3);
  EXPECT_THROW(make(c, o), std::invalid_argument);
  o.edge_weight = Eigen::VectorXd::Ones(mesh_edges(F).rows());
  o.edge_weight(2) = 0.0;
  EXPECT_THROW(make(c, o), std::invalid_argument);
  o = ok;
  o.direction = Vertices::Ones(3, 3);
  EXPECT_THROW(make(c, o), std::invalid_argument);
  o.direction = Vertices::Ones(V.rows(), 3);
  o.direction(2, 1) = std::nan("");
  EXPECT_THROW(make(c, o), std::invalid_argument);
  // stiffness times weight beyond 1e300 (each alone may be that large)
  o = ok;
  o.stretch = 1e300;
  o.bend = 1e300;
  EXPECT_NO_THROW(make(c, o));
  o.edge_weight = Eigen::VectorXd::Constant(mesh_edges(F).rows(), 10.0);
  EXPECT_THROW(make(c, o), std::invalid_argument);
  // a flat sheet with stretch 0 and one constrained vertex is not determined
  o = ok;
  o.stretch = 0.0;
  EXPECT_THROW(make({12}, o), std::invalid_argument);
  Faces bad = F;
  bad(3, 1) = 99;
  EXPECT_THROW(EdgeDeformer(V, bad, c), std::invalid_argument);
  bad = F;
  bad(3, 1) = -4;
  EXPECT_THROW(EdgeDeformer(V, bad, c), std::invalid_argument);

  EdgeDeformer d(V, F, c);
  const Vertices X = d.solve(rows_of(V, c), iterations(2));
  EXPECT_EQ(d.last_iterations(), 2);
  EdgeSolveOptions s = iterations(2);
  EXPECT_THROW(d.solve(Vertices::Zero(3, 3), s), std::invalid_argument);
  Vertices nanpos = rows_of(V, c);
  nanpos(1, 1) = std::nan("");
  EXPECT_THROW(d.solve(nanpos, s), std::invalid_argument);
  const Vertices short_init = V.topRows(4);
  EXPECT_THROW(d.solve(rows_of(V, c), s, &short_init), std::invalid_argument);
  s.iterations = 0;
  EXPECT_THROW(d.solve(rows_of(V, c), s), std::invalid_argument);
  s = iterations(2);
  s.tol = -1.0;
  EXPECT_THROW(d.solve(rows_of(V, c), s), std::invalid_argument);
  s = iterations(2);
  s.p_stretch = 1.5;
  EXPECT_THROW(d.solve(rows_of(V, c), s), std::invalid_argument);
  s = iterations(2);
  s.p_bend = -0.1;
  EXPECT_THROW(d.solve(rows_of(V, c), s), std::invalid_argument);
  s = iterations(2);
  s.p_bend = std::nan("");
  EXPECT_THROW(d.solve(rows_of(V, c), s), std::invalid_argument);
  s = iterations(2);
  s.gravity << 0, std::nan(""), 0;
  EXPECT_THROW(d.solve(rows_of(V, c), s), std::invalid_argument);
  // positions beyond 1e50 mesh sizes of the rest mesh, as targets or as the start
  Vertices far = rows_of(V, c);
  far(2, 0) += 1e52 * d.diagonal();
  EXPECT_THROW(d.solve(far, iterations(2)), std::invalid_argument);
  far = rows_of(V, c);
  far(2, 0) += 0.9e50 * d.diagonal();
  EXPECT_NO_THROW(d.solve(far, iterations(2)));
  Vertices far_start = V;
  far_start(7, 2) = -1e200;
  EXPECT_THROW(d.solve(rows_of(V, c), iterations(2), &far_start), std::invalid_argument);
  // gravity that throws the iterate out of that range: refused after the fact
  d.solve(rows_of(V, c), iterations(2));
  const double move = d.last_move();
  s = iterations(3);
  s.gravity << 0, 0, -1e300;
  EXPECT_THROW(d.solve(rows_of(V, c), s), std::runtime_error);
  EXPECT_EQ(d.last_move(), move);
  EXPECT_EQ(d.last_iterations(), 2);  // the failed calls changed nothing
  EXPECT_EQ(max_diff(d.solve(rows_of(V, c), iterations(2)), X), 0.0);
}
