// Waiting for a test thread that may hang: a hang must fail the test, not stall the suite.
#pragma once

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <future>

namespace matdeform::test_timeout {

// Returns f.get(); if f is not ready within `seconds`, reports and ends the process with exit
// code 1 (a hung thread cannot be joined, and std::async's future would wait for it forever).
template <class T>
T get_or_exit(std::future<T>& f, int seconds, const char* what) {
  if (f.wait_for(std::chrono::seconds(seconds)) != std::future_status::ready) {
    std::fprintf(stderr, "%s: no result after %d s (hung)\n", what, seconds);
    std::fflush(stderr);
    std::_Exit(1);
  }
  return f.get();
}

}  // namespace matdeform::test_timeout
