#include "matdeform/mesh.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

namespace matdeform {

DualEdges dual_edges(const Faces& faces) {
  const Eigen::Index m = faces.rows();
  // (min vertex, max vertex, face) for every face side; sorting groups faces by mesh edge.
  std::vector<std::array<int, 3>> sides;
  sides.reserve(static_cast<size_t>(3 * m));
  for (Eigen::Index f = 0; f < m; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = faces(f, k), b = faces(f, (k + 1) % 3);
      sides.push_back({std::min(a, b), std::max(a, b), static_cast<int>(f)});
    }
  }
  std::sort(sides.begin(), sides.end());
  // (f, g, a, b)
  std::vector<std::array<int, 4>> rows;
  rows.reserve(sides.size() / 2 + 1);
  for (size_t s = 0; s < sides.size();) {
    size_t t = s;
    while (t < sides.size() && sides[t][0] == sides[s][0] && sides[t][1] == sides[s][1]) ++t;
    for (size_t p = s; p < t; ++p) {
      for (size_t q = p + 1; q < t; ++q) {
        const int f = sides[p][2], g = sides[q][2];
        if (f == g) continue;
        rows.push_back({std::min(f, g), std::max(f, g), sides[s][0], sides[s][1]});
      }
    }
    s = t;
  }
  std::sort(rows.begin(), rows.end());
  // Two faces sharing two edges (a folded pair) would be counted twice: keep the first.
  rows.erase(std::unique(rows.begin(), rows.end(),
                         [](const auto& x, const auto& y) { return x[0] == y[0] && x[1] == y[1]; }),
             rows.end());
  DualEdges out;
  out.pairs.resize(static_cast<Eigen::Index>(rows.size()), 2);
  out.shared.resize(static_cast<Eigen::Index>(rows.size()), 2);
  for (size_t e = 0; e < rows.size(); ++e) {
    const auto i = static_cast<Eigen::Index>(e);
    out.pairs(i, 0) = rows[e][0];
    out.pairs(i, 1) = rows[e][1];
    out.shared(i, 0) = rows[e][2];
    out.shared(i, 1) = rows[e][3];
  }
  return out;
}

void validate_mesh(const Vertices& vertices, const Faces& faces) {
  const Eigen::Index n = vertices.rows();
  if (!vertices.allFinite()) throw std::invalid_argument("vertices contain NaN or infinity");
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (faces(f, k) < 0 || faces(f, k) >= n) {
        throw std::invalid_argument("faces[" + std::to_string(f) + "] references vertex " +
                                    std::to_string(faces(f, k)) + " outside [0, " +
                                    std::to_string(n) + ")");
      }
    }
    if (faces(f, 0) == faces(f, 1) || faces(f, 1) == faces(f, 2) || faces(f, 0) == faces(f, 2)) {
      throw std::invalid_argument("faces[" + std::to_string(f) + "] repeats a vertex");
    }
  }
}

namespace {
int find_root(std::vector<int>& parent, int x) {
  while (parent[static_cast<size_t>(x)] != x) {
    parent[static_cast<size_t>(x)] = parent[static_cast<size_t>(parent[static_cast<size_t>(x)])];
    x = parent[static_cast<size_t>(x)];
  }
  return x;
}
}  // namespace

std::vector<int> face_components(int num_faces, const IndexPairs& pairs, int* count) {
  std::vector<int> parent(static_cast<size_t>(num_faces));
  std::iota(parent.begin(), parent.end(), 0);
  for (Eigen::Index e = 0; e < pairs.rows(); ++e) {
    const int a = find_root(parent, pairs(e, 0)), b = find_root(parent, pairs(e, 1));
    if (a != b) parent[static_cast<size_t>(std::max(a, b))] = std::min(a, b);
  }
  std::vector<int> label(static_cast<size_t>(num_faces), -1);
  int next = 0;
  for (int f = 0; f < num_faces; ++f) {
    const int r = find_root(parent, f);
    if (label[static_cast<size_t>(r)] < 0) label[static_cast<size_t>(r)] = next++;
    label[static_cast<size_t>(f)] = label[static_cast<size_t>(r)];
  }
  if (count) *count = next;
  return label;
}

Eigen::VectorXd double_areas(const Vertices& vertices, const Faces& faces) {
  Eigen::VectorXd out(faces.rows());
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    const Eigen::Vector3d a = vertices.row(faces(f, 0)), b = vertices.row(faces(f, 1)),
                          c = vertices.row(faces(f, 2));
    out(f) = (b - a).cross(c - a).norm();
  }
  return out;
}

IndexPairs mesh_edges(const Faces& faces) {
  std::vector<std::array<int, 2>> sides;
  sides.reserve(static_cast<size_t>(3 * faces.rows()));
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = faces(f, k), b = faces(f, (k + 1) % 3);
      if (a != b) sides.push_back({std::min(a, b), std::max(a, b)});
    }
  }
  std::sort(sides.begin(), sides.end());
  sides.erase(std::unique(sides.begin(), sides.end()), sides.end());
  IndexPairs out(static_cast<Eigen::Index>(sides.size()), 2);
  for (size_t e = 0; e < sides.size(); ++e) {
    out(static_cast<Eigen::Index>(e), 0) = sides[e][0];
    out(static_cast<Eigen::Index>(e), 1) = sides[e][1];
  }
  return out;
}

}  // namespace matdeform
