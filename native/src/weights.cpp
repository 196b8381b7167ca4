#include "matdeform/weights.hpp"

#include <Eigen/SparseCore>
#include <algorithm>
#include <cmath>
#include <memory>
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

namespace {

// The Dirichlet problem of harmonic_weights: anchor faces fixed, the other faces of the
// components an anchor reaches unknown, factored once. Faces in a component that no anchor
// reaches have no boundary condition; they keep weight 0.
struct HarmonicSystem {
  std::vector<int> anchor_of, unknown;
  int nu = 0;
  // Right-hand-side couplings, in dual-edge order: unknown row u gets w in anchor a's column.
  struct Coupling {
    int row, anchor;
    double w;
  };
  std::vector<Coupling> couplings;
  std::unique_ptr<SparseCholesky> chol;

  HarmonicSystem(int num_faces, const IndexPairs& pairs, const Eigen::VectorXd& phi,
                 const AnchorList& anchors, SparseCholesky::Reuse reuse) {
    if (num_faces < 0) throw std::invalid_argument("num_faces: expected >= 0");
    validate_anchors(num_faces, anchors);
    check_indices(pairs, num_faces, "pairs");
    if (phi.size() != pairs.rows()) {
      throw std::invalid_argument("bend: one value per dual edge expected");
    }
    check_stiffness(phi.data(), phi.size(), "bend");
    const int k = static_cast<int>(anchors.size());
    anchor_of.assign(static_cast<size_t>(num_faces), -1);
    for (int a = 0; a < k; ++a) {
      for (int f : anchors[a]) anchor_of[f] = a;
    }
    int ncomp = 0;
    const std::vector<int> comp = face_components(num_faces, pairs, &ncomp);
    std::vector<char> reached(static_cast<size_t>(ncomp), 0);
    for (int f = 0; f < num_faces; ++f) {
      if (anchor_of[f] >= 0) reached[static_cast<size_t>(comp[f])] = 1;
    }
    unknown.assign(static_cast<size_t>(num_faces), -1);
    for (int f = 0; f < num_faces; ++f) {
      if (anchor_of[f] < 0 && reached[static_cast<size_t>(comp[f])]) unknown[f] = nu++;
    }
    if (nu == 0) return;
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(static_cast<size_t>(3 * pairs.rows()));
    for (Eigen::Index e = 0; e < pairs.rows(); ++e) {
      const int f = pairs(e, 0), g = pairs(e, 1);
      const int uf = unknown[f], ug = unknown[g];
      const double w = phi(e);
      if (uf >= 0) trip.emplace_back(uf, uf, w);
      if (ug >= 0) trip.emplace_back(ug, ug, w);
      if (uf >= 0 && ug >= 0) {
        trip.emplace_back(std::max(uf, ug), std::min(uf, ug), -w);
      } else if (uf >= 0 && anchor_of[g] >= 0) {
        couplings.push_back({uf, anchor_of[g], w});
      } else if (ug >= 0 && anchor_of[f] >= 0) {
        couplings.push_back({ug, anchor_of[f], w});
      }
    }
    Eigen::SparseMatrix<double> L(nu, nu);
    L.setFromTriplets(trip.begin(), trip.end());
    chol = std::make_unique<SparseCholesky>(L, reuse);
  }

  // Weights of the unknown faces for anchors [a0, a0 + cols): (nu, cols) column-major in *sol.
  void solve(int a0, int cols, Eigen::MatrixXd* rhs, Eigen::MatrixXd* sol) const {
    rhs->setZero(nu, cols);
    for (const Coupling& c : couplings) {
      if (c.anchor >= a0 && c.anchor < a0 + cols) (*rhs)(c.row, c.anchor - a0) += c.w;
    }
    sol->resize(nu, cols);
    chol->solve(rhs->data(), sol->data(), cols);
  }
};

}  // namespace

RowMatrix harmonic_weights(int num_faces, const IndexPairs& pairs, const Eigen::VectorXd& phi,
                           const AnchorList& anchors) {
  const HarmonicSystem sys(num_faces, pairs, phi, anchors, SparseCholesky::Reuse::Once);
  const int k = static_cast<int>(anchors.size());
  RowMatrix W = RowMatrix::Zero(num_faces, k);
  for (int f = 0; f < num_faces; ++f) {
    if (sys.anchor_of[f] >= 0) W(f, sys.anchor_of[f]) = 1.0;
  }
  if (sys.nu == 0) return W;
  Eigen::MatrixXd rhs, sol;
  sys.solve(0, k, &rhs, &sol);
  for (int f = 0; f < num_faces; ++f) {
    const int u = sys.unknown[f];
    if (u >= 0) W.row(f) = sol.row(u);
  }
  return W;
}

SparseWeights largest_harmonic_weights(int num_faces, const IndexPairs& pairs,
                                       const Eigen::VectorXd& phi, const AnchorList& anchors,
                                       int keep) {
  if (keep < 1) throw std::invalid_argument("keep: expected >= 1");
  // Hundreds of columns: the ordering with the least fill and the multi-threaded substitution
  // pay off (100k faces, 500 anchors, one thread: 2.3 s -> 1.3 s for the whole pose-space bind).
  const HarmonicSystem sys(num_faces, pairs, phi, anchors, SparseCholesky::Reuse::PerPose);
  const int k = static_cast<int>(anchors.size());
  keep = std::min(keep, k);
  constexpr double kTie = 1e-12;  // weights lie in [0, 1]; the solve's round-off is ~1e-15
  // Per face, up to `keep` (weight, anchor) entries, best first: larger weight, then lower anchor.
  // Weights within kTie count as tied: on a symmetric mesh tied weights differ by round-off,
  // which depends on the node numbering, and must not decide which anchor is kept.
  std::vector<double> best_w(static_cast<size_t>(num_faces) * keep, 0.0);
  std::vector<int> best_a(best_w.size(), -1);
  std::vector<int> count(static_cast<size_t>(num_faces), 0);
  auto offer = [&](int f, int a, double w) {
    if (!(w > 0.0)) return;
    double* bw = &best_w[static_cast<size_t>(f) * keep];
    int* ba = &best_a[static_cast<size_t>(f) * keep];
    int& c = count[f];
    auto better = [&](int i) { return w > bw[i] + kTie || (w >= bw[i] - kTie && a < ba[i]); };
    if (c == keep && !better(c - 1)) return;
    int i = c < keep ? c++ : c - 1;
    for (; i > 0 && better(i - 1); --i) {
      bw[i] = bw[i - 1];
      ba[i] = ba[i - 1];
    }
    bw[i] = w;
    ba[i] = a;
  };
  for (int f = 0; f < num_faces; ++f) {
    if (sys.anchor_of[f] >= 0) offer(f, sys.anchor_of[f], 1.0);
  }
  if (sys.nu > 0) {
    // Columns in blocks of about 32 MB (a multiple of the 4 columns CHOLMOD's solve takes at a
    // time): the dense (nu, k) solution of a 1M-face mesh would take gigabytes.
    const int block =
        std::clamp(static_cast<int>((size_t{1} << 22) / static_cast<size_t>(sys.nu)) / 4 * 4, 4, k);
    std::vector<int> face_of(static_cast<size_t>(sys.nu));
    for (int f = 0; f < num_faces; ++f) {
      if (sys.unknown[f] >= 0) face_of[sys.unknown[f]] = f;
    }
    Eigen::MatrixXd rhs, sol;
    for (int a0 = 0; a0 < k; a0 += block) {
      const int cols = std::min(block, k - a0);
      sys.solve(a0, cols, &rhs, &sol);
      for (int c = 0; c < cols; ++c)
        for (int u = 0; u < sys.nu; ++u) offer(face_of[u], a0 + c, sol(u, c));
    }
  }
  SparseWeights out;
  out.ptr.assign(1, 0);
  for (int f = 0; f < num_faces; ++f) {
    for (int i = 0; i < count[f]; ++i) {
      out.idx.push_back(best_a[static_cast<size_t>(f) * keep + i]);
      out.w.push_back(best_w[static_cast<size_t>(f) * keep + i]);
    }
    out.ptr.push_back(static_cast<int>(out.idx.size()));
  }
  return out;
}

}  // namespace matdeform
