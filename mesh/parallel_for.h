#pragma once

// for (i = begin; i < end; ++i) body(i) on num_threads OpenMP threads, or as
// a plain loop when num_threads <= 1. An OpenMP region still sets up and
// tears down a team when it runs on one thread, even under an if(false)
// clause (libgomp: an allocation and a futex call per region); in a scene
// of 120 small bodies, whose CG solve applies each body's matrix 75 times a
// step, that cost more than the products themselves. Header-only: the
// including library must compile with OpenMP (collision and deformable do).
// The iterations must be independent; with one thread they run in order.

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

}  // namespace tetcosim
