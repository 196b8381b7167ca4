#include "sparse_cholesky.hpp"

#include <cholmod.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <mutex>
#include <queue>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "matdeform/threads.hpp"
#include "simd.hpp"
#include "task_pool.hpp"

namespace matdeform {

namespace {

std::atomic<long long> g_factorizations{0};

constexpr int kWidth = 4;  // right-hand sides per pass; 3 coordinates fill it with one pad

// What the user can change when a factorisation fails on a system that is positive definite in
// exact arithmetic (every caller removes the null space first).
constexpr const char* kIllConditioned =
    "the linear system is too ill-conditioned to factor in double precision: reduce the "
    "stiffness ratio (max/min) or remove faces far smaller than their neighbours";

// Forward pass L y = b over rows [b, e) in gather form: y_i = (b_i - sum_j<i L_ij y_j) / L_ii.
// All j are descendants of i in the elimination tree. Four partial sums break the FMA latency
// chain of long rows.
MD_ALWAYS_INLINE void forward_body(const int* rp, const int* ri, const double* rx,
                                   const double* dinv, Vec4d* Y, int b, int e) {
  for (int i = b; i < e; ++i) {
    Vec4d a0 = Y[i], a1 = {0, 0, 0, 0}, a2 = a1, a3 = a1;
    int q = rp[i];
    const int qe = rp[i + 1];
    for (; q + 3 < qe; q += 4) {
      a0 -= rx[q] * Y[ri[q]];
      a1 -= rx[q + 1] * Y[ri[q + 1]];
      a2 -= rx[q + 2] * Y[ri[q + 2]];
      a3 -= rx[q + 3] * Y[ri[q + 3]];
    }
    for (; q < qe; ++q) a0 -= rx[q] * Y[ri[q]];
    Y[i] = ((a0 + a1) + (a2 + a3)) * dinv[i];
  }
}

// Backward pass L^T x = y over rows [b, e), last first, in scatter form on the same storage: once
// x_i is final it is subtracted from the rows of its descendants j < i. Descendants of a subtree
// stay inside it, so subtrees still run on different threads without conflicts.
MD_ALWAYS_INLINE void backward_body(const int* rp, const int* ri, const double* rx,
                                    const double* dinv, Vec4d* Y, int b, int e) {
  for (int i = e - 1; i >= b; --i) {
    const Vec4d x = Y[i] * dinv[i];
    Y[i] = x;
    for (int q = rp[i]; q < rp[i + 1]; ++q) Y[ri[q]] -= rx[q] * x;
  }
}

void forward_base(const int* rp, const int* ri, const double* rx, const double* dinv, Vec4d* Y,
                  int b, int e) {
  forward_body(rp, ri, rx, dinv, Y, b, e);
}
MD_TARGET_AVX2 void forward_avx2(const int* rp, const int* ri, const double* rx, const double* dinv,
                                 Vec4d* Y, int b, int e) {
  forward_body(rp, ri, rx, dinv, Y, b, e);
}
void backward_base(const int* rp, const int* ri, const double* rx, const double* dinv, Vec4d* Y,
                   int b, int e) {
  backward_body(rp, ri, rx, dinv, Y, b, e);
}
MD_TARGET_AVX2 void backward_avx2(const int* rp, const int* ri, const double* rx,
                                  const double* dinv, Vec4d* Y, int b, int e) {
  backward_body(rp, ri, rx, dinv, Y, b, e);
}

void forward_rows(const int* rp, const int* ri, const double* rx, const double* dinv, double* Y,
                  int b, int e) {
  Vec4d* y = reinterpret_cast<Vec4d*>(Y);
  if (cpu_has_avx2_fma()) {
    forward_avx2(rp, ri, rx, dinv, y, b, e);
  } else {
    forward_base(rp, ri, rx, dinv, y, b, e);
  }
}

void backward_rows(const int* rp, const int* ri, const double* rx, const double* dinv, double* Y,
                   int b, int e) {
  Vec4d* y = reinterpret_cast<Vec4d*>(Y);
  if (cpu_has_avx2_fma()) {
    backward_avx2(rp, ri, rx, dinv, y, b, e);
  } else {
    backward_base(rp, ri, rx, dinv, y, b, e);
  }
}

// Substitution with the strictly lower part of L stored by rows (the forward pass gathers, the
// backward pass scatters). Either pass touches only the rows of a node's subtree, so disjoint
// subtrees of the elimination tree run on different threads without locks; the nodes above them
// (the top separators of the nested-dissection ordering) run serially in between.
struct Substitution {
  int n = 0;
  std::vector<int> perm;  // row i of the permuted system is row perm[i] of the original
  std::vector<int> rp, ri;
  std::vector<double> rx, dinv;
  std::vector<int> parent, first;  // elimination tree; subtree of j is [first[j], j] if postordered
  std::vector<int> child_ptr, child;
  std::vector<double> own_work, tree_work;
  bool postordered = false;

  struct Schedule {
    int requested = 0;                      // num_threads() it was made for
    int threads = 0;                        // 1: run serially
    std::vector<std::pair<int, int>> jobs;  // subtree row ranges [b, e), heaviest first
    std::vector<int> serial;                // ascending
  };
  mutable Schedule sched;
  mutable std::vector<double> Y;

  // The factor comes from a relaxed supernodal factorisation, which stores explicit zeros
  // (about a quarter of the entries on mesh Laplacians): they are dropped from the rows, which
  // only removes dependencies. The elimination tree is still taken from the full structure, so
  // every remaining entry L_ij links i to a descendant j and the subtree schedule stays valid.
  Substitution(const cholmod_factor* L) {
    if (L->is_super || !L->is_ll) throw std::runtime_error("unexpected CHOLMOD factor type");
    n = static_cast<int>(L->n);
    const int* Lp = static_cast<const int*>(L->p);
    const int* Li = static_cast<const int*>(L->i);
    const int* Lnz = static_cast<const int*>(L->nz);
    const double* Lx = static_cast<const double*>(L->x);
    const int* P = static_cast<const int*>(L->Perm);
    perm.assign(P, P + n);
    dinv.assign(n, 0.0);
    parent.assign(n, -1);
    rp.assign(n + 1, 0);
    for (int j = 0; j < n; ++j) {
      const int b = Lp[j], e = Lp[j] + Lnz[j];
      // CHOLMOD keeps the diagonal first in each simplicial column.
      if (e <= b || Li[b] != j) throw std::runtime_error("unexpected CHOLMOD factor layout");
      // A zero, negative or NaN pivot: CHOLMOD lost positive definiteness to round-off.
      if (!(Lx[b] > 0.0) || !std::isfinite(Lx[b])) throw std::invalid_argument(kIllConditioned);
      dinv[j] = 1.0 / Lx[b];
      for (int q = b + 1; q < e; ++q) {
        const int i = Li[q];
        if (Lx[q] != 0.0) ++rp[i + 1];
        if (parent[j] < 0 || i < parent[j]) parent[j] = i;
      }
    }
    for (int i = 0; i < n; ++i) rp[i + 1] += rp[i];
    ri.resize(static_cast<size_t>(rp[n]));
    rx.resize(static_cast<size_t>(rp[n]));
    std::vector<int> cursor(rp.begin(), rp.end() - 1);
    for (int j = 0; j < n; ++j) {  // columns in order: each row's entries come out sorted
      for (int q = Lp[j] + 1; q < Lp[j] + Lnz[j]; ++q) {
        if (Lx[q] == 0.0) continue;
        const int i = Li[q];
        ri[cursor[i]] = j;
        rx[cursor[i]++] = Lx[q];
      }
    }

    // Subtree sizes and work (entries touched per pass). Children follow their parent's index.
    own_work.resize(n);
    tree_work.resize(n);
    first.resize(n);
    std::vector<int> size(n, 1);
    child_ptr.assign(n + 2, 0);  // node n is a virtual root above all roots
    for (int j = 0; j < n; ++j) {
      own_work[j] = 1.0 + (rp[j + 1] - rp[j]);
      tree_work[j] = own_work[j];
      first[j] = j;
      ++child_ptr[(parent[j] < 0 ? n : parent[j]) + 1];
    }
    for (int j = 0; j < n; ++j) {
      if (parent[j] < 0) continue;
      tree_work[parent[j]] += tree_work[j];
      size[parent[j]] += size[j];
      first[parent[j]] = std::min(first[parent[j]], first[j]);
    }
    for (int p = 0; p <= n; ++p) child_ptr[p + 1] += child_ptr[p];
    child.resize(n);
    std::vector<int> cc(child_ptr.begin(), child_ptr.end() - 1);
    for (int j = 0; j < n; ++j) child[cc[parent[j] < 0 ? n : parent[j]]++] = j;
    postordered = true;
    for (int j = 0; j < n; ++j) postordered = postordered && first[j] == j - size[j] + 1;
    Y.resize(static_cast<size_t>(kWidth) * n);
  }

  // Greedy: keep moving the root of the heaviest subtree to the serial part while that does not
  // raise the estimated time (serial + max(parallel / threads, heaviest subtree)). Then keep
  // splitting a little further, for at most 3 % more serial work, until there are several
  // subtrees per thread: they are claimed dynamically, so when a worker is descheduled (this
  // project's VMs lose 10 % of their CPU time to other guests) the others take over all but the
  // subtree it holds.
  void make_schedule(int threads) const {
    sched = Schedule();
    sched.requested = threads;
    sched.threads = threads;
    double total = 0.0;
    for (double w : own_work) total += w;
    // Below this many entries (~15k-face meshes) waking a parked worker costs more than it saves.
    constexpr double kMinParallelWork = 400000.0;
    if (threads < 2 || !postordered || total < kMinParallelWork) {
      sched.threads = 1;
      return;
    }
    using Item = std::pair<double, int>;
    std::priority_queue<Item> heap;
    for (int q = child_ptr[n]; q < child_ptr[n + 1]; ++q)
      heap.emplace(tree_work[child[q]], child[q]);
    double serial_work = 0.0, parallel_work = total;
    auto estimate = [&](double s, double p, double heaviest) {
      return s + std::max(p / threads, heaviest);
    };
    const size_t wanted_jobs = static_cast<size_t>(4 * threads);
    double extra_budget = -1.0;  // serial work allowed past the greedy optimum, once reached
    while (!heap.empty()) {
      const Item top = heap.top();
      heap.pop();
      const int r = top.second;
      double heaviest = heap.empty() ? 0.0 : heap.top().first;
      for (int q = child_ptr[r]; q < child_ptr[r + 1]; ++q) {
        heaviest = std::max(heaviest, tree_work[child[q]]);
      }
      if (extra_budget < 0.0) {
        const double now = estimate(serial_work, parallel_work, top.first);
        const double split =
            estimate(serial_work + own_work[r], parallel_work - own_work[r], heaviest);
        if (split > now) extra_budget = 0.03 * total;
      }
      if (extra_budget >= 0.0) {
        if (heap.size() + 1 >= wanted_jobs || own_work[r] > extra_budget) {
          heap.push(top);
          break;
        }
        extra_budget -= own_work[r];
      }
      sched.serial.push_back(r);
      serial_work += own_work[r];
      parallel_work -= own_work[r];
      for (int q = child_ptr[r]; q < child_ptr[r + 1]; ++q) {
        heap.emplace(tree_work[child[q]], child[q]);
      }
    }
    if (estimate(serial_work, parallel_work, heap.empty() ? 0.0 : heap.top().first) > 0.8 * total) {
      sched = Schedule();  // not worth a parallel region
      sched.requested = threads;
      sched.threads = 1;
      return;
    }
    while (!heap.empty()) {  // pops heaviest first: claimed in this order, an online LPT
      const int r = heap.top().second;
      heap.pop();
      sched.jobs.emplace_back(first[r], r + 1);
    }
    std::sort(sched.serial.begin(), sched.serial.end());
  }

  void run(double* Yd) const {
    const int threads = num_threads();
    if (sched.requested != threads) make_schedule(threads);
    if (sched.threads <= 1) {
      forward_rows(rp.data(), ri.data(), rx.data(), dinv.data(), Yd, 0, n);
      backward_rows(rp.data(), ri.data(), rx.data(), dinv.data(), Yd, 0, n);
      return;
    }
    const int jobs = static_cast<int>(sched.jobs.size());
    run_tasks(jobs, [&](int t) {
      const auto& r = sched.jobs[t];
      forward_rows(rp.data(), ri.data(), rx.data(), dinv.data(), Yd, r.first, r.second);
    });
    for (int j : sched.serial)
      forward_rows(rp.data(), ri.data(), rx.data(), dinv.data(), Yd, j, j + 1);
    for (auto it = sched.serial.rbegin(); it != sched.serial.rend(); ++it) {
      backward_rows(rp.data(), ri.data(), rx.data(), dinv.data(), Yd, *it, *it + 1);
    }
    run_tasks(jobs, [&](int t) {
      const auto& r = sched.jobs[t];
      backward_rows(rp.data(), ri.data(), rx.data(), dinv.data(), Yd, r.first, r.second);
    });
  }

  void solve(const double* B, double* X, int nrhs) const {
    for (int c0 = 0; c0 < nrhs; c0 += kWidth) {
      const int w = std::min(kWidth, nrhs - c0);
      for (int i = 0; i < n; ++i) {
        const size_t src = static_cast<size_t>(perm[i]);
        for (int c = 0; c < kWidth; ++c) {
          Y[static_cast<size_t>(kWidth) * i + c] =
              c < w ? B[static_cast<size_t>(c0 + c) * n + src] : 0.0;
        }
      }
      run(Y.data());
      for (int i = 0; i < n; ++i) {
        const size_t dst = static_cast<size_t>(perm[i]);
        for (int c = 0; c < w; ++c) {
          X[static_cast<size_t>(c0 + c) * n + dst] = Y[static_cast<size_t>(kWidth) * i + c];
        }
      }
    }
  }
};

// One factorisation at a time in the process. The supernodal factorisation calls BLAS, and
// the serial OpenBLAS that Debian ships (libopenblas0-serial) is not safe for concurrent
// calls: two deformers built on two threads at once got wrong factors (weights off by 0.6)
// or "not positive definite". Factorisations are the expensive, once-per-bind part, so running
// them one after another costs little; solves never take this lock.
std::mutex& factor_mutex() {
  static std::mutex m;
  return m;
}

}  // namespace

struct SparseCholesky::Impl {
  std::mutex mutex;  // guards every mutable member (and sub's) during a solve
  cholmod_common c;
  cholmod_factor* L = nullptr;
  mutable cholmod_dense* X = nullptr;
  mutable cholmod_dense* Y = nullptr;
  mutable cholmod_dense* E = nullptr;
  std::unique_ptr<Substitution> sub;

  explicit Impl(Reuse reuse) {
    cholmod_start(&c);
    c.print = 0;  // errors become exceptions, not stderr noise
    c.error_handler = nullptr;
    // On mesh Laplacians nested dissection (METIS) gives ~5-15% less fill than AMD but takes
    // ~5x longer to compute (about 1 s at 100k unknowns). Worth it only when the factor is
    // reused for many solves; then try both and keep the sparser one. Nested dissection also
    // gives the elimination tree the balanced subtrees the parallel substitution needs.
    c.nmethods = reuse == Reuse::PerPose ? 2 : 1;
    c.method[0].ordering = CHOLMOD_AMD;
    c.method[1].ordering = CHOLMOD_METIS;
    c.postorder = 1;
    c.final_ll = 1;  // small systems are factored simplicial LDL' otherwise; keep one layout
  }
  ~Impl() {
    if (X) cholmod_free_dense(&X, &c);
    if (Y) cholmod_free_dense(&Y, &c);
    if (E) cholmod_free_dense(&E, &c);
    if (L) cholmod_free_factor(&L, &c);
    cholmod_finish(&c);
  }
};

SparseCholesky::SparseCholesky(const Eigen::SparseMatrix<double>& A_in, Reuse reuse)
    : impl_(std::make_unique<Impl>(reuse)), n_(static_cast<int>(A_in.rows())) {
  if (A_in.rows() != A_in.cols()) throw std::invalid_argument("SparseCholesky: A must be square");
  if (n_ == 0) return;
  Eigen::SparseMatrix<double> A = A_in.triangularView<Eigen::Lower>();
  A.makeCompressed();
  for (Eigen::Index i = 0; i < A.nonZeros(); ++i) {
    if (!std::isfinite(A.valuePtr()[i])) throw std::invalid_argument(kIllConditioned);
  }
  cholmod_common* c = &impl_->c;
  cholmod_sparse* As =
      cholmod_allocate_sparse(static_cast<size_t>(n_), static_cast<size_t>(n_),
                              static_cast<size_t>(A.nonZeros()), 1, 1, -1, CHOLMOD_REAL, c);
  if (!As) throw std::runtime_error("CHOLMOD could not allocate the matrix");
  std::memcpy(As->p, A.outerIndexPtr(), sizeof(int) * static_cast<size_t>(n_ + 1));
  std::memcpy(As->i, A.innerIndexPtr(), sizeof(int) * static_cast<size_t>(A.nonZeros()));
  std::memcpy(As->x, A.valuePtr(), sizeof(double) * static_cast<size_t>(A.nonZeros()));
  int status;
  {
    const std::lock_guard<std::mutex> lock(factor_mutex());
    impl_->L = cholmod_analyze(As, c);
    if (impl_->L) cholmod_factorize(As, impl_->L, c);
    status = c->status;
    // Supernodal factorisation is fastest to compute, but for a handful of right-hand sides a
    // simplicial solve is faster (no BLAS call overhead per supernode): convert once here.
    if (impl_->L && status >= CHOLMOD_OK && status != CHOLMOD_NOT_POSDEF && impl_->L->is_super) {
      cholmod_change_factor(CHOLMOD_REAL, 1, 0, 1, 1, impl_->L, c);
      status = c->status;
    }
  }
  cholmod_free_sparse(&As, c);
  if (impl_->L && status == CHOLMOD_NOT_POSDEF) {
    throw std::invalid_argument(kIllConditioned);
  }
  if (!impl_->L || status < CHOLMOD_OK) {
    // Out of memory or a CHOLMOD limit: nothing the input could fix but its size.
    throw std::runtime_error("sparse Cholesky factorisation failed (CHOLMOD status " +
                             std::to_string(status) + ")");
  }

  if (reuse == Reuse::PerPose) {
    impl_->sub = std::make_unique<Substitution>(impl_->L);
    cholmod_free_factor(&impl_->L, c);  // the copy above is all the solves need
  }
  g_factorizations.fetch_add(1, std::memory_order_relaxed);
}

long long SparseCholesky::factorizations() { return g_factorizations.load(); }

SparseCholesky::~SparseCholesky() = default;

void SparseCholesky::solve(const double* B, double* X, int nrhs) const {
  if (n_ == 0 || nrhs == 0) return;
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  if (impl_->sub) {
    impl_->sub->solve(B, X, nrhs);
    return;
  }
  cholmod_dense Bd;
  std::memset(&Bd, 0, sizeof(Bd));
  Bd.nrow = static_cast<size_t>(n_);
  Bd.ncol = static_cast<size_t>(nrhs);
  Bd.nzmax = Bd.nrow * Bd.ncol;
  Bd.d = Bd.nrow;
  Bd.x = const_cast<double*>(B);  // CHOLMOD only reads B
  Bd.xtype = CHOLMOD_REAL;
  Bd.dtype = CHOLMOD_DOUBLE;
  const int ok = cholmod_solve2(CHOLMOD_A, impl_->L, &Bd, nullptr, &impl_->X, nullptr, &impl_->Y,
                                &impl_->E, &impl_->c);
  if (!ok || !impl_->X) throw std::runtime_error("CHOLMOD solve failed");
  std::memcpy(X, impl_->X->x, sizeof(double) * Bd.nzmax);
}

const std::vector<int>& SparseCholesky::permutation() const {
  static const std::vector<int> none;
  if (n_ == 0) return none;
  if (!impl_->sub) throw std::logic_error("permutation(): not a PerPose factor");
  return impl_->sub->perm;
}

void SparseCholesky::solve_permuted4(double* Y) const {
  if (n_ == 0) return;
  if (!impl_->sub) throw std::logic_error("solve_permuted4(): not a PerPose factor");
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->sub->run(Y);
}

int SparseCholesky::substitution_threads() const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->sub ? impl_->sub->sched.threads : 0;
}

}  // namespace matdeform
