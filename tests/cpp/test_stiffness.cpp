// Stiffness conversions (Popa et al. 2006, Sec. 4.1) against their closed forms.
#include <gtest/gtest.h>

#include <stdexcept>

#include "matdeform/mesh.hpp"
#include "matdeform/stiffness.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

TEST(Stiffness, ConversionsAreMeansOverTheRightElements) {
  Vertices V;
  Faces F;
  meshes::make_grid(3, 2, &V, &F);
  const DualEdges dual = dual_edges(F);
  const Eigen::Index m = F.rows(), n = V.rows();
  Eigen::VectorXd psi(m), s(n);
  for (Eigen::Index f = 0; f < m; ++f) psi(f) = 1.0 + f * f;  // all different
  for (Eigen::Index v = 0; v < n; ++v) s(v) = 0.5 + 3.0 * v;
  const Eigen::VectorXd phi = bend_from_shear(dual.pairs, psi);
  const Eigen::VectorXd bv = bend_from_vertex(dual, s);
  ASSERT_EQ(phi.size(), dual.pairs.rows());
  for (Eigen::Index e = 0; e < dual.pairs.rows(); ++e) {
    EXPECT_EQ(phi(e), 0.5 * (psi(dual.pairs(e, 0)) + psi(dual.pairs(e, 1))));
    EXPECT_EQ(bv(e), 0.5 * (s(dual.shared(e, 0)) + s(dual.shared(e, 1))));
  }
  const Eigen::VectorXd sv = shear_from_vertex(F, s);
  for (Eigen::Index f = 0; f < m; ++f) {
    EXPECT_DOUBLE_EQ(sv(f), (s(F(f, 0)) + s(F(f, 1)) + s(F(f, 2))) / 3.0);
  }
  // By hand: faces (0,1,2) and (2,1,3) share edge (1,2).
  Faces T(2, 3);
  T << 0, 1, 2, 2, 1, 3;
  const DualEdges d2 = dual_edges(T);
  EXPECT_EQ(bend_from_shear(d2.pairs, Eigen::Vector2d(1.0, 3.0))(0), 2.0);
  EXPECT_EQ(bend_from_vertex(d2, Eigen::Vector4d(10, 1, 3, 100))(0), 2.0);
  const Eigen::VectorXd st = shear_from_vertex(T, Eigen::Vector4d(1, 2, 6, 100));
  EXPECT_DOUBLE_EQ(st(0), 3.0);
  EXPECT_DOUBLE_EQ(st(1), 36.0);
  EXPECT_THROW(shear_from_vertex(T, Eigen::Vector3d(1, 2, 3)), std::invalid_argument);
}
