// The per-pose work-sharing pool: every task runs exactly once, for any thread count, also when
// calls follow each other faster than the workers wake up.
#include <gtest/gtest.h>

#include <atomic>
#include <numeric>
#include <thread>
#include <vector>

#include "matdeform/threads.hpp"
#include "task_pool.hpp"

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

}  // namespace
