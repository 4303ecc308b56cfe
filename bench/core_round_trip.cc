// How long a cache line takes to go from one core to another and back: two
// threads, one on each of two cores, pass a counter to and fro through one
// shared atomic; each hand-over moves the line to the other core. This is
// what a parallel loop pays where one thread reads what another has just
// written (a team's start and join, a shared cursor, data made by the other
// core). On a machine whose cores are far apart, small solves do not gain
// from a second thread; scripts/bench-collision prints this beside its
// speed-ups so that they can be read against it.
//
//     build/bench/core_round_trip [cpu_a cpu_b]   (default 0 1; prints ns)
//
// Prints the fastest of 9 rounds of 100,000 round trips, in nanoseconds.
// The threads are pinned to the two CPUs where the system allows it (else
// the scheduler places them).

#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>

namespace {

using Clock = std::chrono::steady_clock;

constexpr long kRoundTrips = 100000;
constexpr int kRounds = 9;

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
  if (end == text || *end != '\0' || value < 0 || value >= CPU_SETSIZE) return false;
  cpu = static_cast<int>(value);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  int cpus[2] = {0, 1};
  if (argc != 1 && (argc != 3 || !ParseCpu(argv[1], cpus[0]) || !ParseCpu(argv[2], cpus[1]))) {
    std::fprintf(stderr, "usage: core_round_trip [cpu_a cpu_b]  (two CPU numbers, default 0 1)\n");
    return 2;
  }
  if (std::thread::hardware_concurrency() < 2) {
    std::fprintf(stderr, "error: this machine has one CPU: there is no other core to measure\n");
    return 1;
  }
  // (on its own line: the counter's line is the only one passed to and fro)
  alignas(64) std::atomic<long> counter{0};
  bool responder_pinned = false;
  // the responder waits for each odd value and answers with the next even
  std::thread responder([&] {
    responder_pinned = PinTo(cpus[1]);
    for (long i = 0; i < kRounds * kRoundTrips; ++i) {
      while (counter.load(std::memory_order_acquire) != 2 * i + 1) {
      }
      counter.store(2 * i + 2, std::memory_order_release);
    }
  });
  const bool pinned = PinTo(cpus[0]);
  double best = 1e300;
  long i = 0;
  for (int round = 0; round < kRounds; ++round) {
    const Clock::time_point start = Clock::now();
    for (long end = i + kRoundTrips; i < end; ++i) {
      counter.store(2 * i + 1, std::memory_order_release);
      while (counter.load(std::memory_order_acquire) != 2 * i + 2) {
      }
    }
    best = std::min(best, std::chrono::duration<double>(Clock::now() - start).count());
  }
  responder.join();
  if (!pinned || !responder_pinned) {
    std::fprintf(stderr, "note: could not pin the threads to CPUs %d and %d\n", cpus[0], cpus[1]);
  }
  std::printf("%.1f\n", best / kRoundTrips * 1e9);
  return 0;
}
