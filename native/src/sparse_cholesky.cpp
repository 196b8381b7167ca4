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

#ifdef _OPENMP
#include <omp.h>
#endif

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

// Supernodal substitution: the factor kept in CHOLMOD's supernodes, each a dense lower
// triangle over its k columns plus a dense block of its m rows below (row-major), so one row index
// serves k values and the inner loops run over contiguous memory. The forward pass scatters each
// supernode's block into the rows below it (ancestors); the backward pass gathers them back.
// Subtrees of the supernodal elimination tree run on different threads: a job's forward updates
// of rows outside its subtree (the serial top separators) go to per-job slots that are added in
// before the serial part, so no two threads write one row.
struct Substitution {
  int n = 0, ns = 0;
  std::vector<int> perm;
  std::vector<int> col;   // ns + 1: columns of supernode s are [col[s], col[s + 1])
  std::vector<int> rptr;  // ns + 1: rows below s are rows[rptr[s], rptr[s + 1]), ascending
  std::vector<int> rows;
  std::vector<size_t> vptr;  // values of s: strict lower triangle by rows, then the m x k block
  std::vector<double> vals, dinv;
  std::vector<int> parent, first, child_ptr, child;
  std::vector<double> own_work, tree_work;
  bool postordered = false;

  struct Schedule {
    int requested = 0;
    int threads = 0;
    std::vector<std::pair<int, int>> jobs;  // supernode ranges [b, e), heaviest first
    std::vector<int> serial;                // ascending
    std::vector<int> frows;                 // rows for the forward pass: ~slot outside a job
    std::vector<int> slot_row;
  };
  mutable Schedule sched;
  mutable std::vector<double> Y, S;

  explicit Substitution(const cholmod_factor* L) {
    if (!L->is_super || !L->is_ll) throw std::runtime_error("unexpected CHOLMOD factor type");
    n = static_cast<int>(L->n);
    ns = static_cast<int>(L->nsuper);
    const int* Ls = static_cast<const int*>(L->super);
    const int* Lpi = static_cast<const int*>(L->pi);
    const int* Lpx = static_cast<const int*>(L->px);
    const int* Li = static_cast<const int*>(L->s);
    const double* Lx = static_cast<const double*>(L->x);
    const int* P = static_cast<const int*>(L->Perm);
    perm.assign(P, P + n);
    col.assign(Ls, Ls + ns + 1);
    rptr.assign(ns + 1, 0);
    vptr.assign(ns + 1, 0);
    dinv.assign(n, 0.0);
    for (int s = 0; s < ns; ++s) {
      const int k = col[s + 1] - col[s];
      const int m = (Lpi[s + 1] - Lpi[s]) - k;
      rptr[s + 1] = rptr[s] + m;
      vptr[s + 1] = vptr[s] + static_cast<size_t>(k) * (k - 1) / 2 + static_cast<size_t>(m) * k;
    }
    rows.resize(static_cast<size_t>(rptr[ns]));
    vals.resize(vptr[ns]);
    std::vector<int> snode(n);
    for (int s = 0; s < ns; ++s)
      for (int j = col[s]; j < col[s + 1]; ++j) snode[j] = s;
    parent.assign(ns, -1);
    for (int s = 0; s < ns; ++s) {
      const int k = col[s + 1] - col[s];
      const int nr = Lpi[s + 1] - Lpi[s];
      const int m = nr - k;
      const double* x = Lx + Lpx[s];  // column-major nr x k
      double* v = vals.data() + vptr[s];
      for (int c = 0; c < k; ++c) {
        const double d = x[c + static_cast<size_t>(c) * nr];
        if (!(d > 0.0) || !std::isfinite(d)) throw std::invalid_argument(kIllConditioned);
        dinv[col[s] + c] = 1.0 / d;
        for (int q = 0; q < c; ++q) *v++ = x[c + static_cast<size_t>(q) * nr];
      }
      for (int i = 0; i < m; ++i) {
        rows[rptr[s] + i] = Li[Lpi[s] + k + i];
        for (int c = 0; c < k; ++c) *v++ = x[k + i + static_cast<size_t>(c) * nr];
      }
      if (m > 0) parent[s] = snode[rows[rptr[s]]];
    }

    own_work.resize(ns);
    tree_work.resize(ns);
    first.resize(ns);
    std::vector<int> size(ns, 1);
    child_ptr.assign(ns + 2, 0);
    for (int s = 0; s < ns; ++s) {
      own_work[s] = static_cast<double>(vptr[s + 1] - vptr[s]) + (col[s + 1] - col[s]);
      tree_work[s] = own_work[s];
      first[s] = s;
      ++child_ptr[(parent[s] < 0 ? ns : parent[s]) + 1];
    }
    for (int s = 0; s < ns; ++s) {
      if (parent[s] < 0) continue;
      tree_work[parent[s]] += tree_work[s];
      size[parent[s]] += size[s];
      first[parent[s]] = std::min(first[parent[s]], first[s]);
    }
    for (int p = 0; p <= ns; ++p) child_ptr[p + 1] += child_ptr[p];
    child.resize(ns);
    std::vector<int> cc(child_ptr.begin(), child_ptr.end() - 1);
    for (int s = 0; s < ns; ++s) child[cc[parent[s] < 0 ? ns : parent[s]]++] = s;
    postordered = true;
    for (int s = 0; s < ns; ++s) postordered = postordered && first[s] == s - size[s] + 1;
    Y.resize(static_cast<size_t>(kWidth) * n);
  }

  void make_schedule(int threads) const;
  void run(double* Yd) const;
  void solve(const double* B, double* X, int nrhs) const;
};

// How far ahead (in doubles, 4 KB) the block loops prefetch the factor's values: the passes
// stream the whole factor, which beyond ~10k unknowns no longer fits in cache, and the hardware
// prefetcher loses the stream at each supernode boundary (~10 % per iteration at 30k).
constexpr int kPrefetch = 512;
MD_ALWAYS_INLINE void sn_forward_body(const Substitution& f, const int* frows, Vec4d* Y, Vec4d* S,
                                      int b, int e) {
  const Vec4d zero = {0, 0, 0, 0};
  for (int s = b; s < e; ++s) {
    const int k1 = f.col[s], k = f.col[s + 1] - k1;
    const double* t = f.vals.data() + f.vptr[s];
    const double* dinv = f.dinv.data() + k1;
    Vec4d* y = Y + k1;
    for (int c = 0; c < k; ++c) {
      Vec4d a0 = y[c], a1 = zero;
      int q = 0;
      for (; q + 1 < c; q += 2) {
        a0 -= t[q] * y[q];
        a1 -= t[q + 1] * y[q + 1];
      }
      if (q < c) a0 -= t[q] * y[q];
      y[c] = (a0 + a1) * dinv[c];
      t += c;
    }
    const int* r = frows + f.rptr[s];
    const int m = f.rptr[s + 1] - f.rptr[s];
    auto sub = [&](int row, const Vec4d& a) {
      if (row >= 0) {
        Y[row] -= a;
      } else {
        S[~row] -= a;
      }
    };
    int i = 0;
    for (; i + 3 < m; i += 4, t += 4 * k) {
      const double *b0 = t, *b1 = t + k, *b2 = t + 2 * k, *b3 = t + 3 * k;
      for (int p = 0; p < 4 * k; p += 8) MD_PREFETCH(t + kPrefetch + p);
      Vec4d a0 = zero, a1 = zero, a2 = zero, a3 = zero;
      for (int c = 0; c < k; ++c) {
        const Vec4d yc = y[c];
        a0 += b0[c] * yc;
        a1 += b1[c] * yc;
        a2 += b2[c] * yc;
        a3 += b3[c] * yc;
      }
      sub(r[i], a0);
      sub(r[i + 1], a1);
      sub(r[i + 2], a2);
      sub(r[i + 3], a3);
    }
    for (; i < m; ++i, t += k) {
      Vec4d a0 = zero;
      for (int c = 0; c < k; ++c) a0 += t[c] * y[c];
      sub(r[i], a0);
    }
  }
}

MD_ALWAYS_INLINE void sn_backward_body(const Substitution& f, Vec4d* Y, int b, int e) {
  for (int s = e - 1; s >= b; --s) {
    const int k1 = f.col[s], k = f.col[s + 1] - k1;
    const double* tri = f.vals.data() + f.vptr[s];
    const double* t = tri + static_cast<size_t>(k) * (k - 1) / 2;
    const double* dinv = f.dinv.data() + k1;
    Vec4d* y = Y + k1;
    const int* r = f.rows.data() + f.rptr[s];
    const int m = f.rptr[s + 1] - f.rptr[s];
    int i = 0;
    for (; i + 3 < m; i += 4, t += 4 * k) {
      const Vec4d x0 = Y[r[i]], x1 = Y[r[i + 1]], x2 = Y[r[i + 2]], x3 = Y[r[i + 3]];
      const double *b0 = t, *b1 = t + k, *b2 = t + 2 * k, *b3 = t + 3 * k;
      for (int p = 0; p < 4 * k; p += 8) MD_PREFETCH(t + kPrefetch + p);
      for (int c = 0; c < k; ++c) {
        y[c] -= (b0[c] * x0 + b1[c] * x1) + (b2[c] * x2 + b3[c] * x3);
      }
    }
    for (; i < m; ++i, t += k) {
      const Vec4d x0 = Y[r[i]];
      for (int c = 0; c < k; ++c) y[c] -= t[c] * x0;
    }
    for (int c = k - 1; c >= 0; --c) {
      const Vec4d x = y[c] * dinv[c];
      y[c] = x;
      const double* tc = tri + static_cast<size_t>(c) * (c - 1) / 2;
      for (int q = 0; q < c; ++q) y[q] -= tc[q] * x;
    }
  }
}

void sn_forward_base(const Substitution& f, const int* fr, Vec4d* Y, Vec4d* S, int b, int e) {
  sn_forward_body(f, fr, Y, S, b, e);
}
MD_TARGET_AVX2 void sn_forward_avx2(const Substitution& f, const int* fr, Vec4d* Y, Vec4d* S, int b,
                                    int e) {
  sn_forward_body(f, fr, Y, S, b, e);
}
void sn_backward_base(const Substitution& f, Vec4d* Y, int b, int e) {
  sn_backward_body(f, Y, b, e);
}
MD_TARGET_AVX2 void sn_backward_avx2(const Substitution& f, Vec4d* Y, int b, int e) {
  sn_backward_body(f, Y, b, e);
}
void sn_forward(const Substitution& f, const int* fr, double* Y, double* S, int b, int e) {
  Vec4d* y = reinterpret_cast<Vec4d*>(Y);
  Vec4d* sl = reinterpret_cast<Vec4d*>(S);
  if (cpu_has_avx2_fma()) {
    sn_forward_avx2(f, fr, y, sl, b, e);
  } else {
    sn_forward_base(f, fr, y, sl, b, e);
  }
}
void sn_backward(const Substitution& f, double* Y, int b, int e) {
  Vec4d* y = reinterpret_cast<Vec4d*>(Y);
  if (cpu_has_avx2_fma()) {
    sn_backward_avx2(f, y, b, e);
  } else {
    sn_backward_base(f, y, b, e);
  }
}

// Greedy: keep moving the root of the heaviest subtree to the serial part while that does not
// raise the estimated time (serial + max(parallel / threads, heaviest subtree)). Then keep
// splitting a little further, for at most 3 % more serial work, until there are several subtrees
// per thread: they are claimed dynamically, so when a worker is descheduled (this project's VMs
// lose 10 % of their CPU time to other guests) the others take over all but the subtree it holds.
void Substitution::make_schedule(int threads) const {
  sched = Schedule();
  sched.requested = threads;
  sched.threads = 1;
  sched.frows = rows;
  double total = 0.0;
  for (double w : own_work) total += w;
  // Below this many entries (~15k-face meshes) waking a parked worker costs more than it saves.
  constexpr double kMinParallelWork = 400000.0;
  if (threads < 2 || !postordered || total < kMinParallelWork) return;
  using Item = std::pair<double, int>;
  std::priority_queue<Item> heap;
  for (int q = child_ptr[ns]; q < child_ptr[ns + 1]; ++q)
    heap.emplace(tree_work[child[q]], child[q]);
  double serial_work = 0.0, parallel_work = total;
  auto estimate = [&](double s, double p, double heaviest) {
    return s + std::max(p / threads, heaviest);
  };
  const size_t wanted_jobs = static_cast<size_t>(4 * threads);
  double extra_budget = -1.0;
  std::vector<int> serial;
  while (!heap.empty()) {
    const Item top = heap.top();
    heap.pop();
    const int r = top.second;
    double heaviest = heap.empty() ? 0.0 : heap.top().first;
    for (int q = child_ptr[r]; q < child_ptr[r + 1]; ++q)
      heaviest = std::max(heaviest, tree_work[child[q]]);
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
    serial.push_back(r);
    serial_work += own_work[r];
    parallel_work -= own_work[r];
    for (int q = child_ptr[r]; q < child_ptr[r + 1]; ++q)
      heap.emplace(tree_work[child[q]], child[q]);
  }
  if (estimate(serial_work, parallel_work, heap.empty() ? 0.0 : heap.top().first) > 0.8 * total)
    return;
  sched.threads = threads;
  sched.serial = serial;
  std::sort(sched.serial.begin(), sched.serial.end());
  while (!heap.empty()) {
    const int r = heap.top().second;
    heap.pop();
    sched.jobs.emplace_back(first[r], r + 1);
  }
  // Forward rows outside a job's subtree (rows >= its last column) go to that job's slots.
  std::vector<int> slot_of(n, -1);
  for (const auto& job : sched.jobs) {
    const int end_col = col[job.second];
    std::vector<int> used;
    for (int s = job.first; s < job.second; ++s) {
      for (int q = rptr[s]; q < rptr[s + 1]; ++q) {
        const int row = rows[q];
        if (row < end_col) continue;
        if (slot_of[row] < 0) {
          slot_of[row] = static_cast<int>(sched.slot_row.size());
          sched.slot_row.push_back(row);
          used.push_back(row);
        }
        sched.frows[q] = ~slot_of[row];
      }
    }
    for (int row : used) slot_of[row] = -1;
  }
  S.assign(kWidth * sched.slot_row.size(), 0.0);
}

void Substitution::run(double* Yd) const {
  const int threads = num_threads();
  if (sched.requested != threads) make_schedule(threads);
  if (sched.threads <= 1) {
    sn_forward(*this, sched.frows.data(), Yd, nullptr, 0, ns);
    sn_backward(*this, Yd, 0, ns);
    return;
  }
  std::fill(S.begin(), S.end(), 0.0);
  const int jobs = static_cast<int>(sched.jobs.size());
  run_tasks(jobs, [&](int t) {
    const auto& r = sched.jobs[t];
    sn_forward(*this, sched.frows.data(), Yd, S.data(), r.first, r.second);
  });
  Vec4d* y = reinterpret_cast<Vec4d*>(Yd);
  const Vec4d* sl = reinterpret_cast<const Vec4d*>(S.data());
  for (size_t q = 0; q < sched.slot_row.size(); ++q) y[sched.slot_row[q]] += sl[q];
  for (int s : sched.serial) sn_forward(*this, sched.frows.data(), Yd, S.data(), s, s + 1);
  for (auto it = sched.serial.rbegin(); it != sched.serial.rend(); ++it)
    sn_backward(*this, Yd, *it, *it + 1);
  run_tasks(jobs, [&](int t) {
    const auto& r = sched.jobs[t];
    sn_backward(*this, Yd, r.first, r.second);
  });
}

void Substitution::solve(const double* B, double* X, int nrhs) const {
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
      for (int c = 0; c < w; ++c)
        X[static_cast<size_t>(c0 + c) * n + dst] = Y[static_cast<size_t>(kWidth) * i + c];
    }
  }
}

// One factorisation at a time in the process. The supernodal factorisation calls BLAS, and
// the serial OpenBLAS that Debian ships (libopenblas0-serial) is not safe for concurrent
// calls: two deformers built on two threads at once got wrong factors (weights off by 0.6)
// or "not positive definite". Factorisations are the expensive, once-per-bind part, so running
// them one after another costs little; solves never take this lock.
std::mutex& factor_mutex() {
  static std::mutex m;
  return m;
}

// CHOLMOD's supernodal factorisation runs a few OpenMP loops per supernode (clearing and
// scattering into it), with a fixed team of 4 threads in SuiteSparse 5. Each loop is a few
// hundred entries of copying behind a team wake-up and barrier; with 4 threads on 2 cores
// those barriers cost more than the factorisation's flops (a 7.5k-unknown pyramid Hessian:
// 115 ms instead of 20). Held while a factorisation runs: OpenMP regions on this thread run
// with one thread (BLAS does the real work, serially, either way).
class SerialOpenMP {
 public:
#ifdef _OPENMP
  SerialOpenMP() : saved_(omp_get_max_active_levels()) { omp_set_max_active_levels(0); }
  ~SerialOpenMP() { omp_set_max_active_levels(saved_); }
#else
  // Without OpenMP there is nothing to serialise (user-provided, so that a guard variable
  // does not read as unused).
  SerialOpenMP() {}
  ~SerialOpenMP() {}
#endif
  SerialOpenMP(const SerialOpenMP&) = delete;
  SerialOpenMP& operator=(const SerialOpenMP&) = delete;

#ifdef _OPENMP
 private:
  int saved_;
#endif
};

}  // namespace

struct SparseCholesky::Impl {
  std::mutex mutex;  // guards every mutable member (and sub's) during a solve
  cholmod_common c;
  cholmod_factor* L = nullptr;
  mutable cholmod_dense* X = nullptr;
  mutable cholmod_dense* Y = nullptr;
  mutable cholmod_dense* E = nullptr;
  cholmod_sparse* A = nullptr;  // Refactor: the pattern, values overwritten per refactor()
  bool factored = false;        // Refactor: the last refactor() succeeded
  std::unique_ptr<Substitution> sub;

  explicit Impl(Reuse reuse) {
    cholmod_start(&c);
    c.print = 0;  // errors become exceptions, not stderr noise
    c.error_handler = nullptr;
    // On mesh Laplacians nested dissection (METIS) gives ~5-15% less fill than AMD but takes
    // ~5x longer to compute (about 1 s at 100k unknowns). Worth it only when the factor is
    // reused for many solves; then try both and keep the sparser one. Nested dissection also
    // gives the elimination tree the balanced subtrees the parallel substitution needs.
    c.nmethods = reuse == Reuse::Once ? 1 : 2;
    c.method[0].ordering = CHOLMOD_AMD;
    c.method[1].ordering = CHOLMOD_METIS;
    c.postorder = 1;
    c.final_ll = 1;  // small systems are factored simplicial LDL' otherwise; keep one layout
    // PerPose factors are always kept supernodal: their substitution runs on the dense blocks.
    // CHOLMOD's default amalgamation (about 9 % explicit zeros on the edge-based system at 30k
    // unknowns) measured as fast as tighter settings, which give more, smaller supernodes.
    if (reuse == Reuse::PerPose) c.supernodal = CHOLMOD_SUPERNODAL;
  }
  ~Impl() {
    if (X) cholmod_free_dense(&X, &c);
    if (Y) cholmod_free_dense(&Y, &c);
    if (E) cholmod_free_dense(&E, &c);
    if (A) cholmod_free_sparse(&A, &c);
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
  nnz_ = A.nonZeros();
  if (reuse != Reuse::Refactor) {
    for (Eigen::Index i = 0; i < A.nonZeros(); ++i) {
      if (!std::isfinite(A.valuePtr()[i])) throw std::invalid_argument(kIllConditioned);
    }
  }
  cholmod_common* c = &impl_->c;
  cholmod_sparse* As =
      cholmod_allocate_sparse(static_cast<size_t>(n_), static_cast<size_t>(n_),
                              static_cast<size_t>(A.nonZeros()), 1, 1, -1, CHOLMOD_REAL, c);
  if (!As) throw std::runtime_error("CHOLMOD could not allocate the matrix");
  std::memcpy(As->p, A.outerIndexPtr(), sizeof(int) * static_cast<size_t>(n_ + 1));
  std::memcpy(As->i, A.innerIndexPtr(), sizeof(int) * static_cast<size_t>(A.nonZeros()));
  std::memcpy(As->x, A.valuePtr(), sizeof(double) * static_cast<size_t>(A.nonZeros()));
  if (reuse == Reuse::Refactor) {
    {
      const std::lock_guard<std::mutex> lock(factor_mutex());
      const SerialOpenMP serial;
      impl_->L = cholmod_analyze(As, c);
    }
    impl_->A = As;
    if (!impl_->L) {
      throw std::runtime_error("sparse Cholesky analysis failed (CHOLMOD status " +
                               std::to_string(c->status) + ")");
    }
    return;
  }
  int status;
  {
    const std::lock_guard<std::mutex> lock(factor_mutex());
    const SerialOpenMP serial;
    impl_->L = cholmod_analyze(As, c);
    if (impl_->L) cholmod_factorize(As, impl_->L, c);
    status = c->status;
    // Supernodal factorisation is fastest to compute, but for a handful of right-hand sides
    // CHOLMOD's simplicial solve beats its supernodal one (a BLAS call per supernode), so Once
    // factors are converted here; PerPose ones keep the supernodes for Substitution.
    if (impl_->L && status >= CHOLMOD_OK && status != CHOLMOD_NOT_POSDEF && impl_->L->is_super &&
        reuse == Reuse::Once) {
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

bool SparseCholesky::refactor(const double* values) {
  if (!impl_->A) throw std::logic_error("refactor(): not a Refactor factor");
  if (n_ == 0) return true;
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->factored = false;
  for (long long i = 0; i < nnz_; ++i) {
    if (!std::isfinite(values[i])) return false;
  }
  std::memcpy(impl_->A->x, values, sizeof(double) * static_cast<size_t>(nnz_));
  cholmod_common* c = &impl_->c;
  int status;
  {
    const std::lock_guard<std::mutex> flock(factor_mutex());
    const SerialOpenMP serial;
    cholmod_factorize(impl_->A, impl_->L, c);
    status = c->status;
  }
  if (status == CHOLMOD_NOT_POSDEF) return false;
  if (status < CHOLMOD_OK) {
    throw std::runtime_error("sparse Cholesky factorisation failed (CHOLMOD status " +
                             std::to_string(status) + ")");
  }
  impl_->factored = true;
  g_factorizations.fetch_add(1, std::memory_order_relaxed);
  return true;
}

SparseCholesky::~SparseCholesky() = default;

void SparseCholesky::solve(const double* B, double* X, int nrhs) const {
  if (n_ == 0 || nrhs == 0) return;
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  if (impl_->A && !impl_->factored) throw std::logic_error("solve(): no successful refactor()");
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
