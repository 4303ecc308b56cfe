#pragma once

// Ctrl-C (SIGINT), or a polite kill (SIGTERM: `kill`, `timeout`, a CI job
// cancelled; SIGHUP: the terminal closed) during a rollout: the commands stop
// at the next step and keep what they wrote valid, instead of dying half-way
// through a file.

#include <atomic>
#include <csignal>

namespace tetcosim::app {

inline std::atomic<bool> interrupted{false};

// SIGINT, SIGTERM and SIGHUP set `interrupted` from now on, except those the
// process was started ignoring (`nohup` ignores SIGHUP, a shell's
// background job SIGINT): they stay ignored.
inline void CatchInterrupt() {
  for (int signal : {SIGINT, SIGTERM, SIGHUP}) {
    if (std::signal(signal, [](int) { interrupted = true; }) == SIG_IGN) {
      std::signal(signal, SIG_IGN);
    }
  }
}

}  // namespace tetcosim::app
