// Private: the pieces of the pyramid-coordinates method shared by its source files
// (pyramid_coordinates.cpp: the description and Eq. 1-2; pyramid_energy.cpp: the pyramids'
// least-squares energy and its derivatives; pyramid_start.cpp: the start; pyramid_deformer.cpp:
// the Newton iteration).
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <memory>
#include <vector>

#include "matdeform/pyramid_deformer.hpp"
#include "sparse_cholesky.hpp"

namespace matdeform {
namespace pyramid {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;

inline Vec3 row(const double* X, int v) { return Vec3(X[3 * v], X[3 * v + 1], X[3 * v + 2]); }

// ----------------------------------------------------------------------------------------------
// The paper's reconstruction (Eq. 1-2), for reconstruct().
struct Placement {
  Vertices rest;
  PyramidCoordinates coords;
  std::vector<double> cot_beta;        // per slot
  std::vector<double> weight_per_len;  // per slot: w_i / l_i, for the stretch factor

  Placement(const Vertices& vertices, const Faces& faces);
  // Vertex v placed from its neighbours in X by Eq. 1-2 (followers: the best-fit similarity of
  // v and its neighbours, rest -> X; isolated: where it is).
  Vec3 place(int v, const double* X, bool stretch) const;
  Vec3 follow(int v, const double* X) const;
};

// ----------------------------------------------------------------------------------------------
// Pyramids: every vertex with at least two neighbours whose rest points are not collinear, with
// its one-ring. The energy is
//   E(X) = sum_c min_{s, R} sum_k |y_k - s R p_k|^2 + kappa s0_c (s - 1)^2,
// y_k = x_k - mean_c(x), p_k = rest_k - mean_c(rest), s0_c = sum_k |p_k|^2, R a rotation.
struct Pyramids {
  std::vector<int> offsets;  // members of pyramid c: members[offsets[c] .. offsets[c+1])
  std::vector<int> members;  // vertex ids, apex first
  std::vector<double> rest;  // 3 per member: rest position minus the pyramid's rest mean
  std::vector<double> size;  // s0 per pyramid
  int count() const { return static_cast<int>(size.size()); }
};

// Pyramids of the vertices v with keep_apex[v] that have a one-ring. Pyramids whose rest points
// are collinear (or coincide) carry no rotation and are left out.
Pyramids make_pyramids(const Vertices& rest, const PyramidCoordinates& coords,
                       const std::vector<char>& keep_apex);

// R maximising tr(R^T H) and that trace: Horn's quaternion fit (fit_rotation), or the SVD where
// it declines (H of rank <= 1, or not finite).
void best_rotation(const Mat3& H, Mat3* R, double* trace);

// The optimal similarity of one pyramid for the current positions.
struct Fit {
  Vec3 centre = Vec3::Zero();  // mean of the current members
  Mat3 R = Mat3::Identity();   // rotation maximising tr(R^T H), H = sum_k y_k p_k^T
  Mat3 H = Mat3::Zero();
  double trace = 0;  // tr(R^T H)
  double scale = 1;  // s = (trace / s0 + kappa) / (1 + kappa)
  double energy = 0;
};

// Fits pyramid c to X (n,3) and returns its energy (finite or not).
Fit fit_pyramid(const Pyramids& P, int c, const double* X, double kappa);
// Fits pyramids c0 .. c0 + count - 1 (count 1 to 4) into out[0 .. count): each exactly as
// fit_pyramid would, whichever pyramids share the call.
void fit_pyramids(const Pyramids& P, int c0, int count, const double* X, double kappa, Fit* out);

// The Hessian of pyramid c's energy with respect to its members' positions (3M x 3M),
//   2 (I - 11^T / M) (x) I_3 - sum_q coef_q u_q u_q^T,
// as at most four vectors u_q (3M each, member-major) and their coefficients. exact = false
// clamps the low-rank part's eigenvalues at 2, which makes it positive semidefinite. Returns
// whether that clamp changed anything (for exact = false) .
constexpr int kTerms = 4;
bool hessian_terms(const Pyramids& P, int c, const Fit& fit, double kappa, bool exact, double* u,
                   double* coef);

// ----------------------------------------------------------------------------------------------
// The start: the control clusters' similarities blended by harmonic weights, and the rest
// mesh's edges rotated and scaled by that field and stitched by one Poisson solve.
class Start {
 public:
  Start(const Vertices& rest, const Faces& faces, const std::vector<int>& control,
        const std::vector<char>& is_free);
  ~Start();
  // rotation_vectors: nullptr, or (k,3) one axis * angle per control (any length); each
  // rotation-carrying cluster then blends the log of its fitted rotation that its controls'
  // vectors give (checked against that rotation), so the field carries whole turns.
  Vertices operator()(const Vertices& control_positions,
                      const Vectors3* rotation_vectors = nullptr) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The best-fit similarity of points `a` (rest) onto `b` (current), k rows each: b ~ s R a + t.
// One or two points (or collinear ones) leave the rotation about their line free: the fit then
// picks the smallest rotation (the SVD's order). Returns s R in *A and the centroids.
void fit_similarity(const std::vector<Vec3>& a, const std::vector<Vec3>& b, Mat3* A, Vec3* ca,
                    Vec3* cb);

}  // namespace pyramid
}  // namespace matdeform
