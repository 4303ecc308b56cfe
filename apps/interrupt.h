#pragma once

// Ctrl-C during a rollout: the commands stop at the next step and keep what
// they wrote valid, instead of dying half-way through a file.

#include <atomic>
#include <csignal>

namespace tetcosim::app {

inline std::atomic<bool> interrupted{false};

// SIGINT sets `interrupted` from now on.
inline void CatchInterrupt() {
  std::signal(SIGINT, [](int) { interrupted = true; });
}

}  // namespace tetcosim::app
