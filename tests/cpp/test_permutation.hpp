// Relabelling checks for any solver: a random vertex numbering, face order and rotation of each
// face's corners must not change the result beyond round-off. A solver test builds its inputs in
// the original labels, maps them with the Relabelling (ids, per-face and per-dual-edge values)
// and compares the two results with max_permuted_error().
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <fstream>
#include <map>
#include <numeric>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "matdeform/mesh.hpp"
#include "matdeform/types.hpp"

namespace matdeform::permutation {

struct Relabelling {
  std::vector<int> vertex;  // original vertex -> new vertex
  std::vector<int> face;    // original face -> new face
  Vertices vertices;        // relabelled mesh
  Faces faces;

  std::vector<int> vertex_ids(const std::vector<int>& ids) const {
    std::vector<int> out;
    for (int v : ids) out.push_back(vertex[static_cast<size_t>(v)]);
    return out;
  }
  std::vector<int> face_ids(const std::vector<int>& ids) const {
    std::vector<int> out;
    for (int f : ids) out.push_back(face[static_cast<size_t>(f)]);
    return out;
  }
  AnchorList anchors(const AnchorList& a) const {
    AnchorList out;
    for (const auto& list : a) out.push_back(face_ids(list));
    return out;
  }
  Eigen::VectorXd per_face(const Eigen::VectorXd& x) const {
    Eigen::VectorXd out(x.size());
    for (Eigen::Index f = 0; f < x.size(); ++f) out(face[static_cast<size_t>(f)]) = x(f);
    return out;
  }
  // Rows given in dual_edges(original faces) order -> rows in dual_edges(faces) order.
  RowMatrix per_dual_edge(const Faces& original, const RowMatrix& x) const {
    const IndexPairs before = dual_edges(original).pairs, after = dual_edges(faces).pairs;
    std::map<std::pair<int, int>, Eigen::Index> row;
    for (Eigen::Index e = 0; e < after.rows(); ++e) row[{after(e, 0), after(e, 1)}] = e;
    RowMatrix out(x.rows(), x.cols());
    for (Eigen::Index e = 0; e < before.rows(); ++e) {
      const int f = face[static_cast<size_t>(before(e, 0))];
      const int g = face[static_cast<size_t>(before(e, 1))];
      out.row(row.at({std::min(f, g), std::max(f, g)})) = x.row(e);
    }
    return out;
  }
};

// Random vertex numbering and face order; with rotate_corners also a random cyclic rotation of
// each face's corners (orientation kept).
inline Relabelling relabel(const Vertices& V, const Faces& F, std::mt19937& rng,
                           bool rotate_corners = true) {
  Relabelling r;
  r.vertex.resize(static_cast<size_t>(V.rows()));
  r.face.resize(static_cast<size_t>(F.rows()));
  std::iota(r.vertex.begin(), r.vertex.end(), 0);
  std::iota(r.face.begin(), r.face.end(), 0);
  std::shuffle(r.vertex.begin(), r.vertex.end(), rng);
  std::shuffle(r.face.begin(), r.face.end(), rng);
  r.vertices.resize(V.rows(), 3);
  for (Eigen::Index v = 0; v < V.rows(); ++v) r.vertices.row(r.vertex[v]) = V.row(v);
  r.faces.resize(F.rows(), 3);
  std::uniform_int_distribution<int> shift(0, rotate_corners ? 2 : 0);
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const int s = shift(rng);
    for (int l = 0; l < 3; ++l) r.faces(r.face[f], l) = r.vertex[F(f, (l + s) % 3)];
  }
  return r;
}

// max_v |X(v) - Xp(new v)| over the bounding-box diagonal of X.
inline double max_permuted_error(const Vertices& X, const Vertices& Xp, const Relabelling& r) {
  double err = 0.0;
  for (Eigen::Index v = 0; v < X.rows(); ++v) {
    err = std::max(err, (X.row(v) - Xp.row(r.vertex[v])).cwiseAbs().maxCoeff());
  }
  const double diag = (X.colwise().maxCoeff() - X.colwise().minCoeff()).norm();
  return err / std::max(diag, 1e-300);
}

// Vertices and triangles of a Wavefront OBJ ("v x y z", "f a/.. b/.. c/.." fan-triangulated).
inline bool read_obj(const std::string& path, Vertices* V, Faces* F) {
  std::ifstream in(path);
  if (!in) return false;
  std::vector<double> xyz;
  std::vector<int> tri;
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream ss(line);
    std::string tag;
    ss >> tag;
    if (tag == "v") {
      double x, y, z;
      ss >> x >> y >> z;
      xyz.insert(xyz.end(), {x, y, z});
    } else if (tag == "f") {
      std::vector<int> idx;
      for (std::string tok; ss >> tok;) idx.push_back(std::stoi(tok.substr(0, tok.find('/'))) - 1);
      for (size_t j = 1; j + 1 < idx.size(); ++j)
        tri.insert(tri.end(), {idx[0], idx[j], idx[j + 1]});
    }
  }
  V->resize(static_cast<Eigen::Index>(xyz.size() / 3), 3);
  for (Eigen::Index i = 0; i < V->size(); ++i) V->data()[i] = xyz[static_cast<size_t>(i)];
  F->resize(static_cast<Eigen::Index>(tri.size() / 3), 3);
  for (Eigen::Index i = 0; i < F->size(); ++i) F->data()[i] = tri[static_cast<size_t>(i)];
  return true;
}

}  // namespace matdeform::permutation
