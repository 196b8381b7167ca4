// The per-pose work-sharing pool: every task runs exactly once, for any thread count, also when
// calls follow each other faster than the workers wake up.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <numeric>
#include <stdexcept>
#include <thread>
#include <vector>

#include "matdeform/threads.hpp"
#include "task_pool.hpp"
#include "test_timeout.hpp"

namespace {

TEST(TaskPool, EveryTaskRunsExactlyOnce) {
  const int before = matdeform::num_threads();
  for (int threads : {1, 2, 3}) {
    matdeform::set_num_threads(threads);
    for (int count : {0, 1, 2, 7, 64}) {
      for (int rep = 0; rep < 200; ++rep) {
        std::vector<std::atomic<int>> hits(static_cast<size_t>(count));
        matdeform::run_tasks(count, [&](int i) { hits[static_cast<size_t>(i)].fetch_add(1); });
        for (int i = 0; i < count; ++i) ASSERT_EQ(hits[static_cast<size_t>(i)].load(), 1);
      }
    }
  }
  matdeform::set_num_threads(before);
}

TEST(TaskPool, WorkersSleepAndWakeUp) {
  const int before = matdeform::num_threads();
  matdeform::set_num_threads(2);
  std::atomic<long> sum{0};
  for (int rep = 0; rep < 3; ++rep) {
    // Longer than the workers' polling window, so the next call must wake them.
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
    matdeform::run_tasks(16, [&](int i) { sum.fetch_add(i); });
  }
  EXPECT_EQ(sum.load(), 3 * 120);
  matdeform::set_num_threads(before);
}

TEST(TaskPool, ParkedWorkersWakeForTheNextCall) {
  const int before = matdeform::num_threads();
  matdeform::set_num_threads(2);
  for (int rep = 0; rep < 500; ++rep) {
    std::atomic<int> ran{0};
    matdeform::run_tasks(4, [&](int) { ran.fetch_add(1); });
    matdeform::park_workers();
    ASSERT_EQ(ran.load(), 4);
  }
  matdeform::set_num_threads(before);
}

TEST(TaskPool, RangesCoverEachIndexOnce) {
  const int before = matdeform::num_threads();
  matdeform::set_num_threads(2);
  for (int n : {0, 1, 100, 10007}) {
    std::vector<int> seen(static_cast<size_t>(n), 0);
    matdeform::parallel_ranges(n, 64, 8, [&](int b, int e) {
      for (int i = b; i < e; ++i) ++seen[static_cast<size_t>(i)];
    });
    EXPECT_EQ(std::accumulate(seen.begin(), seen.end(), 0), n);
    for (int v : seen) ASSERT_EQ(v, 1);
  }
  matdeform::set_num_threads(before);
}

TEST(TaskPool, ConcurrentCallersEachRunEveryTaskOnce) {
  // Issue 11: two threads sharing the pool hung or ran each other's tasks. Now the second caller
  // runs serially while the first holds the pool.
  const int before = matdeform::num_threads();
  matdeform::set_num_threads(2);
  std::atomic<int> ready{0};
  auto caller = [&](int seed) {
    ready.fetch_add(1);
    while (ready.load() < 3) std::this_thread::yield();  // start together
    for (int rep = 0; rep < 300; ++rep) {
      const int count = 2 + (seed + rep) % 13;
      std::vector<std::atomic<int>> hits(static_cast<size_t>(count));
      matdeform::run_tasks(count, [&](int i) {
        const auto until = std::chrono::steady_clock::now() + std::chrono::microseconds(20);
        while (std::chrono::steady_clock::now() < until) {
        }
        hits[static_cast<size_t>(i)].fetch_add(1);
      });
      for (int i = 0; i < count; ++i) {
        if (hits[static_cast<size_t>(i)].load() != 1) return false;
      }
    }
    return true;
  };
  std::vector<std::future<bool>> runs;
  for (int t = 0; t < 3; ++t) runs.push_back(std::async(std::launch::async, caller, t));
  for (auto& r : runs) {
    EXPECT_TRUE(matdeform::test_timeout::get_or_exit(r, 60, "concurrent callers"));
  }
  matdeform::set_num_threads(before);
}

TEST(TaskPool, CallFromInsideATaskRunsSerially) {
  const int before = matdeform::num_threads();
  matdeform::set_num_threads(2);
  auto nested = [] {
    std::atomic<int> inner{0};
    matdeform::run_tasks(4, [&](int) {
      matdeform::run_tasks(5, [&](int) { inner.fetch_add(1); });
      matdeform::parallel_ranges(100, 1, 4, [&](int b, int e) { inner.fetch_add(e - b); });
    });
    return inner.load();
  };
  auto run = std::async(std::launch::async, nested);
  EXPECT_EQ(matdeform::test_timeout::get_or_exit(run, 60, "nested call"), 4 * (5 + 100));
  matdeform::set_num_threads(before);
}

TEST(TaskPool, TaskExceptionReachesTheCaller) {
  const int before = matdeform::num_threads();
  matdeform::set_num_threads(2);
  for (int rep = 0; rep < 100; ++rep) {
    std::atomic<int> ran{0};
    EXPECT_THROW(matdeform::run_tasks(8,
                                      [&](int i) {
                                        ran.fetch_add(1);
                                        if (i == 5) throw std::invalid_argument("task 5");
                                      }),
                 std::invalid_argument);
    EXPECT_EQ(ran.load(), 8);  // the others still ran; nothing refers to the job afterwards
  }
  std::atomic<int> ran{0};
  matdeform::run_tasks(8, [&](int) { ran.fetch_add(1); });  // the pool still works
  EXPECT_EQ(ran.load(), 8);
  matdeform::set_num_threads(before);
}

TEST(Threads, CountIsProcessWide) {
  // Issue 11: set_num_threads(1) did not reach threads started later (OpenMP's per-thread ICV).
  const int before = matdeform::num_threads();
  for (int n : {1, 3}) {
    matdeform::set_num_threads(n);
    int seen = 0;
    std::thread([&] { seen = matdeform::num_threads(); }).join();
    EXPECT_EQ(seen, n);
  }
  EXPECT_THROW(matdeform::set_num_threads(0), std::invalid_argument);
  matdeform::set_num_threads(before);
}

}  // namespace
