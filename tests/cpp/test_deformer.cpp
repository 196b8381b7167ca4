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
// A tube large enough for every parallel path of deform() (blend, right-hand side, substitution).
void big_bar(Vertices* V, Faces* F) { meshes::make_bar(5000, 500.0, V, F); }

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
  big_bar(&V, &F);
  const int m = static_cast<int>(F.rows());
  const DualEdges dual = dual_edges(F);
  const AnchorList anchors = {{m - 4, m - 3}, {m - 2, m - 1}};
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
  matdeform::set_num_threads(before);
}
