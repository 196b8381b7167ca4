#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <chrono>
#include <future>
#include <memory>
#include <vector>

#include "matdeform/deformer.hpp"
#include "matdeform/mesh.hpp"
#include "matdeform/threads.hpp"
#include "test_meshes.hpp"
#include "test_timeout.hpp"

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

namespace {
Eigen::Matrix4d affine(double scale, double angle, const Eigen::Vector3d& axis,
                       const Eigen::Vector3d& t) {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() = scale * Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  T.topRightCorner<3, 1>() = t;
  return T;
}
Eigen::RowVector3d image(const Eigen::Matrix4d& T, const Vertices& V, int v) {
  return (T.topLeftCorner<3, 3>() * V.row(v).transpose() + T.topRightCorner<3, 1>()).transpose();
}
}  // namespace

TEST(Deformer, AnchorsSharingVerticesTakeTheMeanOfTheirTransforms) {
  // Segments 3 and 4 of the bar (faces 24-31 and 32-39) are two anchors sharing ring 4
  // (vertices 16-19), with different transforms; the end caps are two more.
  Vertices V;
  Faces F;
  meshes::make_bar(10, 10.0, &V, &F);
  const int m = static_cast<int>(F.rows());
  AnchorList anchors = {{m - 4, m - 3}, {}, {}, {m - 2, m - 1}};
  for (int f = 24; f < 32; ++f) anchors[1].push_back(f);
  for (int f = 32; f < 40; ++f) anchors[2].push_back(f);
  const DualEdges dual = dual_edges(F);
  const MaterialDeformer d(V, F, anchors, Eigen::VectorXd::Ones(m),
                           RowMatrix::Ones(dual.pairs.rows(), 1));
  const std::vector<Eigen::Matrix4d> T = {
      Eigen::Matrix4d::Identity(), affine(1.0, 0.6, {0, 0, 1}, {0, 0.5, 0}),
      affine(1.3, -0.9, {0, 1, 0.2}, {0.4, 0, 0.2}), affine(0.8, 1.2, {1, 0, 0}, {0, 1, 0})};
  const Vertices X = d.deform(T, true, nullptr);
  for (int v = 12; v < 16; ++v) EXPECT_LT((X.row(v) - image(T[1], V, v)).norm(), 1e-12);
  for (int v = 16; v < 20; ++v) {
    EXPECT_LT((X.row(v) - 0.5 * (image(T[1], V, v) + image(T[2], V, v))).norm(), 1e-12);
  }
  for (int v = 20; v < 24; ++v) EXPECT_LT((X.row(v) - image(T[2], V, v)).norm(), 1e-12);
  // One more translation for every anchor moves the whole result by it (the blended targets
  // do not see translations; the fixed positions, means included, all move by t).
  const Eigen::Vector3d t(0.3, -2.0, 1.5);
  std::vector<Eigen::Matrix4d> moved = T;
  for (auto& M : moved) M.topRightCorner<3, 1>() += t;
  const Vertices Y = d.deform(moved, true, nullptr);
  EXPECT_LT(((Y.rowwise() - t.transpose()) - X).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_GT((X - V).cwiseAbs().maxCoeff(), 0.5);
}

TEST(Deformer, PinnedAnchorVerticesFollowTheirAnchorOnlyWithATranslation) {
  // Pinned without positions: a pinned vertex of an anchor face follows that anchor's full
  // transform when the transforms are 4x4, and stays at rest when they are 3x3 (no translation
  // to follow); a pinned vertex of no anchor stays at rest either way.
  Vertices V;
  Faces F;
  meshes::make_bar(10, 10.0, &V, &F);
  const int m = static_cast<int>(F.rows());
  DeformerOptions options;
  options.pinned = std::vector<int>{0, 1, 2, 3, 20};  // the first cap's ring, one mid vertex
  const DualEdges dual = dual_edges(F);
  const MaterialDeformer d(V, F, {{m - 4, m - 3}, {m - 2, m - 1}}, Eigen::VectorXd::Ones(m),
                           RowMatrix::Ones(dual.pairs.rows(), 1), options);
  const std::vector<Eigen::Matrix4d> T = {affine(1.2, 0.7, {0, 1, 1}, {0.5, -1, 2}),
                                          affine(1.0, -0.4, {1, 0, 0}, {0, 0.3, 0})};
  const Vertices X = d.deform(T, true, nullptr);
  for (int v = 0; v < 4; ++v) EXPECT_LT((X.row(v) - image(T[0], V, v)).norm(), 1e-12);
  EXPECT_EQ(X.row(20), V.row(20));
  const Vertices Y = d.deform(T, false, nullptr);
  for (int v : {0, 1, 2, 3, 20}) EXPECT_EQ(Y.row(v), V.row(v));
  EXPECT_GT((Y - V).cwiseAbs().maxCoeff(), 0.1);  // the rest of the bar did bend
}

TEST(Deformer, RegionBoundaryVerticesOfAnAnchorFaceStayAtRest) {
  // The region is segments 2-9 and the far cap; its boundary is ring 2 (vertices 8-11), which
  // the anchor on segment 2 shares with the outside: that ring stays at rest, ring 3 follows.
  Vertices V;
  Faces F;
  meshes::make_bar(10, 10.0, &V, &F);
  const int m = static_cast<int>(F.rows());
  DeformerOptions options;
  options.region = std::vector<int>();
  for (int f = 16; f < 80; ++f) options.region->push_back(f);
  options.region->insert(options.region->end(), {m - 2, m - 1});
  AnchorList anchors = {{}, {m - 2, m - 1}};
  for (int f = 16; f < 24; ++f) anchors[0].push_back(f);
  const DualEdges dual = dual_edges(F);
  const MaterialDeformer d(V, F, anchors, Eigen::VectorXd::Ones(m),
                           RowMatrix::Ones(dual.pairs.rows(), 1), options);
  const std::vector<Eigen::Matrix4d> T = {affine(1.0, 0.5, {0, 0, 1}, {0, 0.4, 0.1}),
                                          affine(1.0, 0.0, {1, 0, 0}, {0.2, 0, 0})};
  const Vertices X = d.deform(T, true, nullptr);
  for (int v = 8; v < 12; ++v) EXPECT_EQ(X.row(v), V.row(v));
  for (int v = 12; v < 16; ++v) EXPECT_LT((X.row(v) - image(T[0], V, v)).norm(), 1e-12);
  for (int v = 40; v < 44; ++v) EXPECT_LT((X.row(v) - image(T[1], V, v)).norm(), 1e-12);
}

TEST(Deformer, DifferentAnchorTurnsAboutOneAxisCommuteWithATurnAboutIt) {
  // Anchor transforms s_a R_x(theta_a) blend to s R_x(theta) per face, so a further scaled
  // turn G about the same axis (through the origin) gives G times the result, although the
  // anchors' transforms differ and the bar bends between them.
  Vertices V;
  Faces F;
  meshes::make_bar(12, 12.0, &V, &F);
  const int m = static_cast<int>(F.rows());
  const DualEdges dual = dual_edges(F);
  Eigen::VectorXd shear(m);
  for (int f = 0; f < m; ++f) shear(f) = 0.2 + 0.1 * (f % 7);
  RowMatrix bend(dual.pairs.rows(), 1);
  for (Eigen::Index e = 0; e < bend.rows(); ++e) bend(e, 0) = 0.3 + 0.2 * (e % 5);
  const MaterialDeformer d(V, F, {{m - 4, m - 3}, {48, 49, 50, 51}, {m - 2, m - 1}}, shear, bend);
  const Eigen::Vector3d x(1, 0, 0);
  const std::vector<Eigen::Matrix4d> T = {affine(1.0, 0.3, x, {0, 0.2, 0}),
                                          affine(1.2, 1.4, x, {0.5, 0, 0.3}),
                                          affine(0.9, -0.8, x, {0, 0, 1})};
  const Eigen::Matrix4d G = affine(1.1, 0.7, x, Eigen::Vector3d::Zero());
  std::vector<Eigen::Matrix4d> GT;
  for (const auto& M : T) GT.push_back(G * M);
  const Vertices X = d.deform(T, true, nullptr);
  const Vertices Y = d.deform(GT, true, nullptr);
  const Vertices expect = X * G.topLeftCorner<3, 3>().transpose();
  EXPECT_LT((Y - expect).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_GT((X - V).cwiseAbs().maxCoeff(), 0.5);
}

namespace {
// A mesh large enough for every parallel path of deform(): blend and right-hand side (8192
// faces per task) and the threaded substitution (from ~400k factor entries; a thin bar of the
// same face count has a narrow band factor and stays below that).
void big_mesh(Vertices* V, Faces* F) { meshes::make_grid(160, 140, V, F); }

std::vector<Eigen::Matrix4d> pose(int i) {
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() =
      Eigen::AngleAxisd(0.05 * i, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.topRightCorner<3, 1>() << 0.1 * i, 1.0, -0.5;
  return {Eigen::Matrix4d::Identity(), T};
}
}  // namespace

TEST(Deformer, ConcurrentCallsMatchSerialOnesExactly) {
  // Issue 11: two threads with their own deformers hung or returned errors up to 5e5; one shared
  // deformer gave wrong results. Every concurrent result must equal the serial one bit for bit.
  const int before = num_threads();
  set_num_threads(2);  // the pool's parallel paths, also on a one-core machine
  Vertices V;
  Faces F;
  big_mesh(&V, &F);
  const int m = static_cast<int>(F.rows());
  const DualEdges dual = dual_edges(F);
  const AnchorList anchors = {{0, 1}, {m - 2, m - 1}};
  auto make = [&] {
    return std::make_unique<MaterialDeformer>(V, F, anchors, Eigen::VectorXd::Ones(m),
                                              RowMatrix::Ones(dual.pairs.rows(), 1));
  };
  const auto shared = make();
  constexpr int kPoses = 12;
  std::vector<Vertices> expect;
  for (int i = 0; i < kPoses; ++i) expect.push_back(shared->deform(pose(i), true, nullptr));

  auto worker = [&](int offset) {
    // Each thread builds its own deformer, both at once: concurrent factorisations too.
    const auto own = make();
    int wrong = own->weights() != shared->weights();
    for (int rep = 0; rep < 3; ++rep) {
      for (int i = 0; i < kPoses; ++i) {
        const int p = (i + offset) % kPoses;
        if (own->deform(pose(p), true, nullptr) != expect[p]) ++wrong;
        if (shared->deform(pose(p), true, nullptr) != expect[p]) ++wrong;
      }
    }
    return wrong;
  };
  auto a = std::async(std::launch::async, worker, 0);
  auto b = std::async(std::launch::async, worker, 5);
  EXPECT_EQ(test_timeout::get_or_exit(a, 120, "deform thread a"), 0);
  EXPECT_EQ(test_timeout::get_or_exit(b, 120, "deform thread b"), 0);
  EXPECT_EQ(shared->substitution_threads(), 2);  // the threaded substitution was reached
  matdeform::set_num_threads(before);
}

namespace {
// Bar along x (48 segments, length 12) with an anchor at each end cap, uniform stiffness.
struct TwistBar {
  Vertices V;
  Faces F;
  std::unique_ptr<MaterialDeformer> d;
  TwistBar() {
    meshes::make_bar(48, 12.0, &V, &F);
    const int m = static_cast<int>(F.rows());
    const DualEdges dual = dual_edges(F);
    d = std::make_unique<MaterialDeformer>(V, F, AnchorList{{m - 4, m - 3}, {m - 2, m - 1}},
                                           Eigen::VectorXd::Ones(m),
                                           RowMatrix::Ones(dual.pairs.rows(), 1));
  }
};
}  // namespace

TEST(Deformer, RotationVectorsBlendTurnsPastHalfATurn) {
  // The tip turns by 3 pi (540 degrees) about the bar's axis: each face's transform is Eq. 2
  // with the given branch, exp(w_f * 3 pi x) (the principal log would give exp(w_f * pi x)),
  // and the middle ring turns by about 270 degrees.
  TwistBar bar;
  const double total = 3 * M_PI;
  const std::vector<Eigen::Matrix4d> T = {Eigen::Matrix4d::Identity(),
                                          affine(1.0, total, {1, 0, 0}, {0, 0, 0})};
  Vectors3 rv = Vectors3::Zero(2, 3);
  rv(1, 0) = total;
  const Vertices X = bar.d->deform(T, true, nullptr, &rv);
  const Matrix3Array Tf = bar.d->face_transforms();
  const RowMatrix& W = bar.d->weights();
  double worst = 0.0;
  for (size_t f = 0; f < Tf.size(); ++f) {
    const Eigen::Matrix3d expect =
        Eigen::AngleAxisd(W(static_cast<Eigen::Index>(f), 1) * total, Eigen::Vector3d::UnitX())
            .toRotationMatrix();
    worst = std::max(worst, (Tf[f] - expect).cwiseAbs().maxCoeff());
  }
  EXPECT_LT(worst, 1e-12);
  // Ring 24 of 48 (vertices 96-99), corners at angles 225, 315, 45, 135 degrees at rest: each
  // corner turned by 270 degrees +- 2 (harmonic weights on the bar are linear along it).
  for (int v = 96; v < 100; ++v) {
    const double rest = std::atan2(bar.V(v, 2), bar.V(v, 1));
    const double now = std::atan2(X(v, 2), X(v, 1));
    const double turn = std::remainder(now - rest - 1.5 * M_PI, 2 * M_PI) + 1.5 * M_PI;
    EXPECT_NEAR(turn, 1.5 * M_PI, 2.0 * M_PI / 180.0) << "vertex " << v;
  }
}

TEST(Deformer, PrincipalRotationVectorsGiveBitIdenticalResults) {
  // The vectors deform() would compute itself (rotation_log of each polar factor) give the same
  // bits as none given, on the similarity path and with a non-uniformly scaled anchor.
  TwistBar bar;
  for (const bool scaled : {false, true}) {
    std::vector<Eigen::Matrix4d> T = {affine(1.1, 0.4, {0, 1, 1}, {0, 1, 0}),
                                      affine(0.9, 2.9, {1, 0.2, 0}, {1, 0, 2})};
    if (scaled) T[1].topLeftCorner<3, 3>() *= Eigen::Vector3d(1.3, 1.0, 0.8).asDiagonal();
    Vectors3 rv(2, 3);
    for (int a = 0; a < 2; ++a) {
      rv.row(a) = transform_log(T[static_cast<size_t>(a)].topLeftCorner<3, 3>()).rotation;
    }
    const Vertices X0 = bar.d->deform(T, true, nullptr);
    const Vertices X1 = bar.d->deform(T, true, nullptr, &rv);
    EXPECT_TRUE((X0.array() == X1.array()).all()) << "scaled=" << scaled;
    std::vector<float> f0(static_cast<size_t>(3 * X0.rows())), f1(f0.size());
    bar.d->deform(T, true, nullptr, f0.data());
    bar.d->deform(T, true, nullptr, f1.data(), &rv);
    EXPECT_EQ(f0, f1);
  }
}

TEST(Deformer, InconsistentRotationVectorsThrowAndChangeNothing) {
  TwistBar bar;
  const std::vector<Eigen::Matrix4d> T = {Eigen::Matrix4d::Identity(),
                                          affine(1.0, 1.0, {1, 0, 0}, {0, 0, 0})};
  Vectors3 good = Vectors3::Zero(2, 3);
  good(1, 0) = 1.0 + 2 * M_PI;
  const Vertices X = bar.d->deform(T, true, nullptr, &good);
  const Matrix3Array before = bar.d->face_transforms();
  std::vector<float> out(static_cast<size_t>(3 * X.rows()), 7.0f);
  // Off by 2e-4 rad (twice the tolerance), the other sign, another axis, the wrong number of
  // turns about another axis, NaN, too long to exponentiate, the wrong number of rows.
  std::vector<Vectors3> bad(6, good);
  bad[0](1, 0) += 2e-4;
  bad[1](1, 0) = -1.0;
  bad[2].row(1) << 0, 1.0, 0;
  bad[3].row(0) << 0, 2 * M_PI, 0.5;
  bad[4](0, 2) = std::nan("");
  bad[5](0, 1) = 1e200;
  bad.push_back(Vectors3::Zero(3, 3));
  for (size_t i = 0; i < bad.size(); ++i) {
    EXPECT_THROW(bar.d->deform(T, true, nullptr, &bad[i]), std::invalid_argument) << i;
    EXPECT_THROW(bar.d->deform(T, true, nullptr, out.data(), &bad[i]), std::invalid_argument);
  }
  const Matrix3Array after = bar.d->face_transforms();
  for (size_t f = 0; f < before.size(); ++f) EXPECT_EQ(before[f], after[f]);
  for (float x : out) EXPECT_EQ(x, 7.0f);
  // Within the tolerance: accepted (half of it off).
  Vectors3 close = good;
  close(1, 0) += 0.5e-4;
  EXPECT_NO_THROW(bar.d->deform(T, true, nullptr, &close));
}
