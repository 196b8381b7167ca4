// The pose space of the pose-space method: the pose vector of an edit (handle centroids and
// orientations in the frame, joint rotation logs), the example weights by cardinal radial basis
// interpolation of the examples' pose vectors (phi(r) = r with a constant term: 1 at its own
// example, 0 at the others, summing to 1, continuous, bounded), and the blend of the examples'
// encodings with those weights (Q = exp of the blended relative rotation logs, S linear). See
// docs/pose_space.md, "Pose", "Example weights" and "Blend".
#include <Eigen/Dense>
#include <algorithm>
#include <string>

#include "matdeform/frames.hpp"
#include "matdeform/transforms.hpp"
#include "pose_space_internal.hpp"
#include "task_pool.hpp"

namespace matdeform {
namespace pose_space {

Interpolator::Interpolator(const RowMatrix& centers, double regularization, bool convex)
    : centers_(centers), convex_(convex) {
  const Eigen::Index p = centers.rows();
  if (p <= 1) return;
  Eigen::MatrixXd Phi(p, p);
  for (Eigen::Index a = 0; a < p; ++a)
    for (Eigen::Index b = 0; b < p; ++b) Phi(a, b) = (centers.row(a) - centers.row(b)).norm();
  const double big = Phi.maxCoeff();
  for (Eigen::Index a = 0; a < p; ++a) {
    for (Eigen::Index b = a + 1; b < p; ++b) {
      if (!(Phi(a, b) > 1e-9 * big)) {
        fail("examples[" + std::to_string(a) + "] and examples[" + std::to_string(b) +
             "] have the same pose (handle positions and joint rotations), so their weights "
             "are undefined");
      }
    }
  }
  Eigen::MatrixXd S = Eigen::MatrixXd::Zero(p + 1, p + 1);
  S.topLeftCorner(p, p) = Phi;
  // phi(r) = r is conditionally negative definite: -Phi is the positive (energy) matrix on
  // sum a = 0, so the smoothing ridge is subtracted. It pulls the weights at the examples
  // towards mixtures and keeps the partition of unity.
  S.topLeftCorner(p, p).diagonal().array() -= regularization * big;
  // The constant's column scaled like Phi (b = big * c): poses far apart (an example 1e40
  // times the others) otherwise leave a pivot below the rank threshold.
  S.topRightCorner(p, 1).setConstant(big);
  S.bottomLeftCorner(1, p).setConstant(big);
  Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(p + 1, p);
  rhs.topRows(p).setIdentity();
  Eigen::FullPivLU<Eigen::MatrixXd> lu(S);
  if (!lu.isInvertible()) fail("examples: the pose interpolation system is singular");
  const Eigen::MatrixXd sol = lu.solve(rhs);
  A_ = sol.topRows(p);
  b_ = big * sol.row(p).transpose();
}

Eigen::VectorXd Interpolator::operator()(const Eigen::VectorXd& x) const {
  const Eigen::Index p = centers_.rows();
  if (p == 0) return Eigen::VectorXd();
  if (p == 1) return Eigen::VectorXd::Ones(1);
  // A's columns sum to 0, so phi may be shifted by |x - P_0|. The shifted values are formed
  // without cancellation, |x - P_l| - |x - P_0| = (P_0 - P_l).(2x - P_l - P_0) / (sum), so
  // far from the examples (|x| >> |P|) the weights keep their sum 1 and their limits.
  const Eigen::VectorXd p0 = centers_.row(0).transpose();
  const double phi0 = (x - p0).norm();
  Eigen::VectorXd phi(p);
  for (Eigen::Index l = 0; l < p; ++l) {
    const Eigen::VectorXd pl = centers_.row(l).transpose();
    const double den = (x - pl).norm() + phi0;
    phi(l) = den > 0.0 ? (p0 - pl).dot(2.0 * x - pl - p0) / den : 0.0;
  }
  Eigen::VectorXd w = A_.transpose() * phi + b_;
  if (convex_) {
    w = w.cwiseMax(0.0);
    w /= w.sum();  // >= 1 before clipping: sum w = 1 and clipping only raises entries
  }
  return w;
}

}  // namespace pose_space

using namespace pose_space;  // NOLINT: this file is part of the method

void PoseSpaceDeformer::Impl::frame_of(const Vertices& X, Mat3* R, Vec3* o) const {
  if (frame >= 0) {
    const Vec3 a = X.row(frame_vertices[0]), b = X.row(frame_vertices[1]),
               c = X.row(frame_vertices[2]);
    *R = face_rotation(frame_rest_inverse, a, b, c);
    *o = (a + b + c) / 3.0;
  } else {
    *R = Mat3::Identity();
    *o = Vec3::Zero();
    // Without handles the pose is the joint rotations alone; a frozen region holds the model
    // in place, so positions are measured in the mesh's own frame.
    if (h == 0 || !frozen_vertices.empty()) return;
    const Vertices XH = gather_rows(X, handle_all);
    *R = best_rotation(handle_rest, XH);
    *o = XH.colwise().mean().transpose();
  }
}

// Pose vector: handle centroids in the frame (over the bounding-box diagonal), then the joint
// rotation logs (over pi) when given.
int PoseSpaceDeformer::Impl::pose_dim(bool joints) const {
  return 3 * h + 3 * static_cast<int>(oriented.size()) + (joints ? 3 * r : 0);
}

// Pose vector: handle centroids in the frame (over the bounding-box diagonal), the handles'
// best-fit rotations relative to the frame (logs over pi, times orientation_weight; handles
// with at least three non-collinear vertices), then the joint rotation logs (over pi).
Eigen::VectorXd PoseSpaceDeformer::Impl::pose_vector(const Vertices& targets, const Mat3& R,
                                                     const Vec3& o,
                                                     const Matrix3Array* joints) const {
  Eigen::VectorXd x(pose_dim(joints != nullptr));
  for (int j = 0; j < h; ++j) {
    const int b = handle_offset[j], e = handle_offset[j + 1];
    const Vec3 c = targets.middleRows(b, e - b).colwise().mean().transpose();
    x.segment<3>(3 * j) = R.transpose() * (c - o) / diag;
  }
  int at = 3 * h;
  for (int j : oriented) {
    const int b = handle_offset[j], e = handle_offset[j + 1];
    const Mat3 Rj = best_rotation(handle_rest.middleRows(b, e - b), targets.middleRows(b, e - b));
    x.segment<3>(at) = opt.orientation_weight * rotation_log(R.transpose() * Rj) / kPi;
    at += 3;
  }
  if (joints) {
    for (int q = 0; q < r; ++q) x.segment<3>(at + 3 * q) = rotation_log((*joints)[q]) / kPi;
  }
  return x;
}

Eigen::VectorXd PoseSpaceDeformer::Impl::example_pose(const Vertices& X, bool with_joints) const {
  Mat3 R;
  Vec3 o;
  frame_of(X, &R, &o);
  Matrix3Array joints;
  if (with_joints) {
    for (const auto& pr : opt.rotational) {
      joints.push_back(example_face_rotation(X, pr[0]).transpose() *
                       example_face_rotation(X, pr[1]));
    }
  }
  return pose_vector(gather_rows(X, handle_all), R, o, with_joints ? &joints : nullptr);
}

Mat3 PoseSpaceDeformer::Impl::example_face_rotation(const Vertices& X, int f) const {
  const Mat3 Vr = face_frame(rest.row(faces(f, 0)), rest.row(faces(f, 1)), rest.row(faces(f, 2)));
  return face_rotation(Vr.inverse(), X.row(faces(f, 0)), X.row(faces(f, 1)), X.row(faces(f, 2)));
}

void PoseSpaceDeformer::Impl::edit_frame(const Vertices& targets,
                                         const Eigen::Matrix4d* frame_transform, Mat3* R,
                                         Vec3* o) const {
  if (frame >= 0 && frame_transform) {
    *R = frame_transform->topLeftCorner<3, 3>();
    *o = *R * frame_rest_centroid + frame_transform->topRightCorner<3, 1>();
  } else if (frame >= 0) {
    const Vec3 a = targets.row(frame_in_handles[0]), b = targets.row(frame_in_handles[1]),
               c = targets.row(frame_in_handles[2]);
    try {
      *R = face_rotation(frame_rest_inverse, a, b, c);
    } catch (const std::invalid_argument&) {
      fail("handle_positions: the frame face's vertices are placed on a line");
    }
    *o = (a + b + c) / 3.0;
  } else {
    *R = Mat3::Identity();
    *o = Vec3::Zero();
    if (h == 0 || !frozen_vertices.empty()) return;
    *R = best_rotation(handle_rest, targets);
    *o = targets.colwise().mean().transpose();
  }
}

Eigen::VectorXd PoseSpaceDeformer::Impl::weights(const Vertices& targets,
                                                 const Matrix3Array* rotations,
                                                 const Eigen::Matrix4d* frame_transform) const {
  if (p == 0) return Eigen::VectorXd();
  if (p == 1) return Eigen::VectorXd::Ones(1);
  const bool joints = rotations && r > 0;
  if (!joints && !positions_error.empty()) fail(positions_error);
  Mat3 R;
  Vec3 o;
  edit_frame(targets, frame_transform, &R, &o);
  const Eigen::VectorXd x = pose_vector(targets, R, o, joints ? rotations : nullptr);
  return joints ? interp_full(x) : interp_positions(x);
}

void PoseSpaceDeformer::Impl::blend(const Eigen::VectorXd& w, Matrix3Array* Q,
                                    Matrix3Array* S) const {
  const int E = static_cast<int>(ldual.rows()), lm = static_cast<int>(lfaces.rows());
  Q->resize(E);
  S->resize(lm);
  auto body_q = [&](int b, int e) {
    for (int l = b; l < e; ++l) {
      Vec3 om = Vec3::Zero();
      for (int k = 0; k < p; ++k) om += w(k) * omega.row(l).segment<3>(3 * k).transpose();
      (*Q)[l] = rotation_exp(om);
    }
  };
  auto body_s = [&](int b, int e) {
    for (int i = b; i < e; ++i) {
      double s[6] = {1, 1, 1, 0, 0, 0};
      if (p > 0) {
        std::fill(s, s + 6, 0.0);
        for (int k = 0; k < p; ++k)
          for (int c = 0; c < 6; ++c) s[c] += w(k) * stretch(i, 6 * k + c);
      }
      Mat3& M = (*S)[i];
      M << s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2];
    }
  };
  if (E < kParallelMin) {
    body_q(0, E);
    body_s(0, lm);
  } else {
    parallel_ranges(E, kParallelMin / 2, kTasks, body_q);
    parallel_ranges(lm, kParallelMin / 2, kTasks, body_s);
  }
}

}  // namespace matdeform
