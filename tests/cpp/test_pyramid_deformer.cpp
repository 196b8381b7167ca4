#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <stdexcept>

#include "matdeform/mesh.hpp"
#include "matdeform/pyramid_deformer.hpp"
#include "matdeform/threads.hpp"
#include "simd.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

namespace {
double diagonal(const Vertices& V) {
  return (V.colwise().maxCoeff() - V.colwise().minCoeff()).norm();
}

// A grid with a bump (open, boundary and valence-2 corners).
void bumpy_grid(int nx, int ny, Vertices* V, Faces* F) {
  meshes::make_grid(nx, ny, V, F);
  for (Eigen::Index v = 0; v < V->rows(); ++v) {
    const double x = (*V)(v, 0) - nx / 2.0, y = (*V)(v, 1) - ny / 2.0;
    (*V)(v, 2) = 1.5 * std::exp(-(x * x + y * y) / 12.0);
  }
}

// A disc of `k` triangles around vertex 0 (valence k) with a second ring, lifted into a dome.
void dome(int k, Vertices* V, Faces* F) {
  *V = Vertices(1 + 2 * k, 3);
  V->row(0) << 0, 0, 1;
  *F = Faces(3 * k, 3);
  for (int i = 0; i < k; ++i) {
    const double a = 2 * 3.14159265358979 * i / k, b = a + 3.14159265358979 / k;
    V->row(1 + i) << std::cos(a), std::sin(a), 0.7;
    V->row(1 + k + i) << 2 * std::cos(b), 2 * std::sin(b), 0.1 * (i % 3);
    const int p = 1 + i, q = 1 + (i + 1) % k, r = 1 + k + i;
    F->row(3 * i) << 0, p, q;
    F->row(3 * i + 1) << p, r, q;
    F->row(3 * i + 2) << q, r, 1 + k + (i + 1) % k;
  }
}

// The 12-segment bar of length 6 with both end rings (4 vertices each) as controls, interleaved:
// even entries the near ring, odd entries the far one.
std::vector<int> bar_with_end_controls(Vertices* V, Faces* F) {
  meshes::make_bar(12, 6.0, V, F);
  std::vector<int> control;
  for (int j = 0; j < 4; ++j) control.push_back(j), control.push_back(4 * 12 + j);
  return control;
}
}  // namespace

TEST(VertexFans, ClosedOpenAndOrderedByFaces) {
  Vertices V;
  Faces F;
  meshes::make_grid(2, 2, &V, &F);
  const VertexFans fans = vertex_fans(static_cast<int>(V.rows()), F);
  // Centre vertex 4 of the 3x3 grid: a closed fan of six neighbours, each consecutive pair a face
  // in the faces' own orientation.
  EXPECT_EQ(fans.kind[4], kFanClosed);
  ASSERT_EQ(fans.offsets[5] - fans.offsets[4], 6);
  for (int i = 0; i < 6; ++i) {
    const int a = fans.ring[fans.offsets[4] + i], b = fans.ring[fans.offsets[4] + (i + 1) % 6];
    bool found = false;
    for (Eigen::Index f = 0; f < F.rows(); ++f)
      for (int k = 0; k < 3; ++k)
        found |= F(f, k) == 4 && F(f, (k + 1) % 3) == a && F(f, (k + 2) % 3) == b;
    EXPECT_TRUE(found) << a << " " << b;
  }
  EXPECT_EQ(fans.kind[1], kFanOpen);
  EXPECT_EQ(fans.kind[0], kFanOpen);  // corner: open fan with one or two faces
}

TEST(VertexFans, NonManifoldAndIsolated) {
  // Three triangles on the edge (0,1), and vertex 5 in no face.
  Vertices V = Vertices::Zero(6, 3);
  Faces F(3, 3);
  F << 0, 1, 2, 1, 0, 3, 0, 1, 4;
  const VertexFans fans = vertex_fans(6, F);
  EXPECT_EQ(fans.kind[0], kFanNonManifold);
  EXPECT_EQ(fans.kind[1], kFanNonManifold);
  EXPECT_EQ(fans.kind[2], kFanOpen);
  EXPECT_EQ(fans.kind[5], kFanIsolated);
  EXPECT_EQ(fans.offsets[6] - fans.offsets[5], 0);
}

TEST(PyramidDeformer, ReconstructsTheRestMeshAndKeepsItAtRest) {
  Vertices V;
  Faces F;
  bumpy_grid(10, 8, &V, &F);
  const std::vector<int> control = {0, 10, 88, 98, 49};
  PyramidDeformer d(V, F, control);
  const double diag = diagonal(V);
  EXPECT_LT((d.reconstruct(V, false) - V).cwiseAbs().maxCoeff(), 1e-10 * diag);
  EXPECT_LT((d.reconstruct(V, true) - V).cwiseAbs().maxCoeff(), 1e-10 * diag);
  Vertices C(5, 3);
  for (int j = 0; j < 5; ++j) C.row(j) = V.row(control[j]);
  PyramidSolveOptions o;
  o.initial = &V;
  const Vertices X = d.deform(C, o);
  EXPECT_LT((X - V).cwiseAbs().maxCoeff(), 1e-10 * diag);
  EXPECT_EQ(d.last_iterations(), 1);
}

TEST(PyramidDeformer, RigidControlsGiveTheMovedRestMesh) {
  Vertices V;
  Faces F;
  const std::vector<int> control = bar_with_end_controls(&V, &F);
  PyramidDeformer d(V, F, control);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(0.9, Eigen::Vector3d(1, 2, -1).normalized()).toRotationMatrix();
  const Eigen::RowVector3d t(0.5, -1.0, 2.0);
  const Vertices expect = (1.4 * V * R.transpose()).rowwise() + t;
  Vertices C(static_cast<Eigen::Index>(control.size()), 3);
  for (size_t j = 0; j < control.size(); ++j) C.row(j) = expect.row(control[j]);
  PyramidSolveOptions o;
  o.tol = 1e-12;
  // From a perturbed start the iteration returns to the moved rest mesh.
  Vertices start = expect;
  for (Eigen::Index v = 0; v < start.rows(); ++v) start(v, 1) += 0.01 * std::sin(3.0 * v);
  o.initial = &start;
  const Vertices X = d.deform(C, o);
  EXPECT_TRUE(X.allFinite());
  EXPECT_LT((X - expect).cwiseAbs().maxCoeff(), 1e-8 * diagonal(expect));
  EXPECT_LT(d.last_move(), 1e-12);
}

// The sweeps place four vertices of one valence at a time (SIMD lanes); reconstruct() places
// them one by one. One Jacobi sweep without step 2 must be that placement, for every kind of
// vertex: boundary, valence-2 corners (followers), valence > 16 (placed singly), lanes whose
// neighbours collapsed onto a line (scalar fallback inside a group), with both kernel builds.
TEST(PyramidDeformer, OneJacobiSweepIsThePlacementOfEveryVertex) {
  std::vector<std::pair<Vertices, Faces>> cases(3);
  bumpy_grid(9, 7, &cases[0].first, &cases[0].second);
  dome(21, &cases[1].first, &cases[1].second);
  meshes::make_bar(9, 4.0, &cases[2].first, &cases[2].second);
  for (auto& [V, F] : cases) {
    const int n = static_cast<int>(V.rows());
    const std::vector<int> control = {1, n - 2};
    PyramidDeformer d(V, F, control);
    Vertices start = V;
    for (int v = 0; v < n; ++v) {
      for (int c = 0; c < 3; ++c) start(v, c) += 0.05 * std::sin(1.0 + 7.0 * v + 3.0 * c);
    }
    // The ring of an interior vertex flattened onto a line: no plane for its placement.
    const std::vector<int>& off = d.coordinates().offsets;
    int w = n / 2;
    while (w < n && (d.coordinates().kind[w] != kPyramidInterior || off[w + 1] - off[w] > 16)) ++w;
    ASSERT_LT(w, n);
    for (int s = off[w]; s < off[w + 1]; ++s)
      start.row(d.coordinates().neighbors[s]) << 0.3 * s, 0, 0;
    Vertices C(2, 3);
    for (int j = 0; j < 2; ++j) C.row(j) = start.row(control[j]);
    for (bool stretch : {false, true}) {
      for (bool avx2 : {true, false}) {
        if (avx2 && !cpu_has_avx2_fma()) continue;
        const bool before = set_avx2_kernels_enabled(avx2);
        PyramidSolveOptions o;
        o.initial = &start;
        o.max_iterations = 1;
        o.tol = 0;
        o.anderson = 0;
        o.push = false;
        o.stretch = stretch;
        o.method = PyramidMethod::Jacobi;
        const Vertices X = d.deform(C, o);
        const Vertices expect = d.reconstruct(start, stretch);
        set_avx2_kernels_enabled(before);
        double err = 0, moved = 0;
        for (int v = 0; v < n; ++v) {
          if (v == control[0] || v == control[1]) continue;
          err = std::max(err, (X.row(v) - expect.row(v)).norm());
          moved = std::max(moved, (X.row(v) - start.row(v)).norm());
        }
        EXPECT_LT(err, 1e-12 * diagonal(V)) << n << " " << stretch << " " << avx2;
        EXPECT_GT(moved, 1e-3 * diagonal(V));
      }
    }
  }
}

// Anderson's passes (its Gram row, dF^T f and the step) are hand-vectorised kernels; an error in
// them leaves the fixed point alone but costs sweeps. Sweeps to tol 1e-10 measured when this test
// was written (bar 12 x 4, far end turned 0.8 rad and moved): window 20: 97 with either kernel
// build, window 5: 1119, plain sweeps: no convergence in 20000.
TEST(PyramidDeformer, AndersonKernelsConvergeInTheMeasuredSweeps) {
  Vertices V;
  Faces F;
  const std::vector<int> control = bar_with_end_controls(&V, &F);
  PyramidDeformer d(V, F, control);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.8, Eigen::Vector3d::UnitX()).toRotationMatrix();
  Vertices C(8, 3);
  for (int j = 0; j < 8; ++j) {
    C.row(j) = V.row(control[j]);
    if (j % 2) {
      C.row(j) = (R * (V.row(control[j]).transpose() - Eigen::Vector3d(6, 0, 0))).transpose() +
                 Eigen::RowVector3d(6, 0.5, 0);
    }
  }
  PyramidSolveOptions o;
  o.tol = 1e-10;
  auto run = [&](int window, bool avx2, int budget, int* sweeps) {
    const bool before = set_avx2_kernels_enabled(avx2);
    o.anderson = window;
    o.max_iterations = budget;
    const Vertices X = d.deform(C, o);
    set_avx2_kernels_enabled(before);
    *sweeps = d.last_iterations();
    return X;
  };
  int s20 = 0, s5 = 0, s0 = 0, base = 0;
  const Vertices X = run(20, true, 20000, &s20);
  EXPECT_LT(d.last_move(), 1e-10);
  EXPECT_LE(s20, 120);
  run(5, true, 20000, &s5);
  EXPECT_LT(d.last_move(), 1e-10);
  EXPECT_GT(s5, 5 * s20);
  // The plain sweeps run away on this bar (the long-thin-part instability): a clear error
  // once a sweep moves a vertex by 100x the problem's size, not 1e77 coordinates.
  try {
    run(0, true, 20000, &s0);
    ADD_FAILURE() << "plain sweeps converged or stalled (move " << d.last_move() << ")";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("diverged"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(std::isnan(d.last_move()));           // a failed call reports no move
  const Vertices Y = run(20, false, 20000, &base);  // the baseline build: same steps to round-off
  EXPECT_LE(std::abs(base - s20), 0.1 * s20);
  EXPECT_LT((X - Y).cwiseAbs().maxCoeff(), 1e-8 * diagonal(V));
}

// Placement commutes with a similarity for every vertex kind, followers included: the grid's
// valence-2 corners (a planar fit: follow()'s SVD path) and a folded fan (its polar path).
TEST(PyramidDeformer, PlacementCommutesWithASimilarity) {
  Vertices V;
  Faces F;
  bumpy_grid(7, 6, &V, &F);
  V(8 * 3 + 4, 0) += 1.4;  // past its ring: a folded fan, a follower with a full-rank fit
  PyramidDeformer d(V, F, {0});
  int followers = 0;
  for (signed char k : d.coordinates().kind) followers += k == kPyramidFollower;
  ASSERT_GE(followers, 5);
  ASSERT_EQ(d.coordinates().kind[8 * 3 + 4], kPyramidFollower);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.3, -1, 0.6).normalized()).toRotationMatrix();
  for (double scale : {0.6, 1.0, 2.5}) {
    const Vertices W = (scale * V * R.transpose()).rowwise() + Eigen::RowVector3d(-1, 4, 2);
    for (bool stretch : {false, true}) {
      EXPECT_LT((d.reconstruct(W, stretch) - W).cwiseAbs().maxCoeff(), 1e-10 * diagonal(W))
          << scale << " " << stretch;
    }
  }
}

TEST(PyramidDeformer, DescriptionInvariantUnderSimilarity) {
  Vertices V;
  Faces F;
  bumpy_grid(6, 5, &V, &F);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0, Eigen::Vector3d(0.2, 1, 0.4).normalized()).toRotationMatrix();
  const Vertices W = (2.5 * V * R.transpose()).rowwise() + Eigen::RowVector3d(1, 2, 3);
  const PyramidCoordinates a = pyramid_coordinates(V, F), b = pyramid_coordinates(W, F);
  ASSERT_EQ(a.alpha.size(), b.alpha.size());
  for (size_t s = 0; s < a.alpha.size(); ++s) {
    EXPECT_NEAR(a.alpha[s], b.alpha[s], 1e-10);
    EXPECT_NEAR(a.beta[s], b.beta[s], 1e-10);
    EXPECT_NEAR(2.5 * a.length[s], b.length[s], 1e-10);
  }
}

TEST(PyramidDeformer, BadInputThrows) {
  Vertices V;
  Faces F;
  meshes::make_bar(4, 4.0, &V, &F);
  const int n = static_cast<int>(V.rows());
  EXPECT_THROW(PyramidDeformer(V, F, {}), std::invalid_argument);
  EXPECT_THROW(PyramidDeformer(V, F, {n}), std::invalid_argument);
  EXPECT_THROW(PyramidDeformer(V, F, {-1}), std::invalid_argument);
  EXPECT_THROW(PyramidDeformer(V, F, {2, 2}), std::invalid_argument);
  Faces G = F;
  G(0, 1) = n + 3;
  EXPECT_THROW(PyramidDeformer(V, G, {0}), std::invalid_argument);
  Vertices U = V;
  U(1, 1) = std::nan("");
  EXPECT_THROW(PyramidDeformer(U, F, {0}), std::invalid_argument);
  PyramidDeformer d(V, F, {0, 1});
  PyramidSolveOptions o;
  EXPECT_THROW(d.deform(Vertices::Zero(3, 3), o), std::invalid_argument);
  Vertices C = Vertices::Zero(2, 3);
  C(0, 0) = INFINITY;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  C(0, 0) = 0;
  o.max_iterations = -1;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  o.max_iterations = 5;
  o.tol = -1;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  o.tol = 1e-6;
  const Vertices wrong = Vertices::Zero(3, 3);
  o.initial = &wrong;
  EXPECT_THROW(d.deform(C, o), std::invalid_argument);
  EXPECT_THROW(d.reconstruct(wrong, false), std::invalid_argument);
}
