// PyramidDeformer: Newton's method on the pyramids' least-squares energy (pyramid_energy.cpp)
// over all free vertices at once. The Hessian's sparsity pattern (two vertices couple when they
// share a pyramid) never changes, so it is analysed once and each iteration only refactors it.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>

#include "matdeform/mesh.hpp"
#include "matdeform/threads.hpp"
#include "pyramid_internal.hpp"
#include "task_pool.hpp"

namespace matdeform {

using pyramid::Fit;
using pyramid::kTerms;
using pyramid::Mat3;
using pyramid::Vec3;

namespace {
int chunks() { return 16 * num_threads(); }
constexpr int kMinChunk = 64;
// A Newton step of at most this fraction of the diagonal switches from the positive
// semidefinite Hessian to the exact one (near the minimum, where the exact one is positive
// definite and converges quadratically).
constexpr double kExactBelow = 1e-2;
constexpr double kDampingStart = 1e-6;
// Conjugate-gradient iterations with a stale factorisation before refactoring: a 1-RHS solve
// and a product cost ~1/15 of a refactorisation on the cat (docs/pyramid.md, solver).
constexpr int kReuseMost = 20;
// Inexact Newton: while the last step was above kLooseAbove x tol the Newton system is solved
// to kLooseEta relative residual (the step's direction, not its last digits, matters there);
// near the stopping rule to kTightEta.
constexpr double kLooseEta = 1e-3;
constexpr double kLooseAbove = 100;
constexpr double kTightEta = 1e-8;
constexpr double kDampingMost = 1e12;
// L-BFGS before Newton's method: until a step moves no vertex by more than kQuasiUntil of the
// diagonal, times (kQuasiFree / free vertices)^1.5 above kQuasiFree free vertices (the finer the
// mesh, the smaller L-BFGS's steps at the same distance from the minimum, and Newton's method
// handed a point too far away takes steps of 1e-2 of the diagonal and 7-12 iterations), or at
// most kQuasiMost iterations; kHistory correction pairs. Measured on the cat (docs/pyramid.md,
// solver): 5k and 14k faces are fastest at 1e-4 (2e-4 sends 14k pose 4 wandering, 1e-5 costs
// more L-BFGS iterations than it saves); 58k (22812 free) at 1e-5-2e-5, with 2.6e-5 already
// wandering on two poses: the exponent 1.5 puts it at 1.3e-5.
constexpr double kQuasiUntil = 1e-4;
constexpr double kQuasiFree = 6000;
constexpr int kQuasiMost = 1000;
// ... and at most this many per Newton iteration of the call's budget, so that a live update
// with a budget of one iteration stays within a few factorisations' time.
constexpr int kQuasiPerNewton = 50;
constexpr int kHistory = 8;
// Inverse iterations for a saddle's direction of negative curvature (escape_saddle), tried
// when the exact Hessian is not positive definite right after a step of at most kSaddleBelow
// of the diagonal (near a stationary point; a round-off-driven escape grows from ~1e-5).
constexpr int kInverseIterations = 20;
constexpr double kSaddleBelow = 1e-4;
}  // namespace

struct PyramidDeformer::Impl {
  pyramid::Placement placement;
  pyramid::Pyramids pyr;     // pyramids with at least one free member
  std::vector<int> sys;      // vertex -> system index (free vertices), or -1
  std::vector<char> moving;  // free, or undetermined (in no pyramid): placed by the start
  std::vector<int> free;     // system index -> vertex
  int num_passive = 0;
  // Free vertex J's pyramids: (pyramid, member index) for m in [mem_off[J], mem_off[J+1]).
  std::vector<int> mem_off, mem_pyr, mem_local;
  // Per membership m, per member b of its pyramid: where block (b, J) goes in column J's blocks:
  // k >= 0 the k-th block below the diagonal, -1 the diagonal block, -2 nowhere (b is not free
  // or comes before J). slot[slot_off[m] + b].
  std::vector<int> slot_off, slot;
  std::vector<int> colptr;   // (3 nf + 1) lower triangle, compressed columns
  std::vector<double> damp;  // per free vertex: the diagonal of sum 2 C, the damping's scale
  std::unique_ptr<SparseCholesky> chol;
  // The Hessian's constant part, sum over pyramids of 2 (I - 11^T/M), on the free vertices: one
  // scalar matrix for all three coordinates (the energy's Hessian for fits held fixed). Null
  // when it is not positive definite.
  std::unique_ptr<SparseCholesky> fixed;
  std::unique_ptr<pyramid::Start> start;
  // deform() holds `busy` for its whole run: the work buffers below, the factor and the last
  // call's statistics are shared by every call on this deformer (docs/core.md: one deformer may
  // be called from several threads).
  std::mutex busy;
  // Work buffers.
  std::vector<Fit> fits;
  std::vector<int> term_off;  // per pyramid: kTerms * 3M doubles of u at terms[term_off[c]]
  std::vector<double> terms, coefs, values;
  std::vector<char> clamped;

  Impl(const Vertices& vertices, const Faces& faces, const std::vector<int>& control);

  int count() const { return pyr.count(); }
  // Fits every pyramid to X; returns the energy (sum in pyramid order: no dependence on threads).
  double fit_all(const double* X, double kappa, bool keep) {
    return fit_all(X, kappa, keep ? &fits : nullptr);
  }
  // The same, keeping the fits in *keep (if not null).
  double fit_all(const double* X, double kappa, std::vector<Fit>* keep);
  std::vector<Fit> trial_fits;   // a line search's fits, swapped into `fits` when accepted
  std::vector<double> energies;  // fit_all's per-pyramid energies
  std::vector<Eigen::VectorXd> pairs_s, pairs_y;  // L-BFGS's correction pairs (kHistory, 3 nf)
  std::vector<Eigen::VectorXd> pairs_cy;          // C^-1 y of each pair (kHistory, 3 nf)
  Eigen::VectorXd cg, cg_new;                     // C^-1 g at the iterate and at the trial
  void gradient(const double* X, Eigen::VectorXd* g) const;
  // Every pyramid's Hessian terms at the current fits; returns whether the positive
  // semidefinite version changed any (exact = false).
  bool terms_all(double kappa, bool exact);
  // The matrix H + mu diag(damp) from the terms into `values` (compressed lower triangle).
  void assemble(double mu);
  // out = (H + mu diag(damp)) v for v, out of length 3 nf, without the matrix.
  void product(const double* v, double mu, double* out);
  std::vector<double> hv;  // per pyramid 3M: its part of a product
  // out = C^-1 v for v, out of length 3 nf (member-major, like the Newton system).
  void fixed_solve(const Eigen::VectorXd& v, Eigen::VectorXd* out);
  Eigen::VectorXd cols;  // (nf, 3) column-major scratch of fixed_solve
};

PyramidDeformer::Impl::Impl(const Vertices& vertices, const Faces& faces,
                            const std::vector<int>& control)
    : placement(vertices, faces) {
  const int n = static_cast<int>(vertices.rows());
  const auto& off = placement.coords.offsets;
  const auto& nb = placement.coords.neighbors;
  std::vector<char> is_control(static_cast<size_t>(n), 0);
  for (int c : control) is_control[static_cast<size_t>(c)] = 1;
  // Free vertices: reached from a control through edges, not controls, not isolated. The rest
  // (parts no control reaches) stays at rest.
  std::vector<char> reached(is_control.begin(), is_control.end());
  std::vector<int> queue(control.begin(), control.end());
  for (size_t q = 0; q < queue.size(); ++q) {
    const int v = queue[q];
    for (int s = off[v]; s < off[v + 1]; ++s) {
      if (!reached[static_cast<size_t>(nb[s])]) {
        reached[static_cast<size_t>(nb[s])] = 1;
        queue.push_back(nb[s]);
      }
    }
  }
  // Moving vertices: reached, not controls, in a face. The start places all of them.
  moving.assign(static_cast<size_t>(n), 0);
  for (int v = 0; v < n; ++v) {
    if (is_control[static_cast<size_t>(v)]) continue;
    if (reached[static_cast<size_t>(v)] && off[v + 1] > off[v]) {
      moving[static_cast<size_t>(v)] = 1;
    } else {
      ++num_passive;
    }
  }
  // Pyramids with a moving member: the apex moves, or a neighbour of a moving vertex.
  std::vector<char> keep(static_cast<size_t>(n), 0);
  for (int v = 0; v < n; ++v) {
    if (!moving[static_cast<size_t>(v)]) continue;
    keep[static_cast<size_t>(v)] = 1;
    for (int s = off[v]; s < off[v + 1]; ++s) keep[static_cast<size_t>(nb[s])] = 1;
  }
  pyr = pyramid::make_pyramids(vertices, placement.coords, keep);
  // The unknowns of Newton's method: moving vertices in a pyramid. One in none (all its fans
  // degenerate: its neighbours on a line) has no shape to keep and stays at its start.
  std::vector<char> in_pyramid(static_cast<size_t>(n), 0);
  for (int k : pyr.members) in_pyramid[static_cast<size_t>(k)] = 1;
  sys.assign(static_cast<size_t>(n), -1);
  for (int v = 0; v < n; ++v) {
    if (moving[static_cast<size_t>(v)] && in_pyramid[static_cast<size_t>(v)]) {
      sys[static_cast<size_t>(v)] = static_cast<int>(free.size());
      free.push_back(v);
    }
  }
  const int nf = static_cast<int>(free.size());
  const int np = pyr.count();
  // Memberships of the free vertices.
  mem_off.assign(static_cast<size_t>(nf) + 1, 0);
  for (int c = 0; c < np; ++c) {
    for (int i = pyr.offsets[c]; i < pyr.offsets[c + 1]; ++i) {
      const int J = sys[static_cast<size_t>(pyr.members[i])];
      if (J >= 0) ++mem_off[static_cast<size_t>(J) + 1];
    }
  }
  for (int J = 0; J < nf; ++J) mem_off[J + 1] += mem_off[J];
  mem_pyr.resize(static_cast<size_t>(mem_off[nf]));
  mem_local.resize(mem_pyr.size());
  {
    std::vector<int> fill(mem_off.begin(), mem_off.end() - 1);
    for (int c = 0; c < np; ++c) {
      for (int i = pyr.offsets[c]; i < pyr.offsets[c + 1]; ++i) {
        const int J = sys[static_cast<size_t>(pyr.members[i])];
        if (J < 0) continue;
        const int m = fill[static_cast<size_t>(J)]++;
        mem_pyr[m] = c;
        mem_local[m] = i - pyr.offsets[c];
      }
    }
  }
  // Block pattern: column J holds the rows of every free vertex after J that shares a pyramid.
  slot_off.assign(mem_pyr.size() + 1, 0);
  for (size_t m = 0; m < mem_pyr.size(); ++m) {
    const int c = mem_pyr[m];
    slot_off[m + 1] = slot_off[m] + (pyr.offsets[c + 1] - pyr.offsets[c]);
  }
  slot.assign(static_cast<size_t>(slot_off.back()), -2);
  colptr.assign(3 * static_cast<size_t>(nf) + 1, 0);
  damp.assign(static_cast<size_t>(nf), 0.0);
  std::vector<int> rows;
  for (int J = 0; J < nf; ++J) {
    rows.clear();
    for (int m = mem_off[J]; m < mem_off[J + 1]; ++m) {
      const int c = mem_pyr[m];
      const int M = pyr.offsets[c + 1] - pyr.offsets[c];
      damp[static_cast<size_t>(J)] += 2.0 * (1.0 - 1.0 / M);
      for (int i = pyr.offsets[c]; i < pyr.offsets[c + 1]; ++i) {
        const int I = sys[static_cast<size_t>(pyr.members[i])];
        if (I > J) rows.push_back(I);
      }
    }
    std::sort(rows.begin(), rows.end());
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
    for (int m = mem_off[J]; m < mem_off[J + 1]; ++m) {
      const int c = mem_pyr[m];
      for (int i = pyr.offsets[c]; i < pyr.offsets[c + 1]; ++i) {
        const int I = sys[static_cast<size_t>(pyr.members[i])];
        int k = -2;
        if (I == J) {
          k = -1;
        } else if (I > J) {
          k = static_cast<int>(std::lower_bound(rows.begin(), rows.end(), I) - rows.begin());
        }
        slot[static_cast<size_t>(slot_off[m] + i - pyr.offsets[c])] = k;
      }
    }
    const int nb_blocks = static_cast<int>(rows.size());
    for (int cc = 0; cc < 3; ++cc) {
      colptr[3 * static_cast<size_t>(J) + cc + 1] =
          colptr[3 * static_cast<size_t>(J) + cc] + (3 - cc) + 3 * nb_blocks;
    }
  }
  if (nf > 0) {
    // The pattern for the symbolic analysis (row indices from the same walk).
    Eigen::SparseMatrix<double> A(3 * nf, 3 * nf);
    A.resizeNonZeros(colptr.back());
    std::copy(colptr.begin(), colptr.end(), A.outerIndexPtr());
    int* ri = A.innerIndexPtr();
    for (int J = 0; J < nf; ++J) {
      rows.clear();
      for (int m = mem_off[J]; m < mem_off[J + 1]; ++m) {
        const int c = mem_pyr[m];
        for (int i = pyr.offsets[c]; i < pyr.offsets[c + 1]; ++i) {
          const int I = sys[static_cast<size_t>(pyr.members[i])];
          if (I > J) rows.push_back(I);
        }
      }
      std::sort(rows.begin(), rows.end());
      rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
      for (int cc = 0; cc < 3; ++cc) {
        int at = colptr[3 * static_cast<size_t>(J) + cc];
        for (int r = cc; r < 3; ++r) ri[at++] = 3 * J + r;
        for (int I : rows)
          for (int r = 0; r < 3; ++r) ri[at++] = 3 * I + r;
      }
    }
    std::fill(A.valuePtr(), A.valuePtr() + colptr.back(), 0.0);
    chol = std::make_unique<SparseCholesky>(A, SparseCholesky::Reuse::Refactor);
    std::vector<Eigen::Triplet<double>> tri;
    for (int J = 0; J < nf; ++J) {
      for (int m = mem_off[J]; m < mem_off[J + 1]; ++m) {
        const int c = mem_pyr[m];
        const int M = pyr.offsets[c + 1] - pyr.offsets[c];
        for (int i = pyr.offsets[c]; i < pyr.offsets[c + 1]; ++i) {
          const int I = sys[static_cast<size_t>(pyr.members[i])];
          if (I < J) continue;
          tri.emplace_back(I, J, 2.0 * ((I == J ? 1.0 : 0.0) - 1.0 / M));
        }
      }
    }
    Eigen::SparseMatrix<double> C(nf, nf);
    C.setFromTriplets(tri.begin(), tri.end());
    try {
      fixed = std::make_unique<SparseCholesky>(C, SparseCholesky::Reuse::PerPose);
    } catch (const std::invalid_argument&) {
      fixed.reset();  // Newton's method alone
    }
    cols.resize(3 * nf);
    pairs_s.assign(kHistory, Eigen::VectorXd(3 * nf));
    pairs_y = pairs_s;
    pairs_cy = pairs_s;
  }
  values.assign(static_cast<size_t>(colptr.back()), 0.0);
  fits.resize(static_cast<size_t>(np));
  term_off.assign(static_cast<size_t>(np) + 1, 0);
  for (int c = 0; c < np; ++c) {
    term_off[c + 1] = term_off[c] + kTerms * 3 * (pyr.offsets[c + 1] - pyr.offsets[c]);
  }
  terms.assign(static_cast<size_t>(term_off.back()), 0.0);
  coefs.assign(kTerms * static_cast<size_t>(np), 0.0);
  clamped.assign(static_cast<size_t>(np), 0);
  hv.assign(static_cast<size_t>(term_off.back() / kTerms), 0.0);
  start = std::make_unique<pyramid::Start>(vertices, faces, control, moving);
}

double PyramidDeformer::Impl::fit_all(const double* X, double kappa, std::vector<Fit>* keep) {
  const int np = count();
  std::vector<double>& e = energies;
  e.resize(static_cast<size_t>(np));
  if (keep) keep->resize(static_cast<size_t>(np));
  parallel_ranges(np, kMinChunk, chunks(), [&](int b, int end) {
    Fit f[4];
    for (int c = b; c < end; c += 4) {
      const int count = std::min(4, end - c);
      pyramid::fit_pyramids(pyr, c, count, X, kappa, f);
      for (int i = 0; i < count; ++i) {
        e[static_cast<size_t>(c + i)] = f[i].energy;
        if (keep) (*keep)[static_cast<size_t>(c + i)] = f[i];
      }
    }
  });
  double E = 0;
  for (double x : e) E += x;
  return E;
}

void PyramidDeformer::Impl::gradient(const double* X, Eigen::VectorXd* g) const {
  const int nf = static_cast<int>(free.size());
  g->resize(3 * nf);
  parallel_ranges(nf, kMinChunk, chunks(), [&](int b, int e) {
    for (int J = b; J < e; ++J) {
      Vec3 s = Vec3::Zero();
      const Vec3 x = pyramid::row(X, free[static_cast<size_t>(J)]);
      for (int m = mem_off[J]; m < mem_off[J + 1]; ++m) {
        const int c = mem_pyr[m];
        const Fit& f = fits[static_cast<size_t>(c)];
        const double* p = pyr.rest.data() + 3 * static_cast<size_t>(pyr.offsets[c] + mem_local[m]);
        s += 2.0 * (x - f.centre - f.scale * (f.R * Vec3(p[0], p[1], p[2])));
      }
      g->segment<3>(3 * J) = s;
    }
  });
}

bool PyramidDeformer::Impl::terms_all(double kappa, bool exact) {
  const int np = count();
  parallel_ranges(np, kMinChunk, chunks(), [&](int b, int e) {
    for (int c = b; c < e; ++c) {
      clamped[static_cast<size_t>(c)] = pyramid::hessian_terms(
          pyr, c, fits[static_cast<size_t>(c)], kappa, exact, terms.data() + term_off[c],
          coefs.data() + kTerms * static_cast<size_t>(c));
    }
  });
  bool any = false;
  for (char x : clamped) any |= x != 0;
  return any;
}

void PyramidDeformer::Impl::assemble(double mu) {
  const int nf = static_cast<int>(free.size());
  parallel_ranges(nf, kMinChunk / 4, chunks(), [&](int b, int e) {
    for (int J = b; J < e; ++J) {
      double* col[3];
      for (int cc = 0; cc < 3; ++cc) {
        const int b0 = colptr[3 * static_cast<size_t>(J) + cc];
        const int e0 = colptr[3 * static_cast<size_t>(J) + cc + 1];
        std::fill(values.begin() + b0, values.begin() + e0, 0.0);
        col[cc] = values.data() + b0;
      }
      for (int m = mem_off[J]; m < mem_off[J + 1]; ++m) {
        const int c = mem_pyr[m];
        const int M = pyr.offsets[c + 1] - pyr.offsets[c];
        const int a = mem_local[m];
        const int len = 3 * M;
        const double* u = terms.data() + term_off[c];
        const double* w = coefs.data() + kTerms * static_cast<size_t>(c);
        // coef_q u_q[a]: the column side of every block of this membership.
        double ua[kTerms][3];
        for (int q = 0; q < kTerms; ++q)
          for (int cc = 0; cc < 3; ++cc) ua[q][cc] = w[q] * u[q * len + 3 * a + cc];
        const int* sl = slot.data() + slot_off[m];
        for (int bm = 0; bm < M; ++bm) {
          const int k = sl[bm];
          if (k == -2) continue;
          double blk[3][3];  // (row r of member bm, column cc of member a)
          const double centre = 2.0 * ((bm == a ? 1.0 : 0.0) - 1.0 / M);
          for (int r = 0; r < 3; ++r) {
            for (int cc = 0; cc < 3; ++cc) {
              double v = r == cc ? centre : 0.0;
              for (int q = 0; q < kTerms; ++q) v -= u[q * len + 3 * bm + r] * ua[q][cc];
              blk[r][cc] = v;
            }
          }
          if (k == -1) {
            for (int cc = 0; cc < 3; ++cc)
              for (int r = cc; r < 3; ++r) col[cc][r - cc] += blk[r][cc];
          } else {
            for (int cc = 0; cc < 3; ++cc)
              for (int r = 0; r < 3; ++r) col[cc][(3 - cc) + 3 * k + r] += blk[r][cc];
          }
        }
      }
      if (mu > 0) {
        for (int cc = 0; cc < 3; ++cc) col[cc][0] += mu * damp[static_cast<size_t>(J)];
      }
    }
  });
}

void PyramidDeformer::Impl::product(const double* v, double mu, double* out) {
  const int np = count();
  parallel_ranges(np, kMinChunk, chunks(), [&](int b, int e) {
    double vc[3 * 64];
    std::vector<double> big;
    for (int c = b; c < e; ++c) {
      const int M = pyr.offsets[c + 1] - pyr.offsets[c];
      const int len = 3 * M;
      double* x = vc;
      if (len > 3 * 64) {
        big.resize(static_cast<size_t>(len));
        x = big.data();
      }
      Vec3 mean = Vec3::Zero();
      for (int k = 0; k < M; ++k) {
        const int J = sys[static_cast<size_t>(pyr.members[pyr.offsets[c] + k])];
        for (int r = 0; r < 3; ++r) x[3 * k + r] = J >= 0 ? v[3 * J + r] : 0.0;
        mean += Vec3(x[3 * k], x[3 * k + 1], x[3 * k + 2]);
      }
      mean /= M;
      const double* u = terms.data() + term_off[c];
      const double* w = coefs.data() + kTerms * static_cast<size_t>(c);
      double dot[kTerms];
      for (int q = 0; q < kTerms; ++q) {
        double d = 0;
        for (int i = 0; i < len; ++i) d += u[q * len + i] * x[i];
        dot[q] = w[q] * d;
      }
      double* o = hv.data() + term_off[c] / kTerms;
      for (int k = 0; k < M; ++k) {
        for (int r = 0; r < 3; ++r) {
          double y = 2.0 * (x[3 * k + r] - mean(r));
          for (int q = 0; q < kTerms; ++q) y -= dot[q] * u[q * len + 3 * k + r];
          o[3 * k + r] = y;
        }
      }
    }
  });
  const int nf = static_cast<int>(free.size());
  parallel_ranges(nf, kMinChunk, chunks(), [&](int b, int e) {
    for (int J = b; J < e; ++J) {
      Vec3 y = mu * damp[static_cast<size_t>(J)] * Vec3(v[3 * J], v[3 * J + 1], v[3 * J + 2]);
      for (int m = mem_off[J]; m < mem_off[J + 1]; ++m) {
        const int c = mem_pyr[m];
        const double* o = hv.data() + term_off[c] / kTerms + 3 * mem_local[m];
        y += Vec3(o[0], o[1], o[2]);
      }
      for (int r = 0; r < 3; ++r) out[3 * J + r] = y(r);
    }
  });
}

void PyramidDeformer::Impl::fixed_solve(const Eigen::VectorXd& v, Eigen::VectorXd* out) {
  const int nf = static_cast<int>(free.size());
  for (int J = 0; J < nf; ++J)
    for (int r = 0; r < 3; ++r) cols[r * nf + J] = v[3 * J + r];
  out->resize(3 * nf);
  fixed->solve(cols.data(), cols.data(), 3);
  for (int J = 0; J < nf; ++J)
    for (int r = 0; r < 3; ++r) (*out)[3 * J + r] = cols[r * nf + J];
}

PyramidDeformer::PyramidDeformer(const Vertices& vertices, const Faces& faces,
                                 const std::vector<int>& control) {
  validate_mesh(vertices, faces);
  const int n = static_cast<int>(vertices.rows());
  if (control.empty()) throw std::invalid_argument("control: expected at least one vertex");
  std::vector<char> is_control(static_cast<size_t>(n), 0);
  for (int c : control) {
    if (c < 0 || c >= n) {
      throw std::invalid_argument("control: vertex " + std::to_string(c) + " outside [0, " +
                                  std::to_string(n) + ")");
    }
    if (is_control[static_cast<size_t>(c)]) {
      throw std::invalid_argument("control: vertex " + std::to_string(c) + " given twice");
    }
    is_control[static_cast<size_t>(c)] = 1;
  }
  control_ = control;
  diag_ = (vertices.colwise().maxCoeff() - vertices.colwise().minCoeff()).norm();
  const ParkWorkersOnExit park;
  impl_ = std::make_unique<Impl>(vertices, faces, control);
}

PyramidDeformer::~PyramidDeformer() = default;

const PyramidCoordinates& PyramidDeformer::coordinates() const { return (*impl_).placement.coords; }
int PyramidDeformer::num_vertices() const {
  return static_cast<int>((*impl_).placement.rest.rows());
}
int PyramidDeformer::num_free() const { return static_cast<int>((*impl_).free.size()); }
int PyramidDeformer::num_passive() const { return (*impl_).num_passive; }

Vertices PyramidDeformer::reconstruct(const Vertices& X, bool stretch) const {
  const pyramid::Placement& pl = (*impl_).placement;
  if (X.rows() != pl.rest.rows()) {
    throw std::invalid_argument("positions: expected shape (" + std::to_string(pl.rest.rows()) +
                                ",3)");
  }
  if (!X.allFinite()) throw std::invalid_argument("positions: contains NaN or infinity");
  const ParkWorkersOnExit park;
  Vertices Y = X;
  parallel_ranges(static_cast<int>(X.rows()), kMinChunk, chunks(), [&](int b, int e) {
    for (int v = b; v < e; ++v) Y.row(v) = pl.place(v, X.data(), stretch).transpose();
  });
  return Y;
}

namespace {
// Positions the core accepts: finite, within +-kMaxMeshSize (beyond it squared distances, and
// with them the energy, overflow).
void check_positions(const Vertices& X, const char* name) {
  if (!X.allFinite()) throw std::invalid_argument(std::string(name) + ": contains NaN or infinity");
  if (X.size() && X.cwiseAbs().maxCoeff() > kMaxMeshSize) {
    throw std::invalid_argument(std::string(name) +
                                ": coordinates beyond 1e50; rescale the mesh and its poses "
                                "(only shapes matter)");
  }
}
}  // namespace

namespace {
void check_vector_rows(const Vectors3* v, int k) {
  if (v && v->rows() != k) {
    throw std::invalid_argument("rotation_vectors: expected shape (" + std::to_string(k) +
                                ",3), one per control, got " + std::to_string(v->rows()) + " rows");
  }
}
}  // namespace

Vertices PyramidDeformer::start(const Vertices& control_positions,
                                const Vectors3* rotation_vectors) const {
  const int k = static_cast<int>(control_.size());
  if (control_positions.rows() != k) {
    throw std::invalid_argument("control_positions: expected shape (" + std::to_string(k) +
                                ",3), got " + std::to_string(control_positions.rows()) + " rows");
  }
  check_positions(control_positions, "control_positions");
  check_vector_rows(rotation_vectors, k);
  const ParkWorkersOnExit park;
  return (*impl_->start)(control_positions, rotation_vectors);
}

double PyramidDeformer::energy(const Vertices& X, double scale_weight, Vertices* gradient) const {
  if (X.rows() != num_vertices()) {
    throw std::invalid_argument("positions: expected shape (" + std::to_string(num_vertices()) +
                                ",3)");
  }
  check_positions(X, "positions");
  if (!(scale_weight >= 0) || !std::isfinite(scale_weight)) {
    throw std::invalid_argument("scale_weight: expected a finite value >= 0");
  }
  const ParkWorkersOnExit park;
  const pyramid::Pyramids& P = impl_->pyr;
  double E = 0;
  if (gradient) *gradient = Vertices::Zero(X.rows(), 3);
  for (int c = 0; c < P.count(); ++c) {
    const Fit f = pyramid::fit_pyramid(P, c, X.data(), scale_weight);
    E += f.energy;
    if (!gradient) continue;
    for (int i = P.offsets[c]; i < P.offsets[c + 1]; ++i) {
      const int v = P.members[i];
      const Vec3 p(P.rest[3 * i], P.rest[3 * i + 1], P.rest[3 * i + 2]);
      gradient->row(v) += 2.0 * (X.row(v).transpose() - f.centre - f.scale * (f.R * p)).transpose();
    }
  }
  return E;
}

Vertices PyramidDeformer::deform(const Vertices& control_positions,
                                 const PyramidSolveOptions& options) {
  const ParkWorkersOnExit park;
  Impl& S = *impl_;
  const std::lock_guard<std::mutex> lock(S.busy);
  const int n = num_vertices();
  const int k = static_cast<int>(control_.size());
  if (control_positions.rows() != k) {
    throw std::invalid_argument("control_positions: expected shape (" + std::to_string(k) +
                                ",3), got " + std::to_string(control_positions.rows()) + " rows");
  }
  check_positions(control_positions, "control_positions");
  check_vector_rows(options.rotation_vectors, k);
  if (options.max_iterations < 0) throw std::invalid_argument("iterations: expected >= 0");
  if (!(options.tol >= 0) || !std::isfinite(options.tol)) {
    throw std::invalid_argument("tol: expected a finite value >= 0");
  }
  const double kappa = options.scale_weight;
  if (!(kappa >= 0) || !std::isfinite(kappa)) {
    throw std::invalid_argument("scale_weight: expected a finite value >= 0");
  }
  if (!(options.progress_seconds >= 0)) {
    throw std::invalid_argument("progress_seconds: expected a value >= 0");
  }
  Vertices X;
  if (options.initial) {
    if (options.initial->rows() != n) {
      throw std::invalid_argument("initial: expected shape (" + std::to_string(n) + ",3)");
    }
    check_positions(*options.initial, "initial");
    X = *options.initial;
    // Vertices no control reaches stay at rest whatever the start.
    for (int v = 0; v < n; ++v) {
      if (!S.moving[static_cast<size_t>(v)]) X.row(v) = S.placement.rest.row(v);
    }
  } else {
    X = (*S.start)(control_positions, options.rotation_vectors);
  }
  for (int j = 0; j < k; ++j) X.row(control_[static_cast<size_t>(j)]) = control_positions.row(j);
  last_steps_.clear();
  last_iterations_ = 0;
  last_factorizations_ = 0;
  last_converged_ = false;
  last_step_ = std::numeric_limits<double>::quiet_NaN();
  const int nf = num_free();
  if (nf == 0) {
    last_converged_ = true;
    last_step_ = 0;
    last_energy_ = S.fit_all(X.data(), kappa, false);
    return X;
  }
  double E = S.fit_all(X.data(), kappa, true);
  if (!std::isfinite(E)) {
    throw std::runtime_error(
        "pyramid deformer: the energy of the start is not finite; rescale the mesh and its "
        "poses");
  }
  last_energy_ = E;

  const double limit = options.tol * diag_;
  // The positive semidefinite Hessian far from the minimum, the exact one near it; a warm start
  // (a live update from the last result) is usually near it.
  bool exact = options.initial != nullptr;
  double mu = 0;
  Eigen::VectorXd g, d(3 * nf), rhs(3 * nf), r(3 * nf), z(3 * nf), p(3 * nf), Ap(3 * nf);
  Vertices trial;
  auto reported = std::chrono::steady_clock::now();
  // progress(iterations, step / diagonal) at most every progress_seconds, or now if `force`.
  auto report = [&](int iterations, double step_fraction, bool force) {
    if (!options.progress) return;
    const auto now = std::chrono::steady_clock::now();
    if (force ||
        std::chrono::duration<double>(now - reported).count() >= options.progress_seconds) {
      reported = now;
      options.progress(iterations, step_fraction);
    }
  };
  auto step_of = [&](double alpha) {
    double mx = 0;
    for (int J = 0; J < nf; ++J) mx = std::max(mx, alpha * d.segment<3>(3 * J).norm());
    return mx;
  };
  auto moved = [&](double alpha) {
    trial = X;
    for (int J = 0; J < nf; ++J) {
      trial.row(S.free[static_cast<size_t>(J)]) += alpha * d.segment<3>(3 * J).transpose();
    }
  };
  // (H + mu D) d = rhs by conjugate gradients preconditioned with the last factorisation (of an
  // earlier iterate's matrix): true when the residual fell below eta |rhs| within `most`
  // iterations, false also at negative curvature.
  auto pcg = [&](double eta, int most) {
    d.setZero();
    r = rhs;
    const double target = eta * rhs.norm();
    S.chol->solve(r.data(), z.data(), 1);
    p = z;
    double rz = r.dot(z);
    for (int it = 0; it < most; ++it) {
      S.product(p.data(), mu, Ap.data());
      const double pAp = p.dot(Ap);
      if (!(pAp > 0)) return false;
      const double a = rz / pAp;
      d += a * p;
      r -= a * Ap;
      if (r.norm() <= target) return true;
      S.chol->solve(r.data(), z.data(), 1);
      const double rz_new = r.dot(z);
      p = z + (rz_new / rz) * p;
      rz = rz_new;
    }
    return false;
  };
  // Phase 1: L-BFGS whose initial inverse Hessian is the constant part C^-1 (prefactored: a
  // solve costs a fraction of one Newton factorisation). With no history its step is the
  // local-global step (fits held fixed, positions solved exactly). It closes most of the
  // distance from the start cheaply; Newton's method then finishes from close by.
  last_lbfgs_iterations_ = 0;
  const double quasi_until = kQuasiUntil * std::pow(std::min(1.0, kQuasiFree / nf), 1.5);
  const int quasi_most = options.max_lbfgs_iterations >= 0
                             ? options.max_lbfgs_iterations
                             : static_cast<int>(std::min<long long>(
                                   kQuasiMost, 1LL * kQuasiPerNewton * options.max_iterations));
  // Run again after a step off a saddle (escape_saddle below): between a saddle and the next
  // minimum the energy is not convex, where Newton's method with the positive semidefinite
  // Hessian crawls and L-BFGS does not.
  auto run_lbfgs = [&]() {
    if (S.fixed) {
      // The correction pairs in a ring (slot (oldest + j) % kHistory is the j-th oldest), kept
      // by the deformer: a live update does not allocate them again.
      std::vector<Eigen::VectorXd>& hs = S.pairs_s;
      std::vector<Eigen::VectorXd>& hy = S.pairs_y;
      std::vector<Eigen::VectorXd>& hcy = S.pairs_cy;
      double hrho[kHistory], a_hist[kHistory];
      int pairs = 0, oldest = 0;
      // The initial inverse Hessian is gamma C^-1, gamma = s'y / y'C^-1 y of the newest pair:
      // C overestimates the energy's curvature along the soft bending modes (the fits'
      // rotations relax them; gamma 1.5-4 on the cat), and unscaled L-BFGS takes ~1.5x the
      // iterations (cat 14k pose 7: 288 instead of 193). C^-1 g is kept per iterate and
      // C^-1 y = C^-1 g_new - C^-1 g per pair, so the two-loop recursion forms
      // C^-1 q = -C^-1 g - sum a_i C^-1 y_i without a solve: one solve per iteration.
      double gamma = 1;
      auto slot = [&](int j) { return (oldest + j) % kHistory; };
      Eigen::VectorXd q(3 * nf), gn(3 * nf);
      S.gradient(X.data(), &g);
      S.fixed_solve(g, &S.cg);
      while (last_lbfgs_iterations_ < quasi_most) {
        q = -g;
        d = -S.cg;
        for (int j = pairs - 1; j >= 0; --j) {
          const int i = slot(j);
          a_hist[i] = hrho[i] * hs[i].dot(q);
          q -= a_hist[i] * hy[i];
          d -= a_hist[i] * hcy[i];
        }
        if (pairs > 0) d *= gamma;
        for (int j = 0; j < pairs; ++j) {
          const int i = slot(j);
          const double b = hrho[i] * hy[i].dot(d);
          d += (a_hist[i] - b) * hs[i];
        }
        double slope = g.dot(d);
        if (!(slope < 0)) {
          // Restart from the local-global step.
          pairs = 0;
          d = -S.cg;
          slope = g.dot(d);
          if (!(slope < 0)) break;
        }
        const double noise = 1e-13 * std::abs(E);
        double alpha = 1;
        bool accepted = false;
        double Et = E;
        for (int tries = 0; tries < 8; ++tries, alpha *= 0.5) {
          moved(alpha);
          Et = S.fit_all(trial.data(), kappa, &S.trial_fits);
          if (std::isfinite(Et) && Et <= E + 1e-4 * alpha * slope + noise) {
            accepted = true;
            break;
          }
        }
        if (!accepted) break;
        X.swap(trial);
        S.fits.swap(S.trial_fits);
        E = Et;
        ++last_lbfgs_iterations_;
        S.gradient(X.data(), &gn);
        S.fixed_solve(gn, &S.cg_new);
        const double step = step_of(alpha);
        // y into the scratch q first: a pair with no positive curvature would make the inverse
        // update indefinite and is skipped, leaving the ring as it was.
        q = gn - g;
        const double sy = alpha * d.dot(q);
        if (sy > 1e-12 * alpha * d.norm() * q.norm()) {
          // The new pair goes to the next free slot, or over the oldest.
          const int i = pairs < kHistory ? slot(pairs) : oldest;
          hs[i] = alpha * d;
          hy[i].swap(q);
          hcy[i] = S.cg_new - S.cg;
          hrho[i] = 1.0 / sy;
          gamma = sy / hy[i].dot(hcy[i]);
          if (pairs < kHistory) {
            ++pairs;
          } else {
            oldest = (oldest + 1) % kHistory;
          }
        }
        g.swap(gn);
        S.cg.swap(S.cg_new);
        report(0, diag_ > 0 ? step / diag_ : 0.0, false);
        if (step <= quasi_until * diag_) {
          exact = true;
          break;
        }
      }
    }
  };
  run_lbfgs();
  last_energy_ = E;
  bool have_factor = false;
  // At a saddle (a stationary point whose exact Hessian is not positive definite) the steps of
  // the positive semidefinite Hessian vanish, and the iterate leaves only as round-off grows
  // along the unstable direction: hundreds of iterations (a short thick tube twisted by 90
  // degrees, docs/pyramid.md). One step along a direction of negative curvature instead: the
  // exact Hessian shifted by sigma D until positive definite, inverse iteration on D^-1 H for
  // its lowest mode, then the longest step along it (1e-3 to 0.1 of the diagonal, doubling)
  // that keeps lowering the energy. False (nothing changed) without negative curvature.
  auto escape_saddle = [&]() -> bool {
    bool ok = false;
    for (double sigma = kDampingStart; !ok && sigma <= kDampingMost; sigma *= 4) {
      S.assemble(sigma);
      ++last_factorizations_;
      ok = S.chol->refactor(S.values.data());
    }
    have_factor = ok;
    if (!ok) return false;
    auto d_norm = [&](const Eigen::VectorXd& x) {
      double sum = 0;
      for (int J = 0; J < nf; ++J)
        sum += S.damp[static_cast<size_t>(J)] * x.segment<3>(3 * J).squaredNorm();
      return std::sqrt(sum);
    };
    Eigen::VectorXd v = g;
    if (!(v.norm() > 0)) v.setOnes();
    v /= d_norm(v);
    for (int k = 0; k < kInverseIterations; ++k) {
      for (int J = 0; J < nf; ++J)
        z.segment<3>(3 * J) = S.damp[static_cast<size_t>(J)] * v.segment<3>(3 * J);
      S.chol->solve(z.data(), p.data(), 1);
      v = p / d_norm(p);
    }
    S.product(v.data(), 0.0, Ap.data());
    if (!(v.dot(Ap) < 0)) return false;
    d = g.dot(v) > 0 ? Eigen::VectorXd(-v) : v;
    const double unit = step_of(1.0);
    double best = 0, E_best = E;
    for (double len = 1e-3 * diag_; len <= 0.1 * diag_ * (1 + 1e-9); len *= 2) {
      moved(len / unit);
      const double Et = S.fit_all(trial.data(), kappa, false);
      if (!(std::isfinite(Et) && Et < E_best)) break;
      best = len / unit;
      E_best = Et;
    }
    if (!(best > 0 && E_best < E - 1e-13 * std::abs(E))) return false;
    moved(best);
    X.swap(trial);
    E = S.fit_all(X.data(), kappa, true);
    last_step_ = diag_ > 0 ? step_of(best) / diag_ : 0.0;
    return true;
  };
  while (last_iterations_ < options.max_iterations) {
    S.gradient(X.data(), &g);
    const bool changed = S.terms_all(kappa, exact);
    rhs = -g;
    // A Newton step accurate to eta: loose far away, tight where the stopping rule may apply.
    const bool newton = (exact || !changed) && mu == 0;
    // (last_step_ is NaN before the first step: tight)
    const bool tight = newton && !(last_step_ > kLooseAbove * options.tol);
    const double eta = tight ? kTightEta : newton ? kLooseEta : 1e-2;
    bool solved = false;
    // The last factorisation, of an earlier iterate's matrix, often still preconditions this
    // one well enough: a few products and substitutions instead of a factorisation (kReuseMost).
    if (have_factor) solved = pcg(eta, kReuseMost);
    if (!solved) {
      S.assemble(mu);
      ++last_factorizations_;
      have_factor = S.chol->refactor(S.values.data());
      if (!have_factor) {
        // Not positive definite: the exact Hessian away from a minimum, or a singular system.
        if (exact) {
          exact = false;
          // Right after a small step: near a stationary point that is not a minimum.
          if (last_iterations_ > 0 && last_step_ <= kSaddleBelow && escape_saddle()) {
            ++last_iterations_;
            last_steps_.push_back(last_step_);
            report(last_iterations_, last_step_, false);
            run_lbfgs();
            last_energy_ = E;
            have_factor = false;
          }
        } else {
          mu = std::max(4 * mu, kDampingStart);
          if (mu > kDampingMost) {
            throw std::runtime_error("pyramid deformer: the Newton system stayed singular");
          }
        }
        continue;
      }
      S.chol->solve(rhs.data(), d.data(), 1);
    }
    ++last_iterations_;
    const double step = step_of(1.0);
    // The stopping rule: a full step of Newton's method proper (exact Hessian, or the positive
    // semidefinite one where it equals the exact one, no damping) below tol.
    bool accepted = false, done = false;
    double alpha = 1;
    // Round-off of the energy (a sum over all pyramids): below it, energy changes mean nothing.
    const double noise = 1e-13 * std::abs(E);
    if (tight && step <= limit) {
      moved(1.0);
      X.swap(trial);
      E = S.fit_all(X.data(), kappa, true);
      accepted = done = true;
    } else {
      // Energy along the step: a full step, backtracking to 1/8, or (PSD Hessian, which
      // overestimates the curvature) a longer one.
      const double slope = g.dot(d);  // < 0: the matrix is positive definite
      for (int tries = 0; tries < 4 && !accepted; ++tries, alpha *= 0.5) {
        moved(alpha);
        const double Et = S.fit_all(trial.data(), kappa, false);
        if (std::isfinite(Et) && Et <= E + 1e-4 * alpha * slope + noise) {
          accepted = true;
          if (!exact && alpha == 1) {
            Vertices keep = trial;
            for (double longer = 2; longer <= 4; longer *= 2) {
              moved(longer);
              const double El = S.fit_all(trial.data(), kappa, false);
              if (!(std::isfinite(El) && El < Et)) break;
              keep = trial, alpha = longer;
            }
            trial.swap(keep);
          }
        }
        if (accepted) break;
      }
      if (accepted) {
        X.swap(trial);
        const double E_new = S.fit_all(X.data(), kappa, true);
        const double predicted = -(alpha - 0.5 * alpha * alpha) * slope;
        const double rho = predicted > 0 ? (E - E_new) / predicted : 0;
        E = E_new;
        // The damping follows how well the quadratic model predicted the decrease, where the
        // decrease is measurable; a step already below tol goes on undamped and exact, so that
        // the next one can meet the stopping rule.
        if (step <= limit || (alpha >= 1 && rho > 0.5)) {
          mu = mu > kDampingStart ? mu / 4 : 0.0;
        } else if (rho < 0.25 && predicted > 1e3 * noise) {
          mu = std::max(2 * mu, kDampingStart);
        }
        if (step <= limit) mu = 0;
        if (!exact && alpha * step < kExactBelow * diag_) exact = true;
      } else if (exact) {
        // The exact Hessian's step raised the energy: the iterate is farther from a minimum
        // than a warm start or the handover assumed. The projected Hessian retries this
        // iteration instead of spending it: a live update with a budget of one iteration
        // would otherwise return unmoved and meet the same point again on every update.
        exact = false;
        --last_iterations_;
        continue;
      } else {
        mu = std::max(4 * mu, kDampingStart);
      }
    }
    last_step_ = diag_ > 0 ? (accepted ? alpha : 0.0) * step / diag_ : 0.0;
    last_steps_.push_back(last_step_);
    last_energy_ = E;
    if (!std::isfinite(E)) throw std::runtime_error("pyramid deformer: the energy overflowed");
    report(last_iterations_, last_step_, done);
    if (done) {
      last_converged_ = true;
      break;
    }
  }
  return X;
}

}  // namespace matdeform
