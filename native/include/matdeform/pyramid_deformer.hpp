// Shape-preserving deformation with pyramid coordinates (Sheffer & Kraevoy): every vertex is
// described by angles and lengths relative to its one-ring (its "pyramid"), and a pose given by a
// few control vertices is the configuration in which every pyramid is, in least squares, a
// rotated and scaled copy of its description. Solved by Newton's method on all free vertices at
// once (docs/pyramid.md).
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

// How the paper's Eq. 1-2 treat a vertex (reconstruct(), the description's own check).
enum PyramidKind : signed char {
  kPyramidInterior = 0,  // closed fan: the paper's description (Eq. 1-2)
  kPyramidBoundary = 1,  // open fan, closed by the edge between its two boundary neighbours
  kPyramidFollower = 2,  // non-manifold or degenerate fan: reconstruct() places it by the
                         // best-fit similarity of itself and its neighbours (rest -> current)
  kPyramidIsolated = 3,  // in no face: never moves
};

// The per-vertex description at rest. Per-neighbour arrays are CSR: vertex v owns slots
// [offsets[v], offsets[v+1]), in the cyclic order of vertex_fans(). Angles in radians, lengths in
// the mesh's unit. Followers and isolated vertices have normal 0, and their slots hold only the
// neighbour ids (angles, lengths and weights 0).
struct PyramidCoordinates {
  std::vector<int> offsets;    // n + 1
  std::vector<int> neighbors;  // v_i
  // alpha_i: signed angle at v' from v'_i to v'_{i+1} about n, in (-pi, pi]; the last slot wraps
  // to the first neighbour (for an open fan: across the closing edge).
  std::vector<double> alpha;
  std::vector<double> beta;       // beta_i: angle between n and the edge vector v - v_i, in [0, pi]
  std::vector<double> length;     // l_i = |v' - v'_i|
  std::vector<double> weight;     // mean value weights from alpha_i and l_i, normalised to sum 1
  Vertices normal;                // (n,3) unit n: the neighbour polygon's vector area direction
  Eigen::VectorXd offset;         // (n,) d = -mean_i n . v_i: P passes through the neighbours' mean
  Eigen::VectorXd height;         // (n,) n . v + d, the height of v above P
  std::vector<signed char> kind;  // PyramidKind
};

// Throws std::invalid_argument on invalid meshes (validate_mesh()).
PyramidCoordinates pyramid_coordinates(const Vertices& vertices, const Faces& faces);

struct PyramidSolveOptions {
  // >= 0: Newton iterations (each one factorisation at most, or two).
  int max_iterations = 100;
  // The most L-BFGS iterations before them (docs/pyramid.md); < 0: 50 per Newton iteration of
  // max_iterations, at most 1000. 0 goes straight to Newton's method.
  int max_lbfgs_iterations = -1;
  // Converged once a full Newton step (exact Hessian, no damping) moves no vertex by more than
  // tol x the rest diagonal; that step is applied, which leaves the result about tol^2 x diagonal
  // from the minimum (quadratic convergence, docs/pyramid.md). >= 0.
  double tol = 1e-6;
  // How strongly each pyramid keeps its rest size, >= 0 (kappa): 0 keeps only its shape up to
  // scale (what the description itself fixes); larger values approach rigid pyramids.
  double scale_weight = 0.003;
  // (n,3) start (control rows are replaced); nullptr: the start built from the controls alone
  // (harmonic blend of the control clusters' similarities, docs/pyramid.md).
  const Vertices* initial = nullptr;
  // (k,3) or nullptr: one rotation vector (axis * angle, radians, any length) per control, in
  // the order of `control`, e.g. its anchor's unwrapped rotation. The start then blends the
  // control clusters' rotations as these logs, so it carries turns past half a turn (a twist
  // of 540 degrees starts twisted, not at 180). Each control's vector of a cluster that carries a
  // rotation must be a log of the rotation fitted to that cluster (within
  // kRotationVectorTolerance); other controls' vectors are not used. Not used with `initial`.
  const Vectors3* rotation_vectors = nullptr;
  // Called on the calling thread after an iteration with (Newton iterations so far, 0 in the
  // L-BFGS phase; that iteration's step as a fraction of the rest diagonal), at most every
  // progress_seconds (0: after every one) and after the converged one. An exception it throws ends
  // deform() and propagates.
  std::function<void(int, double)> progress;
  double progress_seconds = 0.1;
};

class PyramidDeformer {
 public:
  // vertices (n,3), faces (m,3), control: k >= 1 unique vertex indices in [0, n).
  // Precomputes the description, the pyramids' rest shapes, the Hessian's sparsity pattern and
  // its symbolic factorisation, and the start's harmonic factorisations.
  PyramidDeformer(const Vertices& vertices, const Faces& faces, const std::vector<int>& control);
  ~PyramidDeformer();
  PyramidDeformer(const PyramidDeformer&) = delete;
  PyramidDeformer& operator=(const PyramidDeformer&) = delete;

  // control_positions (k,3) in the order of `control`. Returns (n,3): vertices that no control
  // reaches through edges are exactly at rest. Thread-safe: concurrent calls on one deformer take
  // turns (they share its workspace and the statistics below, which a concurrent call may
  // overwrite before they are read).
  // Throws std::invalid_argument for bad input (also positions beyond the core's size range,
  // "rescale the mesh") and std::runtime_error if the energy stops being finite.
  Vertices deform(const Vertices& control_positions, const PyramidSolveOptions& options);

  // The start deform() uses without `initial` (n,3), for inspection and tests.
  Vertices start(const Vertices& control_positions,
                 const Vectors3* rotation_vectors = nullptr) const;

  // Every vertex (controls too) placed once from its neighbours' positions in X (n,3) by the
  // paper's Eq. 1-2: reconstruct(rest, false) gives back the rest mesh. stretch: the paper's
  // weight scaling by |v' - v'_i| / l_i.
  Vertices reconstruct(const Vertices& X, bool stretch) const;

  // The energy sum_v min_{s,R} |pyramid_v(X) - s R pyramid_v(rest)|^2 + kappa s0_v (s - 1)^2 and
  // its gradient over all vertices (n,3) (zero rows for vertices in no pyramid), for tests.
  double energy(const Vertices& X, double scale_weight, Vertices* gradient) const;

  const PyramidCoordinates& coordinates() const;
  const std::vector<int>& control() const { return control_; }
  int num_vertices() const;
  int num_free() const;
  double diagonal() const { return diag_; }
  // Vertices that never move: isolated, or in a part of the mesh that no control reaches.
  int num_passive() const;

  int last_iterations() const { return last_iterations_; }  // Newton iterations
  // The last iteration's step (largest vertex move) as a fraction of the rest diagonal (NaN
  // after 0 iterations), and every iteration's.
  double last_step() const { return last_step_; }
  const std::vector<double>& last_steps() const { return last_steps_; }
  bool last_converged() const { return last_converged_; }
  double last_energy() const { return last_energy_; }
  int last_factorizations() const { return last_factorizations_; }
  // L-BFGS iterations before the Newton iterations (preconditioned by the Hessian's constant
  // part; docs/pyramid.md).
  int last_lbfgs_iterations() const { return last_lbfgs_iterations_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::vector<int> control_;
  double diag_ = 0;
  int last_iterations_ = 0;
  double last_step_ = 0;
  std::vector<double> last_steps_;
  bool last_converged_ = false;
  double last_energy_ = 0;
  int last_factorizations_ = 0;
  int last_lbfgs_iterations_ = 0;
};

}  // namespace matdeform
