// Shape-preserving deformation with pyramid coordinates (Sheffer & Kraevoy): every vertex is
// described by angles and lengths relative to its one-ring, and a pose given by a few control
// vertices is found by re-placing the other vertices from their descriptions until they settle.
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

// How a vertex is described and placed (docs/pyramid.md).
enum PyramidKind : signed char {
  kPyramidInterior = 0,  // closed fan: the paper's description (Eq. 1-2)
  kPyramidBoundary = 1,  // open fan, closed by the edge between its two boundary neighbours
  kPyramidFollower = 2,  // non-manifold or degenerate fan: follows the best-fit similarity of
                         // itself and its neighbours (rest -> current)
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

enum class PyramidMethod {
  GaussSeidel,  // graph-coloured Gauss-Seidel sweeps (the paper's iteration, in parallel)
  Jacobi,       // Jacobi sweeps
};

struct PyramidSolveOptions {
  int max_iterations = 10000;  // >= 0: the budget of sweeps
  double tol = 1e-6;           // stop once the largest move < tol x the rest diagonal
  bool stretch = true;         // scale w_i by |v' - v'_i| / l_i (paper, Sec. 2)
  bool push = true;            // step 2: control vertices push their neighbours
  PyramidMethod method = PyramidMethod::GaussSeidel;
  int anderson = 20;  // Anderson acceleration window over the sweeps (0: plain sweeps)
  // (n,3) start (controls are replaced); nullptr: the rest mesh moved by the controls' best-fit
  // similarity
  const Vertices* initial = nullptr;
  bool record_moves = false;  // keep every sweep's move in last_moves()
  // Called on the calling thread after a sweep with (sweeps so far, that sweep's largest move as
  // a fraction of the rest diagonal), at most every progress_seconds (0: after every sweep).
  // An exception it throws ends deform() and propagates.
  std::function<void(int, double)> progress;
  double progress_seconds = 0.1;
};

class PyramidDeformer {
 public:
  // vertices (n,3), faces (m,3), control: k >= 1 unique vertex indices in [0, n).
  // Precomputes the description, the colouring and the control adjacency of step 2.
  PyramidDeformer(const Vertices& vertices, const Faces& faces, const std::vector<int>& control);
  ~PyramidDeformer();
  PyramidDeformer(const PyramidDeformer&) = delete;
  PyramidDeformer& operator=(const PyramidDeformer&) = delete;

  // control_positions (k,3) in the order of `control`. Returns (n,3). Not thread-safe (it records
  // the iteration statistics below).
  Vertices deform(const Vertices& control_positions, const PyramidSolveOptions& options);

  // Every vertex (controls too) placed once from its neighbours' positions in X (n,3) by
  // Eq. 1-2, without steps 2-3: reconstruct(rest, false) gives back the rest mesh.
  Vertices reconstruct(const Vertices& X, bool stretch) const;

  const PyramidCoordinates& coordinates() const;
  const std::vector<int>& control() const { return control_; }
  int num_vertices() const;
  int num_colors() const;
  double diagonal() const { return diag_; }
  // Vertices that never move: isolated, or in a part of the mesh that no control reaches.
  int num_passive() const;

  int last_iterations() const { return last_iterations_; }  // sweeps
  double last_move() const { return last_move_; }           // fraction of the rest diagonal
  const std::vector<double>& last_moves() const { return last_moves_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::vector<int> control_;
  double diag_ = 0;
  int last_iterations_ = 0;
  double last_move_ = 0;
  std::vector<double> last_moves_;
};

}  // namespace matdeform
