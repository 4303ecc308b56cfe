// The core's clock rate while it runs, estimated from a chain of dependent
// integer adds: each add waits for the one before, and an add takes one
// cycle, so adds per nanosecond are cycles per nanosecond (GHz). This
// machine gives no hardware counters (`perf stat` reports cycles as not
// supported); scripts/count-instructions --per-cycle divides a solve's
// instructions by its time and this rate.
//
//     build/bench/clock_rate [seconds]   (default 0.1; prints GHz)

#include <chrono>
#include <cstdio>
#include <cstdlib>

namespace {

// one add of 1 to x that the compiler cannot merge with the next: the
// empty asm takes x in a register and may change it
inline void DependentAdd(long& x) {
  x += 1;
  asm volatile("" : "+r"(x));
}

}  // namespace

int main(int argc, char** argv) {
  using Clock = std::chrono::steady_clock;
  const double seconds = argc > 1 ? std::atof(argv[1]) : 0.1;
  if (!(seconds > 0.0 && seconds <= 60.0)) {
    std::fprintf(stderr, "error: seconds must be in (0, 60], got '%s'\n", argv[1]);
    return 2;
  }
  constexpr long kAddsPerRound = 1L << 20;  // (8 adds an iteration)
  long x = 0;
  long adds = 0;
  const Clock::time_point start = Clock::now();
  double elapsed = 0.0;
  do {
    for (long i = 0; i < kAddsPerRound / 8; ++i) {
      DependentAdd(x);
      DependentAdd(x);
      DependentAdd(x);
      DependentAdd(x);
      DependentAdd(x);
      DependentAdd(x);
      DependentAdd(x);
      DependentAdd(x);
    }
    adds += kAddsPerRound;
    elapsed = std::chrono::duration<double>(Clock::now() - start).count();
  } while (elapsed < seconds);
  if (x != adds) return 1;  // (reads x: the chain is not dead code)
  std::printf("%.4f\n", static_cast<double>(adds) / elapsed * 1e-9);
  return 0;
}
