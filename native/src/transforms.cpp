#include "matdeform/transforms.hpp"

#include <Eigen/Dense>
#include <cmath>
#include <stdexcept>
#include <string>

#include "simd.hpp"
#include "task_pool.hpp"

namespace matdeform {

namespace {
// Per-pose loops over faces: a few tasks per thread so that a late worker only takes fewer.
constexpr int kFacesPerTask = 8192;
constexpr int kTasks = 8;
}  // namespace

Eigen::Vector3d rotation_log(const Eigen::Matrix3d& R) {
  // Quaternion route: Eigen's matrix->quaternion conversion picks the largest diagonal pivot,
  // so it stays accurate at angle pi where the trace formula's sin(theta) vanishes.
  Eigen::Quaterniond q(R);
  q.normalize();
  if (q.w() < 0) q.coeffs() = -q.coeffs();  // angle in [0, pi]
  const Eigen::Vector3d v = q.vec();
  const double s = v.norm();
  if (s < 1e-8) {
    // theta/s -> 2/w as s -> 0 (w -> 1); the ratio's next term is O(s^2), below round-off.
    return v * (2.0 / q.w());
  }
  const double theta = 2.0 * std::atan2(s, q.w());
  return v * (theta / s);
}

namespace {
// sin(t)/t and (1 - cos t)/t^2 as power series in s = t^2: sum (-1)^k s^k / (2k+1)! and
// sum (-1)^k s^k / (2k+2)!. With 16 terms the tail is below 1e-19 for s <= 10 (angles up to
// 3.16 > pi, every isotropic blend), and the Horner sums are within 4e-16 of the exact values:
// no sin, cos, sqrt or division per face, and no special case near t = 0.
constexpr int kSeriesTerms = 16;
constexpr double kSeriesMaxT2 = 10.0;
struct RodriguesSeries {
  double a[kSeriesTerms], b[kSeriesTerms];
};
constexpr RodriguesSeries make_series() {
  RodriguesSeries c{};
  double f = 1.0;  // (2k+1)!
  for (int k = 0; k < kSeriesTerms; ++k) {
    if (k > 0) f *= (2.0 * k) * (2.0 * k + 1.0);
    const double sign = k % 2 ? -1.0 : 1.0;
    c.a[k] = sign / f;
    c.b[k] = sign / (f * (2.0 * k + 2.0));
  }
  return c;
}
constexpr RodriguesSeries kSeries = make_series();

// R = I + a K + b K^2 for K = [omega]x.
MD_ALWAYS_INLINE void rodrigues(double x, double y, double z, double scale, Eigen::Matrix3d* R) {
  const double t2 = x * x + y * y + z * z;
  double a, b;
  if (t2 <= kSeriesMaxT2) {
    a = kSeries.a[kSeriesTerms - 1];
    b = kSeries.b[kSeriesTerms - 1];
    for (int k = kSeriesTerms - 2; k >= 0; --k) {
      a = a * t2 + kSeries.a[k];
      b = b * t2 + kSeries.b[k];
    }
  } else {  // large anisotropic blends only
    const double t = std::sqrt(t2);
    a = std::sin(t) / t;
    b = 2.0 * std::sin(0.5 * t) * std::sin(0.5 * t) / t2;
  }
  a *= scale;
  b *= scale;
  double* r = R->data();  // column-major
  r[0] = scale - b * (y * y + z * z);
  r[1] = a * z + b * x * y;
  r[2] = -a * y + b * x * z;
  r[3] = -a * z + b * x * y;
  r[4] = scale - b * (x * x + z * z);
  r[5] = a * x + b * y * z;
  r[6] = a * y + b * x * z;
  r[7] = -a * x + b * y * z;
  r[8] = scale - b * (x * x + y * y);
}
}  // namespace

Eigen::Matrix3d rotation_exp(const Eigen::Vector3d& omega) {
  Eigen::Matrix3d R;
  rodrigues(omega.x(), omega.y(), omega.z(), 1.0, &R);
  return R;
}

void polar_decompose(const Eigen::Matrix3d& M, Eigen::Matrix3d* S, Eigen::Matrix3d* R) {
  if (!M.allFinite()) throw std::invalid_argument("transform contains NaN or infinity");
  const double det = M.determinant();
  if (!(det > 0.0)) {
    throw std::invalid_argument("transform must have a positive determinant (got " +
                                std::to_string(det) + ")");
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Matrix3d& U = svd.matrixU();
  const Eigen::Matrix3d& V = svd.matrixV();
  // det M > 0 and singular values >= 0 imply det(U) det(V) = +1, so U V^T is proper.
  *R = U * V.transpose();
  *S = U * svd.singularValues().asDiagonal() * U.transpose();
}

Eigen::Matrix3d spd_log(const Eigen::Matrix3d& S) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(0.5 * (S + S.transpose()));
  const Eigen::Vector3d lam = es.eigenvalues();
  if (!(lam.minCoeff() > 0.0)) throw std::invalid_argument("stretch is not positive definite");
  return es.eigenvectors() * lam.array().log().matrix().asDiagonal() *
         es.eigenvectors().transpose();
}

Eigen::Matrix3d sym_exp(const Eigen::Matrix3d& L) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(0.5 * (L + L.transpose()));
  return es.eigenvectors() * es.eigenvalues().array().exp().matrix().asDiagonal() *
         es.eigenvectors().transpose();
}

namespace {
bool is_scalar_matrix(const Eigen::Matrix3d& L) {
  const double t = L.trace() / 3.0;
  const Eigen::Matrix3d dev = L - t * Eigen::Matrix3d::Identity();
  return dev.cwiseAbs().maxCoeff() <= 1e-12 * (1.0 + std::abs(t));
}
}  // namespace

TransformLog transform_log(const Eigen::Matrix3d& M) {
  Eigen::Matrix3d S, R;
  polar_decompose(M, &S, &R);
  TransformLog out;
  out.log_stretch = spd_log(S);
  out.rotation = rotation_log(R);
  out.similarity = is_scalar_matrix(out.log_stretch);
  if (out.similarity) {
    out.log_stretch = (out.log_stretch.trace() / 3.0) * Eigen::Matrix3d::Identity();
  }
  return out;
}

Eigen::Matrix3d transform_exp(const TransformLog& L) {
  const Eigen::Matrix3d R = rotation_exp(L.rotation);
  if (L.similarity || is_scalar_matrix(L.log_stretch)) {
    return std::exp(L.log_stretch.trace() / 3.0) * R;
  }
  return sym_exp(L.log_stretch) * R;
}

Eigen::Matrix3d blend_logs(const std::vector<TransformLog>& logs, const double* weights) {
  TransformLog sum;
  sum.similarity = true;
  for (size_t a = 0; a < logs.size(); ++a) {
    sum.log_stretch += weights[a] * logs[a].log_stretch;
    sum.rotation += weights[a] * logs[a].rotation;
    sum.similarity = sum.similarity && logs[a].similarity;
  }
  return transform_exp(sum);
}

namespace {
// Blend of similarity logs for faces [begin, end): P holds per anchor (rotation log, log scale)
// as 4 doubles, W the (m,k) row-major weights. exp(s I + [w]x) = e^s Rodrigues(w).
MD_ALWAYS_INLINE void blend_similar_body(const double* P, int k, bool scaled, const double* W,
                                         int begin, int end, Eigen::Matrix3d* out) {
  for (int i = begin; i < end; ++i) {
    const double* w = W + static_cast<size_t>(i) * k;
    double x = 0.0, y = 0.0, z = 0.0, s = 0.0;
    for (int a = 0; a < k; ++a) {
      x += w[a] * P[4 * a];
      y += w[a] * P[4 * a + 1];
      z += w[a] * P[4 * a + 2];
      s += w[a] * P[4 * a + 3];
    }
    rodrigues(x, y, z, scaled ? std::exp(s) : 1.0, &out[i - begin]);
  }
}
void blend_similar_base(const double* P, int k, bool scaled, const double* W, int begin, int end,
                        Eigen::Matrix3d* out) {
  blend_similar_body(P, k, scaled, W, begin, end, out);
}
MD_TARGET_AVX2 void blend_similar_avx2(const double* P, int k, bool scaled, const double* W,
                                       int begin, int end, Eigen::Matrix3d* out) {
  blend_similar_body(P, k, scaled, W, begin, end, out);
}
}  // namespace

void blend_range(const std::vector<TransformLog>& logs, const RowMatrix& weights, int begin,
                 int end, Eigen::Matrix3d* out) {
  const Eigen::Index k = weights.cols();
  if (static_cast<Eigen::Index>(logs.size()) != k) {
    throw std::invalid_argument("blend: one log per weight column expected");
  }
  bool all_similar = true;
  for (const auto& l : logs) all_similar = all_similar && l.similarity;
  if (!all_similar) {
    for (int i = begin; i < end; ++i) out[i - begin] = blend_logs(logs, weights.row(i).data());
    return;
  }
  // Closed form: exp(s I + [w]x) = e^s * Rodrigues(w), no eigen-solves per face.
  Eigen::Matrix<double, 4, Eigen::Dynamic> P(4, k);
  bool scaled = false;
  for (Eigen::Index a = 0; a < k; ++a) {
    P.col(a).head<3>() = logs[static_cast<size_t>(a)].rotation;
    P(3, a) = logs[static_cast<size_t>(a)].log_stretch(0, 0);
    scaled = scaled || P(3, a) != 0.0;
  }
  const double* W = weights.data();
  if (cpu_has_avx2_fma()) {
    blend_similar_avx2(P.data(), static_cast<int>(k), scaled, W, begin, end, out);
  } else {
    blend_similar_base(P.data(), static_cast<int>(k), scaled, W, begin, end, out);
  }
}

void blend_all(const std::vector<TransformLog>& logs, const RowMatrix& weights, Matrix3Array* out) {
  const int m = static_cast<int>(weights.rows());
  if (static_cast<Eigen::Index>(logs.size()) != weights.cols()) {
    throw std::invalid_argument("blend_all: one log per weight column expected");
  }
  out->resize(static_cast<size_t>(m));
  parallel_ranges(m, kFacesPerTask, kTasks,
                  [&](int b, int e) { blend_range(logs, weights, b, e, out->data() + b); });
}

void blend_range_anisotropic(const std::vector<TransformLog>& logs, const RowMatrix& wx,
                             const RowMatrix& wy, const RowMatrix& wz, const Eigen::Matrix3d& axes,
                             int begin, int end, Eigen::Matrix3d* out) {
  const Eigen::Index m = wx.rows();
  const Eigen::Index k = wx.cols();
  if (static_cast<Eigen::Index>(logs.size()) != k || wy.rows() != m || wz.rows() != m ||
      wy.cols() != k || wz.cols() != k) {
    throw std::invalid_argument("blend_all_anisotropic: weight shapes do not match");
  }
  // Rotation logs in the axes' frame: row c holds every anchor's component along axis c.
  Eigen::Matrix<double, 3, Eigen::Dynamic> C(3, k);
  bool all_similar = true;
  for (Eigen::Index a = 0; a < k; ++a) {
    C.col(a) = axes.transpose() * logs[static_cast<size_t>(a)].rotation;
    all_similar = all_similar && logs[static_cast<size_t>(a)].similarity;
  }
  for (int i = begin; i < end; ++i) {
    Eigen::Vector3d local = Eigen::Vector3d::Zero();
    TransformLog sum;
    sum.similarity = all_similar;
    for (Eigen::Index a = 0; a < k; ++a) {
      local += Eigen::Vector3d(wx(i, a), wy(i, a), wz(i, a)).cwiseProduct(C.col(a));
      const double w = (wx(i, a) + wy(i, a) + wz(i, a)) / 3.0;
      sum.log_stretch += w * logs[static_cast<size_t>(a)].log_stretch;
    }
    sum.rotation = axes * local;
    out[i - begin] = transform_exp(sum);
  }
}

void blend_all_anisotropic(const std::vector<TransformLog>& logs, const RowMatrix& wx,
                           const RowMatrix& wy, const RowMatrix& wz, const Eigen::Matrix3d& axes,
                           Matrix3Array* out) {
  const int m = static_cast<int>(wx.rows());
  if (static_cast<Eigen::Index>(logs.size()) != wx.cols() || wy.rows() != m || wz.rows() != m ||
      wy.cols() != wx.cols() || wz.cols() != wx.cols()) {
    throw std::invalid_argument("blend_all_anisotropic: weight shapes do not match");
  }
  out->resize(static_cast<size_t>(m));
  parallel_ranges(m, kFacesPerTask, kTasks, [&](int b, int e) {
    blend_range_anisotropic(logs, wx, wy, wz, axes, b, e, out->data() + b);
  });
}

}  // namespace matdeform
