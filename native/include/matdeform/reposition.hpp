// Poisson vertex repositioning under shear stiffness (Popa et al. 2006, Eq. 3-4).
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "matdeform/types.hpp"

namespace matdeform {

// Minimises sum_i psi_i |Vt_i V_i^-1 - T_i|_F^2 over new positions, with Vt_i, V_i the
// deformed/rest frames including each face's fourth vertex (frames.hpp).
//
// The fourth vertices appear only in their own face, so their block of the normal equations is
// diagonal. We eliminate them exactly (Schur complement, face by face) and factor an n x n
// system instead of (n+m) x (n+m); the solution for the original vertices is identical.
//
// Fixed vertices are removed from the unknowns. Defined behaviour:
//  - degenerate faces (twice-area below 1e-12 of the longest edge squared) drop out of Eq. 3;
//  - vertices in no usable face keep their rest position (or their fixed position);
//  - a connected component with no fixed vertex is solved up to translation and then shifted so
//    that the mean of its vertices equals their rest mean.
// Factors once in the constructor; solve() only assembles the right-hand side and substitutes.
// solve() may be called from several threads: calls are serialised (one workspace).
class PoissonRepositioner {
 public:
  // vertices (n,3), faces (m,3) (validate_mesh), shear (m,) > 0 with max/min at most
  // kMaxStiffnessRatio, fixed: vertex indices (any order, unique).
  PoissonRepositioner(const Vertices& vertices, const Faces& faces, const Eigen::VectorXd& shear,
                      const std::vector<int>& fixed);
  ~PoissonRepositioner();
  PoissonRepositioner(const PoissonRepositioner&) = delete;
  PoissonRepositioner& operator=(const PoissonRepositioner&) = delete;

  // targets: m per-face 3x3 transforms T_i. fixed_positions: (|fixed|,3) in the order given to
  // the constructor. Writes (n,3) positions into out.
  void solve(const Matrix3Array& targets, const Vertices& fixed_positions, Vertices* out) const;

  // The same with the targets produced block by block: targets(group_begin, group_end, T) writes
  // the transforms of face groups [group_begin, group_end) in the grouped layout (types.hpp) to
  // T[0 ..], padding lanes included (any finite value), possibly from several threads at once
  // (disjoint blocks). Consuming each block while it is in cache saves storing all m transforms.
  using TargetBlocks = std::function<void(int group_begin, int group_end, double* out)>;
  void solve(const TargetBlocks& targets, const Vertices& fixed_positions, Vertices* out) const;

  const std::vector<int>& fixed() const { return fixed_; }
  int num_unknowns() const;
  // Threads the last solve()'s back-substitution ran on (1 = serial, 0 before the first solve
  // or with nothing to solve for). For tests: the parallel path is only taken on large meshes.
  int substitution_threads() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::vector<int> fixed_;
};

}  // namespace matdeform
