#include "matdeform/weights.hpp"

#include <Eigen/SparseCore>
#include <cmath>
#include <stdexcept>
#include <string>

#include "matdeform/mesh.hpp"
#include "matdeform/stiffness.hpp"
#include "sparse_cholesky.hpp"

namespace matdeform {

void validate_anchors(int num_faces, const AnchorList& anchors) {
  if (num_faces < 0) throw std::invalid_argument("num_faces: expected >= 0");
  if (anchors.empty()) throw std::invalid_argument("anchors: at least one anchor is required");
  std::vector<int> owner(static_cast<size_t>(num_faces), -1);
  for (size_t a = 0; a < anchors.size(); ++a) {
    if (anchors[a].empty()) {
      throw std::invalid_argument("anchors[" + std::to_string(a) + "] is empty");
    }
    for (int f : anchors[a]) {
      if (f < 0 || f >= num_faces) {
        throw std::invalid_argument("anchors[" + std::to_string(a) + "] has face " +
                                    std::to_string(f) + " outside [0, " +
                                    std::to_string(num_faces) + ")");
      }
      int& o = owner[f];
      if (o >= 0 && o != static_cast<int>(a)) {
        throw std::invalid_argument("anchors[" + std::to_string(o) + "] and anchors[" +
                                    std::to_string(a) + "] share face " + std::to_string(f));
      }
      o = static_cast<int>(a);
    }
  }
}

RowMatrix harmonic_weights(int num_faces, const IndexPairs& pairs, const Eigen::VectorXd& phi,
                           const AnchorList& anchors) {
  if (num_faces < 0) throw std::invalid_argument("num_faces: expected >= 0");
  validate_anchors(num_faces, anchors);
  check_indices(pairs, num_faces, "pairs");
  if (phi.size() != pairs.rows()) {
    throw std::invalid_argument("bend: one value per dual edge expected");
  }
  check_stiffness(phi.data(), phi.size(), "bend");
  const int k = static_cast<int>(anchors.size());
  std::vector<int> anchor_of(static_cast<size_t>(num_faces), -1);
  for (int a = 0; a < k; ++a) {
    for (int f : anchors[a]) anchor_of[f] = a;
  }

  // Faces in a component that no anchor reaches have no boundary condition; they keep weight 0.
  int ncomp = 0;
  const std::vector<int> comp = face_components(num_faces, pairs, &ncomp);
  std::vector<char> reached(static_cast<size_t>(ncomp), 0);
  for (int f = 0; f < num_faces; ++f) {
    if (anchor_of[f] >= 0) reached[static_cast<size_t>(comp[f])] = 1;
  }

  std::vector<int> unknown(static_cast<size_t>(num_faces), -1);
  int nu = 0;
  for (int f = 0; f < num_faces; ++f) {
    if (anchor_of[f] < 0 && reached[static_cast<size_t>(comp[f])]) {
      unknown[f] = nu++;
    }
  }

  RowMatrix W = RowMatrix::Zero(num_faces, k);
  for (int f = 0; f < num_faces; ++f) {
    if (anchor_of[f] >= 0) W(f, anchor_of[f]) = 1.0;
  }
  if (nu == 0) return W;

  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(static_cast<size_t>(3 * pairs.rows()));
  Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(nu, k);  // column-major for CHOLMOD
  for (Eigen::Index e = 0; e < pairs.rows(); ++e) {
    const int f = pairs(e, 0), g = pairs(e, 1);
    const int uf = unknown[f], ug = unknown[g];
    const double w = phi(e);
    if (uf >= 0) trip.emplace_back(uf, uf, w);
    if (ug >= 0) trip.emplace_back(ug, ug, w);
    if (uf >= 0 && ug >= 0) {
      trip.emplace_back(std::max(uf, ug), std::min(uf, ug), -w);
    } else if (uf >= 0 && anchor_of[g] >= 0) {
      rhs(uf, anchor_of[g]) += w;
    } else if (ug >= 0 && anchor_of[f] >= 0) {
      rhs(ug, anchor_of[f]) += w;
    }
  }
  Eigen::SparseMatrix<double> L(nu, nu);
  L.setFromTriplets(trip.begin(), trip.end());
  SparseCholesky chol(L, SparseCholesky::Reuse::Once);  // solved once
  Eigen::MatrixXd sol(nu, k);
  chol.solve(rhs.data(), sol.data(), k);
  for (int f = 0; f < num_faces; ++f) {
    const int u = unknown[f];
    if (u >= 0) W.row(f) = sol.row(u);
  }
  return W;
}

}  // namespace matdeform
