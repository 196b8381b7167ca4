#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "matdeform/deformer.hpp"
#include "matdeform/mesh.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

TEST(Deformer, FollowModeReproducesCommonRigidTransform) {
  Vertices V;
  Faces F;
  meshes::make_bar(10, 10.0, &V, &F);
  const int m = static_cast<int>(F.rows());
  const DualEdges dual = dual_edges(F);
  MaterialDeformer d(V, F, {{m - 4, m - 3}, {m - 2, m - 1}}, Eigen::VectorXd::Ones(m),
                     RowMatrix::Ones(dual.pairs.rows(), 1));
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() =
      Eigen::AngleAxisd(2.9, Eigen::Vector3d(1, 1, 1).normalized()).toRotationMatrix();
  T.topRightCorner<3, 1>() << 4, -2, 1;
  const Vertices X = d.deform({T, T}, true, nullptr);
  const Vertices expect =
      (V * T.topLeftCorner<3, 3>().transpose()).rowwise() + T.topRightCorner<3, 1>().transpose();
  EXPECT_LT((X - expect).cwiseAbs().maxCoeff(), 1e-9);
}
