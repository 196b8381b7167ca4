#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <stdexcept>

#include "matdeform/mesh.hpp"
#include "matdeform/pyramid_deformer.hpp"
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
  meshes::make_bar(12, 6.0, &V, &F);
  std::vector<int> control;
  for (int j = 0; j < 4; ++j) control.push_back(j), control.push_back(4 * 12 + j);
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
