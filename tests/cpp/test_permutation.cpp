// Relabelling invariance of MaterialDeformer over a small mesh catalogue and the cat: random
// vertex numberings, face orders and corner rotations give the same positions, permuted, to 1e-9
// of the bounding-box diagonal, for (k,4,4), (k,3,3), pinned, region and anisotropic bending.
#include "test_permutation.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "matdeform/deformer.hpp"
#include "matdeform/mesh.hpp"
#include "test_meshes.hpp"

using namespace matdeform;

namespace {

struct Mesh {
  std::string name;
  Vertices V;
  Faces F;
  int trials;
};

std::vector<Mesh> catalogue() {
  std::vector<Mesh> out;
  Mesh m;
  m.name = "two triangles";
  m.V.resize(4, 3);
  m.V << 0, 0, 0, 0, 1, 0, 1, 0, 0, 1, 1, 0;
  m.F.resize(2, 3);
  m.F << 3, 0, 2, 3, 1, 0;  // issue 11: this order used to leave vertex 1 at rest
  m.trials = 12;
  out.push_back(m);
  m.name = "fan";
  meshes::make_fan(3, &m.V, &m.F);
  m.trials = 12;
  out.push_back(m);
  m.name = "grid";
  meshes::make_grid(8, 8, &m.V, &m.F);
  m.trials = 6;
  out.push_back(m);
  m.name = "bar";
  meshes::make_bar(12, 12.0, &m.V, &m.F);
  m.trials = 6;
  out.push_back(m);
  m.name = "cat";
  m.trials = 2;
  m.V = permutation::read_npy<Vertices>(MATDEFORM_DATA "/cat-poses/reference.npy", "<f8");
  m.F = permutation::read_npy<Faces>(MATDEFORM_DATA "/cat-poses/faces.npy", "<i4");
  out.push_back(m);
  return out;
}

enum class Mode { kFollow, kFree, kPinned, kRegion, kAnisotropic };
const char* mode_name(Mode mode) {
  switch (mode) {
    case Mode::kFollow:
      return "(k,4,4)";
    case Mode::kFree:
      return "(k,3,3)";
    case Mode::kPinned:
      return "pinned";
    case Mode::kRegion:
      return "region";
    case Mode::kAnisotropic:
      return "anisotropic";
  }
  return "";
}

// Inputs in one labelling; relabelled() maps them to another.
struct Problem {
  Vertices V;
  Faces F;
  AnchorList anchors;
  Eigen::VectorXd shear;
  RowMatrix bend;
  DeformerOptions options;
  std::vector<Eigen::Matrix4d> transforms;
  bool has_translation = true;
  Vertices pinned_positions;

  Vertices solve() const {
    MaterialDeformer d(V, F, anchors, shear, bend, options);
    return d.deform(transforms, has_translation, options.pinned ? &pinned_positions : nullptr);
  }

  Problem relabelled(const permutation::Relabelling& r) const {
    Problem p = *this;
    p.V = r.vertices;
    p.F = r.faces;
    p.anchors = r.anchors(anchors);
    p.shear = r.per_face(shear);
    p.bend = r.per_dual_edge(F, bend);
    if (options.pinned) p.options.pinned = r.vertex_ids(*options.pinned);
    if (options.region) p.options.region = r.face_ids(*options.region);
    return p;
  }
};

Problem make_problem(const Mesh& mesh, Mode mode, std::mt19937& rng) {
  Problem p;
  p.V = mesh.V;
  p.F = mesh.F;
  const int m = static_cast<int>(mesh.F.rows());
  // Faces ordered along the longest extent; anchors at the ends (or inside the region).
  const Eigen::RowVector3d extent = mesh.V.colwise().maxCoeff() - mesh.V.colwise().minCoeff();
  int axis = 0;
  extent.maxCoeff(&axis);
  std::vector<double> key(static_cast<size_t>(m));
  for (int f = 0; f < m; ++f) {
    key[f] = mesh.V(mesh.F(f, 0), axis) + mesh.V(mesh.F(f, 1), axis) + mesh.V(mesh.F(f, 2), axis);
  }
  std::vector<int> order(static_cast<size_t>(m));
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return key[a] < key[b]; });
  const int size = std::max(1, m / 25);
  int second = m - size;
  if (mode == Mode::kRegion) {
    const int keep = (7 * m + 9) / 10;
    p.options.region = std::vector<int>(order.begin(), order.begin() + keep);
    second = keep / 2;
  }
  p.anchors = {std::vector<int>(order.begin(), order.begin() + size),
               std::vector<int>(order.begin() + second, order.begin() + second + size)};

  std::uniform_real_distribution<double> u(0.3, 3.0), sym(-1.0, 1.0);
  p.shear.resize(m);
  for (int f = 0; f < m; ++f) p.shear(f) = u(rng);
  const Eigen::Index E = dual_edges(mesh.F).pairs.rows();
  p.bend.resize(E, mode == Mode::kAnisotropic ? 3 : 1);
  for (Eigen::Index i = 0; i < p.bend.size(); ++i) p.bend.data()[i] = u(rng);
  if (mode == Mode::kAnisotropic) {
    p.options.axes =
        Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 0.5).normalized()).toRotationMatrix();
  }

  const double diag = extent.norm();
  for (size_t a = 0; a < p.anchors.size(); ++a) {
    Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
    const Eigen::Vector3d axis3(sym(rng), sym(rng), sym(rng) + 1.5);
    T.topLeftCorner<3, 3>() = (0.8 + 0.4 * std::abs(sym(rng))) *
                              Eigen::AngleAxisd(2.5 * sym(rng), axis3.normalized()).matrix();
    T.topRightCorner<3, 1>() << diag * sym(rng), diag * sym(rng), diag * sym(rng);
    p.transforms.push_back(T);
  }
  p.has_translation = mode != Mode::kFree;
  if (mode == Mode::kPinned) {
    std::vector<char> in_anchor(static_cast<size_t>(mesh.V.rows()), 0);
    for (const auto& list : p.anchors)
      for (int f : list)
        for (int l = 0; l < 3; ++l) in_anchor[mesh.F(f, l)] = 1;
    std::vector<int> pinned;
    for (int v = 0; v < mesh.V.rows(); ++v)
      if (!in_anchor[v]) pinned.push_back(v);
    std::shuffle(pinned.begin(), pinned.end(), rng);
    pinned.resize(std::min<size_t>(pinned.size(), 3));
    p.options.pinned = pinned;
    p.pinned_positions.resize(static_cast<Eigen::Index>(pinned.size()), 3);
    for (size_t i = 0; i < pinned.size(); ++i) {
      p.pinned_positions.row(static_cast<Eigen::Index>(i)) =
          mesh.V.row(pinned[i]) + 0.1 * diag * Eigen::RowVector3d(sym(rng), sym(rng), sym(rng));
    }
  }
  return p;
}

TEST(Permutation, MaterialDeformerIsInvariantToRelabelling) {
  std::mt19937 rng(11);
  for (const Mesh& mesh : catalogue()) {
    for (Mode mode :
         {Mode::kFollow, Mode::kFree, Mode::kPinned, Mode::kRegion, Mode::kAnisotropic}) {
      if (mode == Mode::kRegion && mesh.F.rows() < 8) continue;
      const Problem p = make_problem(mesh, mode, rng);
      const Vertices X = p.solve();
      ASSERT_TRUE(X.allFinite());
      for (int t = 0; t < mesh.trials; ++t) {
        const permutation::Relabelling r = permutation::relabel(mesh.V, mesh.F, rng);
        const Vertices Xp = p.relabelled(r).solve();
        EXPECT_LT(permutation::max_permuted_error(X, Xp, r), 1e-9)
            << mesh.name << ", " << mode_name(mode) << ", trial " << t;
      }
    }
  }
}

TEST(Permutation, TwoTrianglesFollowTheirOnlyAnchor) {
  // Issue 11: the same two triangles in two orders; a pure translation moves all four vertices.
  Vertices V(4, 3);
  V << 0, 0, 0, 0, 1, 0, 1, 0, 0, 1, 1, 0;
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T(0, 3) = 1.0;
  for (const Faces& F : {Faces{{3, 0, 2}, {3, 1, 0}}, Faces{{0, 2, 3}, {0, 3, 1}}}) {
    MaterialDeformer d(V, F, {{0}}, Eigen::VectorXd::Ones(2), RowMatrix::Ones(1, 1));
    const Vertices X = d.deform({T}, true, nullptr);
    for (int v = 0; v < 4; ++v) EXPECT_NEAR(X(v, 0) - V(v, 0), 1.0, 1e-12) << "vertex " << v;
  }
}

TEST(DisjointSets, RootIsTheSmallestElementInAnyLinkOrder) {
  std::mt19937 rng(3);
  for (int rep = 0; rep < 200; ++rep) {
    // Chain 0-1-...-9 linked in a random order and direction: one set rooted at 0.
    std::vector<std::pair<int, int>> links;
    for (int i = 0; i + 1 < 10; ++i) links.emplace_back(i, i + 1);
    std::shuffle(links.begin(), links.end(), rng);
    DisjointSets sets(12);
    for (auto [a, b] : links) (rng() % 2 ? sets.unite(a, b) : sets.unite(b, a));
    for (int v = 0; v < 10; ++v) ASSERT_EQ(sets.find(v), 0);
    EXPECT_EQ(sets.find(10), 10);
    EXPECT_EQ(sets.find(11), 11);
    EXPECT_FALSE(sets.unite(3, 7));
  }
}

}  // namespace
