// Relabelling checks for any solver: a random vertex numbering, face order and rotation of each
// face's corners must not change the result beyond round-off. A solver test builds its inputs in
// the original labels, maps them with the Relabelling (ids, per-face and per-dual-edge values)
// and compares the two results with max_permuted_error().
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <numeric>
#include <random>
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

// One C-ordered little-endian .npy array of 2 dimensions ("<f8" or "<i4", as numpy's np.save
// writes them): the cat under data/cat-poses. Throws when the file is missing or of another kind.
template <typename Matrix>
Matrix read_npy(const std::string& path, const std::string& descr) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot open " + path);
  char magic[8];
  in.read(magic, 8);
  if (!in || std::string(magic, 6) != "\x93NUMPY") throw std::runtime_error(path + ": not .npy");
  unsigned char len[2];
  in.read(reinterpret_cast<char*>(len), 2);
  std::string header(static_cast<size_t>(len[0] | (len[1] << 8)), ' ');
  in.read(header.data(), static_cast<std::streamsize>(header.size()));
  if (header.find("'descr': '" + descr + "'") == std::string::npos ||
      header.find("'fortran_order': False") == std::string::npos)
    throw std::runtime_error(path + ": expected C-ordered " + descr);
  const size_t open = header.find("'shape': (");
  long rows = 0, cols = 0;
  if (open == std::string::npos ||
      std::sscanf(header.c_str() + open + 10, "%ld, %ld)", &rows, &cols) != 2)
    throw std::runtime_error(path + ": expected a 2-dimensional array");
  Eigen::Matrix<typename Matrix::Scalar, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> m(rows,
                                                                                            cols);
  in.read(reinterpret_cast<char*>(m.data()),
          static_cast<std::streamsize>(m.size() * sizeof(typename Matrix::Scalar)));
  if (!in) throw std::runtime_error(path + ": truncated");
  return m;
}

}  // namespace matdeform::permutation
