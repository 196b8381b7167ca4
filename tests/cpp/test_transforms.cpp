#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <unsupported/Eigen/MatrixFunctions>
#include <vector>

#include "matdeform/transforms.hpp"
#include "simd.hpp"

using namespace matdeform;

namespace {
Eigen::Matrix3d skew(const Eigen::Vector3d& w) {
  Eigen::Matrix3d K;
  K << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  return K;
}
}  // namespace

TEST(Transforms, RotationExpMatchesMatrixExponential) {
  std::mt19937 rng(1);
  std::normal_distribution<double> g;
  for (int t = 0; t < 50; ++t) {
    const Eigen::Vector3d w(g(rng), g(rng), g(rng));
    const Eigen::Matrix3d ref = skew(w).exp();  // Eigen's general matrix exponential
    EXPECT_LT((rotation_exp(w) - ref).norm(), 1e-12);
  }
}

TEST(Transforms, RotationExpIsExactOnBothSidesOfTheSeriesRange) {
  // rotation_exp sums a power series up to angle sqrt(10) and uses sin/cos beyond; both sides
  // and tiny angles must match the axis-angle matrix to round-off.
  std::mt19937 rng(5);
  std::normal_distribution<double> g;
  const double angles[] = {0.0,    1e-12,  1e-5, 0.1, 1.0, 2.0,           M_PI,
                           3.1622, 3.1623, 3.17, 4.0, 5.5, 2 * M_PI - 0.1};
  for (double theta : angles) {
    for (int t = 0; t < 10; ++t) {
      const Eigen::Vector3d axis = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
      const Eigen::Matrix3d R = Eigen::AngleAxisd(theta, axis).toRotationMatrix();
      EXPECT_LT((rotation_exp(theta * axis) - R).cwiseAbs().maxCoeff(), 2e-15) << "theta=" << theta;
    }
  }
}

TEST(Transforms, RotationExpOfManyTurnsIsExact) {
  // Past the series range the whole turns are taken out of the vector first (no sin/cos): as
  // accurate as the axis-angle matrix, whose own sin/cos carry an error of ~eps * angle.
  std::mt19937 rng(6);
  std::normal_distribution<double> g;
  const double angles[] = {2 * M_PI + 0.1, 3 * M_PI, 3 * M_PI + 1e-9, 20 * M_PI + 1, -7.5, 1000.3};
  for (double theta : angles) {
    for (int t = 0; t < 10; ++t) {
      const Eigen::Vector3d axis = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
      const Eigen::Matrix3d R = Eigen::AngleAxisd(theta, axis).toRotationMatrix();
      EXPECT_LT((rotation_exp(theta * axis) - R).cwiseAbs().maxCoeff(),
                2e-15 * std::max(1.0, std::abs(theta)))
          << "theta=" << theta;
    }
  }
}

TEST(Transforms, RotationLogRoundTripIncludingNearPi) {
  std::mt19937 rng(2);
  std::normal_distribution<double> g;
  const double angles[] = {0.0, 1e-10, 1e-6, 0.3, 1.0, 2.5, M_PI - 1e-3, M_PI - 1e-8, M_PI};
  for (double theta : angles) {
    for (int t = 0; t < 20; ++t) {
      const Eigen::Vector3d axis = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
      const Eigen::Matrix3d R = Eigen::AngleAxisd(theta, axis).toRotationMatrix();
      const Eigen::Vector3d w = rotation_log(R);
      ASSERT_TRUE(w.allFinite());
      EXPECT_NEAR(w.norm(), theta, 1e-7);
      EXPECT_LT((rotation_exp(w) - R).norm(), 1e-12) << "theta=" << theta;
      if (theta > 1e-6 && theta < M_PI - 1e-6) {
        EXPECT_LT((w - theta * axis).norm(), 1e-9);
      }
    }
  }
}

TEST(Transforms, ScaledRotationLogIsLogScaleAndAxisAngle) {
  const Eigen::Vector3d axis = Eigen::Vector3d(1, 2, -0.5).normalized();
  const double theta = 2.0, s = 3.0;
  const Eigen::Matrix3d M = s * Eigen::AngleAxisd(theta, axis).toRotationMatrix();
  const TransformLog L = transform_log(M);
  EXPECT_TRUE(L.similarity);
  EXPECT_LT((L.log_stretch - std::log(s) * Eigen::Matrix3d::Identity()).norm(), 1e-12);
  EXPECT_LT((L.rotation - theta * axis).norm(), 1e-12);
  // For a similarity the algebra is Alexa's: exp(log M) with the real matrix log.
  const Eigen::Matrix3d logM = L.log_stretch + skew(L.rotation);
  EXPECT_LT((logM.exp() - M).norm(), 1e-11);
  EXPECT_LT((transform_exp(L) - M).norm(), 1e-12);
}

TEST(Transforms, GeneralPositiveDeterminantRoundTrip) {
  std::mt19937 rng(3);
  std::normal_distribution<double> g;
  int tested = 0;
  while (tested < 200) {
    Eigen::Matrix3d M;
    for (int i = 0; i < 9; ++i) M(i / 3, i % 3) = g(rng);
    if (M.determinant() <= 0.05) continue;
    ++tested;
    const TransformLog L = transform_log(M);
    EXPECT_FALSE(L.similarity);
    EXPECT_LT((transform_exp(L) - M).norm(), 1e-9 * M.norm());
  }
  // No real matrix log exists for this one, the polar route still works.
  const Eigen::Matrix3d N = Eigen::Vector3d(-1.0, -2.0, 1.0).asDiagonal();
  EXPECT_LT((transform_exp(transform_log(N)) - N).norm(), 1e-12);
}

TEST(Transforms, RejectsNonPositiveDeterminant) {
  EXPECT_THROW(transform_log(Eigen::Vector3d(1, 1, -1).asDiagonal()), std::invalid_argument);
  EXPECT_THROW(transform_log(Eigen::Matrix3d::Zero()), std::invalid_argument);
  Eigen::Matrix3d nan = Eigen::Matrix3d::Identity();
  nan(0, 1) = std::nan("");
  EXPECT_THROW(transform_log(nan), std::invalid_argument);
}

// fit_rotation against the SVD's U D V^T (D flips the last axis when det H < 0) and the signed
// sum of the singular values, over the kinds of H a best-fit similarity meets: generic, mirrored,
// planar point sets (sigma_3 = 0), nearly collinear ones, tiny and huge scales.
TEST(Transforms, FitRotationMatchesTheSvdSolution) {
  std::mt19937 rng(11);
  std::normal_distribution<double> g;
  auto rotation = [&]() {
    return Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  };
  struct Case {
    double s2, s3, det, scale, tol;
  };
  // s2, s3 relative to sigma_1 (0: random in [0.1, 1]); tol on |R - R_svd|_F, which both carry
  // as eps over the gap 2 (s2 + det s3).
  const Case cases[] = {{0, 0, 1, 1, 1e-12},       {0, 0, -1, 1, 1e-10},
                        {0, 1e-9, 1, 1, 1e-12},    {0.3, 0, 1, 1, 1e-12},
                        {1e-3, 5e-4, 1, 1, 1e-10}, {1e-5, 3e-6, -1, 1, 1e-9},
                        {0, 0, 1, 1e-9, 1e-12},    {0, 0, 1, 1e9, 1e-12}};
  for (const Case& k : cases) {
    for (int t = 0; t < 300; ++t) {
      const double s1 = 1 + std::abs(g(rng));
      auto rel = [&](double s) { return s > 0 ? s : 0.1 + 0.9 * std::abs(std::tanh(g(rng))); };
      const Eigen::Vector3d sig(s1, s1 * rel(k.s2), s1 * (k.s3 > 0 || k.s2 == 0.3 ? k.s3 : rel(0)));
      const Eigen::Vector3d d(1, 1, k.det);
      const Eigen::Matrix3d U = rotation(), V = rotation();
      const Eigen::Matrix3d H = k.scale * U * sig.asDiagonal() * d.asDiagonal() * V.transpose();
      Eigen::Matrix3d R;
      double trace = 0;
      ASSERT_TRUE(fit_rotation(H, &R, &trace)) << "case s2=" << k.s2 << " det=" << k.det;
      // H = U diag(sig) (V D)^T with D = diag(1, 1, det): an SVD whose U (V D)^T has determinant
      // det. When sigma_3 is the smallest, the best proper rotation is U D (V D)^T = U V^T.
      const Eigen::Matrix3d expected = U * V.transpose();
      const double sorted3 = std::min({sig(0), sig(1), sig(2)});
      if (sorted3 == sig(2)) {
        EXPECT_LT((R - expected).norm(), k.tol) << "s2=" << k.s2 << " det=" << k.det;
        EXPECT_NEAR(trace, k.scale * (sig(0) + sig(1) + k.det * sig(2)),
                    1e-13 * k.scale * sig.sum());
      }
      EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).norm(), 1e-13);
      EXPECT_NEAR(R.determinant(), 1.0, 1e-13);
      // optimality against the SVD-based rotation whatever the ordering
      const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
      Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
      if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1;
      const Eigen::Matrix3d Rs = svd.matrixU() * D * svd.matrixV().transpose();
      EXPECT_NEAR(trace, (Rs.transpose() * H).trace(), 1e-13 * k.scale * sig.sum());
    }
  }
}

// Below a relative gap of ~1e-6 the fit refuses (a review found rotations turned by pi at gaps
// of 1e-8 and below before the threshold was raised): never a wrong rotation, either way.
TEST(Transforms, FitRotationNeverReturnsAFlippedRotationNearASmallGap) {
  std::mt19937 rng(5);
  std::normal_distribution<double> g;
  auto rotation = [&]() {
    return Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  };
  int refused = 0, total = 0;
  for (const double gap : {3e-9, 1e-8, 1e-7, 1e-6, 3e-6}) {
    for (const double det : {1.0, -1.0}) {
      for (int t = 0; t < 300; ++t, ++total) {
        // relative gap sigma_2 + det sigma_3 = gap
        const Eigen::Vector3d sig = det > 0 ? Eigen::Vector3d(1, 0.7 * gap, 0.3 * gap)
                                            : Eigen::Vector3d(1, 1.3 * gap, 0.3 * gap);
        const Eigen::Matrix3d U = rotation(), V = rotation();
        const Eigen::Vector3d d(1, 1, det);
        const Eigen::Matrix3d H = U * sig.asDiagonal() * d.asDiagonal() * V.transpose();
        Eigen::Matrix3d R;
        double trace = 0;
        if (!fit_rotation(H, &R, &trace)) {
          ++refused;
          continue;
        }
        EXPECT_LT((R - U * V.transpose()).norm(), 1e-6) << "gap " << gap << " det " << det;
      }
    }
  }
  EXPECT_GT(refused, 0);
  EXPECT_LT(refused, total);
}

TEST(Transforms, FitRotationRefusesUndeterminedRotations) {
  Eigen::Matrix3d R = Eigen::Matrix3d::Constant(7), R0 = R;
  double trace = 7;
  const Eigen::Matrix3d rank1 = Eigen::Vector3d(1, 2, 3) * Eigen::RowVector3d(0.3, -1, 2);
  EXPECT_FALSE(fit_rotation(rank1, &R, &trace));
  EXPECT_FALSE(fit_rotation(Eigen::Matrix3d::Zero(), &R, &trace));
  Eigen::Matrix3d bad = Eigen::Matrix3d::Identity();
  bad(1, 2) = std::nan("");
  EXPECT_FALSE(fit_rotation(bad, &R, &trace));
  bad(1, 2) = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(fit_rotation(bad, &R, &trace));
  EXPECT_EQ(R, R0);  // untouched
  EXPECT_EQ(trace, 7);
  // a rotation itself and a scaled one come back exactly enough
  const Eigen::Matrix3d Q =
      Eigen::AngleAxisd(2.9, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  ASSERT_TRUE(fit_rotation(3.5 * Q, &R, &trace));
  EXPECT_LT((R - Q).norm(), 1e-14);
  EXPECT_NEAR(trace, 10.5, 1e-13);
}

// The four-lane fit (the pyramid method's hot loop) gives each lane fit_rotation's answer, in
// both kernel builds: the same acceptance, rotations and traces to round-off where the root
// needs no refining, the very same bits where it does (those lanes are fit_rotation's own), and
// a lane's result does not depend on the lanes beside it.
TEST(Transforms, FitRotations4MatchesFitRotationLaneByLane) {
  std::mt19937 rng(29);
  std::normal_distribution<double> g;
  auto rotation = [&]() {
    return Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  };
  std::vector<Eigen::Matrix3d> H;
  std::vector<double> gap;  // the relative eigenvalue gap, for the tolerance
  // generic, mirrored, planar; gaps either side of the 1e-3 where fit_rotation refines; refused
  for (const double rel_gap : {0.0, 3e-2, 2e-3, 5e-4, 2e-5, 3e-7}) {
    for (const double det : {1.0, -1.0}) {
      for (const double scale : {1.0, 1e-9, 1e9}) {
        for (int t = 0; t < 40; ++t) {
          Eigen::Vector3d sig(1 + std::abs(g(rng)), 0.2 + std::abs(g(rng)), std::abs(g(rng)));
          if (rel_gap > 0) {
            sig = det > 0 ? Eigen::Vector3d(1, 0.7 * rel_gap, 0.3 * rel_gap)
                          : Eigen::Vector3d(1, 1.3 * rel_gap, 0.3 * rel_gap);
          }
          const Eigen::Vector3d d(1, 1, det);
          H.push_back(scale * rotation() * sig.asDiagonal() * d.asDiagonal() *
                      rotation().transpose());
          const Eigen::Vector3d sv = sig.cwiseAbs();
          double s[3] = {sv(0), sv(1), sv(2)};
          std::sort(s, s + 3);
          gap.push_back((s[1] + det * s[0]) / s[2]);
        }
      }
    }
  }
  const Eigen::Matrix3d rank1 = Eigen::Vector3d(1, 2, 3) * Eigen::RowVector3d(0.3, -1, 2);
  Eigen::Matrix3d nan = Eigen::Matrix3d::Identity(), inf = nan;
  nan(1, 2) = std::nan("");
  inf(0, 1) = std::numeric_limits<double>::infinity();
  // 1e60: the adjugate's squared norm overflows while l0^3 does not (a refusal, not R = 0)
  for (const Eigen::Matrix3d& m :
       {rank1, Eigen::Matrix3d(Eigen::Matrix3d::Zero()), nan, inf,
        Eigen::Matrix3d(1e150 * rotation()), Eigen::Matrix3d(1e60 * rotation()),
        Eigen::Matrix3d(3.5 * rotation())}) {
    H.push_back(m);
    gap.push_back(1);
  }
  while (H.size() % 4) H.push_back(rotation()), gap.push_back(1);
  // Shuffled, so that every kind of matrix shares calls with every other kind.
  std::vector<int> order(H.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::shuffle(order.begin(), order.end(), rng);
  {
    std::vector<Eigen::Matrix3d> H2;
    std::vector<double> gap2;
    for (int i : order) H2.push_back(H[i]), gap2.push_back(gap[i]);
    H.swap(H2);
    gap.swap(gap2);
  }
  const int n = static_cast<int>(H.size());
  std::vector<Eigen::Matrix3d> R1(H.size());
  std::vector<double> t1(H.size());
  std::vector<char> ok1(H.size());
  for (int i = 0; i < n; ++i) ok1[i] = fit_rotation(H[i], &R1[i], &t1[i]);
  int refused = 0, refined = 0;
  // qn / l0^3 is 0.77-1.54 x the relative gap: below 5e-4 fit_rotation always refines
  for (int i = 0; i < n; ++i) refused += !ok1[i], refined += ok1[i] && gap[i] <= 5e-4;
  EXPECT_GT(refused, 10);
  EXPECT_GT(refined, 100);
  const Eigen::Matrix3d sentinel = Eigen::Matrix3d::Constant(7);
  for (const bool avx2 : {true, false}) {
    const bool before = set_avx2_kernels_enabled(avx2);
    std::vector<Eigen::Matrix3d> R4(H.size(), sentinel);
    std::vector<double> t4(H.size(), 7);
    for (int i = 0; i < n; i += 4) {
      bool ok[4];
      fit_rotations4(&H[i], &R4[i], &t4[i], ok);
      for (int j = i; j < i + 4; ++j) {
        ASSERT_EQ(ok[j - i], static_cast<bool>(ok1[j])) << j << " avx2 " << avx2;
        if (!ok1[j]) {
          EXPECT_EQ(R4[j], sentinel) << j;  // untouched, as fit_rotation leaves it
          EXPECT_EQ(t4[j], 7) << j;
          continue;
        }
        // both carry the root's round-off, eps over the gap squared (fit_rotation's comments)
        EXPECT_LT((R4[j] - R1[j]).norm(), 1e-14 + 1e-15 / (gap[j] * gap[j]))
            << j << " gap " << gap[j];
        EXPECT_LE(std::abs(t4[j] - t1[j]), 1e-14 * std::abs(t1[j])) << j;
        if (gap[j] <= 5e-4) {  // refined: fit_rotation's own bits
          EXPECT_EQ(R4[j], R1[j]) << j;
        }
      }
    }
    // Each lane alone, the others filled with a different matrix: the same bits.
    for (int i = 0; i < n; i += 37) {
      for (int lane = 0; lane < 4; ++lane) {
        Eigen::Matrix3d Hs[4] = {H[(i + 5) % n], H[(i + 9) % n], H[(i + 13) % n], H[(i + 17) % n]};
        Hs[lane] = H[i];
        Eigen::Matrix3d Rs[4];
        double ts[4];
        bool oks[4];
        fit_rotations4(Hs, Rs, ts, oks);
        const int at = i - i % 4, me = i % 4;
        Eigen::Matrix3d Rg[4];
        double tg[4];
        bool okg[4];
        fit_rotations4(&H[at], Rg, tg, okg);
        ASSERT_EQ(oks[lane], okg[me]);
        if (oks[lane]) {
          EXPECT_EQ(Rs[lane], Rg[me]) << i << " lane " << lane;
          EXPECT_EQ(ts[lane], tg[me]);
        }
      }
    }
    set_avx2_kernels_enabled(before);
  }
}

TEST(Transforms, BlendHalfwayIsHalfAngleAndGeometricMeanScale) {
  const Eigen::Vector3d axis = Eigen::Vector3d(0, 0, 1);
  std::vector<TransformLog> logs = {
      transform_log(Eigen::Matrix3d::Identity()),
      transform_log(4.0 * Eigen::AngleAxisd(M_PI, axis).toRotationMatrix())};
  const double w[2] = {0.5, 0.5};
  const Eigen::Matrix3d B = blend_logs(logs, w);
  const Eigen::Matrix3d expect = 2.0 * Eigen::AngleAxisd(M_PI / 2, axis).toRotationMatrix();
  // The axis at exactly pi has a sign ambiguity; either half-turn direction is valid.
  const Eigen::Matrix3d expect2 = 2.0 * Eigen::AngleAxisd(-M_PI / 2, axis).toRotationMatrix();
  EXPECT_LT(std::min((B - expect).norm(), (B - expect2).norm()), 1e-12);
  ASSERT_TRUE(B.allFinite());
}

TEST(Transforms, BlendAllFastPathMatchesGeneralPath) {
  std::vector<TransformLog> logs = {
      transform_log(1.5 * Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitX()).toRotationMatrix()),
      transform_log(
          0.5 * Eigen::AngleAxisd(3.0, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix()),
      transform_log(Eigen::Matrix3d::Identity())};
  RowMatrix W(4, 3);
  W << 1, 0, 0, 0.2, 0.3, 0.5, 0.5, 0.5, 0, 0, 0, 0;
  Matrix3Array out;
  blend_all(logs, W, &out);
  for (int i = 0; i < 4; ++i) {
    const Eigen::Matrix3d ref = blend_logs(logs, W.row(i).data());
    EXPECT_LT((out[i] - ref).norm(), 1e-12);
  }
  EXPECT_LT((out[3] - Eigen::Matrix3d::Identity()).norm(), 1e-15);  // zero weights: identity
}

namespace {
// blend_groups (the per-pose kernel: Rodrigues series and a 4-wide exp of the blended log-scale)
// against blend_logs (matrix exponential); worst relative error over m faces.
double grouped_blend_error(const std::vector<TransformLog>& logs, const RowMatrix& W) {
  const int m = static_cast<int>(W.rows());
  const int groups = (m + kGroupFaces - 1) / kGroupFaces;
  std::vector<double> out(static_cast<size_t>(kGroupStride) * groups);
  blend_groups(logs, W, 0, groups, out.data());
  double worst = 0.0;
  for (int i = 0; i < m; ++i) {
    const Eigen::Matrix3d ref = blend_logs(logs, W.row(i).data());
    Eigen::Matrix3d got;
    for (int e = 0; e < 9; ++e) {
      got.data()[e] = out[kGroupStride * (i / kGroupFaces) + kGroupFaces * e + i % kGroupFaces];
    }
    worst = std::max(worst, (got - ref).norm() / ref.norm());
  }
  return worst;
}

// The same with m faces of positive weights that sum to 1, different per face.
double grouped_blend_error(const std::vector<TransformLog>& logs, int m) {
  const int k = static_cast<int>(logs.size());
  RowMatrix W(m, k);
  for (int i = 0; i < m; ++i) {
    for (int a = 0; a < k; ++a) W(i, a) = 1.0 + std::sin(0.37 * i * (a + 1) + a);
    W.row(i) /= W.row(i).sum();
  }
  return grouped_blend_error(logs, W);
}
}  // namespace

TEST(Transforms, GroupedBlendMatchesReferenceOverWideScaleRange) {
  // Scales from 1e-6 to 1e6 exercise the exp's range reduction well away from n = 0; 203 faces
  // leave the last group padded. Both kernel builds (simd.hpp) where the CPU has AVX2.
  const Eigen::Vector3d ax = Eigen::Vector3d(0.3, -1, 0.4).normalized();
  const std::vector<TransformLog> logs = {
      transform_log(1e-6 * Eigen::AngleAxisd(0.4, ax).toRotationMatrix()),
      transform_log(1e6 * Eigen::AngleAxisd(-1.1, Eigen::Vector3d::UnitZ()).toRotationMatrix()),
      transform_log(0.7 * Eigen::Matrix3d::Identity()),
      transform_log(Eigen::AngleAxisd(2.5, Eigen::Vector3d::UnitY()).toRotationMatrix())};
  EXPECT_LT(grouped_blend_error(logs, 203), 1e-13);
  const bool avx2_before = set_avx2_kernels_enabled(false);
  EXPECT_LT(grouped_blend_error(logs, 203), 1e-13);
  set_avx2_kernels_enabled(avx2_before);
}

TEST(Transforms, GroupedBlendBeyondTheVectorExpRange) {
  // Log-scales of +-705 (scales of about 1e+-306) take the exp's scalar fallback for some faces
  // and the vector path for others (blends near 0). The vector path would still be exact here
  // (2^n reaches 2^1023): GroupedBlendBeyondTheExponentRangeOf2n is the one that needs the
  // fallback.
  std::vector<TransformLog> logs(2);
  logs[0].log_stretch = 705.0 * Eigen::Matrix3d::Identity();
  logs[1].log_stretch = -705.0 * Eigen::Matrix3d::Identity();
  logs[1].rotation = Eigen::Vector3d(0.0, 0.0, 0.5);
  EXPECT_LT(grouped_blend_error(logs, 41), 1e-13);
}

TEST(Transforms, GroupedBlendBeyondTheExponentRangeOf2n) {
  // A blended log-scale of -720 (weights outside [0, 1]): e^-720 is subnormal, which the
  // vector exp's 2^n cannot build, so that lane takes std::exp. Pure scales: the diagonal is the
  // scale itself.
  std::vector<TransformLog> logs(2);
  logs[0].log_stretch = -705.0 * Eigen::Matrix3d::Identity();
  logs[1].log_stretch = 705.0 * Eigen::Matrix3d::Identity();
  RowMatrix W(5, 2);
  for (int i = 0; i < 5; ++i) W.row(i) << 0.5, 0.5;
  const double w0 = (720.0 / 705.0 + 1.0) / 2.0;  // -705 w0 + 705 (1 - w0) = -720
  W.row(2) << w0, 1.0 - w0;
  for (const bool avx2 : {true, false}) {
    const bool before = set_avx2_kernels_enabled(avx2);
    std::vector<double> out(static_cast<size_t>(kGroupStride) * 2);
    blend_groups(logs, W, 0, 2, out.data());
    set_avx2_kernels_enabled(before);
    const double want = std::exp(-705.0 * w0 + 705.0 * (1.0 - w0));
    EXPECT_GT(want, 0.0);
    EXPECT_NEAR(out[2] / want, 1.0, 1e-9);  // face 2: group 0, lane 2, entry (0,0)
    EXPECT_EQ(out[0], 1.0);                 // face 0: weights 0.5, 0.5, scale 1
  }
}

TEST(Transforms, GroupedBlendBeyondTheRotationSeries) {
  // Weights outside [0, 1] blend angles far beyond pi, where the Rodrigues series would be off
  // (t^2 > 10): single lanes take sin/cos, faces 1 and 6 of 9 (both kernel builds).
  const std::vector<TransformLog> logs = {
      transform_log(
          Eigen::AngleAxisd(3.0, Eigen::Vector3d(1, 2, 0).normalized()).toRotationMatrix()),
      transform_log(Eigen::Matrix3d::Identity())};
  RowMatrix W(9, 2);
  for (int i = 0; i < 9; ++i) W.row(i) << 0.5, 0.5;
  W.row(1) << 3.0, -2.0;  // 9 rad
  W.row(6) << 2.5, -1.5;  // 7.5 rad
  for (const bool avx2 : {true, false}) {
    const bool before = set_avx2_kernels_enabled(avx2);
    EXPECT_LT(grouped_blend_error(logs, W), 1e-13);
    set_avx2_kernels_enabled(before);
  }
}

namespace {
Eigen::Matrix3d rounded_to_float(const Eigen::Matrix3d& M) {
  return M.cast<float>().cast<double>();
}

// Both kernel builds (baseline, and AVX2 where the CPU has it): the worst grouped-blend error.
double grouped_blend_error_both_builds(const std::vector<TransformLog>& logs, int m) {
  const double fast = grouped_blend_error(logs, m);
  const bool avx2_before = set_avx2_kernels_enabled(false);
  const double base = grouped_blend_error(logs, m);
  set_avx2_kernels_enabled(avx2_before);
  return std::max(fast, base);
}
}  // namespace

TEST(Transforms, FloatRoundOffOfASimilarityIsSnappedToIt) {
  // A rotation times a uniform scale, stored in float32 the way Blender keeps matrices, and a
  // product of four such (the add-on's inv(M_obj) M_now inv(M_bind) M_obj_bind).
  std::mt19937 rng(5);
  std::normal_distribution<double> g;
  for (int t = 0; t < 200; ++t) {
    Eigen::Matrix3d prod = Eigen::Matrix3d::Identity();
    for (int f = 0; f < 4; ++f) {
      const Eigen::Vector3d axis = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
      const double scale = std::exp(0.5 * g(rng));
      const Eigen::Matrix3d M =
          rounded_to_float(scale * Eigen::AngleAxisd(3.0 * g(rng), axis).toRotationMatrix());
      prod = f % 2 ? Eigen::Matrix3d(prod * M.inverse()) : Eigen::Matrix3d(prod * M);
      const TransformLog one = transform_log(M);
      ASSERT_TRUE(one.similarity) << t;
      // snapped to the similarity it is up to round-off: the map moves by < 1e-6 relative
      EXPECT_LT((transform_exp(one) - M).norm(), 1e-6 * M.norm());
    }
    const TransformLog L = transform_log(prod);
    ASSERT_TRUE(L.similarity) << t;
    EXPECT_LT((transform_exp(L) - prod).norm(), 1e-6 * prod.norm());
    EXPECT_EQ((L.log_stretch - L.log_stretch(0, 0) * Eigen::Matrix3d::Identity()).norm(), 0.0);
  }
}

TEST(Transforms, GenuineNonUniformScaleIsNotSnapped) {
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.8, Eigen::Vector3d(1, 2, 3).normalized()).matrix();
  for (double eps : {3e-6, 1e-4, 0.3}) {
    const Eigen::Matrix3d M = R * Eigen::Vector3d(1.0 + eps, 1.0, 1.0).asDiagonal();
    const TransformLog L = transform_log(M);
    EXPECT_FALSE(L.similarity) << eps;
    EXPECT_LT((transform_exp(L) - M).norm(), 1e-13) << eps;  // kept exactly
  }
  // just inside the tolerance: a similarity, off by at most that relative amount
  const Eigen::Matrix3d M = R * Eigen::Vector3d(1.0 + 5e-7, 1.0, 1.0).asDiagonal();
  const TransformLog L = transform_log(M);
  EXPECT_TRUE(L.similarity);
  EXPECT_LT((transform_exp(L) - M).norm(), 1e-6);
}

TEST(Transforms, GroupedBlendWithOneNonUniformlyScaledAnchor) {
  // The usual non-similarity pose (one Empty scaled along its own axes): the kernel that
  // exponentiates in that anchor's eigenbasis, against blend_logs (eigen-solve per face).
  const Eigen::Matrix3d Rb =
      Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.2, 1, -0.5).normalized()).matrix();
  const std::vector<TransformLog> logs = {
      transform_log(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitX()).toRotationMatrix()),
      transform_log(Rb * Eigen::Vector3d(1.3, 1.0, 0.8).asDiagonal() * Rb.transpose() *
                    Eigen::AngleAxisd(-0.9, Eigen::Vector3d::UnitZ()).toRotationMatrix()),
      transform_log(1.7 * Eigen::AngleAxisd(2.9, Eigen::Vector3d::UnitY()).toRotationMatrix())};
  ASSERT_TRUE(logs[0].similarity && !logs[1].similarity && logs[2].similarity);
  EXPECT_LT(grouped_blend_error_both_builds(logs, 203), 1e-13);
}

TEST(Transforms, GroupedBlendWithSeveralStretchedAnchors) {
  // Stretches that do not commute, up to a 40x ratio (log-stretch norm ~3: two squarings and
  // more), and one tiny one: the scaling-and-squaring Taylor kernel against blend_logs.
  std::vector<TransformLog> logs = {
      transform_log(Eigen::Vector3d(40.0, 1.0, 0.5).asDiagonal() *
                    Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix()),
      transform_log(Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 1, 0).normalized()).matrix() *
                    Eigen::Vector3d(0.9, 1.2, 1.0).asDiagonal()),
      transform_log(Eigen::Vector3d(1.0 + 1e-5, 1.0, 1.0).asDiagonal() *
                    Eigen::AngleAxisd(2.0, Eigen::Vector3d::UnitX()).toRotationMatrix()),
      transform_log(2.0 * Eigen::Matrix3d::Identity())};
  ASSERT_FALSE(logs[0].similarity || logs[1].similarity || logs[2].similarity);
  EXPECT_LT(grouped_blend_error_both_builds(logs, 203), 1e-12);
  // a zero deviatoric part in some faces (weights only on the similarity anchor)
  std::vector<TransformLog> two = {logs[3], logs[1]};
  EXPECT_LT(grouped_blend_error_both_builds(two, 9), 1e-13);
}

TEST(Transforms, AnisotropicBlendWithEqualWeightsIsIsotropic) {
  std::vector<TransformLog> logs = {
      transform_log(
          1.2 * Eigen::AngleAxisd(0.9, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix()),
      transform_log(Eigen::AngleAxisd(2.0, Eigen::Vector3d::UnitY()).toRotationMatrix())};
  RowMatrix W(3, 2);
  W << 1, 0, 0.3, 0.7, 0.5, 0.5;
  const Eigen::Matrix3d axes =
      Eigen::AngleAxisd(0.4, Eigen::Vector3d(0, 1, 1).normalized()).toRotationMatrix();
  Matrix3Array iso, ani;
  blend_all(logs, W, &iso);
  blend_all_anisotropic(logs, W, W, W, axes, &ani);
  for (int i = 0; i < 3; ++i) EXPECT_LT((iso[i] - ani[i]).norm(), 1e-12);
}

TEST(Transforms, AnisotropicBlendSeparatesAxisComponents) {
  // Anchor 1 rotates by (a, 0, c) about x and z. With x-weights 0 and z-weights 1 the face gets
  // only the z part; the stretch uses the mean weight.
  const double a = 0.8, c = -0.6;
  TransformLog L1;
  L1.rotation = Eigen::Vector3d(a, 0, c);
  L1.log_stretch = std::log(2.0) * Eigen::Matrix3d::Identity();
  std::vector<TransformLog> logs = {TransformLog{}, L1};
  RowMatrix wx(1, 2), wy(1, 2), wz(1, 2);
  wx << 1, 0;
  wy << 0.5, 0.5;
  wz << 0, 1;
  Matrix3Array out;
  blend_all_anisotropic(logs, wx, wy, wz, Eigen::Matrix3d::Identity(), &out);
  const Eigen::Matrix3d expect =
      std::pow(2.0, 0.5) * rotation_exp(Eigen::Vector3d(0, 0, c));  // mean weight 0.5
  EXPECT_LT((out[0] - expect).norm(), 1e-12);
}

TEST(Transforms, RotationLogNearPicksTheWholeTurnsNearest) {
  // Every log of R is (theta + 2 pi n) u; from a reference up to ~1 rad away, the one with the
  // n it came from, also at theta = pi (where the principal axis may flip) and theta = 0.
  std::mt19937 rng(11);
  std::normal_distribution<double> g;
  // (Within the tolerance of the identity the axis is noise: the next test.)
  const double angles[] = {1e-3, 0.3, 2.0, M_PI - 1e-9, M_PI};
  for (double theta : angles) {
    for (int n = -3; n <= 3; ++n) {
      const Eigen::Vector3d u = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
      const Eigen::Vector3d v = (theta + 2 * M_PI * n) * u;
      const Eigen::Matrix3d R = Eigen::AngleAxisd(theta, u).toRotationMatrix();
      const Eigen::Vector3d near = v + 0.5 * Eigen::Vector3d(g(rng), g(rng), g(rng)) / 1.8;
      const Eigen::Vector3d w = rotation_log_near(R, near);
      EXPECT_LT((w - v).norm(), 1e-9) << "theta=" << theta << " n=" << n;
      EXPECT_LT(rotation_vector_mismatch(w, R), 1e-9);
    }
  }
}

TEST(Transforms, RotationLogNearKeepsTheAxisAtAWholeTurn) {
  // After a full turn about z, float noise makes R's own axis arbitrary: within the tolerance
  // of the identity, near's axis and turns are kept (and the part of R along it).
  const Eigen::Vector3d z(0, 0, 1), x(1, 0, 0);
  const Eigen::Vector3d near = 2 * M_PI * z + Eigen::Vector3d(0, 0, 0.01);
  const Eigen::Matrix3d noise = Eigen::AngleAxisd(3e-7, x).toRotationMatrix();
  Eigen::Vector3d w = rotation_log_near(noise, near);
  EXPECT_LT((w - 2 * M_PI * z).norm(), 1e-12);
  EXPECT_LT(rotation_vector_mismatch(w, noise), 3.1e-7);
  const Eigen::Matrix3d along = Eigen::AngleAxisd(5e-5, z).toRotationMatrix();
  w = rotation_log_near(along, near);
  EXPECT_LT((w - (2 * M_PI + 5e-5) * z).norm(), 1e-12);
  EXPECT_LT(rotation_vector_mismatch(w, along), 1e-12);
  // Beyond the tolerance the rotation has its own axis, and its logs lie on that axis only
  // (the exp map is singular at a whole turn): documented, the nearest exact log is taken.
  const Eigen::Matrix3d tilt = Eigen::AngleAxisd(1e-3, x).toRotationMatrix();
  w = rotation_log_near(tilt, near);
  EXPECT_LT(rotation_vector_mismatch(w, tilt), 1e-12);
  EXPECT_LT(w.cross(x).norm(), 1e-12);
}

namespace {
// Frames of k = 2 sequences, frame-major: sequence 0 turns about `axis` by angle(t), sequence 1
// by -2 angle(t) about y, each rounded to float32 and (sequence 0) scaled along its own axes.
Matrix3Array two_sequences(const Eigen::Vector3d& axis, const std::vector<double>& angle) {
  Matrix3Array out;
  for (double a : angle) {
    Eigen::Matrix3d R0 = Eigen::AngleAxisd(a, axis).toRotationMatrix();
    R0 = R0 * Eigen::Vector3d(1.3, 1.0, 0.8).asDiagonal();
    out.push_back(R0.cast<float>().cast<double>());
    out.push_back(Eigen::AngleAxisd(-2 * a, Eigen::Vector3d::UnitY()).toRotationMatrix());
  }
  return out;
}
}  // namespace

TEST(Transforms, UnwrapRotationsFollowsTurnsOfAnyLength) {
  // 0 .. 4 pi in steps of 60 degrees (sequence 1: 120 degrees), through whole turns where the
  // axis is float noise: the closed form is angle * axis; sequence 0 is float32 and scaled
  // (its rotation factor is used).
  const Eigen::Vector3d axis = Eigen::Vector3d(1, -2, 0.5).normalized();
  std::vector<double> angle;
  for (int t = 0; t <= 12; ++t) angle.push_back(t * M_PI / 3);
  const std::vector<Eigen::Vector3d> v = unwrap_rotations(two_sequences(axis, angle), 2, {});
  ASSERT_EQ(v.size(), 2 * angle.size());
  for (size_t t = 0; t < angle.size(); ++t) {
    EXPECT_LT((v[2 * t] - angle[t] * axis).norm(), 2e-6) << "frame " << t;
    EXPECT_LT((v[2 * t + 1] + 2 * angle[t] * Eigen::Vector3d::UnitY()).norm(), 1e-9);
  }
  // A start picks frame 0's branch: the same motion one turn further on.
  const std::vector<Eigen::Vector3d> start = {(2 * M_PI + 0.2) * axis,
                                              Eigen::Vector3d(0, -2 * M_PI, 0)};
  const std::vector<Eigen::Vector3d> w = unwrap_rotations(two_sequences(axis, angle), 2, start);
  for (size_t t = 0; t < angle.size(); ++t) {
    EXPECT_LT((w[2 * t] - (angle[t] + 2 * M_PI) * axis).norm(), 2e-6) << "frame " << t;
    EXPECT_LT((w[2 * t + 1] + (2 * angle[t] + 2 * M_PI) * Eigen::Vector3d::UnitY()).norm(), 1e-9);
  }
}

TEST(Transforms, UnwrapRotationsTakesTheShorterOfTwoStepsOverHalfATurn) {
  // Steps of 200 degrees read as steps of -160 degrees: documented, not decidable.
  const Eigen::Vector3d z(0, 0, 1);
  Matrix3Array frames;
  for (int t = 0; t < 4; ++t) {
    frames.push_back(Eigen::AngleAxisd(t * 200.0 * M_PI / 180.0, z).toRotationMatrix());
  }
  const std::vector<Eigen::Vector3d> v = unwrap_rotations(frames, 1, {});
  for (int t = 0; t < 4; ++t) {
    EXPECT_LT((v[static_cast<size_t>(t)] - t * (-160.0 * M_PI / 180.0) * z).norm(), 1e-9);
  }
}

TEST(Transforms, UnwrapRotationsRejectsBadInput) {
  const Matrix3Array two(2, Eigen::Matrix3d::Identity());
  EXPECT_THROW(unwrap_rotations(two, 0, {}), std::invalid_argument);
  EXPECT_THROW(unwrap_rotations(two, 3, {}), std::invalid_argument);
  EXPECT_THROW(unwrap_rotations(two, 1, {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()}),
               std::invalid_argument);
  EXPECT_THROW(unwrap_rotations(two, 1, {Eigen::Vector3d(std::nan(""), 0, 0)}),
               std::invalid_argument);
  Matrix3Array bad = two;
  bad[1](2, 2) = -1;
  EXPECT_THROW(unwrap_rotations(bad, 1, {}), std::invalid_argument);
  bad[1](2, 2) = std::numeric_limits<double>::infinity();
  EXPECT_THROW(unwrap_rotations(bad, 1, {}), std::invalid_argument);
  EXPECT_TRUE(unwrap_rotations(Matrix3Array(), 2, {}).empty());
}
