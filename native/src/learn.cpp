#include "matdeform/learn.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "matdeform/frames.hpp"
#include "matdeform/mesh.hpp"
#include "matdeform/threads.hpp"
#include "matdeform/transforms.hpp"

namespace matdeform {
namespace {

constexpr double kPi = 3.14159265358979323846;

void validate_inputs(const Vertices& rest, const Faces& faces, const IndexPairs& pairs,
                     const std::vector<Vertices>& poses) {
  validate_mesh(rest, faces);
  if (poses.empty()) throw std::invalid_argument("poses: need at least one pose");
  for (size_t s = 0; s < poses.size(); ++s) {
    if (poses[s].rows() != rest.rows()) {
      throw std::invalid_argument("poses[" + std::to_string(s) + "]: expected (" +
                                  std::to_string(rest.rows()) + ",3) vertices, got (" +
                                  std::to_string(poses[s].rows()) + ",3)");
    }
    if (!poses[s].allFinite()) {
      throw std::invalid_argument("poses[" + std::to_string(s) + "]: non-finite coordinate");
    }
    if (poses[s].rows() > 0 &&
        (poses[s].colwise().maxCoeff() - poses[s].colwise().minCoeff()).maxCoeff() > kMaxMeshSize) {
      throw std::invalid_argument("poses[" + std::to_string(s) +
                                  "]: larger than 1e50 across: rescale it with the mesh");
    }
  }
  check_indices(pairs, faces.rows(), "pairs");
}

// Inverse rest frame of every face (shared by all poses); throws for a degenerate rest face,
// naming the first one.
Matrix3Array inverse_rest_frames(const Vertices& rest, const Faces& faces) {
  const Eigen::Index m = faces.rows();
  Matrix3Array inv(static_cast<size_t>(m));
  std::vector<char> degenerate(static_cast<size_t>(m), 0);
#pragma omp parallel for schedule(static) num_threads(num_threads())
  for (Eigen::Index i = 0; i < m; ++i) {
    const Eigen::Matrix3d V =
        face_frame(rest.row(faces(i, 0)), rest.row(faces(i, 1)), rest.row(faces(i, 2)));
    const Eigen::FullPivLU<Eigen::Matrix3d> lu(V);
    degenerate[static_cast<size_t>(i)] = !lu.isInvertible();
    inv[static_cast<size_t>(i)] =
        lu.isInvertible() ? Eigen::Matrix3d(lu.inverse()) : Eigen::Matrix3d::Identity();
  }
  const auto bad = std::find(degenerate.begin(), degenerate.end(), 1);
  if (bad != degenerate.end()) {
    throw std::invalid_argument("rest face " + std::to_string(bad - degenerate.begin()) +
                                " is degenerate (zero area)");
  }
  return inv;
}

// Deformation gradient of face i in a pose: its frame there times the inverse rest frame.
Eigen::Matrix3d pose_gradient(const Vertices& pose, const Faces& faces,
                              const Matrix3Array& rest_inv, Eigen::Index i) {
  return face_frame(pose.row(faces(i, 0)), pose.row(faces(i, 1)), pose.row(faces(i, 2))) *
         rest_inv[static_cast<size_t>(i)];
}

// Number of dual edges at each face.
Eigen::VectorXd face_degrees(Eigen::Index num_faces, const IndexPairs& pairs) {
  Eigen::VectorXd degree = Eigen::VectorXd::Zero(num_faces);
  for (Eigen::Index e = 0; e < pairs.rows(); ++e) {
    degree(pairs(e, 0)) += 1.0;
    degree(pairs(e, 1)) += 1.0;
  }
  return degree;
}

// `passes` passes of the face-graph averaging: every row of x (one per face) becomes the mean of
// itself and its dual-edge neighbours. degree from face_degrees.
void average_over_face_graph(const IndexPairs& pairs, const Eigen::VectorXd& degree, int passes,
                             RowMatrix* x) {
  RowMatrix next(x->rows(), x->cols());
  for (int p = 0; p < passes; ++p) {
    next = *x;
    for (Eigen::Index e = 0; e < pairs.rows(); ++e) {
      next.row(pairs(e, 0)) += x->row(pairs(e, 1));
      next.row(pairs(e, 1)) += x->row(pairs(e, 0));
    }
    for (Eigen::Index f = 0; f < x->rows(); ++f) next.row(f) /= 1.0 + degree(f);
    x->swap(next);
  }
}

// Polar decomposition of a pose's deformation gradient T = S R; false for a face collapsed in
// the pose (det T <= 0), which is then skipped. Never throws: it runs inside OpenMP loops.
bool pose_polar(const Eigen::Matrix3d& T, Eigen::Matrix3d* S, Eigen::Matrix3d* R) {
  if (!(T.determinant() > 0.0)) return false;
  try {
    polar_decompose(T, S, R);
  } catch (const std::invalid_argument&) {
    return false;  // only for gradients beyond double range; validate_inputs bounds the poses
  }
  return true;
}

// The other axis-angle vector of the same rotation, w - 2 pi w/|w| (the one nearest w).
Eigen::Vector3d other_log(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  return angle < 1e-12 ? w : Eigen::Vector3d(w - (2.0 * kPi / angle) * w);
}

// log Q_j - log Q_i with each log free to take either of its two nearest representatives (w and
// other_log(w)): the shortest of the four differences. Keeps the difference small where the
// principal log jumps at angle pi, and is the same (negated) when i and j swap, so it does not
// depend on how faces are numbered. (Moving only log Q_j towards log Q_i was order-dependent:
// relabelling a mesh changed learned values by up to 8.)
Eigen::Vector3d log_difference(const Eigen::Vector3d& wi, const Eigen::Vector3d& wj) {
  const Eigen::Vector3d a[2] = {wi, other_log(wi)}, b[2] = {wj, other_log(wj)};
  Eigen::Vector3d best = wj - wi;
  for (const auto& x : a) {
    for (const auto& y : b) {
      if ((y - x).squaredNorm() < best.squaredNorm()) best = y - x;
    }
  }
  return best;
}

// numpy-style linear-interpolation percentile (q in [0,100]) of all entries of x.
double percentile(const RowMatrix& x, double q) {
  std::vector<double> v(x.data(), x.data() + x.size());
  if (v.empty()) return 0.0;
  const double pos = q / 100.0 * static_cast<double>(v.size() - 1);
  const auto lo = static_cast<size_t>(std::floor(pos));
  const size_t hi = std::min(lo + 1, v.size() - 1);
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(lo), v.end());
  const double a = v[lo];
  // After nth_element everything right of lo is >= a, so the next order statistic is its min.
  const double b =
      hi == lo ? a : *std::min_element(v.begin() + static_cast<std::ptrdiff_t>(hi), v.end());
  return a + (pos - static_cast<double>(lo)) * (b - a);
}

}  // namespace

Distortions learn_distortions(const Vertices& rest, const Faces& faces, const IndexPairs& pairs,
                              const std::vector<Vertices>& poses, bool anisotropic,
                              AxisFrame frame) {
  validate_inputs(rest, faces, pairs, poses);
  const Eigen::Index m = faces.rows();
  const Eigen::Index num_edges = pairs.rows();

  const Matrix3Array rest_inv = inverse_rest_frames(rest, faces);

  Distortions out;
  out.shear = Eigen::VectorXd::Zero(m);
  out.bend = RowMatrix::Zero(num_edges, anisotropic ? 3 : 1);
  Matrix3Array Q(static_cast<size_t>(m));
  std::vector<Eigen::Vector3d> logs(anisotropic ? static_cast<size_t>(m) : 0);
  std::vector<char> valid(static_cast<size_t>(m));

  for (const Vertices& pose : poses) {
#pragma omp parallel for schedule(static) num_threads(num_threads())
    for (Eigen::Index i = 0; i < m; ++i) {
      const auto u = static_cast<size_t>(i);
      Eigen::Matrix3d S, R;
      valid[u] = pose_polar(pose_gradient(pose, faces, rest_inv, i), &S, &R);
      if (!valid[u]) continue;
      Q[u] = R;
      out.shear(i) = std::max(out.shear(i), (S - Eigen::Matrix3d::Identity()).squaredNorm());
      if (anisotropic && frame == AxisFrame::kWorldLogDifference) logs[u] = rotation_log(R);
    }
#pragma omp parallel for schedule(static) num_threads(num_threads())
    for (Eigen::Index e = 0; e < num_edges; ++e) {
      const auto i = static_cast<size_t>(pairs(e, 0)), j = static_cast<size_t>(pairs(e, 1));
      if (!valid[i] || !valid[j]) continue;
      if (!anisotropic) {
        out.bend(e, 0) = std::max(out.bend(e, 0), (Q[i] - Q[j]).squaredNorm());
        continue;
      }
      const Eigen::Vector3d w = frame == AxisFrame::kRest ? rotation_log(Q[i].transpose() * Q[j])
                                                          : log_difference(logs[i], logs[j]);
      for (int a = 0; a < 3; ++a) out.bend(e, a) = std::max(out.bend(e, a), w(a) * w(a));
    }
  }
  return out;
}

RowMatrix stiffness_from_distortion(const RowMatrix& d, const StiffnessMap& map) {
  if (!(map.eps > 0.0 && map.eps <= 1.0)) throw std::invalid_argument("eps must be in (0, 1]");
  if (!(map.clamp_percent >= 0.0 && map.clamp_percent < 100.0)) {
    throw std::invalid_argument("clamp_percent must be in [0, 100)");
  }
  if (!(map.sharpness >= 0.0 && std::isfinite(map.sharpness))) {
    throw std::invalid_argument("sharpness must be finite and >= 0");
  }
  if (!d.allFinite() || (d.size() > 0 && d.minCoeff() < 0.0)) {
    throw std::invalid_argument("distortion must be finite and >= 0");
  }
  RowMatrix out = RowMatrix::Ones(d.rows(), d.cols());
  if (d.size() == 0) return out;
  const double top =
      map.clamp_percent > 0.0 ? percentile(d, 100.0 - map.clamp_percent) : d.maxCoeff();
  // Distortions are dimensionless; below kNoise (|Q_i - Q_j|_F^2 = 1e-12 is a relative
  // rotation of ~1e-6 rad) they are round-off, which must not be blown up to the full range.
  constexpr double kNoise = 1e-12;
  const double scale = std::max(top, kNoise);
  const double a = map.sharpness;
  const double tail = std::exp(-a);
  for (Eigen::Index k = 0; k < d.size(); ++k) {
    const double u = std::min(d.data()[k], scale) / scale;
    // Below a ~ 1e-8 the exponential form loses all digits; it tends to the linear one anyway.
    const double g = a < 1e-8 ? 1.0 - u : (std::exp(-a * u) - tail) / (1.0 - tail);
    out.data()[k] = map.eps + (1.0 - map.eps) * g;
  }
  return out;
}

Distortions smooth_distortions(const Distortions& d, int num_faces, const IndexPairs& pairs,
                               int passes) {
  if (passes < 0) throw std::invalid_argument("smoothing passes must be >= 0");
  if (d.shear.size() != num_faces || d.bend.rows() != pairs.rows()) {
    throw std::invalid_argument("distortions do not match num_faces / pairs");
  }
  check_indices(pairs, num_faces, "pairs");
  if (!d.bend.allFinite() || !d.shear.allFinite()) {
    throw std::invalid_argument("distortions: contain NaN or infinity");
  }
  if (passes == 0) return d;
  const Eigen::Index m = num_faces, num_edges = pairs.rows(), cols = d.bend.cols();
  // Face values: column 0..cols-1 bending, column cols shear; smoothed together.
  RowMatrix x = RowMatrix::Zero(m, cols + 1);
  const Eigen::VectorXd degree = face_degrees(m, pairs);
  for (Eigen::Index e = 0; e < num_edges; ++e) {
    for (int k = 0; k < 2; ++k) x.row(pairs(e, k)).head(cols) += d.bend.row(e);
  }
  for (Eigen::Index f = 0; f < m; ++f) {
    if (degree(f) > 0) x.row(f).head(cols) /= degree(f);
  }
  x.col(cols) = d.shear;
  average_over_face_graph(pairs, degree, passes, &x);
  Distortions out;
  out.shear = x.col(cols);
  out.bend.resize(num_edges, cols);
  for (Eigen::Index e = 0; e < num_edges; ++e) {
    out.bend.row(e) = 0.5 * (x.row(pairs(e, 0)).head(cols) + x.row(pairs(e, 1)).head(cols));
  }
  return out;
}

RowMatrix rotation_spread(const Vertices& rest, const Faces& faces, const IndexPairs& pairs,
                          const std::vector<Vertices>& poses, int passes) {
  if (passes < 0) throw std::invalid_argument("passes must be >= 0");
  validate_inputs(rest, faces, pairs, poses);
  const Eigen::Index m = faces.rows();
  const auto l = static_cast<Eigen::Index>(poses.size());
  RowMatrix out = RowMatrix::Zero(m, l);
  if (passes == 0) return out;
  const Matrix3Array rest_inv = inverse_rest_frames(rest, faces);
  const Eigen::VectorXd degree = face_degrees(m, pairs);
#pragma omp parallel for schedule(dynamic) num_threads(num_threads())
  for (Eigen::Index s = 0; s < l; ++s) {
    const Vertices& pose = poses[static_cast<size_t>(s)];
    // Columns 0..8: weight * Q (row-major), column 9: weight (1, or 0 for a collapsed face).
    RowMatrix x = RowMatrix::Zero(m, 10);
    for (Eigen::Index i = 0; i < m; ++i) {
      Eigen::Matrix3d S, R;
      if (!pose_polar(pose_gradient(pose, faces, rest_inv, i), &S, &R)) continue;
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) x(i, 3 * a + b) = R(a, b);
      }
      x(i, 9) = 1.0;
    }
    average_over_face_graph(pairs, degree, passes, &x);
    for (Eigen::Index i = 0; i < m; ++i) {
      const double w = x(i, 9);
      // Weighted mean of unit-norm-squared-3 matrices: 3 - |mean|^2 is their variance, >= 0.
      if (w > 0.0) out(i, s) = std::max(0.0, 3.0 - x.row(i).head(9).squaredNorm() / (w * w));
    }
  }
  return out;
}

LearnedStiffness learn_stiffness(const Vertices& rest, const Faces& faces, const IndexPairs& pairs,
                                 const std::vector<Vertices>& poses, bool anisotropic,
                                 const StiffnessMap& map, AxisFrame frame, int smoothing_passes) {
  if (smoothing_passes < 0) throw std::invalid_argument("smoothing passes must be >= 0");
  const Distortions d =
      smooth_distortions(learn_distortions(rest, faces, pairs, poses, anisotropic, frame),
                         static_cast<int>(faces.rows()), pairs, smoothing_passes);
  LearnedStiffness out;
  out.bend = stiffness_from_distortion(d.bend, map);
  out.shear = stiffness_from_distortion(d.shear, map);
  return out;
}

}  // namespace matdeform
