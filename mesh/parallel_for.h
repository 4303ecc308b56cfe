#pragma once

// for (i = begin; i < end; ++i) body(i) on num_threads OpenMP threads, or as
// a plain loop when num_threads <= 1. An OpenMP region still sets up and
// tears down a team when it runs on one thread, even under an if(false)
// clause (libgomp: an allocation and a futex call per region); in a scene
// of 120 small bodies, whose CG solve applies each body's matrix 75 times a
// step, that cost more than the products themselves. Header-only: the
// including library must compile with OpenMP (collision and deformable do).
// The iterations must be independent; with one thread they run in order.

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <span>

namespace tetcosim {

enum class Schedule { kStatic, kDynamic };

template <typename Body>
void ParallelFor(int num_threads, int begin, int end, const Body& body,
                 Schedule schedule = Schedule::kStatic, int chunk = 64) {
  if (num_threads <= 1) {
    for (int i = begin; i < end; ++i) body(i);
    return;
  }
  if (schedule == Schedule::kDynamic) {
#pragma omp parallel for num_threads(num_threads) schedule(dynamic, chunk)
    for (int i = begin; i < end; ++i) body(i);
  } else {
#pragma omp parallel for num_threads(num_threads) schedule(static)
    for (int i = begin; i < end; ++i) body(i);
  }
}

// body(i) for every i in [offsets[0], offsets[groups]), on num_threads
// OpenMP threads, where group g is [offsets[g], offsets[g + 1]): thread t
// first runs the items of group t mod groups, `chunk` at a time, then helps
// with the other groups' remaining items, next group first. For items
// whose data thread t of an earlier loop wrote (then it is in that core's
// cache, and reading it from the other core costs more than the item's
// work). Any item may still run on any thread: the iterations must be
// independent. With one thread, or more than kMaxGroups groups, it is
// ParallelFor (dynamic).
inline constexpr int kMaxGroups = 64;

template <typename Body>
void ParallelForGroups(int num_threads, std::span<const int> offsets, const Body& body, int chunk) {
  const int groups = static_cast<int>(offsets.size()) - 1;
  if (groups < 1) return;
  if (num_threads <= 1 || groups > kMaxGroups) {
    ParallelFor(num_threads, offsets[0], offsets[groups], body, Schedule::kDynamic, chunk);
    return;
  }
  struct alignas(64) Cursor {  // a line each: threads take items from all of them
    std::atomic<int> next;
  };
  Cursor cursors[kMaxGroups];
  for (int g = 0; g < groups; ++g) cursors[g].next.store(offsets[g], std::memory_order_relaxed);
#pragma omp parallel num_threads(num_threads)
  {
    const int first = omp_get_thread_num() % groups;
    for (int k = 0; k < groups; ++k) {
      const int g = (first + k) % groups;
      const int end = offsets[g + 1];
      for (;;) {
        const int begin = cursors[g].next.fetch_add(chunk, std::memory_order_relaxed);
        if (begin >= end) break;
        for (int i = begin; i < std::min(begin + chunk, end); ++i) body(i);
      }
    }
  }
}

}  // namespace tetcosim
