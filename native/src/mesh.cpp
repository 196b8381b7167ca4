#include "matdeform/mesh.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <string>

namespace matdeform {

void check_indices(const int* data, Eigen::Index size, Eigen::Index upper, const char* name) {
  for (Eigen::Index i = 0; i < size; ++i) {
    if (data[i] < 0 || data[i] >= upper) {
      throw std::invalid_argument(std::string(name) + ": index " + std::to_string(data[i]) +
                                  " outside [0, " + std::to_string(upper) + ")");
    }
  }
}

DualEdges dual_edges(const Faces& faces) {
  const Eigen::Index m = faces.rows();
  if (faces.size() > 0 && faces.minCoeff() < 0) {
    throw std::invalid_argument("faces: negative vertex index " + std::to_string(faces.minCoeff()));
  }
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
  if (n > 0) {
    const double size = (vertices.colwise().maxCoeff() - vertices.colwise().minCoeff()).maxCoeff();
    if (size == 0.0) throw std::invalid_argument("vertices: all vertices coincide");
    if (!(size >= kMinMeshSize && size <= kMaxMeshSize)) {
      std::ostringstream msg;
      msg << "vertices: the mesh is " << size << " across; expected " << kMinMeshSize << " to "
          << kMaxMeshSize << ": rescale the mesh (only its shape matters)";
      throw std::invalid_argument(msg.str());
    }
  }
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

DisjointSets::DisjointSets(int n) : parent_(static_cast<size_t>(std::max(n, 0))) {
  std::iota(parent_.begin(), parent_.end(), 0);
}

int DisjointSets::find(int x) {
  auto p = [this](int i) -> int& { return parent_[static_cast<size_t>(i)]; };
  while (p(x) != x) x = p(x) = p(p(x));
  return x;
}

bool DisjointSets::unite(int a, int b) {
  // Both roots are taken now, after any earlier link: linking a stale root would detach the
  // part of its set that was linked in the meantime.
  a = find(a);
  b = find(b);
  if (a == b) return false;
  parent_[static_cast<size_t>(std::max(a, b))] = std::min(a, b);
  return true;
}

std::vector<int> face_components(int num_faces, const IndexPairs& pairs, int* count) {
  if (num_faces < 0) throw std::invalid_argument("num_faces: expected >= 0");
  check_indices(pairs, num_faces, "pairs");
  DisjointSets sets(num_faces);
  for (Eigen::Index e = 0; e < pairs.rows(); ++e) sets.unite(pairs(e, 0), pairs(e, 1));
  std::vector<int> label(static_cast<size_t>(num_faces), -1);
  int next = 0;
  for (int f = 0; f < num_faces; ++f) {
    const int r = sets.find(f);
    if (label[static_cast<size_t>(r)] < 0) label[static_cast<size_t>(r)] = next++;
    label[static_cast<size_t>(f)] = label[static_cast<size_t>(r)];
  }
  if (count) *count = next;
  return label;
}

Eigen::VectorXd double_areas(const Vertices& vertices, const Faces& faces) {
  check_indices(faces, vertices.rows(), "faces");
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

namespace matdeform {

VertexFans vertex_fans(int num_vertices, const Faces& faces) {
  const int n = num_vertices;
  const int m = static_cast<int>(faces.rows());
  // Vertex -> incident faces (CSR).
  std::vector<int> fo(static_cast<size_t>(n) + 1, 0), fi(static_cast<size_t>(3) * m);
  for (int f = 0; f < m; ++f)
    for (int k = 0; k < 3; ++k) ++fo[static_cast<size_t>(faces(f, k)) + 1];
  for (int v = 0; v < n; ++v) fo[v + 1] += fo[v];
  {
    std::vector<int> next(fo.begin(), fo.end() - 1);
    for (int f = 0; f < m; ++f)
      for (int k = 0; k < 3; ++k) fi[static_cast<size_t>(next[faces(f, k)]++)] = f;
  }
  VertexFans out;
  out.offsets.assign(static_cast<size_t>(n) + 1, 0);
  out.kind.assign(static_cast<size_t>(n), kFanIsolated);
  out.ring.reserve(static_cast<size_t>(3) * m);
  // Per vertex: its faces as directed pairs (a, b), face = (v, a, b) up to rotation.
  std::vector<std::array<int, 2>> sides;
  std::vector<char> used;
  std::vector<int> walk, nbrs;
  for (int v = 0; v < n; ++v) {
    sides.clear();
    for (int q = fo[v]; q < fo[v + 1]; ++q) {
      const int f = fi[static_cast<size_t>(q)];
      int k = 0;
      while (faces(f, k) != v) ++k;
      sides.push_back({faces(f, (k + 1) % 3), faces(f, (k + 2) % 3)});
    }
    const size_t nf = sides.size();
    if (nf == 0) {
      out.offsets[static_cast<size_t>(v) + 1] = static_cast<int>(out.ring.size());
      continue;
    }
    // Neighbour degrees in the fan graph (each face links a and b).
    nbrs.clear();
    for (const auto& s : sides) nbrs.insert(nbrs.end(), {s[0], s[1]});
    std::sort(nbrs.begin(), nbrs.end());
    int ends = 0, start = -1;
    bool manifold = true;
    for (size_t i = 0; i < nbrs.size();) {
      size_t j = i;
      while (j < nbrs.size() && nbrs[j] == nbrs[i]) ++j;
      if (j - i > 2) manifold = false;
      if (j - i == 1) {
        ++ends;
        // Start an open fan where a face leaves from it (a of (v, a, b)), to follow orientation.
        for (const auto& s : sides)
          if (s[0] == nbrs[i] && (start < 0 || nbrs[i] < start)) start = nbrs[i];
      }
      i = j;
    }
    if (ends != 0 && ends != 2) manifold = false;
    if (manifold && ends == 2 && start < 0) {
      // Inconsistent orientation: start at the smaller end.
      for (size_t i = 0; i < nbrs.size(); ++i) {
        const bool single =
            (i == 0 || nbrs[i - 1] != nbrs[i]) && (i + 1 == nbrs.size() || nbrs[i + 1] != nbrs[i]);
        if (single) {
          start = nbrs[i];
          break;
        }
      }
    }
    walk.clear();
    if (manifold) {
      used.assign(nf, 0);
      int cur = ends == 2 ? start : sides[0][0];
      walk.push_back(cur);
      for (size_t step = 0; step < nf; ++step) {
        // Prefer the face leaving cur in its own orientation, then one entering it.
        int pick = -1, to = -1;
        for (size_t s = 0; s < nf && pick < 0; ++s)
          if (!used[s] && sides[s][0] == cur) pick = static_cast<int>(s), to = sides[s][1];
        for (size_t s = 0; s < nf && pick < 0; ++s)
          if (!used[s] && sides[s][1] == cur) pick = static_cast<int>(s), to = sides[s][0];
        if (pick < 0) break;
        used[static_cast<size_t>(pick)] = 1;
        cur = to;
        walk.push_back(cur);
      }
      // A closed fan returns to its start after nf faces; an open one ends after nf faces.
      if (ends == 0) {
        if (walk.size() != nf + 1 || walk.back() != walk.front()) manifold = false;
        walk.pop_back();
      } else if (walk.size() != nf + 1) {
        manifold = false;
      }
      if (manifold) {
        std::vector<int> check(walk);
        std::sort(check.begin(), check.end());
        if (std::adjacent_find(check.begin(), check.end()) != check.end()) manifold = false;
      }
    }
    if (manifold) {
      out.kind[static_cast<size_t>(v)] = ends == 0 ? kFanClosed : kFanOpen;
      out.ring.insert(out.ring.end(), walk.begin(), walk.end());
    } else {
      out.kind[static_cast<size_t>(v)] = kFanNonManifold;
      nbrs.erase(std::unique(nbrs.begin(), nbrs.end()), nbrs.end());
      out.ring.insert(out.ring.end(), nbrs.begin(), nbrs.end());
    }
    out.offsets[static_cast<size_t>(v) + 1] = static_cast<int>(out.ring.size());
  }
  return out;
}

}  // namespace matdeform
