// Private: a thin owner of a CHOLMOD factorisation. Keeps cholmod.h out of public headers.
#pragma once

#include <Eigen/SparseCore>
#include <memory>

namespace matdeform {

class SparseCholesky {
 public:
  // A: symmetric positive definite; only its lower triangle is read. Throws std::runtime_error
  // if CHOLMOD finds it not positive definite. minimize_fill spends more time on the ordering
  // to make every later solve cheaper; use it for factors that are solved per pose.
  SparseCholesky(const Eigen::SparseMatrix<double>& A, bool minimize_fill);
  ~SparseCholesky();
  SparseCholesky(const SparseCholesky&) = delete;
  SparseCholesky& operator=(const SparseCholesky&) = delete;

  // Solves A X = B for nrhs column-major columns of length rows(). Reuses CHOLMOD's workspace
  // between calls, so the steady state allocates nothing. Not thread-safe.
  void solve(const double* B, double* X, int nrhs) const;
  int rows() const { return n_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int n_ = 0;
};

}  // namespace matdeform
