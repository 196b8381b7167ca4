// Edge-based iterative material deformation: edge-length (stretch) and dihedral (bend) terms on
// mesh edges, pseudo gravity, direction-field anisotropy and live material change, solved by an
// E-M iteration whose matrix is constant (factored once). See docs/edge.md.
#pragma once

#include <memory>
#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

struct EdgeDeformerOptions {
  double stretch = 1e-4;  // lambda >= 0, weight of E_rho (edge vectors, Eq. 6)
  double bend = 1.0;      // mu > 0, weight of E_sigma (dihedral quantities, Eq. 6)
  // (E,) > 0 per mesh edge in mesh_edges() order, scaling both terms of the edge; empty: all 1.
  Eigen::VectorXd edge_weight;
  // (n,3) direction field f for the anisotropy kappa (Eq. 13-14); empty: isotropic.
  Vertices direction;
  // (k,) anchor id >= 0 of each constrained vertex (constructor order): the groups the first
  // step fits a rotation to and the rows of solve()'s rotation_vectors (ids need not all be
  // used). Empty: the constrained vertices joined by mesh edges, numbered by first appearance.
  std::vector<int> anchors;
};

struct EdgeSolveOptions {
  int iterations = 15;  // >= 1, at most this many E-M iterations
  // >= 0; stop once the estimated distance to the fixed point, move rho / (1 - rho) with move
  // the largest vertex move of an iteration and rho the slowest contraction of moves over the
  // last few iterations, is <= tol * bbox diagonal (0: run every iteration)
  double tol = 1e-5;
  double p_stretch = 1.0;                             // p_rho in [0,1] (Eq. 15)
  double p_bend = 1.0;                                // p_sigma in [0,1] (Eq. 15)
  Eigen::Vector3d gravity = Eigen::Vector3d::Zero();  // g, pointing the way things fall (Eq. 8)
  // omega in (0,1]: each iteration moves the free vertices by omega times the E-M step (1: the
  // paper). Same fixed points; below 1 it damps the two-cycles the plain iteration can fall into.
  double relaxation = 1.0;
};

// min over V: lambda sum_e w_e k_e |rho*_e - (v_i - v_j)|^2
//           + mu sum_e w_e k_e |sigma*_e - (a v_i + (1-a) v_j - b v_l - (1-b) v_m)|^2
//           - sum_i <g, v_i>,   constrained vertices fixed,
// where each iteration takes rho*, sigma* from the previous iterate (rest vectors carried by the
// edge's rest -> current frame), so every iteration solves the same sparse SPD system. When an
// anchor (constrained vertices joined by edges) turns by more than 15 degrees from the start,
// the first iteration also turns those targets by the anchors' fitted rotations, spread over
// the mesh by the same system (docs/edge.md, "The first step when anchors turn"); given
// rotation vectors replace the fitted rotations (docs/edge.md, "Twists past half a turn").
//
// Defined behaviour:
//  - boundary edges, non-manifold edges (3+ faces), edges whose two faces have the same third
//    vertex and edges whose rest faces have no usable normal get no sigma term;
//  - vertices in a connected part (through edges) without a constrained vertex, and vertices in
//    no face, are passive: solve() returns their rest positions bit for bit (whatever `initial`
//    holds);
//  - a system the energy does not determine (e.g. stretch = 0 on a flat part with fewer than
//    three non-collinear constrained vertices) throws std::invalid_argument.
// Factors once in the constructor; solve() only assembles right-hand sides and substitutes.
class EdgeDeformer {
 public:
  // vertices (n,3), faces (m,3), constrained: unique vertex indices (non-empty).
  EdgeDeformer(const Vertices& vertices, const Faces& faces, const std::vector<int>& constrained,
               const EdgeDeformerOptions& options = {});
  ~EdgeDeformer();
  EdgeDeformer(const EdgeDeformer&) = delete;
  EdgeDeformer& operator=(const EdgeDeformer&) = delete;

  // constrained_positions (|constrained|,3) in the constructor's order; initial: (n,3) warm
  // start or nullptr (rest). Returns the last iterate (n,3). Concurrent calls take turns.
  // rotation_vectors: (num_anchors,3) axis * angle (radians, any length) of each anchor's turn
  // from rest, or nullptr. With them the start is the rest mesh (initial must be nullptr) and
  // the first step carries these vectors instead of the fitted rotations, so turns past half a
  // turn survive and the result depends on the arguments only. Row a must be a log of the
  // rotation fitted to anchor a (rest -> constrained_positions) within
  // kRotationVectorTolerance wherever that fit exists (3+ points not in a line).
  Vertices solve(const Vertices& constrained_positions, const EdgeSolveOptions& options,
                 const Vertices* initial = nullptr, const Vectors3* rotation_vectors = nullptr);

  int last_iterations() const { return last_iterations_; }
  double last_move() const { return last_move_; }  // largest move of the last iteration / diag
  // The last solve's estimated distance to the fixed point / diag (infinity while the moves do
  // not contract), and whether it met tol.
  double last_error() const { return last_error_; }
  bool last_converged() const { return last_converged_; }
  int factorizations() const { return factorizations_; }  // done by this object
  // Sparse factorisations done in this process by any solver, so that tests can prove that
  // solve() never refactors.
  static long long process_factorizations();

  // Per mesh edge, in mesh_edges() order:
  const IndexPairs& edges() const { return edges_; }        // (E,2) a < b
  const IndexPairs& opposite() const { return opposite_; }  // (E,2) l, m; -1 without sigma
  // (E,2) alpha (weight of edges(e,0)) and beta (weight of opposite(e,0)); NaN without sigma.
  const RowMatrix& bend_coefficients() const { return coefficients_; }
  const Eigen::VectorXd& anisotropy() const { return kappa_; }  // (E,) kappa in [0,1]
  int num_vertices() const { return n_; }
  int num_free() const;
  int num_anchors() const;
  const std::vector<int>& anchors() const;  // (k,) anchor id of each constrained vertex
  double diagonal() const { return diag_; }

 private:
  void check_rotation_vectors(const Vertices& constrained_positions, const Vertices* initial,
                              const Vectors3& v) const;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int n_ = 0;
  IndexPairs edges_, opposite_;
  RowMatrix coefficients_;
  Eigen::VectorXd kappa_;
  double diag_ = 0.0;
  int factorizations_ = 0;
  int last_iterations_ = 0;
  double last_move_ = 0.0;
  double last_error_ = 0.0;
  bool last_converged_ = false;
};

}  // namespace matdeform
