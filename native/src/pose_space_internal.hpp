// Private: the parts of the pose-space deformer (matdeform/pose_space_deformer.hpp) and the
// state they share. One file per part of the method:
//   pose_space_deformer.cpp       input checks, the bind (parts, frame, level, constraints) and
//                                 deform(): the pipeline that calls the parts below in order;
//   pose_space_encoding.cpp       the rotation-invariant encoding of the examples (per-face
//                                 stretch, per-dual-edge relative rotation logs);
//   pose_space_interpolation.cpp  the pose vector, the example weights (cardinal radial basis
//                                 interpolation) and the blend of the encodings;
//   pose_space_rotations.cpp      step 1: absolute rotations from the blended relative ones;
//   pose_space_positions.cpp      step 2: positions from the per-face targets R S;
//   pose_space_multires.cpp       the coarse mesh and the transfer of its solution to the dense
//                                 vertices (harmonic weights, detail vectors).
// Keeps CHOLMOD (through sparse_cholesky.hpp) out of the public header.
#pragma once

#include <Eigen/Dense>
#include <array>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "matdeform/pose_space_deformer.hpp"
#include "matdeform/types.hpp"
#include "sparse_cholesky.hpp"

namespace matdeform {
namespace pose_space {

using Clock = std::chrono::steady_clock;
using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;

inline constexpr double kPi = 3.14159265358979323846;
// Per-edit loops over faces or vertices: below this size they run serially (waking the pool's
// workers costs more than the work: the 17k-face transfer took 0.75 ms on two threads, 0.24 ms
// on one).
inline constexpr int kParallelMin = 16384;
inline constexpr int kTasks = 8;
// Positions (examples, handle targets, the frame) lie within this many bounding-box diagonals
// of the rest mesh's centre. Then every product the solve forms (squared lengths of pose
// vectors, cross products of target edges, the Kabsch cross-covariance) stays below ~1e200;
// far beyond, they overflow to inf and NaN (handles scaled by 1e155 did).
inline constexpr double kMaxReach = 1e50;
// Within that reach a non-finite result is a defect, but it is never returned.
inline constexpr const char* kOverflow =
    "handle_positions: the solve overflowed (a non-finite value); rescale the mesh and the "
    "positions (only shapes matter)";

// ---- small helpers (pose_space_deformer.cpp)
double ms_since(Clock::time_point t0);
[[noreturn]] void fail(const std::string& msg);
std::string item(const char* name, size_t i);
std::string number(double x);
// Rotation R minimising sum_i |R (p_i - mean p) - (q_i - mean q)|^2 (Kabsch). Points on a line
// get the smallest rotation taking the source direction to the target direction, a single point
// the identity.
Mat3 best_rotation(const Vertices& P, const Vertices& Q);
// Second singular value over the first of the centred point set: 0 for collinear points.
double planarity(const Vertices& P);
Vertices gather_rows(const Vertices& X, const std::vector<int>& ids);
// Rotation factor of the deformation gradient of one triangle, rest (a,b,c) -> (a2,b2,c2).
Mat3 face_rotation(const Mat3& rest_frame_inverse, const Vec3& a, const Vec3& b, const Vec3& c);
// Centroid of a triangle summed in lexicographic order of its corners, so the same bits for any
// corner order (a root chosen by distance must not depend on the numbering, even in ties).
Vec3 centroid(const Vertices& V, int a, int b, int c);
// Mean of the rows `ids` of V, summed in lexicographic order of the points (the same bits for
// any numbering).
Vec3 canonical_mean(const Vertices& V, std::vector<int> ids);
// The face whose rest centroid is nearest to `point` (ties: lexicographic centroid), a choice
// that does not depend on the numbering of faces or vertices. Among the faces in `candidates`
// (-1 when it is empty).
int nearest_face(const Vertices& V, const Faces& F, const Vec3& point,
                 const std::vector<int>& candidates);

// ---- rotations (pose_space_rotations.cpp)
// Nearest proper rotation in the Frobenius norm (the rotation factor of the polar
// decomposition).
Mat3 nearest_rotation(const Mat3& M);

// ---- example weights (pose_space_interpolation.cpp)
//
// Cardinal radial basis interpolation: w(x) = A^T phi(x) + b with phi_l(x) = |x - P_l| and
// [Phi - mu I, 1; 1^T, 0] [A; b^T] = [I; 0]. Phi symmetric makes A symmetric with zero row
// sums, so sum_k w_k = 1 everywhere; with mu = 0, w(P_k) = e_k. phi(r) = r is conditionally
// positive definite of order 1: the system is non-singular for distinct centres, and with the
// constant term the weights stay bounded (they tend to direction-dependent constants far from
// the examples).
class Interpolator {
 public:
  Interpolator() = default;
  Interpolator(const RowMatrix& centers, double regularization, bool convex);
  Eigen::VectorXd operator()(const Eigen::VectorXd& x) const;

 private:
  RowMatrix centers_;
  Eigen::MatrixXd A_;
  Eigen::VectorXd b_;
  bool convex_ = false;
};

// ---- step 1 (pose_space_rotations.cpp)
//
// Links l = (a, b) with weight w_l ask R_b = R_a Q_l (dual edges: the blended relative
// rotations; rotational pairs: the prescribed joint rotation). Energy
//     sum_l w_l |R_b - R_a Q_l|^2 + sum_f lambda_f |R_f - Z_f|^2,   R = I on fixed faces.
// In the gauge R_f = Y_f P_f, with P integrated along a BFS tree (P_root = I, P_b = P_a Q_l on
// tree links), each link term becomes |Y_b - Y_a D_l|^2 with D_l = P_a Q_l P_b^T: the identity
// on tree links, close to it elsewhere. The rows of Y decouple and the matrix is the block
// "connection Laplacian" with blocks D_l; the scalar Laplacian (D = I), factored once, is its
// preconditioner.
class RotationSolver {
 public:
  // tree_roots: where the gauge's spanning tree starts, every fixed face and one face in each
  // rotation component without one (faces the tree does not reach keep the identity gauge).
  RotationSolver(int m, const IndexPairs& dual, const std::vector<std::array<int, 2>>& pairs,
                 double pair_weight, const std::vector<int>& fixed,
                 const std::vector<int>& tree_roots, const std::vector<int>& penalty_faces,
                 double penalty_weight, const std::vector<double>& edge_cost,
                 const std::vector<double>& edge_weight);

  // The same constraints with the geodesic energy sum_l w_l |log(R_a Q_l R_b^T)|^2 +
  // sum_f lambda_f |log(Z_f R_f^T)|^2, by Gauss-Newton in the Lie algebra: with R = exp(xi) P,
  // each link asks xi_b - xi_a = log(P_a Q_l P_b^T), a scalar Laplacian system (the constant
  // preconditioner matrix itself) with three right-hand sides. P starts as the tree gauge (or
  // init) and is updated by exp(xi) until max |xi| < 1e-10 or max_iterations solves. Exact in
  // one solve when the relative rotations are consistent. Returns the number of solves.
  //
  // Turns past half a turn (the energy has a local minimum per number of turns; the matrices
  // alone pick the principal logs): pair_turns, one rotation vector per rotational pair, a log
  // of any length of G (used when G is given), takes each pair's residual on the branch that
  // turns face b against face a by that vector, the start's own relative rotation of the pair
  // counted on its principal branch; face_turns, indexed by face, the residual log(Z_f P_f^T)
  // of each penalty face at the start, of any length. Later steps take the log nearest to what
  // is left of it. nullptr: principal logs.
  int solve_log(const Matrix3Array& Q, const Matrix3Array* G, const Matrix3Array& Z,
                const Matrix3Array* init, int max_iterations, Matrix3Array* R,
                const std::vector<Vec3>* pair_turns = nullptr,
                const std::vector<Vec3>* face_turns = nullptr) const;

  // Chordal energy (the paper's linear step 1). Q: one relative rotation per dual edge; G: one
  // per rotational pair, or nullptr (pairs inactive); Z: targets of the penalty faces (indexed
  // by face); init: a rotation field used as the gauge and starting guess, or nullptr (the tree
  // gauge). Writes m rotations (projected) to R; returns the CG iteration count.
  int solve(const Matrix3Array& Q, const Matrix3Array* G, const Matrix3Array& Z,
            const Matrix3Array* init, int max_iterations, double tolerance, Matrix3Array* R) const;

 private:
  static void run(int n, const std::function<void(int, int)>& body);
  void apply(const Matrix3Array& X, Matrix3Array* out) const;
  void precondition(const Matrix3Array& r, Matrix3Array* z) const;
  static double dot(const Matrix3Array& a, const Matrix3Array& b);
  int cg(int max_iterations, double tolerance) const;

  int m_ = 0, num_dual_ = 0;
  std::vector<int> la_, lb_;
  std::vector<double> lw_, penalty_;
  std::vector<int> unknown_, faces_;
  std::vector<int> adj_ptr_, adj_;  // 2 l + (this face is b)
  std::vector<int> order_, parent_link_;
  std::unique_ptr<SparseCholesky> chol_;
  // Per-call workspace.
  mutable Matrix3Array P_, D_, B_, X_;
  mutable std::vector<Vec3> d_;
  mutable std::vector<Vec3> phi_, pair_expect_;  // solve_log with turns: steps taken, start
  mutable std::vector<char> active_;
  mutable std::vector<double> buf_in_, buf_out_;
};

// ---- step 2 (pose_space_positions.cpp)
//
// Energy sum_i |X_i E_i - T_i|^2 (X_i the deformed frame with the fourth vertex, E_i the
// inverse rest frame) + lambda sum_q |sum_c beta_qc x_c - t_q|^2 (handle rows), fixed vertices
// at rest. Each fourth vertex appears in one face only and is eliminated exactly per face
// (Schur complement), so the system has one unknown per vertex and three right-hand sides.
struct GradientOperator {
  // Per face, times its weight: the rows of (D E) for a, b, c after eliminating the fourth
  // vertex (G'), and the 3x3 Schur block of the face's Hessian. With area weights (area over
  // the mean area) the energy is the integral of |grad x - T|^2; a sliver's gradient terms grow
  // like 1/width^2, and unweighted they would dominate (coarse meshes have slivers).
  std::vector<Mat3> Gp, Hp;
  double mean_diagonal = 1.0;

  GradientOperator(const Vertices& V, const Faces& F, bool area_weights);
};

class PositionSolver {
 public:
  struct Row {
    std::vector<int> idx;  // level vertices
    std::vector<double> beta;
  };

  // part: the mesh part of each vertex (parts 0 .. max). A part that no fixed vertex and no row
  // holds gets a translation gauge: its first vertex is fixed, and its rest mean is restored
  // after the solve.
  PositionSolver(const Vertices& rest, const Faces& F, const GradientOperator& grad,
                 std::vector<int> fixed, const std::vector<Row>& rows, double lambda,
                 const std::vector<int>& part);

  // T: one target per face; row_targets: (rows,3) or nullptr when there are no rows.
  void solve(const Matrix3Array& T, const Vertices* row_targets, Vertices* out) const;

 private:
  const Vertices& rest_;
  const Faces& F_;
  const GradientOperator& grad_;
  std::vector<Row> rows_;
  double lambda_;
  std::vector<int> unknown_;
  int num_unknowns_ = 0;
  std::vector<std::vector<int>> gauge_;  // vertices of each part whose mean is restored
  Eigen::Matrix<double, Eigen::Dynamic, 3> c0_;
  std::unique_ptr<SparseCholesky> chol_;
};

// ---- multiresolution (pose_space_multires.cpp)
//
// The coarse level: quadric simplification (meshoptimizer) of V, F to about `target` faces,
// cleared of flat faces and slivers; coarse vertices are dense vertices. Throws when no
// non-degenerate, manifold coarse mesh is found.
void coarse_mesh(const Vertices& V, const Faces& F, int target, double diag,
                 std::vector<int>* coarse_vertices, Vertices* coarse_rest, Faces* coarse_faces);

}  // namespace pose_space

// The state shared by the parts of the method. Members are defined in the file of the part
// they belong to (see the list at the top).
struct PoseSpaceDeformer::Impl {
  using Vec3 = pose_space::Vec3;
  using Mat3 = pose_space::Mat3;
  using Interpolator = pose_space::Interpolator;
  using RotationSolver = pose_space::RotationSolver;
  using GradientOperator = pose_space::GradientOperator;
  using PositionSolver = pose_space::PositionSolver;

  // Dense input.
  Vertices rest;
  Faces faces;
  int n = 0, m = 0, p = 0, h = 0, r = 0;
  double diag = 1.0;
  Vec3 center = Vec3::Zero();  // of the rest bounding box
  PoseSpaceOptions opt;
  std::vector<std::vector<int>> handles;
  std::vector<int> handle_all;       // concatenated handle vertices
  std::vector<int> handle_offset;    // h + 1
  std::vector<int> frozen_vertices;  // sorted dense ids
  std::vector<char> is_frozen_vertex;
  // Mesh parts (connected through edges). A part with a handle vertex, a frozen face, the frame
  // face or a rotational face is solved; the others are output at rest.
  int parts = 1;
  std::vector<int> vpart;         // dense vertex -> part
  std::vector<char> at_rest;      // dense vertices output at rest: frozen, or in a free part
  std::vector<char> part_frozen;  // parts holding frozen faces (no fitted rotation)
  // Frame.
  int frame = -1;
  std::array<int, 3> frame_vertices = {-1, -1, -1};
  std::array<int, 3> frame_in_handles = {-1, -1, -1};  // position in handle_all, or -1
  Mat3 frame_rest_inverse = Mat3::Identity();
  Vec3 frame_rest_centroid = Vec3::Zero();
  Vertices handle_rest;       // rest positions of handle_all
  std::vector<int> oriented;  // handles whose orientation is part of the pose
  // Pose space.
  Interpolator interp_full, interp_positions;
  std::string positions_error;  // why the positions-only interpolator is unavailable
  // Solve level (the coarse mesh, or the dense mesh itself, or its solved parts).
  bool multires = false;
  bool whole = true;  // the level is the dense mesh, same numbering
  Vertices lrest;
  Faces lfaces;
  std::vector<int> lvertices;   // dense id of each level vertex
  std::vector<int> level_of;    // dense vertex -> level vertex, or -1
  std::vector<int> lface_part;  // level face -> part
  std::vector<int> lvpart;      // level vertex -> part
  IndexPairs ldual;
  RowMatrix omega;    // (E, 3p) relative rotation logs
  RowMatrix stretch;  // (lm, 6p)
  std::vector<std::array<int, 2>> lpairs;
  std::vector<int> lhandle_faces, lhandle_owner;
  std::vector<int> lfixed_faces, lfixed_vertices;
  std::unique_ptr<GradientOperator> grad;
  // Step 1's rotation solvers: `a` for the natural shape, `b` (when handles hold faces) with
  // the handles' rotations; `follow`: level faces whose rotation is the natural shape's turned
  // by their part's fitted rotation (rotation components of `b` that nothing else holds).
  struct RotationSolvers {
    int components = 0;  // rotation components (gauges)
    std::unique_ptr<RotationSolver> a, b;
    std::vector<char> follow;
  };
  RotationSolvers rot;       // the rotational pairs link their faces
  RotationSolvers rot_free;  // without them (rotations not given), where that splits a gauge
  std::unique_ptr<PositionSolver> pos_a, pos_b;
  mutable std::unique_ptr<PositionSolver> pos_b_frame;
  std::vector<PositionSolver::Row> handle_rows, frame_rows;
  double lambda_pos = 1.0;
  // Multiresolution transfer: per dense vertex, coarse neighbours with harmonic weights, and
  // detail vectors (n, 3 max(p,1)).
  std::vector<int> tr_ptr, tr_idx;
  std::vector<double> tr_w;
  RowMatrix detail;
  std::vector<int> vf_ptr, vf_idx;  // coarse vertex -> coarse faces
  Eigen::VectorXd larea;            // coarse face areas: slivers count little in vertex rotations
  // Last call. deform() holds `busy` for its whole run: the solvers' per-call workspaces, the
  // lazily built frame solver and these results are shared by every call on this deformer.
  mutable std::mutex busy;
  mutable Eigen::VectorXd last_weights;
  mutable PoseSpaceStats stats;

  // ---- input checks (pose_space_deformer.cpp)
  // Distance (max norm) of point x from the rest centre, when beyond kMaxReach diagonals.
  std::optional<double> beyond_reach(const Vec3& x) const;
  // Throws for the first row of X beyond reach, naming `what`.
  void check_reach(const Vertices& X, const std::string& what) const;
  void check_inputs(const std::vector<Vertices>& hp, const Matrix3Array* rotations,
                    const Eigen::Matrix4d* frame_transform,
                    const Vectors3* rotation_vectors = nullptr) const;
  void check_rotation_vectors(const std::vector<Vertices>& hp, const Matrix3Array* rotations,
                              const Vectors3& v) const;
  Vertices concat_targets(const std::vector<Vertices>& hp) const;

  // ---- encoding (pose_space_encoding.cpp)
  // Relative rotation logs per level dual edge (omega) and rest-frame stretch per level face
  // (stretch) of every example; each example's level face rotations go to example_rotations.
  void encode_examples(const std::vector<Vertices>& examples,
                       std::vector<Matrix3Array>* example_rotations);

  // ---- pose and weights (pose_space_interpolation.cpp)
  // Frame (rotation, origin) of a full shape X.
  void frame_of(const Vertices& X, Mat3* R, Vec3* o) const;
  int pose_dim(bool joints) const;
  Eigen::VectorXd pose_vector(const Vertices& targets, const Mat3& R, const Vec3& o,
                              const Matrix3Array* joints) const;
  Eigen::VectorXd example_pose(const Vertices& X, bool with_joints) const;
  Mat3 example_face_rotation(const Vertices& X, int f) const;
  // Frame of the edit: from frame_transform, the handle targets, or a best fit.
  void edit_frame(const Vertices& targets, const Eigen::Matrix4d* frame_transform, Mat3* R,
                  Vec3* o) const;
  Eigen::VectorXd weights(const Vertices& targets, const Matrix3Array* rotations,
                          const Eigen::Matrix4d* frame_transform) const;
  // Q_l = exp(sum_k w_k omega_lk) per level dual edge, S_i = sum_k w_k S_ik per level face.
  void blend(const Eigen::VectorXd& w, Matrix3Array* Q, Matrix3Array* S) const;

  // ---- step 1 (pose_space_rotations.cpp)
  int solve_rotations(const RotationSolver& solver, const Matrix3Array& Q, const Matrix3Array* G,
                      const Matrix3Array& Z, const Matrix3Array* init, bool final,
                      Matrix3Array* R) const;

  // ---- multiresolution (pose_space_multires.cpp)
  // Harmonic transfer weights of the dense vertices of `afaces` (the solved parts' faces) and
  // the coarse vertex -> face lists.
  void build_transfer(const Faces& afaces);
  // Detail vectors d_v^k of every example (the rest when p = 0).
  void build_details(const std::vector<Vertices>& examples,
                     const std::vector<Matrix3Array>& example_rotations);
  void vertex_rotations(const Matrix3Array& Rf, Matrix3Array* Rv) const;
  Vec3 dense_position(int v, const Vertices& y, const Matrix3Array& Rv,
                      const Eigen::VectorXd& w) const;
  Vec3 base_position(int v, const Vertices& y) const;
  Vec3 offset(int v, const Matrix3Array& Rv, const Eigen::VectorXd& w) const;
  Vec3 row_target(int v, const Vec3& t, const Matrix3Array& Rv, const Eigen::VectorXd& w) const;
  PositionSolver::Row make_row(int v) const;

  // ---- the pipeline (pose_space_deformer.cpp)
  Vertices run(const std::vector<Vertices>& hp, const Matrix3Array* rotations,
               const Eigen::Matrix4d* frame_transform, const Vectors3* rotation_vectors) const;
};

}  // namespace matdeform
