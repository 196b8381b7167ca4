#include "task_pool.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "matdeform/threads.hpp"

// A hint that this thread is spinning: pause on x86 (GCC/Clang and MSVC spell the platform
// differently), yield on Arm; a real yield elsewhere.
#if defined(__x86_64__) || defined(__i386__) || defined(_M_X64) || defined(_M_IX86)
#include <immintrin.h>
#define MD_CPU_RELAX() _mm_pause()
#elif defined(__aarch64__) && (defined(__GNUC__) || defined(__clang__))
#define MD_CPU_RELAX() __asm__ __volatile__("yield")
#elif defined(_M_ARM64)
#include <intrin.h>
#define MD_CPU_RELAX() __yield()
#else
#define MD_CPU_RELAX() std::this_thread::yield()
#endif

namespace matdeform {

namespace {

// How long an idle worker keeps polling for the next task before it sleeps: long enough to
// bridge the serial gaps inside one deform(), short enough not to compete with the host after it.
constexpr auto kSpin = std::chrono::microseconds(500);

// True on pool workers, and on a caller while it runs a job: run_tasks() from there (a task
// that calls it again) runs serially instead of re-entering the pool.
thread_local bool t_in_pool = false;

class TaskPool {
 public:
  explicit TaskPool(int workers) {
    for (int w = 0; w < workers; ++w) {
      threads_.emplace_back([this] {
        t_in_pool = true;
        work();
      });
    }
  }
  ~TaskPool() {
    {
      std::lock_guard<std::mutex> lk(m_);
      stop_ = true;
      generation_.fetch_add(1, std::memory_order_release);
    }
    cv_.notify_all();
    for (auto& t : threads_) t.join();
  }
  int workers() const { return static_cast<int>(threads_.size()); }
  void park() { park_.fetch_add(1, std::memory_order_release); }

  void run(int count, const std::function<void(int)>& task) {
    {
      std::unique_lock<std::mutex> lk(m_);
      // A worker that woke up for the previous job may still be leaving it; it holds a copy of
      // that job's count, so the claim counter must not be reset under it.
      while (active_ > 0) {
        lk.unlock();
        MD_CPU_RELAX();
        lk.lock();
      }
      job_ = &task;
      count_ = count;
      next_.store(0, std::memory_order_relaxed);
      done_.store(0, std::memory_order_relaxed);
      generation_.fetch_add(1, std::memory_order_release);
    }
    if (sleepers_.load(std::memory_order_acquire) > 0) cv_.notify_all();
    claim(task, count);
    while (done_.load(std::memory_order_acquire) < count) MD_CPU_RELAX();
    if (error_) {  // every task has finished: nothing refers to the job any more
      std::exception_ptr e = std::move(error_);
      error_ = nullptr;
      std::rethrow_exception(e);
    }
  }

 private:
  void work() {
    uint64_t seen = 0;
    uint64_t parked = park_.load(std::memory_order_acquire);  // as of the last job taken
    for (;;) {
      // Poll for a new job for a short while (or until parked), then block until one is posted.
      const auto t0 = std::chrono::steady_clock::now();
      for (unsigned spin = 1; generation_.load(std::memory_order_acquire) == seen; ++spin) {
        MD_CPU_RELAX();
        if (park_.load(std::memory_order_relaxed) != parked ||
            (spin % 256 == 0 && std::chrono::steady_clock::now() - t0 > kSpin)) {
          std::unique_lock<std::mutex> lk(m_);
          sleepers_.fetch_add(1, std::memory_order_acq_rel);
          cv_.wait(lk, [&] { return generation_.load(std::memory_order_acquire) != seen; });
          sleepers_.fetch_sub(1, std::memory_order_acq_rel);
        }
      }
      const std::function<void(int)>* job;
      int count;
      {
        std::lock_guard<std::mutex> lk(m_);
        if (stop_) return;
        seen = generation_.load(std::memory_order_acquire);
        parked = park_.load(std::memory_order_acquire);
        ++active_;
        job = job_;
        count = count_;
      }
      claim(*job, count);
      std::lock_guard<std::mutex> lk(m_);
      --active_;
    }
  }

  // Runs tasks until none is left. A task's exception is kept (the first one) for run() to
  // rethrow on the calling thread; an exception escaping a worker would end the process.
  void claim(const std::function<void(int)>& task, int count) {
    for (int i; (i = next_.fetch_add(1, std::memory_order_relaxed)) < count;) {
      try {
        task(i);
      } catch (...) {
        std::lock_guard<std::mutex> lk(error_mutex_);
        if (!error_) error_ = std::current_exception();
      }
      done_.fetch_add(1, std::memory_order_release);
    }
  }

  std::vector<std::thread> threads_;
  std::mutex m_;
  std::condition_variable cv_;
  std::atomic<uint64_t> generation_{0}, park_{0};
  std::atomic<int> next_{0}, done_{0}, sleepers_{0};
  int active_ = 0;  // workers inside a job; guarded by m_
  int count_ = 0;
  const std::function<void(int)>* job_ = nullptr;
  bool stop_ = false;
  std::mutex error_mutex_;
  std::exception_ptr error_;  // first exception of the current job
};

// The one pool, and the lock its user holds. try_lock only: a second caller never waits for
// the workers (it could be a thread the first caller waits for), it runs serially instead.
std::mutex& pool_mutex() {
  static std::mutex m;
  return m;
}
std::unique_ptr<TaskPool>& the_pool() {  // guarded by pool_mutex()
  static std::unique_ptr<TaskPool> pool;
  return pool;
}

struct InPool {
  InPool() { t_in_pool = true; }
  ~InPool() { t_in_pool = false; }
  InPool(const InPool&) = delete;
  InPool& operator=(const InPool&) = delete;
};

}  // namespace

void run_tasks(int count, const std::function<void(int)>& task) {
  const int threads = num_threads();
  std::unique_lock<std::mutex> lk(pool_mutex(), std::defer_lock);
  if (threads < 2 || count < 2 || t_in_pool || !lk.try_lock()) {
    for (int i = 0; i < count; ++i) task(i);
    return;
  }
  std::unique_ptr<TaskPool>& pool = the_pool();
  if (!pool || pool->workers() != threads - 1) {
    pool.reset();  // joins the old workers first
    pool = std::make_unique<TaskPool>(threads - 1);
  }
  const InPool in_pool;
  pool->run(count, task);
}

void park_workers() {
  // Skipped while another thread holds the pool: its workers are busy, and it parks them itself
  // (or they fall asleep after their polling window).
  std::unique_lock<std::mutex> lk(pool_mutex(), std::try_to_lock);
  if (lk.owns_lock() && the_pool()) the_pool()->park();
}

void parallel_ranges(int n, int min_size, int chunks, const std::function<void(int, int)>& body) {
  const int parts = std::max(1, std::min(chunks, n / std::max(1, min_size)));
  if (parts == 1 || num_threads() < 2) {
    if (n > 0) body(0, n);
    return;
  }
  run_tasks(parts, [&](int p) {
    const int b = static_cast<int>(static_cast<int64_t>(n) * p / parts);
    const int e = static_cast<int>(static_cast<int64_t>(n) * (p + 1) / parts);
    body(b, e);
  });
}

}  // namespace matdeform
