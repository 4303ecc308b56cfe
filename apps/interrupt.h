#pragma once

// Ctrl-C (SIGINT), or a polite kill (SIGTERM: `kill`, `timeout`, a CI job
// cancelled; SIGHUP: the terminal closed) during a rollout: the commands stop
// at the next step and keep what they wrote valid, instead of dying half-way
// through a file.

#include <atomic>
#include <csignal>

namespace tetcosim::app {

inline std::atomic<bool> interrupted{false};

// SIGINT, SIGTERM and SIGHUP set `interrupted` from now on.
inline void CatchInterrupt() {
  for (int signal : {SIGINT, SIGTERM, SIGHUP}) std::signal(signal, [](int) { interrupted = true; });
}

}  // namespace tetcosim::app
