// Private: a thin owner of a CHOLMOD factorisation. Keeps cholmod.h out of public headers.
#pragma once

#include <Eigen/SparseCore>
#include <memory>
#include <vector>

namespace matdeform {

class SparseCholesky {
 public:
  // How often the factor will be solved with. PerPose spends more time on the ordering (least
  // fill) and keeps the factor in its own layout for a multi-threaded substitution; Once keeps
  // CHOLMOD's factor and solve (cheapest to set up). Refactor is for a matrix whose values
  // change while its pattern does not (Newton's method): the constructor only analyses A's
  // pattern (least-fill ordering, symbolic factorisation), refactor() then factors new values.
  enum class Reuse { Once, PerPose, Refactor };

  // A: symmetric positive definite; only its lower triangle is read. Throws
  // std::invalid_argument (a message saying what to change) if A has a non-finite entry or is
  // not positive definite in double precision, std::runtime_error if CHOLMOD fails otherwise.
  // Refactor: only A's pattern is read (its lower triangle, compressed), nothing is factored yet.
  SparseCholesky(const Eigen::SparseMatrix<double>& A, Reuse reuse);
  ~SparseCholesky();
  SparseCholesky(const SparseCholesky&) = delete;
  SparseCholesky& operator=(const SparseCholesky&) = delete;

  // Solves A X = B for nrhs column-major columns of length rows(). Reuses its workspace between
  // calls, so the steady state allocates nothing. PerPose factors use up to num_threads()
  // threads.
  //
  // Ownership: a factor belongs to one solver object, which keeps it for its lifetime. The
  // factor's own mutable state (workspace, CHOLMOD's buffers, the substitution schedule that is
  // rebuilt when num_threads() changes) is guarded by an internal mutex, so solve() and
  // solve_permuted4() are safe from several threads: concurrent calls on one factor run one
  // after another. Buffers the owning solver keeps per call (right-hand sides it assembles in
  // place) are the solver's to guard.
  void solve(const double* B, double* X, int nrhs) const;
  int rows() const { return n_; }

  // Refactor factors only: the numeric factorisation of a matrix with the constructor's pattern;
  // `values` are its lower triangle's entries in that compressed column order (nonzeros() of
  // them). Returns false, leaving no usable factor until the next successful call, when the
  // matrix is not positive definite in double precision (or has a non-finite entry); throws
  // std::runtime_error if CHOLMOD fails otherwise. solve() needs a successful refactor().
  bool refactor(const double* values);
  long long nonzeros() const { return nnz_; }

  // PerPose factors only: the layout the substitution works in, for callers that assemble their
  // right-hand sides in it directly. Row i of the permuted system is row permutation()[i] of A;
  // solve_permuted4 solves in place on (rows(), 4) row-major data in that row order: up to three
  // right-hand sides in columns 0-2, column 3 is scratch.
  const std::vector<int>& permutation() const;
  void solve_permuted4(double* Y) const;
  // Threads the last PerPose solve ran its substitution on (1 = serial; 0 for Once factors).
  int substitution_threads() const;
  // Successful factorisations in this process so far (all instances), so that tests can prove
  // a solver does not refactor per solve.
  static long long factorizations();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int n_ = 0;
  long long nnz_ = 0;
};

}  // namespace matdeform
