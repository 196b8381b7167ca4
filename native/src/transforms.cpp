#include "matdeform/transforms.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "simd.hpp"
#include "task_pool.hpp"

namespace matdeform {

namespace {
// Per-pose loops over faces: a few tasks per thread so that a late worker only takes fewer.
constexpr int kFacesPerTask = 8192;
constexpr int kTasks = 8;
}  // namespace

Eigen::Vector3d rotation_log(const Eigen::Matrix3d& R) {
  // Eigen's matrix -> quaternion conversion picks the largest diagonal pivot, so it stays
  // accurate at angle pi where the trace formula's sin(theta) vanishes; AngleAxis then takes
  // angle = 2 atan2(|v|, |w|) in [0, pi], which ignores the quaternion's norm (R need not be
  // exactly orthonormal). Same accuracy as a hand-written version, and no slower (measured:
  // 80-150 ns against 130-200 ns per call, 200k random rotations including angles 0 and pi).
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
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

// Beyond the series range (blends of rotation vectors longer than pi, or weights outside
// [0, 1]): the factor that takes the whole turns out of a rotation vector of squared length t2,
// i.e. maps angle t to t - 2 pi round(t / 2 pi) in [-pi, pi] about the same axis, the same
// rotation, where the series applies. 2 pi in three parts (Cody-Waite): k * kTwoPiHi is exact
// for k < 2^29 turns and the subtraction from t is exact, so the reduced angle is as accurate
// as sin(t) would be; a square root and a division instead of two sines.
inline double whole_turns_removed(double t2) {
  constexpr double kTwoPiHi = 6.2831854820251465;        // float(2 pi): 24 significant bits
  constexpr double kTwoPiMid = -1.7484556000744487e-07;  // double(2 pi) - kTwoPiHi, exact
  constexpr double kTwoPiLo = 2.4492935982947064e-16;    // 2 pi - double(2 pi)
  const double t = std::sqrt(t2);
  const double k = std::round(t * (1.0 / 6.283185307179586));
  return (((t - k * kTwoPiHi) - k * kTwoPiMid) - k * kTwoPiLo) / t;
}

// e^s for four lanes without a libm call per lane (the blended log-scale of every face is
// exponentiated; it is nonzero whenever an anchor's scale is not exactly 1, round-off included):
// e^s = 2^n e^r with n = round(s / ln 2), r = s - n ln 2 in two parts (Cody-Waite, n ln2_hi is
// exact), |r| <= 0.35, and e^r by 15 Taylor terms (tail below 1e-18). Lanes beyond |s| > 700
// (outside double's exponent range for 2^n) fall back to std::exp.
constexpr int kExpTerms = 15;
struct ExpSeries {
  double c[kExpTerms];
};
constexpr ExpSeries make_exp_series() {
  ExpSeries e{};
  double f = 1.0;
  for (int k = 0; k < kExpTerms; ++k) {
    if (k > 0) f *= k;
    e.c[k] = 1.0 / f;
  }
  return e;
}
constexpr ExpSeries kExp = make_exp_series();
MD_ALWAYS_INLINE void exp4(const Vec4d& s, Vec4d* out) {
  constexpr double kInvLn2 = 1.44269504088896338700e+00, kLn2Hi = 6.93147180369123816490e-01,
                   kLn2Lo = 1.90821492927058770002e-10;
  constexpr double kShifter = 6755399441055744.0;  // 1.5 * 2^52: adding it rounds to an integer
  const Vec4d shifter = Vec4d{0.0, 0.0, 0.0, 0.0} + kShifter;
  const Vec4d t = s * kInvLn2 + shifter;  // n sits in the low mantissa bits of t
  const Vec4d n = t - shifter;            // n = round(s / ln 2) as a double
  const Vec4d r = (s - n * kLn2Hi) - n * kLn2Lo;
  Vec4d p = r * kExp.c[kExpTerms - 1] + kExp.c[kExpTerms - 2];
  for (int k = kExpTerms - 3; k >= 0; --k) p = p * r + kExp.c[k];
  // 2^n built from its bits: the integer n is t's bit pattern minus the shifter's. (A cast
  // between Vec4d and Vec4u keeps the bits, simd.hpp.)
  const Vec4u biased = (Vec4u)t - (Vec4u)shifter + 1023;  // unsigned: wraps, never UB
  p *= (Vec4d)(biased << 52);
  if (any_lane(s * s > 490000.0)) {  // one test for the four lanes: the loop is the rare case
    for (int l = 0; l < 4; ++l) {
      if (!(std::abs(s[l]) <= 700.0)) p[l] = std::exp(s[l]);  // beyond 2^n's exponent range
    }
  }
  *out = p;
}

// R = I + a K + b K^2 for K = [omega]x.
MD_ALWAYS_INLINE void rodrigues(double x, double y, double z, double scale, Eigen::Matrix3d* R) {
  double t2 = x * x + y * y + z * z;
  if (!(t2 <= kSeriesMaxT2)) {
    const double f = whole_turns_removed(t2);
    x *= f, y *= f, z *= f;
    t2 = x * x + y * y + z * z;
  }
  double a = kSeries.a[kSeriesTerms - 1], b = kSeries.b[kSeriesTerms - 1];
  for (int k = kSeriesTerms - 2; k >= 0; --k) {
    a = a * t2 + kSeries.a[k];
    b = b * t2 + kSeries.b[k];
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

double rotation_vector_mismatch(const Eigen::Vector3d& v, const Eigen::Matrix3d& R) {
  const Eigen::Matrix3d E = rotation_exp(v);
  if (!E.allFinite()) return std::numeric_limits<double>::quiet_NaN();
  return rotation_log(E.transpose() * R).norm();
}

void check_rotation_vector(const Eigen::Vector3d& v, const Eigen::Matrix3d& R,
                           const std::string& name, const std::string& of) {
  if (!v.allFinite()) throw std::invalid_argument(name + ": contains NaN or infinity");
  const double err = rotation_vector_mismatch(v, R);
  if (!(err <= kRotationVectorTolerance)) {
    std::ostringstream msg;
    msg << name << ": its exp differs from " << of << " by " << err << " rad (tolerance "
        << kRotationVectorTolerance
        << "); expected a log of that rotation, i.e. its principal log plus whole turns about "
           "the same axis";
    if (std::isnan(err)) msg << " (this vector, " << v.norm() << " rad, is too long)";
    throw std::invalid_argument(msg.str());
  }
}

Eigen::Vector3d rotation_log_near(const Eigen::Matrix3d& R, const Eigen::Vector3d& near) {
  constexpr double kTwoPi = 6.28318530717958647693;
  const Eigen::Vector3d r = rotation_log(R);
  const double theta = r.norm();
  Eigen::Vector3d best = r;
  if (theta > 0.0) {
    // |t u - near|^2 = t^2 - 2 t (u . near) + |near|^2: the t in theta + 2 pi Z nearest u . near.
    const Eigen::Vector3d u = r / theta;
    best = (theta + kTwoPi * std::round((u.dot(near) - theta) / kTwoPi)) * u;
  }
  // At a whole turn every axis is a log of the identity, and R's axis is noise: keep near's.
  const double len = near.norm();
  if (theta <= kRotationVectorTolerance && len >= 0.5 * kTwoPi) {
    const Eigen::Vector3d a = near / len;
    const Eigen::Vector3d kept = (kTwoPi * std::round(len / kTwoPi) + r.dot(a)) * a;
    if ((kept - near).squaredNorm() < (best - near).squaredNorm()) best = kept;
  }
  return best;
}

namespace {
// SVD M = U diag(sigma) V^T of a finite M with det M > 0 (the checks polar_decompose and
// transform_log share).
Eigen::JacobiSVD<Eigen::Matrix3d> checked_svd(const Eigen::Matrix3d& M) {
  if (!M.allFinite()) throw std::invalid_argument("transform contains NaN or infinity");
  const double det = M.determinant();
  if (!(det > 0.0)) {
    throw std::invalid_argument("transform must have a positive determinant (got " +
                                std::to_string(det) + ")");
  }
  return Eigen::JacobiSVD<Eigen::Matrix3d>(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
}
}  // namespace

void polar_decompose(const Eigen::Matrix3d& M, Eigen::Matrix3d* S, Eigen::Matrix3d* R) {
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd = checked_svd(M);
  const Eigen::Matrix3d& U = svd.matrixU();
  const Eigen::Matrix3d& V = svd.matrixV();
  // det M > 0 and singular values >= 0 imply det(U) det(V) = +1, so U V^T is proper.
  *R = U * V.transpose();
  *S = U * svd.singularValues().asDiagonal() * U.transpose();
  if (!S->allFinite())
    throw std::invalid_argument("transform: entries too large (scale overflows)");
}

std::vector<Eigen::Vector3d> unwrap_rotations(const Matrix3Array& frames, int k,
                                              const std::vector<Eigen::Vector3d>& start) {
  if (k < 1 || frames.size() % static_cast<size_t>(k) != 0) {
    throw std::invalid_argument("unwrap_rotations: expected a whole number of frames of k = " +
                                std::to_string(k) + " rotations");
  }
  if (!start.empty() && start.size() != static_cast<size_t>(k)) {
    throw std::invalid_argument("start: expected one vector per sequence (" + std::to_string(k) +
                                "), got " + std::to_string(start.size()));
  }
  for (size_t a = 0; a < start.size(); ++a) {
    if (!start[a].allFinite()) {
      throw std::invalid_argument("start[" + std::to_string(a) + "]: contains NaN or infinity");
    }
  }
  std::vector<Eigen::Vector3d> out(frames.size());
  Eigen::Matrix3d S, R;
  for (size_t i = 0; i < frames.size(); ++i) {
    try {
      polar_decompose(frames[i], &S, &R);
    } catch (const std::invalid_argument& e) {
      const size_t kk = static_cast<size_t>(k);
      throw std::invalid_argument("rotations[" + std::to_string(i / kk) +
                                  (k > 1 ? "][" + std::to_string(i % kk) + "]" : "]") + ": " +
                                  e.what());
    }
    const size_t a = i % static_cast<size_t>(k);
    if (i >= static_cast<size_t>(k)) {
      out[i] = rotation_log_near(R, out[i - static_cast<size_t>(k)]);
    } else {
      out[i] = start.empty() ? rotation_log(R) : rotation_log_near(R, start[a]);
    }
  }
  return out;
}

bool fit_rotation(const Eigen::Matrix3d& H, Eigen::Matrix3d* R, double* trace) {
  // Horn's N for the sums S_ab = sum x_a y_b = H(b, a); for a unit quaternion q,
  // q^T N q = tr(R(q)^T H), so the eigenvector of N's largest eigenvalue gives R.
  const double sxx = H(0, 0), sxy = H(1, 0), sxz = H(2, 0);
  const double syx = H(0, 1), syy = H(1, 1), syz = H(2, 1);
  const double szx = H(0, 2), szy = H(1, 2), szz = H(2, 2);
  double N[4][4] = {{sxx + syy + szz, syz - szy, szx - sxz, sxy - syx},
                    {0, sxx - syy - szz, sxy + syx, szx + sxz},
                    {0, 0, -sxx + syy - szz, syz + szy},
                    {0, 0, 0, -sxx - syy + szz}};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < i; ++j) N[i][j] = N[j][i];
  const double h2 = H.squaredNorm();
  if (!(h2 > 0) || !std::isfinite(h2)) return false;
  // det(N - l I) = l^4 + c2 l^2 + c1 l + c0 (tr N = 0): c2 = -tr(N^2)/2, c1 = -tr(N^3)/3.
  double N2[4][4];
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      double s = 0;
      for (int k = 0; k < 4; ++k) s += N[i][k] * N[k][j];
      N2[i][j] = s;
    }
  double p2 = 0, p3 = 0;
  for (int i = 0; i < 4; ++i) {
    p2 += N2[i][i];
    for (int j = 0; j < 4; ++j) p3 += N2[i][j] * N[j][i];
  }
  const double c2 = -0.5 * p2, c1 = -p3 / 3.0;
  const Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> Nm(&N[0][0]);
  const double c0 = Nm.determinant();
  // Newton from above: lambda_max <= sigma_1 + sigma_2 + sigma_3 <= sqrt(3) |H|_F, and beyond
  // the largest root the quartic is increasing and convex, so the iterates fall monotonically.
  double l = std::sqrt(3.0 * h2);
  const double l0 = l;
  for (int it = 0; it < 100; ++it) {
    const double P = ((l * l + c2) * l + c1) * l + c0;
    const double dP = (4.0 * l * l + 2.0 * c2) * l + c1;
    if (!(dP > 0)) break;
    const double step = P / dP;
    if (!(step > 1e-15 * l0)) break;
    l -= step;
  }
  // The eigenvector spans the kernel of A = N - l I: the generalised cross product of any three
  // of its rows (a column of adj A), the largest of the four choices.
  double A[4][4];
  auto det3 = [&](int r0, int r1, int r2, int a, int b, int c) {
    return A[r0][a] * (A[r1][b] * A[r2][c] - A[r1][c] * A[r2][b]) -
           A[r0][b] * (A[r1][a] * A[r2][c] - A[r1][c] * A[r2][a]) +
           A[r0][c] * (A[r1][a] * A[r2][b] - A[r1][b] * A[r2][a]);
  };
  // |q| is about the product of l's gaps to the other three eigenvalues (the smallest of them is
  // 2 (sigma_2 + sign sigma_3)). The root carries the quartic's round-off, eps l0 over the
  // relative gap, and q's error is that over the gap again: where the gap is small, Rayleigh
  // quotients q^T N q (error eps l0) and new adjugates make it eps over the gap, as an SVD's.
  auto kernel = [&](double lam, Eigen::Vector4d* out) {
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) A[i][j] = N[i][j] - (i == j ? lam : 0.0);
    *out = Eigen::Vector4d::Zero();
    for (int skip = 0; skip < 4; ++skip) {
      int r[3], n = 0;
      for (int i = 0; i < 4; ++i)
        if (i != skip) r[n++] = i;
      const Eigen::Vector4d v(det3(r[0], r[1], r[2], 1, 2, 3), -det3(r[0], r[1], r[2], 0, 2, 3),
                              det3(r[0], r[1], r[2], 0, 1, 3), -det3(r[0], r[1], r[2], 0, 1, 2));
      if (v.squaredNorm() > out->squaredNorm()) *out = v;
    }
    return out->norm();
  };
  const double cube = l0 * l0 * l0;
  // Newton resolves the top root only to ~sqrt(eps) l0 where the gap is tiny, and then the
  // Rayleigh steps can converge to the second eigenvector (a rotation turned by pi; a review
  // found it at relative gaps of 1e-8 and below): refuse below ~1e-6, the SVD takes those.
  constexpr double kRefuse = 1e-6;
  Eigen::Vector4d best;
  double qn = kernel(l, &best);
  // Refine where the relative gap is below ~1e-3, twice below ~1e-5 (the first step leaves an
  // error of eps^2 / gap^4).
  for (const double below : {1e-3, 1e-5}) {
    if (!(qn > kRefuse * cube) || !std::isfinite(qn)) return false;
    if (qn > below * cube) break;
    const Eigen::Vector4d u = best / qn;
    qn = kernel(u.dot(Nm * u), &best);
  }
  if (!(qn > kRefuse * cube) || !std::isfinite(qn)) return false;
  const Eigen::Vector4d q = best / qn;
  const double w = q(0), x = q(1), y = q(2), z = q(3);
  Eigen::Matrix3d Rq;
  Rq << w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y),
      2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x), 2 * (x * z - w * y),
      2 * (y * z + w * x), w * w - x * x - y * y + z * z;
  *R = Rq;
  *trace = (Rq.transpose() * H).trace();
  return true;
}

namespace {
// fit_rotation's common case for four matrices at once, lane by lane the same steps (Horn's
// matrix, Newton's method on its characteristic polynomial from above, the largest adjugate
// column). A lane whose root would need refining (relative eigenvalue gap below ~1e-3), or that
// is not finite, is left to fit_rotation itself.
MD_ALWAYS_INLINE void fit_rotations4_body(const Eigen::Matrix3d* H, Eigen::Matrix3d* R,
                                          double* trace, bool* ok) {
  Vec4d h[9];  // h[r + 3 c] = H(r, c) of the four lanes
  for (int e = 0; e < 9; ++e) {
    h[e] = Vec4d{H[0].data()[e], H[1].data()[e], H[2].data()[e], H[3].data()[e]};
  }
  const Vec4d sxx = h[0], sxy = h[1], sxz = h[2];
  const Vec4d syx = h[3], syy = h[4], syz = h[5];
  const Vec4d szx = h[6], szy = h[7], szz = h[8];
  Vec4d N[4][4];
  N[0][0] = sxx + syy + szz, N[0][1] = syz - szy, N[0][2] = szx - sxz, N[0][3] = sxy - syx;
  N[1][1] = sxx - syy - szz, N[1][2] = sxy + syx, N[1][3] = szx + sxz;
  N[2][2] = -sxx + syy - szz, N[2][3] = syz + szy;
  N[3][3] = -sxx - syy + szz;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < i; ++j) N[i][j] = N[j][i];
  Vec4d h2 = h[0] * h[0];
  for (int e = 1; e < 9; ++e) h2 += h[e] * h[e];
  Vec4d p2 = {0, 0, 0, 0}, p3 = {0, 0, 0, 0};
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      Vec4d n2 = N[i][0] * N[0][j];
      for (int k = 1; k < 4; ++k) n2 += N[i][k] * N[k][j];
      if (i == j) p2 += n2;
      p3 += n2 * N[j][i];
    }
  }
  const Vec4d c2 = -0.5 * p2, c1 = -p3 / 3.0;
  // det N by the 2x2 minors of its first two and last two rows.
  const Vec4d s0 = N[0][0] * N[1][1] - N[1][0] * N[0][1],
              s1 = N[0][0] * N[1][2] - N[1][0] * N[0][2],
              s2 = N[0][0] * N[1][3] - N[1][0] * N[0][3],
              s3 = N[0][1] * N[1][2] - N[1][1] * N[0][2],
              s4 = N[0][1] * N[1][3] - N[1][1] * N[0][3],
              s5 = N[0][2] * N[1][3] - N[1][2] * N[0][3];
  const Vec4d t5 = N[2][2] * N[3][3] - N[3][2] * N[2][3],
              t4 = N[2][1] * N[3][3] - N[3][1] * N[2][3],
              t3 = N[2][1] * N[3][2] - N[3][1] * N[2][2],
              t2 = N[2][0] * N[3][3] - N[3][0] * N[2][3],
              t1 = N[2][0] * N[3][2] - N[3][0] * N[2][2],
              t0 = N[2][0] * N[3][1] - N[3][0] * N[2][1];
  const Vec4d c0 = s0 * t5 - s1 * t4 + s2 * t3 + s3 * t2 - s4 * t1 + s5 * t0;
  Vec4d l;
  sqrt4(3.0 * h2, &l);
  const Vec4d l0 = l, zero = {0, 0, 0, 0};
  // A lane stops at its first failed test, as fit_rotation's loop breaks.
  Vec4m alive = ~(zero > zero);
  for (int it = 0; it < 100; ++it) {
    const Vec4d P = ((l * l + c2) * l + c1) * l + c0;
    const Vec4d dP = (4.0 * l * l + 2.0 * c2) * l + c1;
    const Vec4d step = P / dP;
    alive = alive & (dP > zero) & (step > 1e-15 * l0);
    if (!any_lane(alive)) break;
    l = MD_SELECT4(alive, l - step, l);
  }
  Vec4d A[4][4];
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) A[i][j] = i == j ? N[i][j] - l : N[i][j];
  // (An output argument: returning a vector warns about the ABI in the baseline build.)
  auto det3 = [&](int r0, int r1, int r2, int a, int b, int c, double sign, Vec4d* out) {
    *out = sign * (A[r0][a] * (A[r1][b] * A[r2][c] - A[r1][c] * A[r2][b]) -
                   A[r0][b] * (A[r1][a] * A[r2][c] - A[r1][c] * A[r2][a]) +
                   A[r0][c] * (A[r1][a] * A[r2][b] - A[r1][b] * A[r2][a]));
  };
  Vec4d best[4] = {zero, zero, zero, zero}, best_n = zero;
  for (int skip = 0; skip < 4; ++skip) {
    int r[3], n = 0;
    for (int i = 0; i < 4; ++i)
      if (i != skip) r[n++] = i;
    Vec4d v[4];
    det3(r[0], r[1], r[2], 1, 2, 3, 1.0, &v[0]);
    det3(r[0], r[1], r[2], 0, 2, 3, -1.0, &v[1]);
    det3(r[0], r[1], r[2], 0, 1, 3, 1.0, &v[2]);
    det3(r[0], r[1], r[2], 0, 1, 2, -1.0, &v[3]);
    const Vec4d vn = v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3];
    const Vec4m better = vn > best_n;
    for (int i = 0; i < 4; ++i) best[i] = MD_SELECT4(better, v[i], best[i]);
    best_n = MD_SELECT4(better, vn, best_n);
  }
  Vec4d qn;
  sqrt4(best_n, &qn);
  const Vec4d cube = l0 * l0 * l0;
  const double inf = std::numeric_limits<double>::infinity();
  const Vec4m fast = (qn > 1e-3 * cube) & (qn < Vec4d{inf, inf, inf, inf});
  const Vec4d w = best[0] / qn, x = best[1] / qn, y = best[2] / qn, z = best[3] / qn;
  const Vec4d Rq[9] = {w * w + x * x - y * y - z * z, 2.0 * (x * y + w * z),
                       2.0 * (x * z - w * y),         2.0 * (x * y - w * z),
                       w * w - x * x + y * y - z * z, 2.0 * (y * z + w * x),
                       2.0 * (x * z + w * y),         2.0 * (y * z - w * x),
                       w * w - x * x - y * y + z * z};  // column-major, as h
  Vec4d tr = Rq[0] * h[0];
  for (int e = 1; e < 9; ++e) tr += Rq[e] * h[e];
  for (int lane = 0; lane < 4; ++lane) {
    if (!fast[lane]) {
      ok[lane] = fit_rotation(H[lane], &R[lane], &trace[lane]);
      continue;
    }
    for (int e = 0; e < 9; ++e) R[lane].data()[e] = Rq[e][lane];
    trace[lane] = tr[lane];
    ok[lane] = true;
  }
}
void fit_rotations4_base(const Eigen::Matrix3d* H, Eigen::Matrix3d* R, double* trace, bool* ok) {
  fit_rotations4_body(H, R, trace, ok);
}
#if MD_X86_DISPATCH
MD_TARGET_AVX2 void fit_rotations4_avx2(const Eigen::Matrix3d* H, Eigen::Matrix3d* R, double* trace,
                                        bool* ok) {
  fit_rotations4_body(H, R, trace, ok);
}
#endif
}  // namespace

void fit_rotations4(const Eigen::Matrix3d* H, Eigen::Matrix3d* R, double* trace, bool* ok) {
#if MD_X86_DISPATCH
  if (cpu_has_avx2_fma()) return fit_rotations4_avx2(H, R, trace, ok);
#endif
  fit_rotations4_base(H, R, trace, ok);
}

Eigen::Matrix3d spd_log(const Eigen::Matrix3d& S) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(0.5 * (S + S.transpose()));
  const Eigen::Vector3d lam = es.eigenvalues();
  if (!(lam.minCoeff() > 0.0)) throw std::invalid_argument("stretch is not positive definite");
  const Eigen::Vector3d log_lam = lam.array().log().matrix();
  if (!(log_lam.cwiseAbs().maxCoeff() <= kMaxLogStretch)) {
    std::ostringstream msg;
    msg << "transform: its scale factors (" << lam.minCoeff() << " to " << lam.maxCoeff()
        << ") must lie in [e^-709, e^709]";
    throw std::invalid_argument(msg.str());
  }
  return es.eigenvectors() * log_lam.asDiagonal() * es.eigenvectors().transpose();
}

namespace {
void check_log_stretch(double max_abs_eigenvalue) {
  if (!(max_abs_eigenvalue <= kMaxLogStretch)) {
    std::ostringstream msg;
    msg << "log_stretch: an eigenvalue of magnitude " << max_abs_eigenvalue
        << " is above 709, where exp overflows a double";
    throw std::invalid_argument(msg.str());
  }
}
}  // namespace

Eigen::Matrix3d sym_exp(const Eigen::Matrix3d& L) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(0.5 * (L + L.transpose()));
  check_log_stretch(es.eigenvalues().cwiseAbs().maxCoeff());
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
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd = checked_svd(M);
  const Eigen::Matrix3d& U = svd.matrixU();
  const Eigen::Vector3d sigma = svd.singularValues();
  // log S = U log(sigma) U^T straight from the SVD: an eigen-solve of S = U diag(sigma) U^T
  // would lose the smallest singular values of an ill-conditioned M to round-off.
  const Eigen::Vector3d log_sigma = sigma.array().log().matrix();
  if (!(log_sigma.cwiseAbs().maxCoeff() <= kMaxLogStretch)) {
    std::ostringstream msg;
    msg << "transform: its scale factors (" << sigma.minCoeff() << " to " << sigma.maxCoeff()
        << ") must lie in [e^-709, e^709]";
    throw std::invalid_argument(msg.str());
  }
  TransformLog out;
  out.rotation = rotation_log(U * svd.matrixV().transpose());
  // Round-off as round-off: a spread of the log scales within kSimilarityTolerance (float32
  // matrices, products of a few) is a similarity, blended in closed form.
  out.similarity = log_sigma.maxCoeff() - log_sigma.minCoeff() <= kSimilarityTolerance;
  out.log_stretch = out.similarity ? (log_sigma.sum() / 3.0) * Eigen::Matrix3d::Identity()
                                   : Eigen::Matrix3d(U * log_sigma.asDiagonal() * U.transpose());
  return out;
}

Eigen::Matrix3d transform_exp(const TransformLog& L) {
  const Eigen::Matrix3d R = rotation_exp(L.rotation);
  if (L.similarity || is_scalar_matrix(L.log_stretch)) {
    const double s = L.log_stretch.trace() / 3.0;
    check_log_stretch(std::abs(s));
    return std::exp(s) * R;
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
// Per anchor (rotation log, log scale) as 4 doubles; false if some anchor is not a similarity.
bool similarity_logs(const std::vector<TransformLog>& logs, std::vector<double>* P, bool* scaled) {
  P->assign(4 * logs.size(), 0.0);
  *scaled = false;
  for (size_t a = 0; a < logs.size(); ++a) {
    if (!logs[a].similarity) return false;
    for (int c = 0; c < 3; ++c) (*P)[4 * a + c] = logs[a].rotation(c);
    (*P)[4 * a + 3] = logs[a].log_stretch(0, 0);
    *scaled = *scaled || (*P)[4 * a + 3] != 0.0;
  }
  return true;
}

// sc * Rodrigues(x, y, z) for four lanes, column-major into o[0..8]: sc (I + A K + B K^2) with
// K = [(x, y, z)]x and the series coefficients A = sin t / t, B = (1 - cos t) / t^2.
MD_ALWAYS_INLINE void rodrigues4(const Vec4d& x_in, const Vec4d& y_in, const Vec4d& z_in,
                                 const Vec4d& sc, Vec4d* o) {
  Vec4d x = x_in, y = y_in, z = z_in;
  Vec4d t2 = x * x + y * y + z * z;
  const Vec4d zero = {0.0, 0.0, 0.0, 0.0};
  Vec4d A = zero + kSeries.a[kSeriesTerms - 1], B = zero + kSeries.b[kSeriesTerms - 1];
  for (int j = kSeriesTerms - 2; j >= 0; --j) {
    A = A * t2 + kSeries.a[j];
    B = B * t2 + kSeries.b[j];
  }
  // Not reached by convex blends of principal logs (angles <= pi): rotation vectors past half a
  // turn, weights outside [0, 1]. The series again, after the whole turns are taken out.
  if (any_lane(t2 > kSeriesMaxT2)) {
    Vec4d f = {1.0, 1.0, 1.0, 1.0};
    for (int l = 0; l < kGroupFaces; ++l) {
      if (!(t2[l] <= kSeriesMaxT2)) f[l] = whole_turns_removed(t2[l]);
    }
    x *= f, y *= f, z *= f;
    t2 = x * x + y * y + z * z;
    A = zero + kSeries.a[kSeriesTerms - 1], B = zero + kSeries.b[kSeriesTerms - 1];
    for (int j = kSeriesTerms - 2; j >= 0; --j) {
      A = A * t2 + kSeries.a[j];
      B = B * t2 + kSeries.b[j];
    }
  }
  A *= sc;
  B *= sc;
  const Vec4d xx = x * x, yy = y * y, zz = z * z, xy = x * y, xz = x * z, yz = y * z;
  o[0] = sc - B * (yy + zz);
  o[1] = A * z + B * xy;
  o[2] = B * xz - A * y;
  o[3] = B * xy - A * z;
  o[4] = sc - B * (xx + zz);
  o[5] = A * x + B * yz;
  o[6] = A * y + B * xz;
  o[7] = B * yz - A * x;
  o[8] = sc - B * (xx + yy);
}

// Weights of anchor a for the four faces from f0 (padding lanes: 0, i.e. the identity). An out
// parameter, not a return value: returning a vector type from a baseline-built function
// changes its ABI (-Wpsabi), even inlined.
MD_ALWAYS_INLINE void lane_weights(const double* W, int k, int m, int f0, int a, Vec4d* w) {
  for (int l = 0; l < kGroupFaces; ++l) {
    (*w)[l] = f0 + l < m ? W[static_cast<size_t>(f0 + l) * k + a] : 0.0;
  }
}

// Weights of anchor a for the four faces of a full group (f0 + 4 <= m), straight from the rows:
// no test per lane, and built in registers (the tests made GCC assemble the vector through the
// stack, a store-forwarding stall per anchor; the blend's hottest loop).
#define MD_FULL_GROUP_WEIGHTS(W, k, f0, a)                                                         \
  Vec4d {                                                                                          \
    (W)[static_cast<size_t>(f0) * (k) + (a)], (W)[static_cast<size_t>(f0 + 1) * (k) + (a)],        \
        (W)[static_cast<size_t>(f0 + 2) * (k) + (a)], (W)[static_cast<size_t>(f0 + 3) * (k) + (a)] \
  }

// Weighted sum over the k anchors of the similarity logs P (4 per anchor: w, s) for the four
// faces of group f0: (x, y, z) the rotation log, s the log-scale. If b >= 0, *wb receives the
// weights of anchor b. kFull: the group has four faces.
template <bool kFull>
MD_ALWAYS_INLINE void blend_similarity_logs_t(const double* P, int k, const double* W, int m,
                                              int f0, int b, Vec4d* x, Vec4d* y, Vec4d* z, Vec4d* s,
                                              Vec4d* wb) {
  Vec4d sx = {0.0, 0.0, 0.0, 0.0}, sy = sx, sz = sx, ss = sx;
  for (int a = 0; a < k; ++a) {
    Vec4d w;
    if constexpr (kFull) {
      w = MD_FULL_GROUP_WEIGHTS(W, k, f0, a);
    } else {
      lane_weights(W, k, m, f0, a, &w);
    }
    sx += w * P[4 * a];
    sy += w * P[4 * a + 1];
    sz += w * P[4 * a + 2];
    ss += w * P[4 * a + 3];
    if (a == b) *wb = w;
  }
  *x = sx, *y = sy, *z = sz, *s = ss;
}
MD_ALWAYS_INLINE void blend_similarity_logs(const double* P, int k, const double* W, int m, int f0,
                                            int b, Vec4d* x, Vec4d* y, Vec4d* z, Vec4d* s,
                                            Vec4d* wb) {
  if (f0 + kGroupFaces <= m) {
    blend_similarity_logs_t<true>(P, k, W, m, f0, b, x, y, z, s, wb);
  } else {
    blend_similarity_logs_t<false>(P, k, W, m, f0, b, x, y, z, s, wb);
  }
}

// Isotropic similarity blend, exp(s I + [w]x) = e^s Rodrigues(w), for the faces of groups
// [gb, ge), four at a time: W is the (m,k) row-major weights, P as from similarity_logs.
MD_ALWAYS_INLINE void blend_similar_body(const double* P, int k, bool scaled, const double* W,
                                         int m, int gb, int ge, double* out) {
  for (int g = gb; g < ge; ++g) {
    const int f0 = kGroupFaces * g;
    Vec4d x, y, z, s;
    blend_similarity_logs(P, k, W, m, f0, -1, &x, &y, &z, &s, nullptr);
    Vec4d sc = {1.0, 1.0, 1.0, 1.0};
    if (scaled) exp4(s, &sc);
    rodrigues4(x, y, z, sc,
               reinterpret_cast<Vec4d*>(out + static_cast<size_t>(kGroupStride) * (g - gb)));
  }
}
void blend_similar_base(const double* P, int k, bool scaled, const double* W, int m, int gb, int ge,
                        double* out) {
  blend_similar_body(P, k, scaled, W, m, gb, ge, out);
}
MD_TARGET_AVX2 void blend_similar_avx2(const double* P, int k, bool scaled, const double* W, int m,
                                       int gb, int ge, double* out) {
  blend_similar_body(P, k, scaled, W, m, gb, ge, out);
}

// --- General (non-similarity) blends --------------------------------------------------------
//
// exp(L) R(w) with L = sum_a w_a log S_a symmetric and w = sum_a w_a log R_a, four faces at a
// time. Symmetric 3x3 matrices are kept as their six entries (xx, yy, zz, xy, xz, yz).

// Per anchor: rotation log (3) and the six entries of log S, 9 doubles.
constexpr int kGeneralStride = 9;
std::vector<double> general_logs(const std::vector<TransformLog>& logs) {
  std::vector<double> P(kGeneralStride * logs.size());
  for (size_t a = 0; a < logs.size(); ++a) {
    const Eigen::Matrix3d& L = logs[a].log_stretch;
    double* p = &P[kGeneralStride * a];
    for (int c = 0; c < 3; ++c) p[c] = logs[a].rotation(c);
    p[3] = L(0, 0), p[4] = L(1, 1), p[5] = L(2, 2);
    p[6] = 0.5 * (L(0, 1) + L(1, 0)), p[7] = 0.5 * (L(0, 2) + L(2, 0));
    p[8] = 0.5 * (L(1, 2) + L(2, 1));
  }
  return P;
}

// C = A B for symmetric A, B that commute (so C is symmetric), six entries each.
MD_ALWAYS_INLINE void sym_mul(const Vec4d* A, const Vec4d* B, Vec4d* C) {
  const Vec4d xx = A[0] * B[0] + A[3] * B[3] + A[4] * B[4];
  const Vec4d yy = A[3] * B[3] + A[1] * B[1] + A[5] * B[5];
  const Vec4d zz = A[4] * B[4] + A[5] * B[5] + A[2] * B[2];
  const Vec4d xy = A[0] * B[3] + A[3] * B[1] + A[4] * B[5];
  const Vec4d xz = A[0] * B[4] + A[3] * B[5] + A[4] * B[2];
  const Vec4d yz = A[3] * B[4] + A[1] * B[5] + A[5] * B[2];
  C[0] = xx, C[1] = yy, C[2] = zz, C[3] = xy, C[4] = xz, C[5] = yz;
}

// o = E R (column-major 3x3 into o[0..8]) for symmetric E (six entries) and R column-major.
MD_ALWAYS_INLINE void sym_times(const Vec4d* E, const Vec4d* R, Vec4d* o) {
  for (int c = 0; c < 3; ++c) {
    const Vec4d r0 = R[3 * c], r1 = R[3 * c + 1], r2 = R[3 * c + 2];
    o[3 * c] = E[0] * r0 + E[3] * r1 + E[4] * r2;
    o[3 * c + 1] = E[3] * r0 + E[1] * r1 + E[5] * r2;
    o[3 * c + 2] = E[4] * r0 + E[5] * r1 + E[2] * r2;
  }
}

// One anchor b is stretched, the others are similarities: L = s I + w_b D_b with D_b the
// deviatoric part of log S_b = V diag(lambda) V^T, so exp(L) = sum_c exp(s + w_b lambda_c) Q_c
// with Q_c = v_c v_c^T (six entries each, 18 doubles in Q): three scalar exps per face, exact.
// P holds (rotation log, trace/3 of log S) per anchor, 4 doubles as in similarity_logs.
MD_ALWAYS_INLINE void blend_one_stretch_body(const double* P, int k, int b, const double* lambda,
                                             const double* Q, const double* W, int m, int gb,
                                             int ge, double* out) {
  for (int g = gb; g < ge; ++g) {
    const int f0 = kGroupFaces * g;
    Vec4d x, y, z, s, wb = {0.0, 0.0, 0.0, 0.0};
    blend_similarity_logs(P, k, W, m, f0, b, &x, &y, &z, &s, &wb);
    Vec4d E[6];
    for (int e = 0; e < 6; ++e) E[e] = x * 0.0;
    for (int c = 0; c < 3; ++c) {
      Vec4d ec;
      exp4(s + wb * lambda[c], &ec);
      for (int e = 0; e < 6; ++e) E[e] += ec * Q[6 * c + e];
    }
    Vec4d R[9];
    const Vec4d one = {1.0, 1.0, 1.0, 1.0};
    rodrigues4(x, y, z, one, R);
    sym_times(E, R, reinterpret_cast<Vec4d*>(out + static_cast<size_t>(kGroupStride) * (g - gb)));
  }
}
void blend_one_stretch_base(const double* P, int k, int b, const double* lambda, const double* Q,
                            const double* W, int m, int gb, int ge, double* out) {
  blend_one_stretch_body(P, k, b, lambda, Q, W, m, gb, ge, out);
}
MD_TARGET_AVX2 void blend_one_stretch_avx2(const double* P, int k, int b, const double* lambda,
                                           const double* Q, const double* W, int m, int gb, int ge,
                                           double* out) {
  blend_one_stretch_body(P, k, b, lambda, Q, W, m, gb, ge, out);
}

// (x, y, z) += w * rotation log, L += w * log S (six entries) for one anchor's general log p.
MD_ALWAYS_INLINE void add_general_log(const double* p, const Vec4d& w, Vec4d* x, Vec4d* y, Vec4d* z,
                                      Vec4d* L) {
  *x += w * p[0];
  *y += w * p[1];
  *z += w * p[2];
  for (int e = 0; e < 6; ++e) L[e] += w * p[3 + e];
}

// Any anchors: exp(L) = e^s exp(D) with D = L - s I, s = tr L / 3, by scaling and squaring:
// exp(D) = exp(D / 2^j)^(2^j) with |D / 2^j|_F <= 1/4 and a Taylor polynomial (Horner) whose
// remainder r^(K+1)/(K+1)! is below 1e-17 (r = the group's largest |D / 2^j|_F). j and K are
// chosen per group, so faces far from a stretched anchor (small D) take few terms.
MD_ALWAYS_INLINE void blend_taylor_body(const double* P, int k, const double* W, int m, int gb,
                                        int ge, double* out) {
  for (int g = gb; g < ge; ++g) {
    const int f0 = kGroupFaces * g;
    const Vec4d zero = {0.0, 0.0, 0.0, 0.0};
    Vec4d x = zero, y = zero, z = zero, L[6] = {zero, zero, zero, zero, zero, zero};
    if (f0 + kGroupFaces <= m) {
      for (int a = 0; a < k; ++a) {
        add_general_log(P + kGeneralStride * a, MD_FULL_GROUP_WEIGHTS(W, k, f0, a), &x, &y, &z, L);
      }
    } else {
      for (int a = 0; a < k; ++a) {
        Vec4d w;
        lane_weights(W, k, m, f0, a, &w);
        add_general_log(P + kGeneralStride * a, w, &x, &y, &z, L);
      }
    }
    const Vec4d s = (L[0] + L[1] + L[2]) * (1.0 / 3.0);
    Vec4d D[6] = {L[0] - s, L[1] - s, L[2] - s, L[3], L[4], L[5]};
    const Vec4d n2 =
        D[0] * D[0] + D[1] * D[1] + D[2] * D[2] + (D[3] * D[3] + D[4] * D[4] + D[5] * D[5]) * 2.0;
    double r = 0.0;
    for (int l = 0; l < kGroupFaces; ++l) r = std::max(r, n2[l]);
    r = std::sqrt(r);
    int squarings = 0;
    while (r > 0.25) {
      r *= 0.5;
      ++squarings;
    }
    const double h = std::ldexp(1.0, -squarings);
    for (int e = 0; e < 6; ++e) D[e] *= h;
    int terms = 0;  // smallest K with r^(K+1) / (K+1)! <= 1e-17
    for (double rem = r; rem > 1e-17; rem *= r / (terms + 1)) ++terms;
    Vec4d E[6] = {zero + 1.0, zero + 1.0, zero + 1.0, zero, zero, zero};
    for (int t = terms; t >= 1; --t) {  // E = I + (D / t) E
      Vec4d DE[6];
      sym_mul(D, E, DE);
      const double inv = 1.0 / t;
      for (int e = 0; e < 6; ++e) E[e] = DE[e] * inv;
      E[0] += 1.0, E[1] += 1.0, E[2] += 1.0;
    }
    for (int q = 0; q < squarings; ++q) {
      Vec4d E2[6];
      sym_mul(E, E, E2);
      for (int e = 0; e < 6; ++e) E[e] = E2[e];
    }
    Vec4d es;
    exp4(s, &es);
    for (int e = 0; e < 6; ++e) E[e] *= es;
    Vec4d R[9];
    rodrigues4(x, y, z, zero + 1.0, R);
    sym_times(E, R, reinterpret_cast<Vec4d*>(out + static_cast<size_t>(kGroupStride) * (g - gb)));
  }
}
void blend_taylor_base(const double* P, int k, const double* W, int m, int gb, int ge,
                       double* out) {
  blend_taylor_body(P, k, W, m, gb, ge, out);
}
MD_TARGET_AVX2 void blend_taylor_avx2(const double* P, int k, const double* W, int m, int gb,
                                      int ge, double* out) {
  blend_taylor_body(P, k, W, m, gb, ge, out);
}

// Groups [gb, ge) from a per-face kernel that writes faces [b, e) to T[0 .. e - b).
template <class PerFace>
void groups_from_faces(int m, int gb, int ge, double* out, const PerFace& per_face) {
  Eigen::Matrix3d T[kGroupFaces];
  for (int g = gb; g < ge; ++g) {
    const int b = kGroupFaces * g, e = std::min(b + kGroupFaces, m);
    per_face(b, e, T);
    double* o = out + static_cast<size_t>(kGroupStride) * (g - gb);
    for (int l = 0; l < kGroupFaces; ++l) {
      const Eigen::Matrix3d& M = b + l < e ? T[l] : Eigen::Matrix3d::Identity().eval();
      for (int c = 0; c < 9; ++c) o[4 * c + l] = M.data()[c];
    }
  }
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
  std::vector<double> P;
  bool scaled = false;
  similarity_logs(logs, &P, &scaled);
  for (int i = begin; i < end; ++i) {
    const double* w = weights.row(i).data();
    double x = 0.0, y = 0.0, z = 0.0, s = 0.0;
    for (Eigen::Index a = 0; a < k; ++a) {
      x += w[a] * P[4 * a];
      y += w[a] * P[4 * a + 1];
      z += w[a] * P[4 * a + 2];
      s += w[a] * P[4 * a + 3];
    }
    rodrigues(x, y, z, scaled ? std::exp(s) : 1.0, &out[i - begin]);
  }
}

void blend_groups(const std::vector<TransformLog>& logs, const RowMatrix& weights, int group_begin,
                  int group_end, double* out) {
  const int m = static_cast<int>(weights.rows());
  const int k = static_cast<int>(weights.cols());
  if (static_cast<int>(logs.size()) != k) {
    throw std::invalid_argument("blend: one log per weight column expected");
  }
  const bool avx2 = cpu_has_avx2_fma();
  std::vector<double> P;
  bool scaled = false;
  if (similarity_logs(logs, &P, &scaled)) {
    (avx2 ? blend_similar_avx2 : blend_similar_base)(P.data(), k, scaled, weights.data(), m,
                                                     group_begin, group_end, out);
    return;
  }
  int stretched = -1, count = 0;
  for (int a = 0; a < k; ++a) {
    if (!logs[static_cast<size_t>(a)].similarity) stretched = a, ++count;
  }
  if (count == 1) {  // the usual non-similarity pose: one Empty scaled non-uniformly
    const Eigen::Matrix3d& Lb = logs[static_cast<size_t>(stretched)].log_stretch;
    P.assign(4 * static_cast<size_t>(k), 0.0);
    for (int a = 0; a < k; ++a) {
      for (int c = 0; c < 3; ++c) P[4 * a + c] = logs[static_cast<size_t>(a)].rotation(c);
      P[4 * a + 3] = logs[static_cast<size_t>(a)].log_stretch.trace() / 3.0;
    }
    const double sb = Lb.trace() / 3.0;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(0.5 * (Lb + Lb.transpose()) -
                                                      sb * Eigen::Matrix3d::Identity());
    const Eigen::Vector3d lambda = es.eigenvalues();
    const Eigen::Matrix3d& V = es.eigenvectors();
    double Q[18];
    for (int c = 0; c < 3; ++c) {
      const Eigen::Vector3d v = V.col(c);
      const double q[6] = {v(0) * v(0), v(1) * v(1), v(2) * v(2),
                           v(0) * v(1), v(0) * v(2), v(1) * v(2)};
      for (int e = 0; e < 6; ++e) Q[6 * c + e] = q[e];
    }
    (avx2 ? blend_one_stretch_avx2 : blend_one_stretch_base)(
        P.data(), k, stretched, lambda.data(), Q, weights.data(), m, group_begin, group_end, out);
    return;
  }
  const std::vector<double> G = general_logs(logs);
  (avx2 ? blend_taylor_avx2 : blend_taylor_base)(G.data(), k, weights.data(), m, group_begin,
                                                 group_end, out);
}

namespace {
// Throws unless every row of w is finite and keeps its blended log-stretch within range.
void check_blend_weights(const std::vector<TransformLog>& logs, const RowMatrix& w) {
  std::vector<double> size(logs.size());
  for (size_t a = 0; a < logs.size(); ++a) size[a] = logs[a].log_stretch.norm();
  for (Eigen::Index i = 0; i < w.rows(); ++i) {
    double bound = 0.0;
    for (Eigen::Index a = 0; a < w.cols(); ++a) {
      if (!std::isfinite(w(i, a))) throw std::invalid_argument("weights: contain NaN or infinity");
      bound += std::abs(w(i, a)) * size[static_cast<size_t>(a)];
    }
    if (!(bound <= kMaxLogStretch)) {
      throw std::invalid_argument("weights: row " + std::to_string(i) +
                                  " blends the scales to beyond e^709 (exp would overflow); use "
                                  "smaller weights or scales");
    }
  }
}
}  // namespace

void blend_all(const std::vector<TransformLog>& logs, const RowMatrix& weights, Matrix3Array* out) {
  const int m = static_cast<int>(weights.rows());
  if (static_cast<Eigen::Index>(logs.size()) != weights.cols()) {
    throw std::invalid_argument("blend_all: one log per weight column expected");
  }
  check_blend_weights(logs, weights);
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

void blend_groups_anisotropic(const std::vector<TransformLog>& logs, const RowMatrix& wx,
                              const RowMatrix& wy, const RowMatrix& wz, const Eigen::Matrix3d& axes,
                              int group_begin, int group_end, double* out) {
  groups_from_faces(static_cast<int>(wx.rows()), group_begin, group_end, out,
                    [&](int b, int e, Eigen::Matrix3d* T) {
                      blend_range_anisotropic(logs, wx, wy, wz, axes, b, e, T);
                    });
}

void blend_all_anisotropic(const std::vector<TransformLog>& logs, const RowMatrix& wx,
                           const RowMatrix& wy, const RowMatrix& wz, const Eigen::Matrix3d& axes,
                           Matrix3Array* out) {
  const int m = static_cast<int>(wx.rows());
  if (static_cast<Eigen::Index>(logs.size()) != wx.cols() || wy.rows() != m || wz.rows() != m ||
      wy.cols() != wx.cols() || wz.cols() != wx.cols()) {
    throw std::invalid_argument("blend_all_anisotropic: weight shapes do not match");
  }
  check_blend_weights(logs, (wx + wy + wz) / 3.0);
  out->resize(static_cast<size_t>(m));
  parallel_ranges(m, kFacesPerTask, kTasks, [&](int b, int e) {
    blend_range_anisotropic(logs, wx, wy, wz, axes, b, e, out->data() + b);
  });
}

}  // namespace matdeform
