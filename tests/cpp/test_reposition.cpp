#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "matdeform/reposition.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

TEST(Reposition, UniformTargetWithFixedVertexIsAffineImage) {
  Vertices V;
  Faces F;
  meshes::make_bar(6, 6.0, &V, &F);
  const Eigen::Matrix3d A =
      0.8 * Eigen::AngleAxisd(1.2, Eigen::Vector3d(0.3, 1, 0.2).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(1, 2, 3);
  PoissonRepositioner rep(V, F, Eigen::VectorXd::Constant(F.rows(), 2.0), {5});
  Vertices fixed(1, 3);
  fixed.row(0) = (A * V.row(5).transpose() + t).transpose();
  Vertices X;
  rep.solve(Matrix3Array(F.rows(), A), fixed, &X);
  const Vertices expect = (V * A.transpose()).rowwise() + t.transpose();
  EXPECT_LT((X - expect).cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_EQ(rep.num_unknowns(), V.rows() - 1);
}

TEST(Reposition, NothingFixedKeepsVertexMeanAtRest) {
  Vertices V;
  Faces F;
  meshes::make_bar(5, 5.0, &V, &F);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  PoissonRepositioner rep(V, F, Eigen::VectorXd::Ones(F.rows()), {});
  Vertices X;
  rep.solve(Matrix3Array(F.rows(), R), Vertices(0, 3), &X);
  const Eigen::RowVector3d c = V.colwise().mean();
  const Vertices expect = ((V.rowwise() - c) * R.transpose()).rowwise() + c;
  EXPECT_LT((X - expect).cwiseAbs().maxCoeff(), 1e-10);
}

TEST(Reposition, DegenerateFacesAndLooseVerticesAreHandled) {
  Vertices V;
  Faces F;
  meshes::make_grid(3, 3, &V, &F);
  // Append a loose vertex and a zero-area sliver using it twice with an existing vertex.
  Vertices V2(V.rows() + 2, 3);
  V2 << V, 10, 10, 10, 0.5, 0.0, 0.0;  // second extra vertex lies on edge (0,1): zero area
  Faces F2(F.rows() + 1, 3);
  F2 << F, 0, 1, static_cast<int>(V.rows()) + 1;
  PoissonRepositioner rep(V2, F2, Eigen::VectorXd::Ones(F2.rows()), {});
  Vertices X;
  rep.solve(Matrix3Array(F2.rows(), Eigen::Matrix3d::Identity()), Vertices(0, 3), &X);
  EXPECT_LT((X - V2).cwiseAbs().maxCoeff(), 1e-10);  // identity: everything at rest
  // A turn: the grid turns about its vertex mean (nothing is fixed); the loose vertex and the
  // one only the sliver uses keep their rest positions.
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(1.3, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  rep.solve(Matrix3Array(F2.rows(), R), Vertices(0, 3), &X);
  const Eigen::RowVector3d c = V.colwise().mean();
  const Vertices expect = ((V.rowwise() - c) * R.transpose()).rowwise() + c;
  EXPECT_LT((X.topRows(V.rows()) - expect).cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_EQ(X.row(V.rows()), V2.row(V.rows()));
  EXPECT_EQ(X.row(V.rows() + 1), V2.row(V.rows() + 1));
}
