// What a second thread can add on this machine, in three numbers:
//
// - round trip (ns): how long a cache line takes to go from one core to
//   the other and back. Two threads, one on each core, pass a counter to
//   and fro through one shared atomic; each hand-over moves the line. A
//   parallel loop pays this where one thread reads what another has just
//   written (a team's start and join, a shared cursor, positions the
//   caller wrote on its own core).
// - capacity: how much faster two threads do twice the work than the
//   faster core alone does it once (2 x that core's time / the time of
//   both at once), on work that shares nothing (chains of integer
//   operations in registers): 2.00 on two free cores. Less means a core
//   is shared with other work (this VM's cores are), and a loop split
//   evenly over both threads cannot gain more from the second.
// - fork and join (us): what an empty OpenMP parallel region of two
//   threads costs, start to end: what every ParallelFor of the solver pays
//   before any work is split (a few round trips of the team's lines). The
//   two-cube solves use two such regions; at 3 to 4.5 us each (seen on
//   2026-12-03, round trip 415 to 490 ns) they are a tenth of the 10%
//   cubes' two-thread solve.
//
//     build/bench/two_cores [cpu_a cpu_b]   (default 0 1)
//
// prints "round_trip_ns capacity fork_join_us": the fastest of 9 rounds of
// 100,000 round trips, the fastest of 5 timings each of each core alone and
// both, and the fastest of 9 rounds of 10,000 regions. The round trip's and
// the work's threads are pinned to the two CPUs where the system allows it
// (else the scheduler places them); the OpenMP team is placed as the
// solver's is, by the runtime. scripts/bench-collision prints all three
// beside its speed-ups on two threads, which cannot be read without them: on
// the development machine the first two moved within an hour between 69 and
// 560 ns and between 2.00 and 1.03.

#include <omp.h>
#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <thread>

namespace {

using Clock = std::chrono::steady_clock;

constexpr long kRoundTrips = 100000;
constexpr int kRounds = 9;
constexpr long kWorkIterations = 20'000'000;  // about 15 ms on one core
constexpr int kWorkRounds = 5;
constexpr int kRegions = 10000;
constexpr int kRegionRounds = 9;

// Pins the calling thread to one CPU; false if the system refuses.
bool PinTo(int cpu) {
  cpu_set_t set;
  CPU_ZERO(&set);
  CPU_SET(cpu, &set);
  return pthread_setaffinity_np(pthread_self(), sizeof(set), &set) == 0;
}

// Whether text is a CPU number, written to cpu.
bool ParseCpu(const char* text, int& cpu) {
  char* end = nullptr;
  const long value = std::strtol(text, &end, 10);
  const bool valid = end != text && *end == '\0' && value >= 0 && value < CPU_SETSIZE;
  if (valid) cpu = static_cast<int>(value);
  return valid;
}

// Waits until counter holds value. Spins (a wait is a few hundred ns), but
// yields now and then: were both threads on one CPU, each hand-over would
// otherwise wait for the scheduler's time slice, and the rounds take hours.
void WaitFor(const std::atomic<long>& counter, long value) {
  for (long spins = 1; counter.load(std::memory_order_acquire) != value; ++spins) {
    if (spins % (1 << 16) == 0) std::this_thread::yield();
  }
}

// Fastest round trip of the counter's cache line between the two CPUs, in
// seconds; pinned tells whether both threads could be pinned.
double RoundTrip(const int cpus[2], bool& pinned) {
  // (on its own line: the counter's line is the only one passed to and fro)
  alignas(64) std::atomic<long> counter{0};
  bool responder_pinned = false;
  // the responder waits for each odd value and answers with the next even
  std::thread responder([&] {
    responder_pinned = PinTo(cpus[1]);
    for (long i = 0; i < kRounds * kRoundTrips; ++i) {
      WaitFor(counter, 2 * i + 1);
      counter.store(2 * i + 2, std::memory_order_release);
    }
  });
  pinned = PinTo(cpus[0]);
  double best = 1e300;
  long i = 0;
  for (int round = 0; round < kRounds; ++round) {
    const Clock::time_point start = Clock::now();
    for (long end = i + kRoundTrips; i < end; ++i) {
      counter.store(2 * i + 1, std::memory_order_release);
      WaitFor(counter, 2 * i + 2);
    }
    best = std::min(best, std::chrono::duration<double>(Clock::now() - start).count());
  }
  responder.join();
  pinned = pinned && responder_pinned;
  return best / kRoundTrips;
}

// Work that shares nothing: six chains of integer operations, in
// registers. Returns a value that depends on all of it.
std::uint64_t Work() {
  std::uint64_t a = 1, b = 2, c = 3, d = 4, e = 5, f = 6;
  for (long i = 0; i < kWorkIterations; ++i) {
    a = a * 3 + 1;
    b ^= b >> 3;
    c += a ^ b;
    d = d * 5 + c;
    e ^= d << 1;
    f += e;
  }
  return a + b + c + d + e + f;
}

// Fastest time of Work() alone on each of the two CPUs, and of Work() on
// both at once, in seconds.
void TimeWork(const int cpus[2], double alone[2], double& both) {
  std::atomic<std::uint64_t> sink{0};
  alone[0] = alone[1] = both = 1e300;
  auto time = [](auto&& run) {
    const Clock::time_point start = Clock::now();
    run();
    return std::chrono::duration<double>(Clock::now() - start).count();
  };
  for (int round = 0; round < kWorkRounds; ++round) {
    for (int k = 0; k < 2; ++k) {
      PinTo(cpus[k]);
      alone[k] = std::min(alone[k], time([&] { sink += Work(); }));
    }
    PinTo(cpus[0]);
    both = std::min(both, time([&] {
                      std::thread other([&] {
                        PinTo(cpus[1]);
                        sink += Work();
                      });
                      sink += Work();
                      other.join();
                    }));
  }
  if (sink.load() == 0) std::fprintf(stderr, "(never: the work's value is not 0)\n");
}

// Fastest time of one empty parallel region of two OpenMP threads, in
// seconds (over rounds of kRegions, after one region that starts the team).
double ForkJoin() {
  std::atomic<int> sink{0};
  auto region = [&] {
#pragma omp parallel num_threads(2)
    sink.fetch_add(omp_get_thread_num(), std::memory_order_relaxed);
  };
  region();
  double best = 1e300;
  for (int round = 0; round < kRegionRounds; ++round) {
    const Clock::time_point start = Clock::now();
    for (int i = 0; i < kRegions; ++i) region();
    best = std::min(best, std::chrono::duration<double>(Clock::now() - start).count());
  }
  if (sink.load() == 0) {
    std::fprintf(stderr,
                 "note: the OpenMP team had one thread: the region's cost is one thread's\n");
  }
  return best / kRegions;
}

}  // namespace

int main(int argc, char** argv) {
  int cpus[2] = {0, 1};
  if (argc != 1 && (argc != 3 || !ParseCpu(argv[1], cpus[0]) || !ParseCpu(argv[2], cpus[1]) ||
                    cpus[0] == cpus[1])) {
    std::fprintf(stderr, "usage: two_cores [cpu_a cpu_b]  (two different CPUs, default 0 1)\n");
    return 2;
  }
  cpu_set_t allowed;
  if (sched_getaffinity(0, sizeof(allowed), &allowed) != 0 || CPU_COUNT(&allowed) < 2) {
    std::fprintf(stderr,
                 "error: this process may run on one CPU only: there is no second core "
                 "to measure\n");
    return 1;
  }
  for (const int cpu : cpus) {
    if (!CPU_ISSET(cpu, &allowed)) {
      std::fprintf(stderr,
                   "error: CPU %d is not one this process may run on (see `taskset -p $$`); "
                   "give two that are\n",
                   cpu);
      return 2;
    }
  }
  bool pinned = false;
  const double round_trip = RoundTrip(cpus, pinned);
  double alone[2], both = 0.0;
  TimeWork(cpus, alone, both);
  // (unpinned again: the OpenMP team's threads are placed by the system,
  // as the solver's are)
  sched_setaffinity(0, sizeof(allowed), &allowed);
  const double fork_join = ForkJoin();
  if (!pinned) {
    std::fprintf(stderr, "note: could not pin the threads to CPUs %d and %d\n", cpus[0], cpus[1]);
  }
  std::printf("%.1f %.2f %.2f\n", round_trip * 1e9, 2.0 * std::min(alone[0], alone[1]) / both,
              fork_join * 1e6);
  return 0;
}
