// The least-squares energy of the pyramids (every vertex with its one-ring) against rotated and
// scaled copies of their rest shapes, its gradient and its Hessian (docs/pyramid.md).
//
// For one pyramid with members x_k (k < M), rest offsets p_k (sum_k p_k = 0), s0 = sum |p_k|^2:
//   y_k = x_k - mean(x), H = sum_k y_k p_k^T, R the rotation maximising t = tr(R^T H),
//   s = (t / s0 + kappa) / (1 + kappa),
//   E = sum_k |y_k - s R p_k|^2 + kappa s0 (s - 1)^2        (the minimum over s and R),
//   dE/dx_k = 2 (y_k - s R p_k)                             (R and s optimal: envelope theorem),
//   d2E/dx dx = 2 C - (2 / (s0 (1 + kappa))) z z^T - 2 s B G^-1 B^T,
// with C = (I - 11^T / M) (x) I_3, z_k = R p_k, B_k = R [p_k]x (rows of the 3M x 3 matrix B) and
// G = t I - R^T H, the derivative of the polar factor (dR = R [w]x, G w = 2 vee(skew(R^T dH))).
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>

#include "matdeform/transforms.hpp"
#include "pyramid_internal.hpp"

namespace matdeform {
namespace pyramid {

Pyramids make_pyramids(const Vertices& rest, const PyramidCoordinates& coords,
                       const std::vector<char>& keep_apex) {
  Pyramids P;
  P.offsets.push_back(0);
  const int n = static_cast<int>(rest.rows());
  const double* X = rest.data();
  std::vector<int> mem;
  for (int v = 0; v < n; ++v) {
    if (!keep_apex[static_cast<size_t>(v)]) continue;
    const int o = coords.offsets[static_cast<size_t>(v)];
    const int m = coords.offsets[static_cast<size_t>(v) + 1] - o;
    if (m < 2) continue;
    mem.assign(1, v);
    mem.insert(mem.end(), coords.neighbors.begin() + o, coords.neighbors.begin() + o + m);
    Vec3 c = Vec3::Zero();
    for (int k : mem) c += row(X, k);
    c /= static_cast<double>(mem.size());
    Mat3 S = Mat3::Zero();
    double s0 = 0;
    for (int k : mem) {
      const Vec3 p = row(X, k) - c;
      S += p * p.transpose();
      s0 += p.squaredNorm();
    }
    // Collinear (or coinciding) rest points leave a rotation about their line free.
    const Eigen::SelfAdjointEigenSolver<Mat3> eig(S, Eigen::EigenvaluesOnly);
    if (!(eig.eigenvalues()(1) > 1e-12 * eig.eigenvalues()(2))) continue;
    for (int k : mem) {
      P.members.push_back(k);
      const Vec3 p = row(X, k) - c;
      P.rest.insert(P.rest.end(), {p(0), p(1), p(2)});
    }
    P.size.push_back(s0);
    P.offsets.push_back(static_cast<int>(P.members.size()));
  }
  return P;
}

namespace {
// The SVD's rotation, where fit_rotation declines (H of rank <= 1, or nearly so).
void svd_rotation(const Mat3& H, Mat3* R, double* trace) {
  const Eigen::JacobiSVD<Mat3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 D = Mat3::Identity();
  Vec3 sig = svd.singularValues();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) {
    D(2, 2) = -1;
    sig(2) = -sig(2);
  }
  *R = svd.matrixU() * D * svd.matrixV().transpose();
  *trace = sig.sum();
}
}  // namespace

void best_rotation(const Mat3& H, Mat3* R, double* trace) {
  if (fit_rotation(H, R, trace)) return;
  svd_rotation(H, R, trace);
}

void fit_pyramids(const Pyramids& P, int c0, int count, const double* X, double kappa, Fit* out) {
  Mat3 H[4], R[4];
  double trace[4];
  bool ok[4];
  for (int i = 0; i < count; ++i) {
    const int c = c0 + i;
    Fit& f = out[i];
    f = Fit();
    const int b = P.offsets[static_cast<size_t>(c)], e = P.offsets[static_cast<size_t>(c) + 1];
    const int M = e - b;
    const int* mem = P.members.data() + b;
    const double* p = P.rest.data() + 3 * static_cast<size_t>(b);
    for (int k = 0; k < M; ++k) f.centre += row(X, mem[k]);
    f.centre /= M;
    for (int k = 0; k < M; ++k) {
      f.H += (row(X, mem[k]) - f.centre) * Vec3(p[3 * k], p[3 * k + 1], p[3 * k + 2]).transpose();
    }
    H[i] = f.H;
  }
  // Padding: lanes do not affect each other, and a rotation never needs fit_rotation's slow path.
  for (int i = count; i < 4; ++i) H[i] = Mat3::Identity();
  // Four at a time: the same rotation, to round-off, as one fit_rotation call each, and what a
  // pyramid gets does not depend on which others share its call (relabelling, thread counts).
  fit_rotations4(H, R, trace, ok);
  for (int i = 0; i < count; ++i) {
    const int c = c0 + i;
    Fit& f = out[i];
    if (ok[i]) {
      f.R = R[i];
      f.trace = trace[i];
    } else {
      svd_rotation(f.H, &f.R, &f.trace);
    }
    const int b = P.offsets[static_cast<size_t>(c)], e = P.offsets[static_cast<size_t>(c) + 1];
    const int M = e - b;
    const int* mem = P.members.data() + b;
    const double* p = P.rest.data() + 3 * static_cast<size_t>(b);
    const double s0 = P.size[static_cast<size_t>(c)];
    f.scale = (f.trace / s0 + kappa) / (1 + kappa);
    // The residual form (not |y|^2 - t^2 / s0): no cancellation when the fit is good.
    const Mat3 sR = f.scale * f.R;
    double E = kappa * s0 * (f.scale - 1) * (f.scale - 1);
    for (int k = 0; k < M; ++k) {
      E += (row(X, mem[k]) - f.centre - sR * Vec3(p[3 * k], p[3 * k + 1], p[3 * k + 2]))
               .squaredNorm();
    }
    f.energy = E;
  }
}

Fit fit_pyramid(const Pyramids& P, int c, const double* X, double kappa) {
  Fit f;
  fit_pyramids(P, c, 1, X, kappa, &f);
  return f;
}

bool hessian_terms(const Pyramids& P, int c, const Fit& fit, double kappa, bool exact, double* u,
                   double* coef) {
  const int b = P.offsets[static_cast<size_t>(c)], e = P.offsets[static_cast<size_t>(c) + 1];
  const int M = e - b, len = 3 * M;
  const double* p = P.rest.data() + 3 * static_cast<size_t>(b);
  const double s0 = P.size[static_cast<size_t>(c)];
  // z_k = R p_k
  for (int k = 0; k < M; ++k) {
    const Vec3 z = fit.R * Vec3(p[3 * k], p[3 * k + 1], p[3 * k + 2]);
    for (int r = 0; r < 3; ++r) u[3 * k + r] = z(r);
  }
  coef[0] = 2.0 / (s0 * (1 + kappa));
  // G = t I - R^T H in its eigenbasis: B G^-1 B^T = sum_i (B v_i)(B v_i)^T / g_i.
  Mat3 S = fit.R.transpose() * fit.H;
  S = 0.5 * (S + S.transpose()).eval();
  const Mat3 G = fit.trace * Mat3::Identity() - S;
  Eigen::SelfAdjointEigenSolver<Mat3> eig;
  eig.computeDirect(G);
  const double floor = 1e-9 * std::max(std::abs(fit.trace), 1e-300);
  for (int i = 0; i < 3; ++i) {
    const Vec3 v = eig.eigenvectors().col(i);
    const double g = eig.eigenvalues()(i);
    double* ui = u + static_cast<size_t>(i + 1) * len;
    // Where G is (nearly) singular the fit's rotation is not differentiable (a pyramid folded
    // flat): that direction gets no rotation term.
    coef[i + 1] = std::abs(g) > floor ? 2.0 * fit.scale / g : 0.0;
    for (int k = 0; k < M; ++k) {
      const Vec3 w = fit.R * Vec3(p[3 * k], p[3 * k + 1], p[3 * k + 2]).cross(v);
      for (int r = 0; r < 3; ++r) ui[3 * k + r] = w(r);
    }
  }
  if (exact) return false;
  // Positive semidefinite version: the Hessian is 2 minus sum_q coef_q u_q u_q^T on span(u), so
  // clamp that low-rank part's eigenvalues at 2. In an orthonormal basis of span(u) (from the
  // Gram matrix U Sigma U^T of the u_q) it is the 4x4 K = Sigma^1/2 U^T diag(coef) U Sigma^1/2.
  Eigen::Matrix4d gram;
  for (int q = 0; q < kTerms; ++q) {
    for (int r = 0; r <= q; ++r) {
      double d = 0;
      const double* a = u + static_cast<size_t>(q) * len;
      const double* bb = u + static_cast<size_t>(r) * len;
      for (int i = 0; i < len; ++i) d += a[i] * bb[i];
      gram(q, r) = gram(r, q) = d;
    }
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> ge(gram);
  const Eigen::Vector4d sig = ge.eigenvalues();
  Eigen::Vector4d root = Eigen::Vector4d::Zero(), inv_root = Eigen::Vector4d::Zero();
  for (int q = 0; q < kTerms; ++q) {
    if (sig(q) > 1e-12 * sig(3)) root(q) = std::sqrt(sig(q)), inv_root(q) = 1 / root(q);
  }
  const Eigen::Matrix4d US = ge.eigenvectors() * root.asDiagonal();
  const Eigen::Matrix4d K =
      US.transpose() * Eigen::Vector4d(coef[0], coef[1], coef[2], coef[3]).asDiagonal() * US;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> ke(K);
  // New vectors u'_j = sum_q u_q T_qj, T = U Sigma^-1/2 P: orthonormal, with eigenvalues lambda_j.
  const Eigen::Matrix4d T = ge.eigenvectors() * inv_root.asDiagonal() * ke.eigenvectors();
  bool clamped = false;
  double tmp[kTerms];
  for (int i = 0; i < len; ++i) {
    for (int j = 0; j < kTerms; ++j) {
      double d = 0;
      for (int q = 0; q < kTerms; ++q) d += u[static_cast<size_t>(q) * len + i] * T(q, j);
      tmp[j] = d;
    }
    for (int j = 0; j < kTerms; ++j) u[static_cast<size_t>(j) * len + i] = tmp[j];
  }
  for (int j = 0; j < kTerms; ++j) {
    const double lam = ke.eigenvalues()(j);
    // 2 (1 - 1e-9): at rest the similarity's modes sit exactly at 2 (zero energy change).
    if (lam > 2.0 * (1 + 1e-9)) clamped = true;
    coef[j] = std::min(lam, 2.0);
  }
  return clamped;
}

void fit_similarity(const std::vector<Vec3>& a, const std::vector<Vec3>& b, Mat3* A, Vec3* ca,
                    Vec3* cb) {
  const size_t k = a.size();
  *ca = Vec3::Zero();
  *cb = Vec3::Zero();
  for (size_t j = 0; j < k; ++j) *ca += a[j], *cb += b[j];
  *ca /= static_cast<double>(k);
  *cb /= static_cast<double>(k);
  Mat3 H = Mat3::Zero();
  double s0 = 0;
  for (size_t j = 0; j < k; ++j) {
    const Vec3 p = a[j] - *ca;
    H += (b[j] - *cb) * p.transpose();
    s0 += p.squaredNorm();
  }
  *A = Mat3::Identity();
  if (!(s0 > 0) || !H.allFinite() || !(H.norm() > 0)) return;
  // The SVD's rotation: for rank-deficient H (one or two points, or a line) its order picks
  // the smallest rotation, where fit_rotation would decline.
  const Eigen::JacobiSVD<Mat3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 D = Mat3::Identity();
  Vec3 sig = svd.singularValues();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1, sig(2) *= -1;
  *A = (sig.sum() / s0) * (svd.matrixU() * D * svd.matrixV().transpose());
}

}  // namespace pyramid
}  // namespace matdeform
