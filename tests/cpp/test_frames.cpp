#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "matdeform/frames.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

TEST(Frames, FourthVertexIsNormalOffsetWithEdgeScale) {
  const Eigen::Vector3d a(0, 0, 0), b(2, 0, 0), c(0, 2, 0);
  const Eigen::Vector3d d = fourth_vertex(a, b, c);
  // |n| = 4, offset n/sqrt(|n|) has length 2 along +z.
  EXPECT_LT((d - Eigen::Vector3d(0, 0, 2)).norm(), 1e-15);
  const Eigen::Matrix3d V = face_frame(a, b, c);
  EXPECT_NEAR(V.determinant(), 8.0, 1e-12);
}

TEST(Frames, GradientOfAffineMapIsItsLinearPart) {
  Vertices V;
  Faces F;
  meshes::make_bar(3, 3.0, &V, &F);
  // Similarity: rotation times uniform scale. The fourth vertex of the deformed face is
  // recomputed from the deformed triangle, so the gradient recovers A exactly only when A maps
  // normals consistently with n/sqrt|n|, which similarities do.
  const Eigen::Matrix3d A =
      1.7 * Eigen::AngleAxisd(0.9, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(0.3, -1.0, 2.0);
  Vertices X = (V * A.transpose()).rowwise() + t.transpose();
  const Matrix3Array T = deformation_gradients(V, X, F);
  ASSERT_EQ(T.size(), static_cast<size_t>(F.rows()));
  for (const auto& Ti : T) EXPECT_LT((Ti - A).norm(), 1e-12);
}

TEST(Frames, InPlaneShearIsRecoveredOnTangentDirections) {
  Vertices V;
  Faces F;
  meshes::make_grid(2, 2, &V, &F);
  Eigen::Matrix3d S = Eigen::Matrix3d::Identity();
  S(0, 1) = 0.5;  // shear in the z=0 plane
  Vertices X = V * S.transpose();
  const Matrix3Array T = deformation_gradients(V, X, F);
  for (const auto& Ti : T) {
    EXPECT_LT((Ti.leftCols<2>() - S.leftCols<2>()).norm(), 1e-12);
    // Normal column: the deformed normal scaled by 1/sqrt of the area change (=1 here).
    EXPECT_LT((Ti.col(2) - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
  }
}

TEST(Frames, DegenerateRestFaceThrows) {
  Vertices V(3, 3);
  V << 0, 0, 0, 1, 0, 0, 2, 0, 0;
  Faces F(1, 3);
  F << 0, 1, 2;
  EXPECT_THROW(deformation_gradients(V, V, F), std::invalid_argument);
}
