// Closed-form checks of stiffness learning (Popa et al. 2006, Sec. 6).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "matdeform/learn.hpp"
#include "matdeform/mesh.hpp"
#include "test_meshes.hpp"

namespace md = matdeform;
using md::meshes::make_grid;

namespace {

// Folds everything right of the line x = x0 about the y axis by `angle` (a rigid hinge).
md::Vertices fold(const md::Vertices& V, double x0, double angle) {
  md::Vertices out = V;
  const Eigen::Matrix3d R = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Vector3d c(x0, 0, 0);
  for (Eigen::Index v = 0; v < V.rows(); ++v) {
    if (V(v, 0) > x0) out.row(v) = (R * (V.row(v).transpose() - c) + c).transpose();
  }
  return out;
}

md::Vertices rigid(const md::Vertices& V, const Eigen::Vector3d& axis, double angle,
                   const Eigen::Vector3d& t) {
  const Eigen::Matrix3d R = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  md::Vertices out = V;
  for (Eigen::Index v = 0; v < V.rows(); ++v)
    out.row(v) = (R * V.row(v).transpose() + t).transpose();
  return out;
}

// Dual edges whose shared mesh edge lies on the line x = x0.
std::vector<bool> on_line(const md::Vertices& V, const md::DualEdges& d, double x0) {
  std::vector<bool> out(static_cast<size_t>(d.pairs.rows()));
  for (Eigen::Index e = 0; e < d.pairs.rows(); ++e) {
    out[static_cast<size_t>(e)] = V(d.shared(e, 0), 0) == x0 && V(d.shared(e, 1), 0) == x0;
  }
  return out;
}

class HingeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    make_grid(10, 3, &V, &F);
    dual = md::dual_edges(F);
    // Pose 0 bends at x = 3 (twice, the larger angle counts), pose 1 at x = 7.
    poses = {fold(V, 3.0, 0.4), fold(V, 7.0, -1.1), fold(V, 3.0, -0.7)};
  }
  md::Vertices V;
  md::Faces F;
  md::DualEdges dual;
  std::vector<md::Vertices> poses;
};

constexpr double kPi = 3.14159265358979323846;

double frob_sq_rotation_gap(double angle) { return 8.0 * std::pow(std::sin(angle / 2.0), 2); }

}  // namespace

TEST_F(HingeTest, IsotropicDistortionIsMaxOverPosesAtHingesOnly) {
  const md::Distortions d = md::learn_distortions(V, F, dual.pairs, poses, false);
  ASSERT_EQ(d.bend.rows(), dual.pairs.rows());
  ASSERT_EQ(d.bend.cols(), 1);
  const auto at3 = on_line(V, dual, 3.0), at7 = on_line(V, dual, 7.0);
  int hinges = 0;
  for (Eigen::Index e = 0; e < d.bend.rows(); ++e) {
    const auto u = static_cast<size_t>(e);
    const double want = at3[u] ? frob_sq_rotation_gap(0.7) : at7[u] ? frob_sq_rotation_gap(1.1) : 0;
    hinges += at3[u] || at7[u];
    EXPECT_NEAR(d.bend(e, 0), want, 1e-12) << "edge " << e;
  }
  EXPECT_EQ(hinges, 6);  // 3 quads high, one diagonal-free vertical edge per row per hinge
  EXPECT_LT(d.shear.maxCoeff(), 1e-20);  // rigid folds: no stretch anywhere
}

TEST_F(HingeTest, LearnedBendingIsMinimalExactlyAtHinges) {
  md::StiffnessMap map;
  map.eps = 0.05;
  map.clamp_percent = 0.0;
  const md::LearnedStiffness s = md::learn_stiffness(V, F, dual.pairs, poses, false, map);
  const auto at3 = on_line(V, dual, 3.0), at7 = on_line(V, dual, 7.0);
  for (Eigen::Index e = 0; e < s.bend.rows(); ++e) {
    const auto u = static_cast<size_t>(e);
    if (at7[u]) {
      EXPECT_NEAR(s.bend(e, 0), 0.05, 1e-12);  // the largest bend maps to eps
    } else if (at3[u]) {
      const double ratio = frob_sq_rotation_gap(0.7) / frob_sq_rotation_gap(1.1);
      EXPECT_NEAR(s.bend(e, 0), 0.05 + 0.95 * (1.0 - ratio), 1e-12);
    } else {
      EXPECT_DOUBLE_EQ(s.bend(e, 0), 1.0);
    }
  }
  // No face stretched: all shear stiffness is 1.
  EXPECT_DOUBLE_EQ(s.shear.minCoeff(), 1.0);
}

TEST_F(HingeTest, AnisotropicBendingSeesOnlyTheHingeAxis) {
  for (md::AxisFrame frame : {md::AxisFrame::kRest, md::AxisFrame::kWorldLogDifference}) {
    const md::Distortions d = md::learn_distortions(V, F, dual.pairs, poses, true, frame);
    ASSERT_EQ(d.bend.cols(), 3);
    const auto at3 = on_line(V, dual, 3.0), at7 = on_line(V, dual, 7.0);
    for (Eigen::Index e = 0; e < d.bend.rows(); ++e) {
      const auto u = static_cast<size_t>(e);
      const double want = at3[u] ? 0.7 * 0.7 : at7[u] ? 1.1 * 1.1 : 0.0;
      EXPECT_NEAR(d.bend(e, 0), 0.0, 1e-20);
      EXPECT_NEAR(d.bend(e, 1), want, 1e-12);  // folds turn about y
      EXPECT_NEAR(d.bend(e, 2), 0.0, 1e-20);
    }
  }
}

TEST_F(HingeTest, InvariantToRigidMotionOfEachPose) {
  const md::Distortions a = md::learn_distortions(V, F, dual.pairs, poses, false);
  const md::Distortions aa = md::learn_distortions(V, F, dual.pairs, poses, true);
  std::vector<md::Vertices> moved = {
      rigid(poses[0], Eigen::Vector3d(1, 2, 3), 2.5, Eigen::Vector3d(4, -1, 7)),
      rigid(poses[1], Eigen::Vector3d(-1, 0, 1), 1.0, Eigen::Vector3d(0, 0, -3)),
      rigid(poses[2], Eigen::Vector3d(0, 1, 0), 3.0, Eigen::Vector3d(1, 1, 1))};
  const md::Distortions b = md::learn_distortions(V, F, dual.pairs, moved, false);
  const md::Distortions bb = md::learn_distortions(V, F, dual.pairs, moved, true);
  EXPECT_LT((a.bend - b.bend).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((a.shear - b.shear).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((aa.bend - bb.bend).cwiseAbs().maxCoeff(), 1e-12);
}

TEST_F(HingeTest, SmoothingSpreadsAroundTheHinges) {
  md::StiffnessMap map;
  map.clamp_percent = 0.0;
  const md::LearnedStiffness s =
      md::learn_stiffness(V, F, dual.pairs, poses, false, map, md::AxisFrame::kRest, 2);
  Eigen::Index argmin = 0;
  const double lowest = s.bend.col(0).minCoeff(&argmin);
  EXPECT_NEAR(lowest, 0.01, 1e-12);  // the smoothed maximum still maps to eps
  // ... and it sits next to the larger fold at x = 7, not at x = 3 or far away.
  const double x = 0.5 * (V(dual.shared(argmin, 0), 0) + V(dual.shared(argmin, 1), 0));
  EXPECT_GE(x, 6.0);
  EXPECT_LE(x, 8.0);
  int softened = 0;
  for (Eigen::Index e = 0; e < s.bend.rows(); ++e) {
    const double xe = std::max(V(dual.shared(e, 0), 0), V(dual.shared(e, 1), 0));
    if (xe <= 1.0) {
      EXPECT_DOUBLE_EQ(s.bend(e, 0), 1.0);  // out of reach of two passes
    }
    softened += s.bend(e, 0) < 1.0;
  }
  EXPECT_GT(softened, 12);  // more than the 6 hinge edges are now flexible
}

TEST(SmoothDistortions, ClosedFormOnTwoFacesAndConstantsPreserved) {
  md::IndexPairs pairs(1, 2);
  pairs << 0, 1;
  md::Distortions d;
  d.bend = md::RowMatrix::Constant(1, 3, 0.5);
  d.shear = Eigen::Vector2d(1.0, 3.0);
  const md::Distortions s = md::smooth_distortions(d, 2, pairs, 1);
  EXPECT_NEAR(s.shear(0), 2.0, 1e-15);
  EXPECT_NEAR(s.shear(1), 2.0, 1e-15);
  EXPECT_NEAR((s.bend.array() - 0.5).abs().maxCoeff(), 0.0, 1e-15);

  md::Vertices V;
  md::Faces F;
  make_grid(5, 4, &V, &F);
  const md::IndexPairs grid_pairs = md::dual_edges(F).pairs;
  md::Distortions c;
  c.bend = md::RowMatrix::Constant(grid_pairs.rows(), 1, 0.25);
  c.shear = Eigen::VectorXd::Constant(F.rows(), 0.75);
  const md::Distortions cs = md::smooth_distortions(c, static_cast<int>(F.rows()), grid_pairs, 7);
  EXPECT_LT((cs.bend.array() - 0.25).abs().maxCoeff(), 1e-14);
  EXPECT_LT((cs.shear.array() - 0.75).abs().maxCoeff(), 1e-14);
  EXPECT_THROW(md::smooth_distortions(c, static_cast<int>(F.rows()), grid_pairs, -1),
               std::invalid_argument);
}

TEST(LearnShear, UniformStretchMatchesClosedForm) {
  md::Vertices V;
  md::Faces F;
  make_grid(4, 4, &V, &F);
  md::Vertices P = V;
  P.col(0) *= 2.0;
  // In-plane x doubles; the fourth vertex offset n / sqrt|n| grows by sqrt(2) since the area
  // doubles, so T = S = diag(2, 1, sqrt 2) on every face.
  const md::Distortions d = md::learn_distortions(V, F, md::dual_edges(F).pairs, {P}, false);
  const double want = 1.0 + std::pow(std::sqrt(2.0) - 1.0, 2);
  for (Eigen::Index i = 0; i < F.rows(); ++i) EXPECT_NEAR(d.shear(i), want, 1e-12);
  EXPECT_LT(d.bend.maxCoeff(), 1e-24);
}

namespace {
// Frame of face f with the fourth vertex at n / sqrt|n| (written here, not frames.hpp's).
Eigen::Matrix3d frame_of(const md::Vertices& X, const md::Faces& F, int f) {
  const Eigen::Vector3d a = X.row(F(f, 0)), b = X.row(F(f, 1)), c = X.row(F(f, 2));
  const Eigen::Vector3d n = (b - a).cross(c - a);
  Eigen::Matrix3d M;
  M << b - a, c - a, n / std::sqrt(n.norm());
  return M;
}
// Polar factors T = S Q of face f's deformation gradient, S = sqrt(T T^T) by an eigen-solve.
void polar_of(const md::Vertices& rest, const md::Vertices& pose, const md::Faces& F, int f,
              Eigen::Matrix3d* S, Eigen::Matrix3d* Q) {
  const Eigen::Matrix3d T = frame_of(pose, F, f) * frame_of(rest, F, f).inverse();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(T * T.transpose());
  *S = es.operatorSqrt();
  *Q = S->inverse() * T;
}
}  // namespace

TEST(LearnShear, CollapsedFacesAreSkipped) {
  md::Vertices V;
  md::Faces F;
  make_grid(2, 1, &V, &F);  // faces 0 = (0,1,4), 1 = (0,4,3) left, 2 = (1,2,5), 3 = (1,5,4) right
  md::Vertices P = V;
  P.row(4) << 0.0, 0.5, 0.0;  // vertex (1,1) onto edge (0,0)-(0,1): face 1 = (0,4,3) collapses
  const md::DualEdges dual = md::dual_edges(F);
  ASSERT_EQ(dual.pairs.rows(), 3);  // (0,1), (0,3), (2,3)
  Eigen::Matrix3d S0, Q0, S3, Q3;
  polar_of(V, P, F, 0, &S0, &Q0);  // face 0 is squashed, not collapsed
  polar_of(V, P, F, 3, &S3, &Q3);
  for (bool aniso : {false, true}) {
    const md::Distortions d = md::learn_distortions(V, F, dual.pairs, {V, P}, aniso);
    EXPECT_EQ(d.shear(1), 0.0);  // only the rest pose counted for the collapsed face
    // The edge to the collapsed face: that pose is skipped, only the rest pose counts.
    EXPECT_EQ(d.bend.row(0).cwiseAbs().maxCoeff(), 0.0) << "aniso " << aniso;
    EXPECT_NEAR(d.shear(0), (S0 - Eigen::Matrix3d::Identity()).squaredNorm(), 1e-12);
    EXPECT_GT(d.shear(0), 0.1);
    EXPECT_NEAR(d.shear(3), (S3 - Eigen::Matrix3d::Identity()).squaredNorm(), 1e-12);
    EXPECT_NEAR(d.shear(2), 0.0, 1e-24);  // face 2 does not move
    if (!aniso) {
      EXPECT_NEAR(d.bend(1, 0), (Q0 - Q3).squaredNorm(), 1e-12);
      EXPECT_NEAR(d.bend(2, 0), (Eigen::Matrix3d::Identity() - Q3).squaredNorm(), 1e-12);
      EXPECT_GT(d.bend(1, 0), 1e-3);
    } else {
      // Rest frame: the relative rotation's axis-angle components, squared. The grid stays in
      // its plane, so the turns are about z only.
      const Eigen::AngleAxisd r03(Q0.transpose() * Q3), r23(Q3);
      EXPECT_NEAR(d.bend(1, 2), std::pow(r03.angle() * r03.axis().z(), 2), 1e-12);
      EXPECT_NEAR(d.bend(2, 2), std::pow(r23.angle() * r23.axis().z(), 2), 1e-12);
      EXPECT_NEAR(d.bend.leftCols(2).cwiseAbs().maxCoeff(), 0.0, 1e-20);
    }
  }
}

TEST(Learn, FaceCollapsedInAPoseIsLeftOutOfEveryStatistic) {
  // A 4x3 grid whose corner vertex (4,0) belongs to face 6 = (3,4,9) only: moving it onto
  // vertex 9 collapses that face (exactly, also after the rigid motion) and nothing else. The
  // pose is the grid turned and moved rigidly: every other face has the same rotation, so
  // every statistic is zero once face 6 is left out (rest pose first: a stale rotation of
  // face 6 would be the identity).
  md::Vertices V;
  md::Faces F;
  make_grid(4, 3, &V, &F);
  ASSERT_EQ(F(6, 0), 3);
  ASSERT_EQ(F(6, 1), 4);
  ASSERT_EQ(F(6, 2), 9);
  md::Vertices P = rigid(V, Eigen::Vector3d(1, 2, 3), 2.0, Eigen::Vector3d(1, -2, 0.5));
  P.row(4) = P.row(9);
  const md::IndexPairs pairs = md::dual_edges(F).pairs;
  // Face 6's only dual edge is (6,7): the collapsed face is the first of the pair.
  int at6 = 0;
  for (Eigen::Index e = 0; e < pairs.rows(); ++e) at6 += pairs(e, 0) == 6 || pairs(e, 1) == 6;
  ASSERT_EQ(at6, 1);
  for (md::AxisFrame frame : {md::AxisFrame::kRest, md::AxisFrame::kWorldLogDifference}) {
    for (bool aniso : {false, true}) {
      const md::Distortions d = md::learn_distortions(V, F, pairs, {V, P}, aniso, frame);
      EXPECT_NEAR(d.bend.cwiseAbs().maxCoeff(), 0.0, 1e-12) << "aniso " << aniso;
      EXPECT_NEAR(d.shear.cwiseAbs().maxCoeff(), 0.0, 1e-12);
    }
  }
  // rotation_spread: face 6 has weight 0 in the averages, the others all see one rotation.
  // (Normalising by the weight w instead of w^2 would give 3 (1 - w) > 0 next to face 6.)
  const md::RowMatrix s = md::rotation_spread(V, F, pairs, {P, V}, 2);
  EXPECT_NEAR(s.cwiseAbs().maxCoeff(), 0.0, 1e-12);
}

TEST(Learn, WorldFrameTakesTheClosestLogNearPi) {
  // Hinge folds of the strip about y, each pose then turned about y by nearly pi: the faces on
  // one side of the hinge have angle < pi, the other side's > pi, so their principal logs point
  // opposite ways. The world-frame difference of the logs is still the fold angle (same axis),
  // as in the rest frame; the plain difference of the principal logs would be ~2 pi - angle.
  md::Vertices V;
  md::Faces F;
  make_grid(10, 3, &V, &F);
  const md::DualEdges dual = md::dual_edges(F);
  const Eigen::Vector3d y = Eigen::Vector3d::UnitY(), zero = Eigen::Vector3d::Zero();
  const std::vector<md::Vertices> poses = {rigid(fold(V, 3.0, 0.4), y, kPi - 0.1, zero),
                                           rigid(fold(V, 7.0, 1.1), y, kPi - 0.5, zero)};
  const auto at3 = on_line(V, dual, 3.0), at7 = on_line(V, dual, 7.0);
  for (md::AxisFrame frame : {md::AxisFrame::kRest, md::AxisFrame::kWorldLogDifference}) {
    const md::Distortions d = md::learn_distortions(V, F, dual.pairs, poses, true, frame);
    for (Eigen::Index e = 0; e < d.bend.rows(); ++e) {
      const auto u = static_cast<size_t>(e);
      const double want = at3[u] ? 0.4 * 0.4 : at7[u] ? 1.1 * 1.1 : 0.0;
      EXPECT_NEAR(d.bend(e, 1), want, 1e-9) << "edge " << e;
      EXPECT_NEAR(d.bend(e, 0) + d.bend(e, 2), 0.0, 1e-9);
    }
  }
}

TEST(StiffnessMap, LinearAndExponentialClosedForm) {
  md::RowMatrix d(4, 1);
  d << 0.0, 1.0, 2.0, 4.0;
  md::StiffnessMap map;
  map.eps = 0.1;
  map.clamp_percent = 0.0;
  md::RowMatrix s = md::stiffness_from_distortion(d, map);
  EXPECT_NEAR(s(0), 1.0, 1e-15);
  EXPECT_NEAR(s(1), 0.1 + 0.9 * 0.75, 1e-15);
  EXPECT_NEAR(s(2), 0.1 + 0.9 * 0.5, 1e-15);
  EXPECT_NEAR(s(3), 0.1, 1e-15);
  map.sharpness = 3.0;
  s = md::stiffness_from_distortion(d, map);
  const double g = (std::exp(-1.5) - std::exp(-3.0)) / (1.0 - std::exp(-3.0));
  EXPECT_NEAR(s(2), 0.1 + 0.9 * g, 1e-15);
  EXPECT_NEAR(s(0), 1.0, 1e-15);
  EXPECT_NEAR(s(3), 0.1, 1e-15);
}

TEST(StiffnessMap, PercentileClampKeepsOutlierFromSquashingTheScale) {
  // 0, 1, ..., 99 and one huge outlier. The 99th percentile of 101 values (linear
  // interpolation) sits at position 99 -> value 99.
  md::RowMatrix d(101, 1);
  for (int i = 0; i < 100; ++i) d(i) = i;
  d(100) = 1e6;
  md::StiffnessMap map;
  map.eps = 0.01;
  map.clamp_percent = 1.0;
  const md::RowMatrix s = md::stiffness_from_distortion(d, map);
  EXPECT_NEAR(s(50), 0.01 + 0.99 * (1.0 - 50.0 / 99.0), 1e-14);
  EXPECT_NEAR(s(99), 0.01, 1e-14);
  EXPECT_NEAR(s(100), 0.01, 1e-14);
  EXPECT_GE(s.minCoeff(), 0.01);
  EXPECT_LE(s.maxCoeff(), 1.0);
  // Without the clamp the outlier pushes every other value to within 1e-4 of stiffness 1.
  map.clamp_percent = 0.0;
  EXPECT_GT(md::stiffness_from_distortion(d, map)(99), 0.999);
}

TEST(StiffnessMap, AllZeroIsAllStiffAndBadInputThrows) {
  md::StiffnessMap map;
  EXPECT_DOUBLE_EQ(md::stiffness_from_distortion(md::RowMatrix::Zero(5, 3), map).minCoeff(), 1.0);
  md::RowMatrix neg(1, 1);
  neg << -1.0;
  EXPECT_THROW(md::stiffness_from_distortion(neg, map), std::invalid_argument);
  map.eps = 0.0;
  EXPECT_THROW(md::stiffness_from_distortion(md::RowMatrix::Zero(2, 1), map),
               std::invalid_argument);
}

TEST(LearnInput, BadPosesThrow) {
  md::Vertices V;
  md::Faces F;
  make_grid(2, 2, &V, &F);
  const md::IndexPairs pairs = md::dual_edges(F).pairs;
  EXPECT_THROW(md::learn_distortions(V, F, pairs, {}, false), std::invalid_argument);
  md::Vertices short_pose = V.topRows(V.rows() - 1);
  EXPECT_THROW(md::learn_distortions(V, F, pairs, {short_pose}, false), std::invalid_argument);
  md::Vertices nan_pose = V;
  nan_pose(2, 1) = std::nan("");
  EXPECT_THROW(md::learn_distortions(V, F, pairs, {V, nan_pose}, false), std::invalid_argument);
  md::IndexPairs bad = pairs;
  bad(0, 1) = static_cast<int>(F.rows());
  EXPECT_THROW(md::learn_distortions(V, F, bad, {V}, false), std::invalid_argument);
}

TEST(RotationSpread, ClosedFormOnTwoFacesLocalityAndRigidInvariance) {
  // A quad folded along x = 1 by theta: after one pass both faces see the mean of the two
  // rotations, so spread = 3 - |Q1 + Q2|^2 / 4 = |Q1 - Q2|^2 / 4 = 2 sin^2(theta / 2).
  md::Vertices V(4, 3);
  V << 0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0;
  md::Faces F(2, 3);
  F << 0, 1, 2, 0, 2, 3;
  md::Vertices P = V;
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(0.9, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
  P.row(3) = (R * V.row(3).transpose()).transpose();
  const md::IndexPairs pairs = md::dual_edges(F).pairs;
  const md::RowMatrix s = md::rotation_spread(V, F, pairs, {V, P}, 1);
  ASSERT_EQ(s.rows(), 2);
  ASSERT_EQ(s.cols(), 2);
  const double want = 2.0 * std::pow(std::sin(0.45), 2);
  for (int i = 0; i < 2; ++i) {
    EXPECT_NEAR(s(i, 0), 0.0, 1e-14);
    EXPECT_NEAR(s(i, 1), want, 1e-12);
  }
  EXPECT_EQ(md::rotation_spread(V, F, pairs, {P}, 0).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_THROW(md::rotation_spread(V, F, pairs, {P}, -1), std::invalid_argument);

  // A longer strip folded at x = 3: zero beyond the reach of the passes, invariant to a rigid
  // motion of the pose.
  md::Vertices G;
  md::Faces H;
  make_grid(10, 3, &G, &H);
  const md::IndexPairs gp = md::dual_edges(H).pairs;
  const md::Vertices folded = fold(G, 3.0, 0.8);
  const md::RowMatrix a = md::rotation_spread(G, H, gp, {folded}, 3);
  const md::Vertices moved = rigid(folded, Eigen::Vector3d(1, 2, 3), 2.0, Eigen::Vector3d(4, 5, 6));
  const md::RowMatrix b = md::rotation_spread(G, H, gp, {moved}, 3);
  EXPECT_LT((a - b).cwiseAbs().maxCoeff(), 1e-12);
  for (Eigen::Index i = 0; i < H.rows(); ++i) {
    const double x = (G(H(i, 0), 0) + G(H(i, 1), 0) + G(H(i, 2), 0)) / 3.0;
    if (std::abs(x - 3.0) > 3.0) {
      EXPECT_NEAR(a(i, 0), 0.0, 1e-12);
    }
  }
  EXPECT_GT(a.maxCoeff(), 0.01);
}
