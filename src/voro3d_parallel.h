// One helper shared by the compiled kernels: a loop over work items on a few std::threads.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <system_error>
#include <thread>
#include <vector>

namespace voro3d {

// Runs body(worker, item) for every item in [0, items) on up to `threads` threads, the caller
// being worker 0; items are handed out in order from a shared counter, so a thread the machine
// runs less often simply takes fewer. body must not throw.
template <typename Body>
void parallel_for(int threads, std::int64_t items, const Body& body) {
  std::atomic<std::int64_t> next{0};
  auto work = [&](int worker) {
    for (std::int64_t item = next++; item < items; item = next++) body(worker, item);
  };
  std::vector<std::thread> helpers;
  for (int worker = 1; worker < std::min<std::int64_t>(threads, items); ++worker) {
    try {
      helpers.emplace_back(work, worker);
    } catch (const std::system_error&) {
      break;  // no more threads to be had: the started ones and the caller do the rest
    }
  }
  work(0);
  for (auto& helper : helpers) helper.join();
}

}  // namespace voro3d
