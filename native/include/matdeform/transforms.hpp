// Transformation algebra for blending (Alexa 2002; Popa et al. 2006 Eq. 2 and Appendix A).
//
// A linear map M with det M > 0 is split by polar decomposition into M = S * R, S symmetric
// positive definite (stretch), R a rotation (the paper's T = S Q order). Its log is the pair
// (log S, log R): log S is the real symmetric matrix log, log R the axis-angle vector (angle in
// [0, pi]). Blending with weights w_a is
//     exp(sum_a w_a log S_a) * exp(sum_a w_a log R_a).
// For similarities (rotation times uniform scale) S and R commute and this equals Alexa's
// exp(sum_a w_a log M_a) exactly; for general M it is the real, always-defined variant (a
// generic M with det > 0 can have no real matrix log at all, e.g. diag(-1,-2,1)).
#pragma once

#include <Eigen/Core>
#include <string>

#include "matdeform/types.hpp"

namespace matdeform {

// Largest |eigenvalue| of a log-stretch: e^709 = 8e307 is the last power of e below the largest
// double. transform_log refuses stretches beyond it, transform_exp logs beyond it; blends of
// valid logs with convex weights stay inside.
constexpr double kMaxLogStretch = 709.0;

// A linear map whose singular values agree to this relative spread, max(log sigma) -
// min(log sigma) <= kSimilarityTolerance, is taken as the similarity it is up to round-off
// (rotation times the geometric mean of the scales): transform_log snaps it, so blends take the
// closed-form path. Blender stores matrices in float32 (about 6e-8 relative per entry), and an
// anchor transform is a product of up to four of them, whose spread stays below ~5e-7. A real
// non-uniform scale (an Empty scaled along one axis) is far above it. Snapping changes the map
// by at most this relative amount, so deformed positions move by about 1e-6 of the mesh size.
constexpr double kSimilarityTolerance = 1e-6;

// Largest angle, in radians, by which exp(v) of a caller's rotation vector v (an unwrapped log:
// any length) may differ from the rotation it stands for. Blender stores matrices in float32
// (~1e-7 rad per matrix, a few per transform) and a float32 vector of a few turns is rounded by
// ~1e-6 rad: 1e-4 leaves a wide margin for both, and any real mistake (another frame's or
// another anchor's vector, degrees for radians, a wrong axis) is far above it. Disagreeing this
// little, the blend moves a vertex by at most ~1e-4 of its distance to the anchor.
constexpr double kRotationVectorTolerance = 1e-4;

struct TransformLog {
  Eigen::Matrix3d log_stretch = Eigen::Matrix3d::Zero();  // symmetric
  Eigen::Vector3d rotation = Eigen::Vector3d::Zero();     // axis * angle, angle in [0, pi]
  bool similarity = true;  // log_stretch is a multiple of the identity
};

// Axis-angle vector of rotation R (orthonormalised first). Never NaN, also at angle pi.
Eigen::Vector3d rotation_log(const Eigen::Matrix3d& R);
// Rodrigues formula, exact also for tiny angles.
Eigen::Matrix3d rotation_exp(const Eigen::Vector3d& omega);

// Angle in [0, pi] of the rotation between exp(v) and R (R orthonormalised first): how far the
// rotation vector v is from being a log of R. NaN when exp(v) is not finite (|v| ~ 1e154).
double rotation_vector_mismatch(const Eigen::Vector3d& v, const Eigen::Matrix3d& R);
// Throws std::invalid_argument "<name>: ..." unless v is finite and a log of R within
// kRotationVectorTolerance; `of` names R in the message ("the rotation of transforms[2]").
void check_rotation_vector(const Eigen::Vector3d& v, const Eigen::Matrix3d& R,
                           const std::string& name, const std::string& of);

// The log of rotation R (orthonormalised first) nearest to `near`. R's logs are
// (theta + 2 pi n) u for its axis u, angle theta and every integer n, so this picks the whole
// number of turns closest to near. Where R is within kRotationVectorTolerance of the identity
// (its axis is then round-off) and near is at least half a turn long, it returns near's own
// axis times the nearest multiple of 2 pi (plus R's angle along it): exp of that differs from R
// by at most R's angle, so the turns survive float noise at a whole turn.
Eigen::Vector3d rotation_log_near(const Eigen::Matrix3d& R, const Eigen::Vector3d& near);

// Rotation vectors continuous along sequences of rotations. frames holds count * k maps with
// det > 0, frame-major (frame t of sequence a at t * k + a); each one's rotation factor (polar
// decomposition) is used. Frame 0 of sequence a is rotation_log_near(R, start[a]) (start empty:
// the principal log), every later frame rotation_log_near(R, previous vector). A step of more
// than pi between two frames cannot be told from the opposite step of less than pi: the shorter
// is taken. Throws std::invalid_argument for a wrong size or start, non-finite entries, det <= 0.
std::vector<Eigen::Vector3d> unwrap_rotations(const Matrix3Array& frames, int k,
                                              const std::vector<Eigen::Vector3d>& start);

// M = S * R with S symmetric positive definite, R proper rotation. Throws
// std::invalid_argument unless det M > 0 and M is finite (and S stays finite).
void polar_decompose(const Eigen::Matrix3d& M, Eigen::Matrix3d* S, Eigen::Matrix3d* R);

// The proper rotation R maximising tr(R^T H) (the rotation of a Kabsch / Umeyama fit with
// H = sum_i y_i x_i^T, centred point pairs x_i -> y_i), and that trace, which is
// sigma_1 + sigma_2 + sign(det H) sigma_3. Horn's quaternion form: R is the eigenvector of the
// largest eigenvalue of a 4x4 symmetric matrix, found by Newton's method on its characteristic
// polynomial (Theobald's QCP) and the adjugate; no SVD, a few times cheaper than a 3x3 one.
// Returns false (R, trace untouched) when the eigenvalue gap 2 (sigma_2 + sign sigma_3) is below
// ~1e-6 of sigma_1 (H of rank <= 1 or nearly so) or H is not finite: the caller then decides,
// e.g. with an SVD. Accepted fits agree with the SVD's to ~eps over that relative gap.
bool fit_rotation(const Eigen::Matrix3d& H, Eigen::Matrix3d* R, double* trace);
// Four fits at once, each as fit_rotation's (to round-off; lanes do not affect each other): H
// and R point to four matrices, trace and ok to four values; ok[i] is fit_rotation's return
// value (false: R[i], trace[i] untouched). Lanes whose eigenvalue gap needs fit_rotation's
// refinement are handed to it. Several times faster per fit than four fit_rotation calls.
void fit_rotations4(const Eigen::Matrix3d* H, Eigen::Matrix3d* R, double* trace, bool* ok);

// Log of a symmetric positive definite matrix and exp of a symmetric one (eigen-decomposition).
// Both throw std::invalid_argument when an eigenvalue of the log is beyond +-kMaxLogStretch.
Eigen::Matrix3d spd_log(const Eigen::Matrix3d& S);
Eigen::Matrix3d sym_exp(const Eigen::Matrix3d& L);

// Throws std::invalid_argument as polar_decompose and spd_log do. M whose singular values agree
// within kSimilarityTolerance comes back as an exact similarity (similarity = true).
TransformLog transform_log(const Eigen::Matrix3d& M);
// Throws std::invalid_argument when the log-stretch is beyond +-kMaxLogStretch (the result
// would overflow).
Eigen::Matrix3d transform_exp(const TransformLog& L);

// Blend of anchor logs with weights (k,), the exp of the weighted log sum.
Eigen::Matrix3d blend_logs(const std::vector<TransformLog>& logs, const double* weights);

// Blends for all faces: weights is (m,k), output m matrices. Parallel over faces. Throws
// std::invalid_argument for non-finite weights and for rows whose blended log-stretch could
// exceed kMaxLogStretch (sum_a |w_a| |log S_a|_F above it).
void blend_all(const std::vector<TransformLog>& logs, const RowMatrix& weights, Matrix3Array* out);
// Serial kernel of blend_all for faces [begin, end), written to out[0 .. end - begin).
void blend_range(const std::vector<TransformLog>& logs, const RowMatrix& weights, int begin,
                 int end, Eigen::Matrix3d* out);

// blend_range for the faces of groups [group_begin, group_end), written in the grouped layout
// (types.hpp) from out[0]; lanes past the last face get the identity. Isotropic similarity
// blends (the usual case) run four faces at a time.
void blend_groups(const std::vector<TransformLog>& logs, const RowMatrix& weights, int group_begin,
                  int group_end, double* out);

// Anisotropic blend (paper Sec. 5). Each anchor rotation log is split into its components along
// the columns of `axes` (c_x = <log Q, log R_x> up to the basis normalisation); component x is
// blended with weights wx, and so on. The stretch part uses the mean of the three weights.
// All weight matrices are (m,k). With wx = wy = wz this equals blend_all, and it throws as
// blend_all does (for the mean weights).
void blend_all_anisotropic(const std::vector<TransformLog>& logs, const RowMatrix& wx,
                           const RowMatrix& wy, const RowMatrix& wz, const Eigen::Matrix3d& axes,
                           Matrix3Array* out);
// Serial kernel of blend_all_anisotropic for faces [begin, end), written to out[0 .. end - begin).
void blend_range_anisotropic(const std::vector<TransformLog>& logs, const RowMatrix& wx,
                             const RowMatrix& wy, const RowMatrix& wz, const Eigen::Matrix3d& axes,
                             int begin, int end, Eigen::Matrix3d* out);
// blend_range_anisotropic for whole groups, in the grouped layout (see blend_groups).
void blend_groups_anisotropic(const std::vector<TransformLog>& logs, const RowMatrix& wx,
                              const RowMatrix& wy, const RowMatrix& wz, const Eigen::Matrix3d& axes,
                              int group_begin, int group_end, double* out);

}  // namespace matdeform
