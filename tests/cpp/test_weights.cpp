#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <queue>
#include <random>
#include <vector>

#include "matdeform/mesh.hpp"
#include "matdeform/weights.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

TEST(Weights, PartitionOfUnityAnchorsExactAndMaximumPrinciple) {
  Vertices V;
  Faces F;
  meshes::make_bar(20, 10.0, &V, &F);
  const DualEdges dual = dual_edges(F);
  const int m = static_cast<int>(F.rows());
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0.001, 1.0);
  Eigen::VectorXd phi(dual.pairs.rows());
  for (Eigen::Index e = 0; e < phi.size(); ++e) phi(e) = u(rng);
  const AnchorList anchors = {{m - 4, m - 3}, {m - 2, m - 1}, {10, 11}};
  const RowMatrix W = harmonic_weights(m, dual.pairs, phi, anchors);
  ASSERT_EQ(W.rows(), m);
  ASSERT_EQ(W.cols(), 3);
  for (int i = 0; i < m; ++i) {
    EXPECT_NEAR(W.row(i).sum(), 1.0, 1e-12);
    EXPECT_GE(W.row(i).minCoeff(), -1e-14);
    EXPECT_LE(W.row(i).maxCoeff(), 1.0 + 1e-14);
  }
  for (size_t a = 0; a < anchors.size(); ++a) {
    for (int f : anchors[a]) {
      for (int b = 0; b < 3; ++b) EXPECT_EQ(W(f, b), b == static_cast<int>(a) ? 1.0 : 0.0);
    }
  }
  // Interior faces are strict mixtures: harmonic functions have no interior extrema.
  EXPECT_GT(W(static_cast<int>(m / 2), 0), 0.0);
  EXPECT_LT(W(static_cast<int>(m / 2), 0), 1.0);
}

TEST(Weights, PathGraphMatchesSeriesResistanceClosedForm) {
  // A one-square-wide strip: its dual graph is a path, where the harmonic weight of the first
  // end is the resistance (sum of 1/phi) to the far end over the total resistance.
  Vertices V;
  Faces F;
  meshes::make_grid(12, 1, &V, &F);
  const DualEdges dual = dual_edges(F);
  const int m = static_cast<int>(F.rows());
  ASSERT_EQ(dual.pairs.rows(), m - 1);
  std::vector<std::vector<std::pair<int, int>>> adj(m);
  for (int e = 0; e < dual.pairs.rows(); ++e) {
    adj[dual.pairs(e, 0)].push_back({dual.pairs(e, 1), e});
    adj[dual.pairs(e, 1)].push_back({dual.pairs(e, 0), e});
  }
  int start = -1;
  for (int f = 0; f < m; ++f)
    if (adj[f].size() == 1) start = f;
  std::vector<int> order = {start}, via = {-1};
  std::vector<char> seen(m, 0);
  seen[start] = 1;
  while (static_cast<int>(order.size()) < m) {
    for (auto [g, e] : adj[order.back()]) {
      if (!seen[g]) {
        seen[g] = 1;
        order.push_back(g);
        via.push_back(e);
        break;
      }
    }
  }
  Eigen::VectorXd phi(dual.pairs.rows());
  for (int e = 0; e < phi.size(); ++e) phi(e) = 0.1 + (e % 5) * 0.7;
  // Resistance from path position p to the far end: r[p] = sum of 1/phi over the rest.
  std::vector<double> r(m, 0.0);
  for (int p = m - 2; p >= 0; --p) r[p] = r[p + 1] + 1.0 / phi(via[p + 1]);
  // Two anchors at the ends: W0 = r[p] / r[0], W1 = 1 - W0.
  const RowMatrix W = harmonic_weights(m, dual.pairs, phi, {{order.front()}, {order.back()}});
  for (int p = 0; p < m; ++p) {
    EXPECT_NEAR(W(order[p], 0), r[p] / r[0], 1e-12) << p;
    EXPECT_NEAR(W(order[p], 1), 1.0 - r[p] / r[0], 1e-12) << p;
  }
  // Three anchors (ends and middle, given in another order): each stretch of the path between
  // two anchors interpolates those two by resistance, and the third anchor's column is zero.
  const int c = m / 2;
  const RowMatrix W3 =
      harmonic_weights(m, dual.pairs, phi, {{order[c]}, {order.back()}, {order.front()}});
  for (int p = 0; p < m; ++p) {
    Eigen::RowVector3d want;
    if (p <= c) {
      const double t = (r[p] - r[c]) / (r[0] - r[c]);  // weight of the front anchor
      want << 1.0 - t, 0.0, t;
    } else {
      const double t = r[p] / r[c];  // weight of the middle anchor
      want << t, 1.0 - t, 0.0;
    }
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(W3(order[p], a), want(a), 1e-12) << p << " " << a;
  }
}

TEST(Weights, UnreachedComponentGetsZeroWeights) {
  Vertices V1, V2;
  Faces F1, F2;
  meshes::make_grid(3, 3, &V1, &F1);
  Faces F(2 * F1.rows(), 3);
  F << F1, (F1.array() + static_cast<int>(V1.rows())).matrix();
  const DualEdges dual = dual_edges(F);
  const int m = static_cast<int>(F.rows());
  const RowMatrix W =
      harmonic_weights(m, dual.pairs, Eigen::VectorXd::Ones(dual.pairs.rows()), {{0}, {5}});
  for (int f = 0; f < m / 2; ++f) EXPECT_NEAR(W.row(f).sum(), 1.0, 1e-12);
  for (int f = m / 2; f < m; ++f) EXPECT_EQ(W.row(f).squaredNorm(), 0.0);
}

TEST(Weights, RejectsBadAnchors) {
  Vertices V;
  Faces F;
  meshes::make_grid(2, 2, &V, &F);
  const DualEdges dual = dual_edges(F);
  const Eigen::VectorXd phi = Eigen::VectorXd::Ones(dual.pairs.rows());
  EXPECT_THROW(harmonic_weights(8, dual.pairs, phi, {}), std::invalid_argument);
  EXPECT_THROW(harmonic_weights(8, dual.pairs, phi, {{0}, {}}), std::invalid_argument);
  EXPECT_THROW(harmonic_weights(8, dual.pairs, phi, {{0, 1}, {1}}), std::invalid_argument);
  EXPECT_THROW(harmonic_weights(8, dual.pairs, phi, {{8}}), std::invalid_argument);
  Eigen::VectorXd bad = phi;
  bad(0) = 0.0;
  EXPECT_THROW(harmonic_weights(8, dual.pairs, bad, {{0}}), std::invalid_argument);
}

TEST(Mesh, DualEdgesOfTwoTrianglesAndNonManifoldFan) {
  Faces F(3, 3);
  F << 0, 1, 2, 2, 1, 3, 1, 2, 4;  // edge (1,2) shared by three faces
  const DualEdges d = dual_edges(F);
  ASSERT_EQ(d.pairs.rows(), 3);
  EXPECT_EQ(d.pairs(0, 0), 0);
  EXPECT_EQ(d.pairs(0, 1), 1);
  EXPECT_EQ(d.pairs(1, 0), 0);
  EXPECT_EQ(d.pairs(1, 1), 2);
  EXPECT_EQ(d.pairs(2, 0), 1);
  EXPECT_EQ(d.pairs(2, 1), 2);
  for (int e = 0; e < 3; ++e) {
    EXPECT_EQ(d.shared(e, 0), 1);
    EXPECT_EQ(d.shared(e, 1), 2);
  }
}

// largest_harmonic_weights keeps, per row, the largest entries of the dense row: checked against
// harmonic_weights on a grid large enough that the columns are solved in several blocks, with
// anchor rows and a component no anchor reaches (empty rows). The two use different orderings,
// so values agree to round-off, and which of two tied entries is kept may differ.
TEST(Weights, LargestHarmonicWeightsAreTheDenseRowsLargest) {
  Vertices V;
  Faces F1;
  meshes::make_grid(100, 100, &V, &F1);  // 20k faces
  Faces F(F1.rows() + 2, 3);
  const int nv = static_cast<int>(V.rows());
  F << F1, nv, nv + 1, nv + 2, nv + 1, nv + 3, nv + 2;  // an island of two faces
  const DualEdges dual = dual_edges(F);
  const int m = static_cast<int>(F.rows());
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.5, 2.0);
  Eigen::VectorXd phi(dual.pairs.rows());
  for (Eigen::Index e = 0; e < phi.size(); ++e) phi(e) = u(rng);
  AnchorList anchors;
  for (int j = 5; j < 100; j += 6)
    for (int i = 5; i < 100; i += 6) anchors.push_back({2 * (j * 100 + i)});  // 16 x 16 faces
  const int k = static_cast<int>(anchors.size());
  ASSERT_GT(k, (1 << 22) / (m - k));  // more columns than one block
  const RowMatrix W = harmonic_weights(m, dual.pairs, phi, anchors);
  for (const int keep : {1, 8, 300}) {
    const SparseWeights S = largest_harmonic_weights(m, dual.pairs, phi, anchors, keep);
    ASSERT_EQ(S.ptr.size(), static_cast<size_t>(m) + 1);
    int bad = 0;
    for (int f = 0; f < m - 2; ++f) {
      const int b = S.ptr[f], e = S.ptr[f + 1];
      bad += e - b != std::min(keep, static_cast<int>((W.row(f).array() > 0.0).count()));
      std::vector<char> kept(k, 0);
      for (int i = b; i < e; ++i) {
        kept[S.idx[i]] = 1;
        bad += std::abs(S.w[i] - W(f, S.idx[i])) > 1e-12;  // the dense value
        bad += i > b && S.w[i] > S.w[i - 1] + 1e-12;       // largest first (ties by anchor)
      }
      for (int a = 0; a < k; ++a) bad += !kept[a] && W(f, a) > S.w[e - 1] + 1e-12;
    }
    EXPECT_EQ(bad, 0) << "keep " << keep;
    const int anchor_face = anchors[3][0];
    ASSERT_EQ(S.ptr[anchor_face + 1] - S.ptr[anchor_face], 1);
    EXPECT_EQ(S.idx[S.ptr[anchor_face]], 3);
    EXPECT_EQ(S.w[S.ptr[anchor_face]], 1.0);
    EXPECT_EQ(S.ptr[m] - S.ptr[m - 2], 0);  // the island
  }
  EXPECT_THROW(largest_harmonic_weights(m, dual.pairs, phi, anchors, 0), std::invalid_argument);
}
