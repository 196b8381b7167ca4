// The per-pose kernels exist as a baseline x86-64 build and an AVX2+FMA build (simd.hpp). Both
// must give the same deformation. Without AVX2 there is nothing to compare, and the test says so.
// Vec4d's operators are checked lane by lane on whichever path this build uses (the test command
// builds the portable one too, MATDEFORM_PORTABLE_SIMD).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <vector>

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

TEST(Simd, BuildUsesTheRequestedPath) {
#if defined(MATDEFORM_PORTABLE_SIMD) || !(defined(__GNUC__) || defined(__clang__))
  EXPECT_STREQ(simd_path(), "portable");
  EXPECT_FALSE(cpu_has_avx2_fma()) << "the portable path has no AVX2 copies";
#else
  EXPECT_STREQ(simd_path(), "vector extension");
#endif
}

TEST(Simd, Vec4dOperatorsAreLaneWise) {
  const Vec4d a = {1.5, -2.0, 3.25, 0.5}, b = {0.25, 4.0, -1.0, 2.0};
  const double s = 1.75;
  const Vec4d r[] = {a + b, a - b, a * b, a + s, s + a, a - s, s - a, a * s, s * a};
  for (int l = 0; l < 4; ++l) {
    const double want[] = {a[l] + b[l], a[l] - b[l], a[l] * b[l], a[l] + s, s + a[l],
                           a[l] - s,    s - a[l],    a[l] * s,    s * a[l]};
    for (int k = 0; k < 9; ++k) EXPECT_EQ(r[k][l], want[k]) << "operator " << k << " lane " << l;
  }
  Vec4d c = a;
  c += b;
  c *= s;
  c -= a;
  c += 2;  // an integer scalar converts, as with the vector extension
  for (int l = 0; l < 4; ++l) EXPECT_EQ(c[l], (a[l] + b[l]) * s - a[l] + 2.0);

  // The kernels read double arrays as Vec4d at any multiple of 8 bytes (a row of 4 doubles).
  double buf[9] = {0, 1, 2, 3, 4, 5, 6, 7, 8};
  Vec4d* row = reinterpret_cast<Vec4d*>(buf + 1);
  row[1] -= 0.5 * row[0];
  const double after[9] = {0, 1, 2, 3, 4, 4.5, 5, 5.5, 6};
  for (int i = 0; i < 9; ++i) EXPECT_EQ(buf[i], after[i]) << i;

  // exp4's 2^n from its exponent bits, and the bit patterns back.
  const Vec4u biased = {1023, 1024, 1020, 1023 + 52};
  const Vec4d p = (Vec4d)(biased << 52);
  const double pow2[] = {1.0, 2.0, 0.125, 4503599627370496.0};
  for (int l = 0; l < 4; ++l) EXPECT_EQ(p[l], pow2[l]);
  const Vec4u back = (Vec4u)p - (Vec4u)Vec4d{1.0, 1.0, 1.0, 1.0} + 1;
  EXPECT_EQ(back[0], 1u);
  EXPECT_EQ(back[1], (std::uint64_t{1} << 52) + 1);
}

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
