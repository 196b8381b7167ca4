// The per-pose kernels exist as a baseline x86-64 build and an AVX2+FMA build (simd.hpp). Both
// must give the same deformation. Without AVX2 there is nothing to compare, and the test says so.
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "matdeform/deformer.hpp"
#include "matdeform/mesh.hpp"
#include "simd.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

namespace {

struct BaselineKernels {
  bool before;
  BaselineKernels() : before(set_avx2_kernels_enabled(false)) {}
  ~BaselineKernels() { set_avx2_kernels_enabled(before); }
};

TEST(Simd, BaselineAndAvx2KernelsGiveTheSameDeformation) {
  if (!cpu_has_avx2_fma()) GTEST_SKIP() << "CPU without AVX2+FMA: only the baseline build runs";
  Vertices V;
  Faces F;
  meshes::make_grid(60, 40, &V, &F);
  AnchorList anchors(2);
  for (int i = 0; i < F.rows(); ++i) {
    const double x = (V(F(i, 0), 0) + V(F(i, 1), 0) + V(F(i, 2), 0)) / 3.0;
    if (x < 2.0) anchors[0].push_back(i);
    if (x > 58.0) anchors[1].push_back(i);
  }
  ASSERT_FALSE(anchors[0].empty());
  ASSERT_FALSE(anchors[1].empty());
  const DualEdges de = dual_edges(F);
  Eigen::VectorXd shear(F.rows());
  for (int i = 0; i < F.rows(); ++i) shear(i) = 0.01 + (i % 7) * 0.2;
  const MaterialDeformer d(V, F, anchors, shear, RowMatrix::Constant(de.pairs.rows(), 1, 0.5));

  std::vector<Eigen::Matrix4d> T(2, Eigen::Matrix4d::Identity());
  T[1].topLeftCorner<3, 3>() =
      1.3 * Eigen::AngleAxisd(2.0, Eigen::Vector3d(0.3, 1, 0.2).normalized()).toRotationMatrix();
  T[1].topRightCorner<3, 1>() << 0.2, -0.4, 0.5;
  const Vertices fast = d.deform(T, true, nullptr);
  Vertices base;
  {
    const BaselineKernels off;
    ASSERT_FALSE(cpu_has_avx2_fma());
    base = d.deform(T, true, nullptr);
  }
  // Same math, different rounding (FMA, summation order): equal to round-off, and the pose is
  // far from rest, so a kernel that dropped or doubled a term would be off by O(1).
  EXPECT_GT((fast - V).cwiseAbs().maxCoeff(), 5.0);
  EXPECT_LT((fast - base).cwiseAbs().maxCoeff(), 1e-11);
}

}  // namespace
