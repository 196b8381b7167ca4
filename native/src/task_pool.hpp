// Private: low-latency work sharing for the per-pose path (blend, right-hand side, substitution).
//
// Why not OpenMP here: a deform() is a few milliseconds split into several parallel steps. With
// OpenMP's default wait policy idle threads spin for a long time after each region and steal the
// core from the host (Blender's own threads); with the passive policy every step pays a thread
// wake-up, which on the project's VM costs about a millisecond. This pool lets its workers spin
// only briefly between steps, and tasks are claimed dynamically, so a worker that is late (asleep
// or descheduled) just takes fewer tasks: a call is never slower than running serially.
#pragma once

#include <functional>

namespace matdeform {

// Runs task(0), ..., task(count - 1) on the calling thread plus up to num_threads() - 1 pool
// workers, and returns when all have finished. Tasks must be independent. Safe from any number
// of threads and from inside a task: the pool serves one caller at a time, and a call that finds
// it busy (another thread's, or its own caller's from inside a task) runs its tasks serially on
// the calling thread instead of waiting. If tasks throw, the first exception is rethrown here
// after every task has finished.
void run_tasks(int count, const std::function<void(int)>& task);

// Tells idle workers to sleep now instead of polling for more tasks: call it when a burst of
// run_tasks calls (one deform()) is over, so the workers leave the cores to the host at once.
void park_workers();

// Calls park_workers() when it goes out of scope.
struct ParkWorkersOnExit {
  ParkWorkersOnExit() = default;
  ParkWorkersOnExit(const ParkWorkersOnExit&) = delete;
  ParkWorkersOnExit& operator=(const ParkWorkersOnExit&) = delete;
  ~ParkWorkersOnExit() { park_workers(); }
};

// Splits [0, n) into at most `chunks` contiguous ranges of at least `min_size` items and runs
// body(begin, end) on each through run_tasks (serially when there is only one range).
void parallel_ranges(int n, int min_size, int chunks, const std::function<void(int, int)>& body);

}  // namespace matdeform
